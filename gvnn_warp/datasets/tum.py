"""TUM RGB-D / ICL-NUIM sequence folders and TUM trajectory files (numpy + Pillow; no torch).

A sequence folder holds (the format of the TUM RGB-D benchmark, also used by ICL-NUIM's
"TUM-compatible" downloads)::

    rgb.txt           timestamp filename        (lines starting with # are comments)
    depth.txt         timestamp filename
    groundtruth.txt   timestamp tx ty tz qx qy qz qw    (optional; T_world_cam, metres)
    intrinsics.txt    fx fy cx cy [k1 k2 p1 p2 k3]      (optional; not part of TUM's own format;
                                                        the 5 radial-tangential coefficients of
                                                        OpenCV's model when the images are
                                                        distorted, none for a pinhole)
    rgb/*.png         8-bit colour images
    depth/*.png       16-bit single-channel depth, metres * depth_scale (5000), 0 = no depth

How frames are formed (the rules of TUM's ``associate.py`` and of ``evo``):

- Colour and depth images are associated by timestamp: every pair closer than ``max_difference``
  (0.02 s) is a candidate, candidates are taken greedily by smallest time difference (ties by the
  earlier stamps), and each stamp is used at most once. The frames are the associated pairs in
  colour-time order; a frame's timestamp is its colour image's.
- A frame's ground-truth pose is *interpolated* at its timestamp: a ground-truth stamp must lie
  closer than ``max_difference`` (otherwise the frame has no ground truth: NaN pose,
  ``gt_valid`` False), and the pose is interpolated between the two ground-truth samples that
  bracket the frame's time (translation linearly, rotation by slerp) - the way ``evo``'s
  ``SyncMethod.interpolation`` resamples a trajectory - or taken from the nearest sample when the
  frame lies before the first or after the last.

Poses follow the project's conventions (docs/conventions.md): ``T_world_cam`` (4, 4) float64 maps
camera points into the world; TUM's quaternions are (qx, qy, qz, qw) in the files, Hamilton,
the rotation of ``T_world_cam``.

Every problem with the files raises :class:`DatasetError` (a ``ValueError``) with a one-line
message that names the file.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = [
    "DEFAULT_DEPTH_SCALE",
    "DISTORTION_PRESETS",
    "INTRINSICS_PRESETS",
    "DatasetError",
    "TUMSequence",
    "TUMWriter",
    "associate",
    "intrinsics_preset",
    "matrix_to_quaternion_xyzw",
    "quaternion_xyzw_to_matrix",
    "read_depth",
    "read_rgb",
    "read_trajectory",
    "read_tum",
    "write_trajectory",
]

#: TUM RGB-D and ICL-NUIM store depth as metres * 5000 in 16-bit PNGs.
DEFAULT_DEPTH_SCALE = 5000.0
#: Maximum time difference (s) for associating stamps, as TUM's associate.py and evaluate_ate.py.
DEFAULT_MAX_DIFFERENCE = 0.02

#: Published intrinsics (fx, fy, cx, cy) of 640x480 images. fr1, fr2, fr3: the TUM RGB-D
#: benchmark's calibrated colour cameras of the Freiburg 1/2/3 sequences (fr1's and fr2's lens
#: distortion: :data:`DISTORTION_PRESETS`; fr3's images are already undistorted); icl: ICL-NUIM
#: (fy given there as -480 for their y-up renderer; +480 for the TUM-compatible files).
INTRINSICS_PRESETS: dict[str, tuple[float, float, float, float]] = {
    "fr1": (517.3, 516.5, 318.6, 255.3),
    "fr2": (520.9, 521.0, 325.1, 249.7),
    "fr3": (535.4, 539.2, 320.1, 247.6),
    "icl": (481.20, 480.0, 319.5, 239.5),
}
_PRESET_SIZE = (640, 480)
#: The radial-tangential distortion (k1, k2, p1, p2, k3; OpenCV's order, TUM's d0..d4) the TUM
#: RGB-D benchmark publishes for the fr1 and fr2 colour cameras (the images are distorted); the
#: other presets are pinholes. The coefficients act on normalized coordinates: they hold for any
#: image size.
DISTORTION_PRESETS: dict[str, tuple[float, float, float, float, float]] = {
    "fr1": (0.2624, -0.9531, -0.0054, 0.0026, 1.1633),
    "fr2": (0.2312, -0.7849, -0.0033, -0.0001, 0.9172),
}


class DatasetError(ValueError):
    """A sequence folder or trajectory file that cannot be read; the message names the file."""


# ------------------------------------------------------------------------------------------------
# Quaternions (x, y, z, w as in TUM files), rotations and poses


def quaternion_xyzw_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) float64 from Hamilton quaternions (..., 4) ordered
    (qx, qy, qz, qw) as in TUM files (the torch ``gvnn_warp.quaternion_to_matrix`` takes
    (w, x, y, z), docs/conventions.md); any non-zero norm (normalised here)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    R = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )
    return R.reshape(q.shape[:-1] + (3, 3))


def matrix_to_quaternion_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) ordered (qx, qy, qz, qw), with qw >= 0, of rotation matrices
    (..., 3, 3) (Shepperd's method: the numerically best of four branches per matrix)."""
    R = np.asarray(R, dtype=np.float64)
    shape = R.shape[:-2]
    R = R.reshape(-1, 3, 3)
    t = np.trace(R, axis1=1, axis2=2)
    diag = np.diagonal(R, axis1=1, axis2=2)
    q = np.empty((R.shape[0], 4))
    # branch = which of w, x, y, z is largest in magnitude
    branch = np.argmax(np.concatenate([t[:, None], diag], axis=1), axis=1)
    for k in range(R.shape[0]):
        m = R[k]
        if branch[k] == 0:
            s = 2.0 * math.sqrt(max(1.0 + t[k], 0.0))
            q[k] = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
        else:
            i = branch[k] - 1
            j, l = (i + 1) % 3, (i + 2) % 3
            s = 2.0 * math.sqrt(max(1.0 + m[i, i] - m[j, j] - m[l, l], 0.0))
            v = np.empty(3)
            v[i] = s / 4
            v[j] = (m[j, i] + m[i, j]) / s
            v[l] = (m[l, i] + m[i, l]) / s
            q[k] = [*v, (m[l, j] - m[j, l]) / s]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1.0
    return q.reshape(shape + (4,))


def _poses_from_rows(rows: np.ndarray) -> np.ndarray:
    """(N, 4, 4) float64 poses from (N, 7) rows tx ty tz qx qy qz qw."""
    T = np.zeros((rows.shape[0], 4, 4))
    T[:, :3, :3] = quaternion_xyzw_to_matrix(rows[:, 3:7])
    T[:, :3, 3] = rows[:, :3]
    T[:, 3, 3] = 1.0
    return T


def _slerp(q0: np.ndarray, q1: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Spherical interpolation (N, 4) between unit quaternions q0, q1 (N, 4) at fractions s (N,),
    along the shorter arc."""
    dot = np.sum(q0 * q1, axis=1)
    q1 = np.where(dot[:, None] < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    small = theta < 1e-8
    sin = np.where(small, 1.0, np.sin(theta))
    a = np.where(small, 1.0 - s, np.sin((1.0 - s) * theta) / sin)
    b = np.where(small, s, np.sin(s * theta) / sin)
    q = a[:, None] * q0 + b[:, None] * q1
    return q / np.linalg.norm(q, axis=1, keepdims=True)


# ------------------------------------------------------------------------------------------------
# Text files


def _read_table(path: Path, columns: int, what: str) -> tuple[np.ndarray, list[list[str]], list[int]]:
    """Rows of a TUM text file, sorted by time: (timestamps (N,) float64, the other ``columns - 1``
    fields per row, each row's line number).

    Comment lines (``#``) and blank lines are skipped; fields are separated by spaces, tabs or
    commas (as TUM's tools accept). Raises DatasetError naming the file and line otherwise.
    """
    try:
        text = path.read_text(encoding="utf-8-sig", errors="replace")  # (a byte-order mark is dropped)
    except FileNotFoundError:
        raise DatasetError(f"{path}: missing {what} file") from None
    except OSError as e:
        raise DatasetError(f"{path}: cannot read {what} file ({e.strerror or e})") from None
    stamps: list[float] = []
    rows: list[list[str]] = []
    lines: list[int] = []
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        fields = re.split(r"[\s,]+", line)
        if len(fields) != columns:
            raise DatasetError(f"{path}:{number}: expected {columns} fields per line, got {len(fields)}: {line!r}")
        try:
            t = float(fields[0])
        except ValueError:
            raise DatasetError(f"{path}:{number}: timestamp {fields[0]!r} is not a number") from None
        if not math.isfinite(t):
            raise DatasetError(f"{path}:{number}: timestamp {fields[0]!r} is not finite")
        stamps.append(t)
        rows.append(fields[1:])
        lines.append(number)
    if not stamps:
        raise DatasetError(f"{path}: no entries in {what} file")
    times = np.array(stamps)
    order = np.argsort(times, kind="stable")
    sorted_times = times[order]
    dup = np.flatnonzero(np.diff(sorted_times) == 0)
    if dup.size:
        first, second = sorted((lines[order[dup[0]]], lines[order[dup[0] + 1]]))
        raise DatasetError(f"{path}:{second}: timestamp {sorted_times[dup[0]]:.6f} appears more than once (also on "
                           f"line {first})")
    return sorted_times, [rows[i] for i in order], [lines[i] for i in order]


def read_trajectory(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory file (``timestamp tx ty tz qx qy qz qw`` per line, ``#`` comments).

    Returns:
        ``(timestamps (N,) float64, T_world_cam (N, 4, 4) float64)``, sorted by time.
    """
    path = Path(path)
    stamps, rows, lines = _read_table(path, 8, "trajectory")
    values = np.empty((len(rows), 7))
    for k in sorted(range(len(rows)), key=lines.__getitem__):  # checked in file order: the first bad line
        row, number = rows[k], lines[k]
        try:
            values[k] = [float(v) for v in row]
        except ValueError:
            raise DatasetError(f"{path}:{number}: pose entries must be numbers: {' '.join(row)!r}") from None
        if not np.all(np.isfinite(values[k])):
            raise DatasetError(f"{path}:{number}: pose entries must be finite: {' '.join(row)!r}")
        if np.linalg.norm(values[k, 3:7]) < 1e-12:
            raise DatasetError(f"{path}:{number}: the quaternion (qx qy qz qw) has zero norm")
    return stamps, _poses_from_rows(values)


def write_trajectory(path: str | Path, timestamps: np.ndarray, poses: np.ndarray, comment: str | None = None) -> None:
    """Write poses ``T_world_cam`` (N, 4, 4) with their timestamps (N,) as a TUM trajectory file
    (``timestamp tx ty tz qx qy qz qw``; stamps to 1 us, translations to 1 nm, unit quaternions
    with qw >= 0 to 1e-9). ``comment`` lines are written first, each prefixed with ``#``."""
    timestamps = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    poses = np.asarray(poses, dtype=np.float64)
    if poses.shape != (timestamps.shape[0], 4, 4):
        raise ValueError(f"write_trajectory: poses must be (N, 4, 4) with N = {timestamps.shape[0]}, got {poses.shape}")
    if not (np.all(np.isfinite(poses)) and np.all(np.isfinite(timestamps))):
        raise ValueError("write_trajectory: timestamps and poses must be finite")
    q = matrix_to_quaternion_xyzw(poses[:, :3, :3])
    lines = [f"# {c}" for c in (comment.splitlines() if comment else [])]
    lines.append("# timestamp tx ty tz qx qy qz qw")
    for t, T, qk in zip(timestamps, poses, q):
        lines.append(f"{t:.6f} " + " ".join(f"{v:.9f}" for v in (*T[:3, 3], *qk)))
    Path(path).write_text("\n".join(lines) + "\n")


# ------------------------------------------------------------------------------------------------
# Association


def associate(
    first: np.ndarray, second: np.ndarray, max_difference: float = DEFAULT_MAX_DIFFERENCE, offset: float = 0.0
) -> np.ndarray:
    """Associate two lists of timestamps the way TUM's ``associate.py`` does.

    Every pair (a, b) with ``|a - (b + offset)| < max_difference`` is a candidate; candidates are
    accepted in order of increasing difference (ties: smaller ``a``, then smaller ``b``), skipping
    any whose ``a`` or ``b`` is already used. Returns an int64 array (M, 2) of index pairs
    ``(i, j)`` into ``first`` and ``second``, sorted by ``first[i]``.
    """
    a = np.asarray(first, dtype=np.float64).reshape(-1)
    b = np.asarray(second, dtype=np.float64).reshape(-1) + offset
    order = np.argsort(b, kind="stable")
    bs = b[order]
    lo = np.searchsorted(bs, a - max_difference, side="left")
    hi = np.searchsorted(bs, a + max_difference, side="right")
    cand_i = np.repeat(np.arange(a.size), hi - lo)
    cand_j = order[np.concatenate([np.arange(s, e) for s, e in zip(lo, hi)])] if a.size else np.zeros(0, np.int64)
    diff = np.abs(a[cand_i] - b[cand_j])
    keep = diff < max_difference
    cand_i, cand_j, diff = cand_i[keep], cand_j[keep], diff[keep]
    ranked = np.lexsort((b[cand_j], a[cand_i], diff))
    used_a = np.zeros(a.size, dtype=bool)
    used_b = np.zeros(b.size, dtype=bool)
    pairs = []
    for k in ranked:
        i, j = cand_i[k], cand_j[k]
        if not (used_a[i] or used_b[j]):
            used_a[i] = used_b[j] = True
            pairs.append((i, j))
    pairs.sort(key=lambda p: a[p[0]])
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)


def _interpolate_poses(
    gt_times: np.ndarray, gt_poses: np.ndarray, times: np.ndarray, max_difference: float
) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth poses at ``times`` (see the module docstring): (poses (N, 4, 4) with NaN where
    invalid, valid (N,) bool)."""
    n = times.shape[0]
    poses = np.full((n, 4, 4), np.nan)
    k = np.searchsorted(gt_times, times)  # gt_times[k - 1] < t <= gt_times[k]
    prev = np.clip(k - 1, 0, gt_times.size - 1)
    nxt = np.clip(k, 0, gt_times.size - 1)
    nearest = np.minimum(np.abs(times - gt_times[prev]), np.abs(times - gt_times[nxt]))
    valid = nearest < max_difference
    span = gt_times[nxt] - gt_times[prev]
    s = np.where(span > 0, (times - gt_times[prev]) / np.where(span > 0, span, 1.0), 0.0)
    s = np.clip(s, 0.0, 1.0)
    t = (1.0 - s)[:, None] * gt_poses[prev, :3, 3] + s[:, None] * gt_poses[nxt, :3, 3]
    q = _slerp(matrix_to_quaternion_xyzw(gt_poses[prev, :3, :3]), matrix_to_quaternion_xyzw(gt_poses[nxt, :3, :3]), s)
    poses[valid, :3, :3] = quaternion_xyzw_to_matrix(q[valid])
    poses[valid, :3, 3] = t[valid]
    poses[valid, 3] = [0.0, 0.0, 0.0, 1.0]
    return poses, valid


# ------------------------------------------------------------------------------------------------
# Intrinsics


def intrinsics_preset(name: str, width: int = 640, height: int = 480) -> np.ndarray:
    """``K`` (3, 3) float64 of a preset (``fr1``, ``fr2``, ``fr3``, ``icl``; see
    ``INTRINSICS_PRESETS``) for images of ``width`` x ``height``. The presets are for 640x480;
    for other sizes they are scaled about the pixel grid (f * s, (c + 0.5) * s - 0.5), as for
    an image resized by s."""
    if name not in INTRINSICS_PRESETS:
        raise ValueError(f"intrinsics_preset: unknown preset {name!r}; expected one of {', '.join(INTRINSICS_PRESETS)}")
    fx, fy, cx, cy = INTRINSICS_PRESETS[name]
    sx, sy = width / _PRESET_SIZE[0], height / _PRESET_SIZE[1]
    return np.array([[fx * sx, 0.0, (cx + 0.5) * sx - 0.5], [0.0, fy * sy, (cy + 0.5) * sy - 0.5], [0.0, 0.0, 1.0]])


def _k_from_values(values, source: str) -> np.ndarray:
    fx, fy, cx, cy = (float(v) for v in values)
    if not all(math.isfinite(v) for v in (fx, fy, cx, cy)) or fx <= 0 or fy <= 0:
        raise DatasetError(f"{source}: intrinsics must be finite with fx, fy > 0, got {fx} {fy} {cx} {cy}")
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _dist_from_values(values, source: str) -> np.ndarray:
    d = np.array([float(v) for v in values])
    if not np.all(np.isfinite(d)):
        raise DatasetError(f"{source}: distortion coefficients must be finite, got {' '.join(map(str, d))}")
    return d


def _read_intrinsics_file(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    for number, line in enumerate(path.read_text(encoding="utf-8-sig", errors="replace").splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        fields = re.split(r"[\s,]+", line)
        try:
            values = [float(v) for v in fields]
        except ValueError:
            values = []
        if len(values) not in (4, 9):
            raise DatasetError(f"{path}:{number}: expected 'fx fy cx cy' (four numbers) or 'fx fy cx cy k1 k2 p1 p2 "
                               f"k3' (nine: with radial-tangential distortion), got {line!r}")
        dist = _dist_from_values(values[4:], str(path)) if len(values) == 9 else None
        return _k_from_values(values[:4], str(path)), dist
    raise DatasetError(f"{path}: no 'fx fy cx cy' line")


def _preset_from_name(root: Path) -> str | None:
    """fr1/fr2/fr3 for folders named like TUM's downloads (rgbd_dataset_freiburg2_xyz)."""
    m = re.search(r"freiburg([123])", root.resolve().name)
    return f"fr{m.group(1)}" if m else None


# ------------------------------------------------------------------------------------------------
# Images


def _open_image(path: Path, what: str, load: bool = True):
    """The Pillow image at ``path`` (its pixels read unless ``load`` is False: the header only);
    DatasetError naming the file if it is missing or cannot be read."""
    from PIL import Image, UnidentifiedImageError

    try:
        im = Image.open(path)
        if load:
            im.load()
    except FileNotFoundError:
        raise DatasetError(f"{path}: missing {what} image") from None
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as e:
        raise DatasetError(f"{path}: cannot read {what} image ({type(e).__name__}: {e})") from None
    return im


_RGB_MODES = ("RGB", "RGBA", "RGBX", "L", "LA", "P", "PA")
_DEPTH_MODES = ("I;16", "I;16L", "I;16B", "I;16N", "I")  # "I": some Pillow versions open 16-bit PNGs so


def _check_rgb_mode(path: Path, mode: str) -> None:
    if mode not in _RGB_MODES:
        raise DatasetError(f"{path}: colour image must be 8-bit RGB or grey, got Pillow mode {mode}")


def _check_depth_mode(path: Path, mode: str) -> None:
    if mode in _DEPTH_MODES:
        return
    if mode in ("L", "P", "1"):
        raise DatasetError(f"{path}: depth image is 8-bit (Pillow mode {mode}); expected a 16-bit single-channel PNG")
    if mode in ("RGB", "RGBA", "RGBX", "LA", "PA", "CMYK", "YCbCr"):
        raise DatasetError(f"{path}: depth image has colour channels (Pillow mode {mode}); "
                           "expected a 16-bit single-channel PNG")
    raise DatasetError(f"{path}: depth image has Pillow mode {mode}; expected a 16-bit single-channel PNG")


def read_rgb(path: str | Path) -> np.ndarray:
    """An 8-bit colour (or grey) image as float32 (3, H, W) in [0, 1]."""
    path = Path(path)
    im = _open_image(path, "colour")
    _check_rgb_mode(path, im.mode)
    rgb = np.asarray(im.convert("RGB"), dtype=np.float32) / np.float32(255.0)
    return np.ascontiguousarray(rgb.transpose(2, 0, 1))


def read_depth(path: str | Path, depth_scale: float = DEFAULT_DEPTH_SCALE) -> np.ndarray:
    """A 16-bit single-channel depth PNG as float32 (1, H, W) metres (raw / ``depth_scale``; 0 = no
    depth). 8-bit, colour and floating-point images are refused."""
    path = Path(path)
    im = _open_image(path, "depth")
    _check_depth_mode(path, im.mode)
    raw = np.asarray(im)
    if im.mode == "I" and (raw.min(initial=0) < 0 or raw.max(initial=0) > 65535):
        raise DatasetError(f"{path}: depth image must be 16-bit, got 32-bit values outside 0..65535")
    raw = raw.astype(np.float32)
    return (raw / np.float32(depth_scale))[None]


def _to_gray(rgb: np.ndarray) -> np.ndarray:
    """(1, H, W) luma 0.299 R + 0.587 G + 0.114 B (ITU-R BT.601, as OpenCV and Open3D) of (3, H, W)."""
    return (np.float32(0.299) * rgb[0] + np.float32(0.587) * rgb[1] + np.float32(0.114) * rgb[2])[None]


# ------------------------------------------------------------------------------------------------
# Sequences


@dataclass
class Frame:
    """One associated frame of a :class:`TUMSequence`."""

    index: int
    timestamp: float
    image: np.ndarray  #: float32 (3, H, W) in [0, 1], or (1, H, W) grey
    depth: np.ndarray  #: float32 (1, H, W) metres, 0 = no depth
    pose: np.ndarray | None  #: T_world_cam (4, 4) float64, None without ground truth


@dataclass
class TUMSequence:
    """A TUM-format RGB-D sequence (see the module docstring); made by :func:`read_tum`.

    ``len(seq)`` frames; ``seq[i]`` / :meth:`frame` read frame ``i`` (colour or grey image and
    depth); :meth:`image` and :meth:`depth` read one of them. Images are read from disk on every
    access (nothing is cached).

    Attributes:
        root: the folder.
        K: (3, 3) float64 intrinsics; ``intrinsics_source`` says where they came from.
        dist: (5,) float64 radial-tangential distortion (k1, k2, p1, p2, k3) of the images, or
            None (a pinhole: undistorted images); from the same source as K.
        width, height: image size (from the first colour image).
        timestamps: (N,) float64 colour timestamps of the frames.
        depth_timestamps: (N,) float64 timestamps of their depth images.
        rgb_files, depth_files: the N image paths.
        depth_scale: raw depth units per metre.
        gt_poses: (N, 4, 4) float64 ``T_world_cam`` interpolated at the frames' timestamps (NaN
            where ``gt_valid`` is False), or None without ``groundtruth.txt``.
        gt_valid: (N,) bool, or None.
        gt_timestamps, gt_raw_poses: the ground-truth file as read (for evaluation tools).
    """

    root: Path
    K: np.ndarray
    intrinsics_source: str
    width: int
    height: int
    timestamps: np.ndarray
    depth_timestamps: np.ndarray
    rgb_files: list[Path]
    depth_files: list[Path]
    depth_scale: float
    gt_poses: np.ndarray | None = None
    gt_valid: np.ndarray | None = None
    gt_timestamps: np.ndarray | None = None
    gt_raw_poses: np.ndarray | None = field(default=None, repr=False)
    dist: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.rgb_files)

    def _check(self, i: int) -> int:
        if not -len(self) <= i < len(self):
            raise IndexError(f"frame {i} out of range for a sequence of {len(self)} frames")
        return i % len(self)

    def image(self, i: int, gray: bool = False) -> np.ndarray:
        """Frame ``i``'s colour image, float32 (3, H, W) in [0, 1], or its grey (BT.601 luma) image
        (1, H, W) when ``gray``."""
        path = self.rgb_files[self._check(i)]
        rgb = read_rgb(path)
        if rgb.shape[1:] != (self.height, self.width):
            raise DatasetError(f"{path}: image is {rgb.shape[2]}x{rgb.shape[1]}, "
                               f"the sequence's first image is {self.width}x{self.height}")
        return _to_gray(rgb) if gray else rgb

    def depth(self, i: int) -> np.ndarray:
        """Frame ``i``'s depth, float32 (1, H, W) metres (0 = no depth)."""
        path = self.depth_files[self._check(i)]
        d = read_depth(path, self.depth_scale)
        if d.shape[1:] != (self.height, self.width):
            raise DatasetError(f"{path}: depth image is {d.shape[2]}x{d.shape[1]}, "
                               f"the colour images are {self.width}x{self.height}")
        return d

    def check_files(self, n: int | None = None) -> None:
        """Check the first ``n`` frames' image files (default: all) without decoding them: each
        exists and can be opened, has a colour / 16-bit depth format and the sequence's size.
        Raises DatasetError naming the first bad file, so that a long run does not stop at it
        (Pillow reads only the headers: ~0.1 ms per file)."""
        for k in range(len(self) if n is None else min(n, len(self))):
            for path, what, check in ((self.rgb_files[k], "colour", _check_rgb_mode),
                                      (self.depth_files[k], "depth", _check_depth_mode)):
                with _open_image(path, what, load=False) as im:
                    mode, size = im.mode, im.size
                check(path, mode)
                if size != (self.width, self.height):
                    raise DatasetError(f"{path}: {what} image is {size[0]}x{size[1]}, the sequence's first image is "
                                       f"{self.width}x{self.height}")

    def pose(self, i: int) -> np.ndarray | None:
        """Frame ``i``'s ground-truth ``T_world_cam`` (4, 4), or None if it has none."""
        i = self._check(i)
        if self.gt_poses is None or not self.gt_valid[i]:
            return None
        return self.gt_poses[i].copy()

    def frame(self, i: int, gray: bool = False) -> Frame:
        i = self._check(i)
        return Frame(i, float(self.timestamps[i]), self.image(i, gray), self.depth(i), self.pose(i))

    def __getitem__(self, i: int) -> Frame:
        return self.frame(i)


def read_tum(
    root: str | Path,
    *,
    intrinsics: str | np.ndarray | tuple | list | None = None,
    depth_scale: float = DEFAULT_DEPTH_SCALE,
    max_difference: float = DEFAULT_MAX_DIFFERENCE,
) -> TUMSequence:
    """Open a TUM RGB-D / ICL-NUIM style folder (see the module docstring for the rules).

    Args:
        root: the folder with ``rgb.txt`` and ``depth.txt``.
        intrinsics: a preset name (``fr1``, ``fr2``, ``fr3``, ``icl``; fr1 and fr2 with their
            published distortion, :data:`DISTORTION_PRESETS`), ``(fx, fy, cx, cy)``, ``(fx, fy,
            cx, cy, k1, k2, p1, p2, k3)`` (with radial-tangential distortion) or a (3, 3) ``K``;
            overrides ``intrinsics.txt``. None: ``root/intrinsics.txt`` if present, else the
            Freiburg preset named by the folder (``rgbd_dataset_freiburg2_*`` -> fr2), else an
            error. The result's ``K`` and ``dist`` (None for a pinhole) come from it.
        depth_scale: raw depth units per metre (5000 for TUM and ICL-NUIM).
        max_difference: seconds; colour/depth association and ground-truth matching.

    Only the first colour image is opened here (for the size); the others when read.
    """
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"{root}: not a directory" if root.exists() else f"{root}: no such directory")
    if not (math.isfinite(depth_scale) and depth_scale > 0):
        raise ValueError(f"read_tum: depth_scale must be a positive number, got {depth_scale}")
    if not (math.isfinite(max_difference) and max_difference > 0):
        raise ValueError(f"read_tum: max_difference must be a positive number, got {max_difference}")

    rgb_times, rgb_rows, _ = _read_table(root / "rgb.txt", 2, "colour list")
    depth_times, depth_rows, _ = _read_table(root / "depth.txt", 2, "depth list")
    pairs = associate(rgb_times, depth_times, max_difference)
    if pairs.shape[0] == 0:
        raise DatasetError(f"{root / 'depth.txt'}: no depth timestamp within {max_difference} s "
                           f"of any colour timestamp in {root / 'rgb.txt'}")
    rgb_files = [root / rgb_rows[i][0] for i in pairs[:, 0]]
    depth_files = [root / depth_rows[j][0] for j in pairs[:, 1]]
    first = read_rgb(rgb_files[0])
    height, width = first.shape[1:]

    K, source, dist = _resolve_intrinsics(root, intrinsics, width, height)
    seq = TUMSequence(
        root=root, K=K, intrinsics_source=source, width=width, height=height, dist=dist,
        timestamps=rgb_times[pairs[:, 0]], depth_timestamps=depth_times[pairs[:, 1]],
        rgb_files=rgb_files, depth_files=depth_files, depth_scale=float(depth_scale),
    )
    gt_path = root / "groundtruth.txt"
    if gt_path.exists():
        seq.gt_timestamps, seq.gt_raw_poses = read_trajectory(gt_path)
        seq.gt_poses, seq.gt_valid = _interpolate_poses(seq.gt_timestamps, seq.gt_raw_poses, seq.timestamps,
                                                        max_difference)
    return seq


def _resolve_intrinsics(root: Path, intrinsics, width: int, height: int):
    """(K, source, dist or None)."""
    scaled = "" if (width, height) == (640, 480) else f", scaled from 640x480 to {width}x{height}"
    if isinstance(intrinsics, str):
        if intrinsics not in INTRINSICS_PRESETS:
            raise ValueError(f"read_tum: unknown intrinsics preset {intrinsics!r}; "
                             f"expected one of {', '.join(INTRINSICS_PRESETS)} or fx,fy,cx,cy")
        return intrinsics_preset(intrinsics, width, height), f"preset {intrinsics}{scaled}", _preset_dist(intrinsics)
    if intrinsics is not None:
        arr = np.asarray(intrinsics, dtype=np.float64)
        if arr.shape == (3, 3):
            return _k_from_values((arr[0, 0], arr[1, 1], arr[0, 2], arr[1, 2]), "read_tum"), "given", None
        if arr.shape == (4,):
            return _k_from_values(arr, "read_tum"), "given", None
        if arr.shape == (9,):
            return _k_from_values(arr[:4], "read_tum"), "given", _dist_from_values(arr[4:], "read_tum")
        raise ValueError(f"read_tum: intrinsics must be a preset name, (fx, fy, cx, cy), (fx, fy, cx, cy, k1, k2, "
                         f"p1, p2, k3) or a (3, 3) K, got shape {arr.shape}")
    path = root / "intrinsics.txt"
    if path.exists():
        K, dist = _read_intrinsics_file(path)
        return K, str(path), dist
    preset = _preset_from_name(root)
    if preset is not None:
        return (intrinsics_preset(preset, width, height), f"preset {preset} (from the folder name{scaled})",
                _preset_dist(preset))
    raise DatasetError(f"{path}: missing; give intrinsics ({', '.join(INTRINSICS_PRESETS)} or fx,fy,cx,cy)")


def _preset_dist(name: str) -> np.ndarray | None:
    d = DISTORTION_PRESETS.get(name)
    return None if d is None else np.array(d, dtype=np.float64)


# ------------------------------------------------------------------------------------------------
# Writing sequences


class TUMWriter:
    """Write an RGB-D sequence as a TUM folder, frame by frame.

    ``root/rgb/<stamp>.png`` (8-bit RGB), ``root/depth/<stamp>.png`` (16-bit, metres *
    ``depth_scale`` rounded; depths that are not finite, not positive, or beyond 65535 /
    ``depth_scale`` metres are written as 0 = no depth), and on :meth:`close` (or leaving a
    ``with`` block without an error) ``rgb.txt``, ``depth.txt``, ``groundtruth.txt`` (if poses
    were given) and ``intrinsics.txt`` (with ``dist``, the images' radial-tangential
    coefficients (k1, k2, p1, p2, k3), after fx fy cx cy).
    """

    def __init__(self, root: str | Path, K: np.ndarray, depth_scale: float = DEFAULT_DEPTH_SCALE,
                 comment: str = "written by gvnn_warp.datasets.tum.TUMWriter", dist=None):
        self.root = Path(root)
        self.K = np.asarray(K, dtype=np.float64)
        self.dist = None if dist is None else np.asarray(dist, dtype=np.float64).reshape(5)
        self.depth_scale = float(depth_scale)
        self.comment = comment
        self._stamps: list[float] = []
        self._poses: list[np.ndarray] = []
        (self.root / "rgb").mkdir(parents=True, exist_ok=True)
        (self.root / "depth").mkdir(parents=True, exist_ok=True)

    def add(self, timestamp: float, image: np.ndarray, depth: np.ndarray, pose: np.ndarray | None = None) -> None:
        """Write one frame: ``image`` float (3, H, W) in [0, 1], ``depth`` (1, H, W) or (H, W) metres,
        ``pose`` ``T_world_cam`` (4, 4) (give it for all frames or none)."""
        from PIL import Image

        image = np.asarray(image)
        depth = np.asarray(depth, dtype=np.float64).reshape(image.shape[1:])
        rgb8 = np.clip(np.rint(image.transpose(1, 2, 0) * 255.0), 0, 255).astype(np.uint8)
        raw = depth * self.depth_scale
        raw = np.where(np.isfinite(raw) & (raw > 0) & (raw <= 65535.0), np.rint(np.nan_to_num(raw)), 0.0)
        name = f"{timestamp:.6f}.png"
        Image.fromarray(np.ascontiguousarray(rgb8)).save(self.root / "rgb" / name, compress_level=1)
        Image.fromarray(raw.astype(np.uint16)).save(self.root / "depth" / name, compress_level=1)
        self._stamps.append(float(timestamp))
        if pose is not None:
            self._poses.append(np.asarray(pose, dtype=np.float64))

    def close(self) -> None:
        if self._poses and len(self._poses) != len(self._stamps):
            raise ValueError("TUMWriter: give a pose for every frame or for none")
        names = [f"{t:.6f}" for t in self._stamps]
        for kind in ("rgb", "depth"):
            lines = [f"# {self.comment}", f"# {kind} images", "# timestamp filename"]
            lines += [f"{n} {kind}/{n}.png" for n in names]
            (self.root / f"{kind}.txt").write_text("\n".join(lines) + "\n")
        if self._poses:
            write_trajectory(self.root / "groundtruth.txt", np.array(self._stamps), np.stack(self._poses),
                             comment=f"{self.comment}\nground-truth trajectory T_world_cam")
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        if self.dist is None:
            (self.root / "intrinsics.txt").write_text(f"# fx fy cx cy (pixel centres at integer coordinates)\n"
                                                      f"{fx:.9g} {fy:.9g} {cx:.9g} {cy:.9g}\n")
        else:
            k = " ".join(f"{v:.9g}" for v in self.dist)
            (self.root / "intrinsics.txt").write_text(
                "# fx fy cx cy k1 k2 p1 p2 k3 (pixel centres at integer coordinates; radial-tangential distortion)\n"
                f"{fx:.9g} {fy:.9g} {cx:.9g} {cy:.9g} {k}\n")

    def __enter__(self) -> TUMWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
