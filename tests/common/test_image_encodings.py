"""Camera encodings converted once, at the edge (issue #42): every one a user's camera may send
gives the RGB uint8 image the nodes compute on."""

import numpy as np
import pytest
from vehicle_common.image_conversion import (
    ImageConversionError,
    image_to_rgb,
    mono16_to_mono8,
    numpy_to_compressed,
    numpy_to_image,
)

RNG = np.random.default_rng(4)
RGB = RNG.integers(0, 256, size=(6, 8, 3), dtype=np.uint8)


@pytest.mark.parametrize(
    "encoding, array",
    [
        ("rgb8", RGB),
        ("bgr8", RGB[:, :, ::-1]),
        ("rgba8", np.dstack([RGB, np.full(RGB.shape[:2], 7, np.uint8)])),
        ("bgra8", np.dstack([RGB[:, :, ::-1], np.full(RGB.shape[:2], 200, np.uint8)])),
    ],
)
def test_colour_encodings_give_the_same_rgb(encoding, array):
    msg = numpy_to_image(array, encoding)
    assert msg.step == 8 * array.shape[2]
    np.testing.assert_array_equal(image_to_rgb(msg), RGB)


def test_mono8_is_repeated_in_three_channels():
    gray = RGB[:, :, 0]
    out = image_to_rgb(numpy_to_image(gray, "mono8"))
    assert out.shape == (6, 8, 3) and out.dtype == np.uint8
    np.testing.assert_array_equal(out[:, :, 1], gray)


def test_mono16_keeps_a_12_bit_sensors_contrast():
    gray = (RGB[:, :, 0].astype(np.uint16) << 4) | 0xF  # 12-bit data in 16 bits
    out = image_to_rgb(numpy_to_image(gray, "mono16"))
    np.testing.assert_array_equal(out[:, :, 2], RGB[:, :, 0])
    full = RGB[:, :, 1].astype(np.uint16) << 8
    np.testing.assert_array_equal(mono16_to_mono8(full), RGB[:, :, 1])
    assert mono16_to_mono8(np.zeros((2, 2), np.uint16)).max() == 0


def _yuv422(rgb: np.ndarray, order: str) -> np.ndarray:
    """Pack RGB as 4:2:2, BT.601 video range as cameras send it (chroma of each pixel pair
    averaged): 'uyvy' or 'yuyv'."""
    r, g, b = (rgb[:, :, i].astype(float) for i in range(3))
    y = 16 + 0.257 * r + 0.504 * g + 0.098 * b
    u_full = 128 - 0.148 * r - 0.291 * g + 0.439 * b
    v_full = 128 + 0.439 * r - 0.368 * g - 0.071 * b
    u = (u_full[:, 0::2] + u_full[:, 1::2]) / 2
    v = (v_full[:, 0::2] + v_full[:, 1::2]) / 2
    out = np.zeros((rgb.shape[0], rgb.shape[1], 2))
    out[:, :, 0 if order == "yuyv" else 1] = y
    chroma = out[:, :, 1 if order == "yuyv" else 0]
    chroma[:, 0::2], chroma[:, 1::2] = u, v
    return np.round(out).astype(np.uint8)


@pytest.mark.parametrize(
    "encoding, order",
    [("yuv422", "uyvy"), ("uyvy", "uyvy"), ("yuv422_yuy2", "yuyv"), ("yuyv", "yuyv")],
)
def test_yuv422_encodings(encoding, order):
    # a smooth image: 4:2:2 keeps it within a few levels (chroma is shared by pixel pairs)
    rgb = np.zeros((4, 8, 3), np.uint8)
    rgb[:, :, 0], rgb[:, :, 1], rgb[:, :, 2] = 180, 90, 40
    rgb[2:] = (30, 140, 220)
    msg = numpy_to_image(_yuv422(rgb, order), encoding)
    assert msg.step == 16
    out = image_to_rgb(msg)
    assert out.shape == rgb.shape
    assert np.abs(out.astype(int) - rgb).max() <= 3
    # the other byte order gives another picture: the order is really read
    other = "yuyv" if order == "uyvy" else "uyvy"
    wrong = image_to_rgb(numpy_to_image(_yuv422(rgb, other), encoding))
    assert np.abs(wrong.astype(int) - rgb).max() > 30


def test_compressed_image_gives_the_same_rgb():
    np.testing.assert_array_equal(image_to_rgb(numpy_to_compressed(RGB, "png")), RGB)


def test_unknown_encoding_is_named():
    msg = numpy_to_image(RGB, "rgb8")
    msg.encoding = "bayer_rggb8"
    with pytest.raises(ImageConversionError, match="unsupported image encoding 'bayer_rggb8'"):
        image_to_rgb(msg)
