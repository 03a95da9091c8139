"""CompressedImage conversion (vehicle_common.image_conversion): PNG is lossless, JPEG follows its
quality, image_transport's format strings, and corrupt or foreign data give one clear error."""

from __future__ import annotations

import numpy as np
import pytest
from vehicle_common.image_conversion import (
    ImageConversionError,
    image_size,
    image_to_rgb,
    numpy_to_compressed,
    numpy_to_image,
)


def _scene(h: int = 60, w: int = 90) -> np.ndarray:
    """A smooth colour image with some texture (what JPEG is made for)."""
    v, u = np.mgrid[0:h, 0:w]
    rng = np.random.default_rng(0)
    img = np.stack([u * 2.5, v * 3.5, (u + v) * 1.5], axis=-1) + rng.normal(0, 4, (h, w, 3))
    return np.clip(img, 0, 255).astype(np.uint8)


def test_png_is_lossless_and_keeps_colour_order():
    rgb = _scene()
    msg = numpy_to_compressed(rgb, "png")
    assert msg.format == "rgb8; png compressed bgr8"
    np.testing.assert_array_equal(image_to_rgb(msg), rgb)
    assert image_size(msg) == (90, 60) == image_size(numpy_to_image(rgb, "rgb8"))
    mono = rgb[:, :, 1].copy()
    m = numpy_to_compressed(mono, "png")
    assert m.format == "mono8; png compressed mono8"
    np.testing.assert_array_equal(image_to_rgb(m), np.repeat(mono[:, :, None], 3, axis=2))


def test_jpeg_quality_trades_size_for_error():
    rgb = _scene()
    q90, q75 = (numpy_to_compressed(rgb, "jpeg", q) for q in (90, 75))
    assert q90.format == "rgb8; jpeg compressed bgr8"
    assert len(q75.data) < len(q90.data) < len(numpy_to_compressed(rgb, "png").data)
    err90, err75 = (np.abs(image_to_rgb(m).astype(int) - rgb).mean() for m in (q90, q75))
    assert err90 < err75 < 6.0  # close, colour channels in the right order
    assert err90 > 0.0  # lossy


def test_header_is_kept():
    from std_msgs.msg import Header

    h = Header(frame_id="left_camera_optical_frame")
    h.stamp.sec = 7
    msg = numpy_to_compressed(_scene(), "jpeg", 80, h)
    assert msg.header.frame_id == "left_camera_optical_frame" and msg.header.stamp.sec == 7


def test_bad_input_gives_one_clear_error():
    with pytest.raises(ImageConversionError, match="'webp' is not png or jpeg"):
        numpy_to_compressed(_scene(), "webp")
    with pytest.raises(ImageConversionError, match="cannot compress"):
        numpy_to_compressed(np.zeros((4, 4, 3), np.float32), "png")
    msg = numpy_to_compressed(_scene(), "png")
    msg.data = msg.data[: len(msg.data) // 3]  # truncated in transit
    with pytest.raises(ImageConversionError, match="cannot be decoded"):
        image_to_rgb(msg)
    assert image_size(msg) is None  # the oracle detector then does not clip its boxes
    msg.format = "rgb8; theora compressed"
    with pytest.raises(ImageConversionError, match="unsupported compressed image format"):
        image_to_rgb(msg)
