"""KITTI file formats: calibration, label rows, and the tracking and object dataset layouts.

This module is the one place in the workspace that reads and writes KITTI files; the detector's
training, the synthetic sequence generator, the tracker's offline CLI and the evaluator all use it.

Conventions (as in the KITTI devkits):
- Label 3D quantities are in the rectified reference camera (camera 0) frame: x right, y down,
  z forward, metres. ``location`` is the *bottom centre* of the 3D box; the centre of mass is
  ``h/2`` above it (``y - h/2``, since y points down).
- The left image is camera 2, the right image camera 3. A point ``X0`` in camera-0 coordinates
  is at ``X0 + calib.left_camera_offset`` in the left camera's optical frame.
- Tracking labels (``label_02/SSSS.txt``) start every row with ``frame track_id``; object labels
  (``label_2/NNNNNN.txt``) do not. Result files add a trailing score column.

Errors in input files raise :class:`KittiFormatError`, whose message names the file (and the line
where there is one); command-line tools print it as one line and exit with code 2.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

#: Types that count as vehicles of class "car" in KITTI's evaluation; 'Van' is a neighbouring
#: class (ignored, neither TP nor FP) for the Car benchmark.
DONTCARE = "DontCare"

#: Mean dimensions (h, w, l) in metres of KITTI's labelled cars, for boxes of unknown size.
MEAN_CAR_DIMENSIONS = (1.53, 1.63, 3.88)


class KittiFormatError(ValueError):
    """A KITTI file or folder is missing or malformed. The message names the file (and line)."""


# ----------------------------------------------------------------------------- calibration


@dataclass(frozen=True)
class Calibration:
    """Calibration of one KITTI sequence or frame.

    ``P0``..``P3`` are the 3x4 projection matrices of the rectified cameras (0, 1 gray; 2 left
    colour; 3 right colour), ``R_rect`` the 3x3 rectifying rotation and ``Tr_velo_cam`` the 3x4
    LiDAR-to-camera transform (identity-like defaults when a file lacks them).
    """

    P0: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    P3: np.ndarray
    R_rect: np.ndarray = field(default_factory=lambda: np.eye(3))
    Tr_velo_cam: np.ndarray = field(
        default_factory=lambda: np.hstack([np.eye(3), np.zeros((3, 1))])
    )
    Tr_imu_velo: np.ndarray = field(
        default_factory=lambda: np.hstack([np.eye(3), np.zeros((3, 1))])
    )

    @property
    def fx(self) -> float:
        return float(self.P2[0, 0])

    @property
    def fy(self) -> float:
        return float(self.P2[1, 1])

    @property
    def cx(self) -> float:
        return float(self.P2[0, 2])

    @property
    def cy(self) -> float:
        return float(self.P2[1, 2])

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsics of the left (camera 2) rectified image."""
        return self.P2[:, :3].copy()

    @property
    def baseline(self) -> float:
        """Stereo baseline between cameras 2 and 3 in metres (about 0.54 m for KITTI)."""
        return float((self.P2[0, 3] - self.P3[0, 3]) / self.P2[0, 0])

    @property
    def left_camera_offset(self) -> np.ndarray:
        """Translation t with ``p_left = p_cam0 + t`` (camera 2 relative to camera 0)."""
        return np.linalg.solve(self.P2[:, :3], self.P2[:, 3])

    def cam0_to_left(self, points: np.ndarray) -> np.ndarray:
        """Camera-0 (label) coordinates -> left optical frame. ``points``: (..., 3)."""
        return np.asarray(points, dtype=float) + self.left_camera_offset

    def left_to_cam0(self, points: np.ndarray) -> np.ndarray:
        """Left optical frame -> camera-0 (label) coordinates. ``points``: (..., 3)."""
        return np.asarray(points, dtype=float) - self.left_camera_offset


# Both spellings of the KITTI calibration keys map onto the Calibration fields.
_CALIB_KEYS = {
    "P0": "P0",
    "P1": "P1",
    "P2": "P2",
    "P3": "P3",
    "R_rect": "R_rect",
    "R0_rect": "R_rect",
    "Tr_velo_cam": "Tr_velo_cam",
    "Tr_velo_to_cam": "Tr_velo_cam",
    "Tr_imu_velo": "Tr_imu_velo",
    "Tr_imu_to_velo": "Tr_imu_velo",
}
_CALIB_SHAPES = {"R_rect": (3, 3)}


def read_calib(path: str | os.PathLike) -> Calibration:
    """Read a KITTI calibration file in either spelling (``R_rect`` / ``R0_rect:``...)."""
    path = Path(path)
    text = read_text(path, "calibration file")
    values: dict[str, np.ndarray] = {}
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        key, _, rest = line.partition(" ")
        key = key.rstrip(":")
        if key not in _CALIB_KEYS:
            continue  # other keys (e.g. calib_time) are not needed
        name = _CALIB_KEYS[key]
        shape = _CALIB_SHAPES.get(name, (3, 4))
        try:
            numbers = np.array([float(tok) for tok in rest.split()], dtype=float)
        except ValueError:
            raise KittiFormatError(f"{path}:{lineno}: {key}: non-numeric value") from None
        if numbers.size != shape[0] * shape[1]:
            raise KittiFormatError(
                f"{path}:{lineno}: {key}: expected {shape[0] * shape[1]} numbers, "
                f"got {numbers.size}"
            )
        matrix = numbers.reshape(shape)
        bad = np.argwhere(~np.isfinite(matrix))
        if bad.size:  # float() reads "nan" and "inf": a calibration never holds them
            r, c = (int(v) for v in bad[0])
            raise KittiFormatError(
                f"{path}:{lineno}: {key}[{r},{c}]: non-finite value {float(matrix[r, c])!r} "
                "(a calibration holds finite numbers only)"
            )
        values[name] = matrix
    missing = [k for k in ("P0", "P1", "P2", "P3") if k not in values]
    if missing:
        raise KittiFormatError(f"{path}: missing calibration rows {', '.join(missing)}")
    if abs(values["P2"][0, 0]) < 1e-9:
        raise KittiFormatError(f"{path}: P2 has a zero focal length")
    return Calibration(**values)


def check_stereo_calibration(calib: Calibration, path: str | os.PathLike) -> None:
    """Raise KittiFormatError naming ``path`` unless ``calib`` describes a stereo pair the graph
    can range with: positive focal lengths in P2 and a positive baseline (camera 3, P3, right of
    camera 2, P2: ``P2[0,3] - P3[0,3] > 0``)."""
    if not (calib.P2[0, 0] > 0 and calib.P2[1, 1] > 0):
        raise KittiFormatError(
            f"{path}: P2 focal lengths fx, fy = {calib.fx:g}, {calib.fy:g} must be > 0"
        )
    if not calib.baseline > 0:
        raise KittiFormatError(
            f"{path}: P2[0,3] - P3[0,3] = {calib.P2[0, 3] - calib.P3[0, 3]:g} gives a stereo "
            f"baseline of {calib.baseline:g} m: camera 3 (P3) must lie right of camera 2 (P2)"
        )


def write_calib(path: str | os.PathLike, calib: Calibration) -> None:
    """Write a calibration file in the object-benchmark spelling (``R0_rect:`` ...)."""

    def row(name: str, m: np.ndarray) -> str:
        return name + ": " + " ".join(f"{v:.12e}" for v in np.asarray(m).ravel()) + "\n"

    text = "".join(
        [
            row("P0", calib.P0),
            row("P1", calib.P1),
            row("P2", calib.P2),
            row("P3", calib.P3),
            row("R0_rect", calib.R_rect),
            row("Tr_velo_to_cam", calib.Tr_velo_cam),
            row("Tr_imu_to_velo", calib.Tr_imu_velo),
        ]
    )
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(text)


def stereo_calibration(
    fx: float, fy: float, cx: float, cy: float, baseline: float, left_offset_x: float = 0.0
) -> Calibration:
    """A calibration for an ideal rectified stereo pair (used by the synthetic generator).

    ``left_offset_x`` places camera 2 at ``x = -left_offset_x`` in camera-0 coordinates, as in
    KITTI where P2[0,3] = fx * 0.06.
    """
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    def P(tx: float) -> np.ndarray:
        return np.hstack([K, (K @ np.array([tx, 0.0, 0.0]))[:, None]])

    return Calibration(
        P0=P(0.0),
        P1=P(-baseline),
        P2=P(left_offset_x),
        P3=P(left_offset_x - baseline),
    )


# ----------------------------------------------------------------------------- labels


@dataclass(frozen=True)
class KittiObject:
    """One KITTI label (or result) row.

    ``bbox`` is (x1, y1, x2, y2) in pixels of the left image; ``dimensions`` (h, w, l) and
    ``location`` (bottom centre, camera 0) in metres; angles in radians.
    """

    type: str
    truncated: float = 0.0
    occluded: int = 0
    alpha: float = -10.0
    bbox: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    dimensions: tuple[float, float, float] = (-1.0, -1.0, -1.0)
    location: tuple[float, float, float] = (-1000.0, -1000.0, -1000.0)
    rotation_y: float = -10.0
    frame: int = -1
    track_id: int = -1
    score: float | None = None

    @property
    def is_dontcare(self) -> bool:
        return self.type == DONTCARE

    @property
    def height_px(self) -> float:
        return float(self.bbox[3] - self.bbox[1])

    @property
    def centre_of_mass(self) -> np.ndarray:
        """Centre of the 3D box in camera-0 coordinates (``location`` is the bottom centre)."""
        x, y, z = self.location
        return np.array([x, y - self.dimensions[0] / 2.0, z])

    def with_(self, **changes) -> KittiObject:
        """A copy with some fields changed."""
        return replace(self, **changes)


#: the numeric columns of a label row after its type, as error messages name them
_ROW_FIELDS = (
    "truncated",
    "occluded",
    "alpha",
    "bbox x1",
    "bbox y1",
    "bbox x2",
    "bbox y2",
    "height",
    "width",
    "length",
    "location x",
    "location y",
    "location z",
    "rotation_y",
    "score",
)


def _parse_row(tokens: list[str], path: Path, lineno: int, tracking: bool) -> KittiObject:
    head = 2 if tracking else 0
    n = len(tokens) - head
    if n not in (15, 16):
        layout = "tracking (frame id type ...)" if tracking else "object (type ...)"
        raise KittiFormatError(
            f"{path}:{lineno}: expected {15 + head} or {16 + head} columns for a {layout} label, "
            f"got {len(tokens)}"
        )
    try:
        frame = int(tokens[0]) if tracking else -1
        track_id = int(tokens[1]) if tracking else -1
        t = tokens[head:]
        nums = [float(v) for v in t[1:]]
    except ValueError:
        raise KittiFormatError(f"{path}:{lineno}: non-numeric value in label row") from None
    for name, value in zip(_ROW_FIELDS, nums, strict=False):
        if not math.isfinite(value):  # float() reads "nan" and "inf"; no KITTI field holds them
            raise KittiFormatError(f"{path}:{lineno}: {name}: non-finite value {value!r}")
    if tracking and frame < 0:
        raise KittiFormatError(f"{path}:{lineno}: frame: {frame} is negative (frames count from 0)")
    left, top, right, bottom = nums[3:7]
    if right < left or bottom < top:  # an inverted box was scored (its IoU as if upright)
        axis = ("x2", right, "x1", left) if right < left else ("y2", bottom, "y1", top)
        raise KittiFormatError(
            f"{path}:{lineno}: bbox: inverted box ({axis[0]} {axis[1]:g} < {axis[2]} {axis[3]:g}; "
            "a box is left, top, right, bottom in pixels)"
        )
    if tracking and track_id < -1:
        raise KittiFormatError(
            f"{path}:{lineno}: track id: {track_id} (ids are >= 0; -1 only for DontCare rows)"
        )
    return KittiObject(
        type=t[0],
        truncated=nums[0],
        occluded=int(nums[1]),
        alpha=nums[2],
        bbox=(nums[3], nums[4], nums[5], nums[6]),
        dimensions=(nums[7], nums[8], nums[9]),
        location=(nums[10], nums[11], nums[12]),
        rotation_y=nums[13],
        score=nums[14] if len(nums) > 14 else None,
        frame=frame,
        track_id=track_id,
    )


def read_text(path: Path, what: str) -> str:
    """The text of ``path``; a KittiFormatError naming the file and ``what`` it should hold when
    it cannot be read."""
    try:
        return path.read_text()
    except OSError as exc:
        raise KittiFormatError(f"{path}: cannot read {what} ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise KittiFormatError(
            f"{path}: not a text file (byte 0x{exc.object[exc.start]:02x} at offset {exc.start} "
            f"is not UTF-8): cannot read {what}"
        ) from None


def read_tracking_labels(path: str | os.PathLike) -> dict[int, list[KittiObject]]:
    """Read a tracking label (or result) file: ``{frame: [objects...]}``, frames ascending.

    Frames without any row are absent from the dict; use the sequence's frame list to iterate.
    Raises KittiFormatError naming the file and line for a malformed row, a non-finite value, a
    negative frame or a track id that appears twice in one frame (a track is one object; the
    KITTI benchmark's HOTA code, TrackEval, refuses that in results and ground truth alike).
    """
    path = Path(path)
    frames: dict[int, list[KittiObject]] = {}
    first_line: dict[tuple[int, int], int] = {}  # (frame, track id) -> line
    for lineno, line in enumerate(read_text(path, "labels").splitlines(), start=1):
        tokens = line.split()
        if not tokens:
            continue
        obj = _parse_row(tokens, path, lineno, tracking=True)
        if obj.track_id >= 0:
            seen = first_line.setdefault((obj.frame, obj.track_id), lineno)
            if seen != lineno:
                raise KittiFormatError(
                    f"{path}:{lineno}: track id {obj.track_id} appears twice in frame "
                    f"{obj.frame} (also on line {seen})"
                )
        frames.setdefault(obj.frame, []).append(obj)
    return dict(sorted(frames.items()))


def read_object_labels(path: str | os.PathLike) -> list[KittiObject]:
    """Read an object-benchmark label file (one frame, no frame/track columns)."""
    path = Path(path)
    return [
        _parse_row(line.split(), path, lineno, tracking=False)
        for lineno, line in enumerate(read_text(path, "labels").splitlines(), start=1)
        if line.split()
    ]


def format_row(obj: KittiObject, tracking: bool = True, with_score: bool | None = None) -> str:
    """One label row (no newline). Scores are written when present unless ``with_score=False``."""
    if with_score is None:
        with_score = obj.score is not None
    parts = []
    if tracking:
        parts += [str(int(obj.frame)), str(int(obj.track_id))]
    parts += [obj.type, _fmt(obj.truncated), str(int(obj.occluded)), _fmt(obj.alpha)]
    parts += [_fmt(v) for v in obj.bbox]
    parts += [_fmt(v) for v in obj.dimensions]
    parts += [_fmt(v) for v in obj.location]
    parts.append(_fmt(obj.rotation_y))
    if with_score:
        parts.append(_fmt(obj.score if obj.score is not None else 1.0))
    return " ".join(parts)


def _fmt(v: float) -> str:
    s = f"{float(v):.6f}".rstrip("0")
    return s + "0" if s.endswith(".") else s


def write_tracking_labels(path: str | os.PathLike, objects: list[KittiObject]) -> None:
    """Write tracking label/result rows (sorted by frame, then track id)."""
    rows = sorted(objects, key=lambda o: (o.frame, o.track_id))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text("".join(format_row(o, tracking=True) + "\n" for o in rows))


def write_object_labels(path: str | os.PathLike, objects: list[KittiObject]) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text("".join(format_row(o, tracking=False) + "\n" for o in objects))


# ----------------------------------------------------------------------------- images


def read_png(path: str | os.PathLike) -> np.ndarray:
    """Read an 8-bit image as an RGB ``uint8`` array (H, W, 3) (grayscale is expanded)."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise KittiFormatError(f"{path}: image file not found")
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise KittiFormatError(f"{path}: unreadable image (not a valid PNG)")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def write_png(path: str | os.PathLike, rgb: np.ndarray) -> None:
    import cv2

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR)):
        raise KittiFormatError(f"{path}: cannot write image")


# ----------------------------------------------------------------------------- layouts


def calib_path(root: Path, sequence: str) -> Path:
    """The calibration file of a tracking sequence: ``root/calib/SSSS.txt``."""
    return Path(root) / "calib" / f"{sequence}.txt"


def _frame_ids(folder: Path) -> list[int]:
    ids = []
    for p in folder.iterdir():
        if p.suffix.lower() == ".png" and p.stem.isdigit():
            ids.append(int(p.stem))
    return sorted(ids)


@dataclass
class TrackingSequence:
    """One sequence of a KITTI Object Tracking layout rooted at ``root`` (the folder holding
    ``image_02``, ``image_03``, ``calib`` and optionally ``label_02``)."""

    root: Path
    sequence: str
    calib: Calibration
    frame_ids: list[int]
    labels: dict[int, list[KittiObject]] | None

    @classmethod
    def open(cls, root: str | os.PathLike, sequence: str | int) -> TrackingSequence:
        root = Path(root)
        seq = f"{int(sequence):04d}" if str(sequence).isdigit() else str(sequence)
        if not root.is_dir():
            raise KittiFormatError(f"{root}: KITTI tracking root not found")
        left_dir, right_dir = root / "image_02" / seq, root / "image_03" / seq
        for d in (left_dir, right_dir):
            if not d.is_dir():
                raise KittiFormatError(f"{d}: image folder of sequence {seq} not found")
        left, right = _frame_ids(left_dir), _frame_ids(right_dir)
        if not left:
            raise KittiFormatError(f"{left_dir}: no PNG frames")
        if left != right:
            raise KittiFormatError(
                f"{right_dir}: left/right frame counts differ ({len(left)} in image_02, "
                f"{len(right)} in image_03)"
            )
        calib = read_calib(calib_path(root, seq))
        label_path = root / "label_02" / f"{seq}.txt"
        labels = read_tracking_labels(label_path) if label_path.is_file() else None
        return cls(root=root, sequence=seq, calib=calib, frame_ids=left, labels=labels)

    @property
    def calib_path(self) -> Path:
        return calib_path(self.root, self.sequence)

    def left_path(self, frame: int) -> Path:
        return self.root / "image_02" / self.sequence / f"{frame:06d}.png"

    def right_path(self, frame: int) -> Path:
        return self.root / "image_03" / self.sequence / f"{frame:06d}.png"

    def read_stereo(self, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """The rectified (left, right) RGB pair of a frame."""
        left, right = read_png(self.left_path(frame)), read_png(self.right_path(frame))
        if left.shape != right.shape:
            raise KittiFormatError(
                f"{self.right_path(frame)}: size {right.shape[1]}x{right.shape[0]} differs from "
                f"the left image's {left.shape[1]}x{left.shape[0]}"
            )
        return left, right

    def objects(self, frame: int) -> list[KittiObject]:
        """Ground-truth rows of a frame (empty without labels)."""
        return list(self.labels.get(frame, [])) if self.labels else []


def list_tracking_sequences(root: str | os.PathLike) -> list[str]:
    """Sequence names that have left images under ``root/image_02``."""
    d = Path(root) / "image_02"
    if not d.is_dir():
        raise KittiFormatError(f"{d}: KITTI tracking image folder not found")
    return sorted(p.name for p in d.iterdir() if p.is_dir())


@dataclass
class ObjectFrame:
    """One frame of the KITTI object layout (``image_2``/``image_3``/``calib``/``label_2``)."""

    root: Path
    frame_id: str

    @property
    def left_path(self) -> Path:
        return self.root / "image_2" / f"{self.frame_id}.png"

    @property
    def right_path(self) -> Path:
        return self.root / "image_3" / f"{self.frame_id}.png"

    def calib(self) -> Calibration:
        return read_calib(self.root / "calib" / f"{self.frame_id}.txt")

    def objects(self) -> list[KittiObject]:
        p = self.root / "label_2" / f"{self.frame_id}.txt"
        return read_object_labels(p) if p.is_file() else []


def list_object_frames(root: str | os.PathLike) -> list[ObjectFrame]:
    """Frames of a KITTI object layout rooted at ``root`` (the folder holding ``image_2``)."""
    root = Path(root)
    d = root / "image_2"
    if not d.is_dir():
        raise KittiFormatError(f"{d}: KITTI object image folder not found")
    return [ObjectFrame(root, p.stem) for p in sorted(d.glob("*.png"))]


# ----------------------------------------------------------------------------- angles


def wrap_angle(a):
    """Wrap an angle, or an array of angles, to (-pi, pi]."""
    if np.ndim(a) > 0:
        return np.pi - np.mod(np.pi - np.asarray(a, dtype=float), 2.0 * np.pi)
    a = math.fmod(float(a) + math.pi, 2.0 * math.pi)
    if a <= 0.0:
        a += 2.0 * math.pi
    return a - math.pi


def alpha_from_rotation_y(rotation_y: float, x: float, z: float) -> float:
    """KITTI observation angle alpha of an object at (x, z) with yaw rotation_y."""
    return wrap_angle(rotation_y - math.atan2(x, z))


def rotation_y_from_alpha(alpha: float, x: float, z: float) -> float:
    return wrap_angle(alpha + math.atan2(x, z))
