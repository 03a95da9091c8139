"""Synthetic KITTI Object Tracking sequences: the project's embedded default data.

``generate_sequence`` renders a procedural street scene (textured road, buildings, vegetation,
sky; cars and vans that follow lanes, change lanes, come the other way, cross and turn at a
junction, or are parked) with an exact ray caster (:mod:`.synthetic_render`) and writes it in
the KITTI tracking layout under ``root``::

    image_02/SSSS/FFFFFF.png  image_03/SSSS/FFFFFF.png  calib/SSSS.txt  label_02/SSSS.txt

plus ``synthetic_SSSS.json`` (the generator settings; an unchanged sequence is not rendered
again). The calibration is KITTI sequence 0005's (fx = fy = 721.5377, cx = 609.5593,
cy = 172.854, baseline 0.5327 m, camera 2 0.06 m left of camera 0), scaled with the image size
when it differs from 1242x375; or another rectified stereo camera: ``focal`` (fx = fy, principal
point at the image centre) and ``baseline``, e.g. 1280x720, f = 700 px, 0.12 m (a ZED-like
camera; docs/bags_and_cameras.md). Output is byte-identical for the same settings and seed.

Console script: ``kitti_synth --output DIR --sequence 0000 --frames 100 --seed 0``
[``--width 1280 --height 720 --focal 700 --baseline 0.12``].
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np
from vehicle_common.kitti import (
    Calibration,
    KittiFormatError,
    stereo_calibration,
    write_calib,
    write_png,
    write_tracking_labels,
)
from vehicle_common.output_paths import make_output_dir

from .synthetic_render import StereoRenderer
from .synthetic_scene import random_scene

GENERATOR_VERSION = 2  # bump whenever the output changes (invalidates manifests)
KITTI_WIDTH, KITTI_HEIGHT = 1242, 375
KITTI_FX, KITTI_FY, KITTI_CX, KITTI_CY = 721.5377, 721.5377, 609.5593, 172.854
KITTI_BASELINE = 0.5327
KITTI_LEFT_OFFSET = 0.06
IMAGE_NOISE_STD = 1.5  # grey levels, seeded


def synthetic_calibration(
    width: int = KITTI_WIDTH,
    height: int = KITTI_HEIGHT,
    focal: float = 0.0,
    baseline: float = KITTI_BASELINE,
) -> Calibration:
    """KITTI 0005's rectified stereo calibration, intrinsics scaled to ``width`` x ``height``
    (``focal`` 0), or a camera with fx = fy = ``focal`` [px] and the principal point at the
    image centre; ``baseline`` [m] either way."""
    if focal > 0:
        return stereo_calibration(
            focal, focal, width / 2.0, height / 2.0, baseline, KITTI_LEFT_OFFSET
        )
    sx, sy = width / KITTI_WIDTH, height / KITTI_HEIGHT
    return stereo_calibration(
        KITTI_FX * sx,
        KITTI_FY * sy,
        KITTI_CX * sx,
        KITTI_CY * sy,
        baseline,
        KITTI_LEFT_OFFSET,
    )


def _sequence_index(sequence: str) -> int:
    return int(sequence) if sequence.isdigit() else sum(sequence.encode())


def build_renderer(
    sequence: str = "0000",
    frames: int = 100,
    seed: int = 0,
    vehicles: int = 12,
    width: int = KITTI_WIDTH,
    height: int = KITTI_HEIGHT,
    focal: float = 0.0,
    baseline: float = KITTI_BASELINE,
) -> StereoRenderer:
    """The renderer of a random scene with the synthetic calibration."""
    scene = random_scene(seed, frames, vehicles, _sequence_index(sequence))
    calib = synthetic_calibration(width, height, focal, baseline)
    return StereoRenderer(scene, calib, width, height)


def to_uint8(image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Float RGB in [0, 1] -> uint8 with mild seeded sensor noise (Gaussian, IMAGE_NOISE_STD)."""
    n = image.size
    pool = _noise_pool(n)
    start = int(rng.integers(0, pool.size - n))
    noise = pool[start : start + n].reshape(image.shape)
    return np.clip(image * np.float32(255.0) + noise, 0, 255).astype(np.uint8)


_NOISE_POOLS: dict[int, np.ndarray] = {}


def _noise_pool(n: int) -> np.ndarray:
    """A fixed pool of Gaussian noise (+0.5 for rounding) from which images take windows."""
    if n not in _NOISE_POOLS:
        rng = np.random.default_rng(0x401CE)
        pool = rng.standard_normal(n + 65536, dtype=np.float32) * np.float32(IMAGE_NOISE_STD)
        _NOISE_POOLS.clear()
        _NOISE_POOLS[n] = pool + np.float32(0.5)
    return _NOISE_POOLS[n]


def render_stereo_frame(renderer: StereoRenderer, frame: int, sequence: str = "0000"):
    """(left uint8, right uint8, label rows) of one frame."""
    left = renderer.render(frame, 0)
    right = renderer.render(frame, 1)
    labels = renderer.labels(frame, left)
    rng = np.random.default_rng([renderer.scene.seed, _sequence_index(sequence), frame, 0xC0DE])
    return to_uint8(left.image, rng), to_uint8(right.image, rng), labels


def generate_sequence(
    root: str | os.PathLike,
    sequence: str = "0000",
    frames: int = 100,
    seed: int = 0,
    vehicles: int = 12,
    width: int = KITTI_WIDTH,
    height: int = KITTI_HEIGHT,
    force: bool = False,
    progress=None,
    focal: float = 0.0,
    baseline: float = KITTI_BASELINE,
) -> Path:
    """Render a sequence into the KITTI tracking root ``root``; returns ``root``. ``focal`` and
    ``baseline``: the camera (:func:`synthetic_calibration`).

    Skips the work when ``root/synthetic_SSSS.json`` records the same settings and all files
    exist (unless ``force``). ``progress(frame)`` is called after each frame when given.
    """
    sequence = _check_settings(sequence, frames, seed, vehicles, width, height, focal, baseline)
    root = Path(root)
    settings = {
        "generator": "kitti_player_node.synthetic",
        "version": GENERATOR_VERSION,
        "sequence": sequence,
        "frames": frames,
        "seed": seed,
        "vehicles": vehicles,
        "width": width,
        "height": height,
    }
    if focal > 0 or baseline != KITTI_BASELINE:  # (KITTI's camera: manifests as before)
        settings.update(focal=focal, baseline=baseline)
    manifest = root / f"synthetic_{sequence}.json"
    if not force and _up_to_date(root, manifest, settings):
        return root
    renderer = build_renderer(sequence, frames, seed, vehicles, width, height, focal, baseline)
    try:
        manifest.unlink(missing_ok=True)
        write_calib(root / "calib" / f"{sequence}.txt", renderer.calib)
        for d in ("image_02", "image_03"):
            folder = root / d / sequence
            folder.mkdir(parents=True, exist_ok=True)
            for stale in folder.glob("*.png"):
                if stale.stem.isdigit() and int(stale.stem) >= frames:
                    stale.unlink()
        rows = []
        for k in range(frames):
            left, right, labels = render_stereo_frame(renderer, k, sequence)
            write_png(root / "image_02" / sequence / f"{k:06d}.png", left)
            write_png(root / "image_03" / sequence / f"{k:06d}.png", right)
            rows += labels
            if progress is not None:
                progress(k)
        write_tracking_labels(root / "label_02" / f"{sequence}.txt", rows)
        manifest.write_text(json.dumps(settings, indent=1, sort_keys=True) + "\n")
    except OSError as exc:
        raise KittiFormatError(f"{root}: cannot write sequence ({exc.strerror})") from None
    return root


def _check_settings(
    sequence, frames, seed, vehicles, width, height, focal=0.0, baseline=KITTI_BASELINE
) -> str:
    sequence = str(sequence)
    if sequence.isdigit():
        sequence = f"{int(sequence):04d}"
    if not sequence or not sequence.replace("_", "").isalnum():
        raise ValueError(f"sequence: invalid name {sequence!r}")
    if frames < 1:
        raise ValueError(f"frames: must be >= 1, got {frames}")
    if vehicles < 0:
        raise ValueError(f"vehicles: must be >= 0, got {vehicles}")
    if seed < 0:
        raise ValueError(f"seed: must be >= 0, got {seed}")
    if not (32 <= width <= 8192 and 32 <= height <= 8192):
        raise ValueError(f"width/height: must be 32..8192 pixels, got {width}x{height}")
    if not (focal == 0 or 10 <= focal <= 100_000):
        raise ValueError(f"focal: must be 0 (KITTI's, scaled) or 10..100000 px, got {focal}")
    if not 0.01 <= baseline <= 5.0:
        raise ValueError(f"baseline: must be 0.01..5 m, got {baseline}")
    return sequence


def _up_to_date(root: Path, manifest: Path, settings: dict) -> bool:
    try:
        if json.loads(manifest.read_text()) != settings:
            return False
    except (OSError, ValueError):
        return False
    seq, n = settings["sequence"], settings["frames"]
    files = [root / "calib" / f"{seq}.txt", root / "label_02" / f"{seq}.txt"]
    files += [root / d / seq / f"{k:06d}.png" for d in ("image_02", "image_03") for k in range(n)]
    return all(f.is_file() for f in files)


class _ArgumentParser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, exit code 2
        sys.stderr.write(f"error: arguments: {message}\n")
        raise SystemExit(2)


def main(argv: list[str] | None = None) -> int:
    """``kitti_synth``: write a synthetic KITTI tracking sequence."""
    p = _ArgumentParser(prog="kitti_synth", description=__doc__.splitlines()[0])
    p.add_argument("--output", required=True, help="KITTI tracking root to write into")
    p.add_argument("--sequence", default="0000", help="sequence name (default 0000)")
    p.add_argument("--frames", type=int, default=100, help="number of frames (default 100)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--vehicles", type=int, default=12, help="vehicles in the scene (default 12)")
    p.add_argument("--width", type=int, default=KITTI_WIDTH, help="image width (default 1242)")
    p.add_argument("--height", type=int, default=KITTI_HEIGHT, help="image height (default 375)")
    p.add_argument(
        "--focal",
        type=float,
        default=0.0,
        help="fx = fy [px], principal point at the centre "
        "(default 0: KITTI 0005's intrinsics scaled to the image size)",
    )
    p.add_argument(
        "--baseline", type=float, default=KITTI_BASELINE, help="stereo baseline [m] (0.5327)"
    )
    p.add_argument("--force", action="store_true", help="render even if up to date")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    try:
        args = p.parse_args(argv)
    except SystemExit as exc:  # --help (0) or a usage error (2, already reported)
        return int(exc.code or 0)
    out = Path(args.output)
    names = ("sequence", "frames", "seed", "vehicles", "width", "height", "focal", "baseline")
    settings = {k: getattr(args, k) for k in names}
    try:
        _check_settings(**settings)
        make_output_dir(out)
    except ValueError as exc:  # KittiFormatError included
        msg = str(exc)
        if not isinstance(exc, KittiFormatError):
            msg = f"--{msg}"
        sys.stderr.write(f"error: {msg}\n")
        return 2

    def progress(k: int) -> None:
        if not args.quiet and (k + 1) % 10 == 0:
            print(f"kitti_synth: {args.sequence}: frame {k + 1}/{args.frames}", flush=True)

    try:
        generate_sequence(out, force=args.force, progress=progress, **settings)
    except (KittiFormatError, ValueError) as exc:
        sys.stderr.write(f"error: {exc}\n")
        return 2
    if not args.quiet:
        print(f"kitti_synth: wrote sequence {args.sequence} to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
