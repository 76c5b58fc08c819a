"""TUM trajectory files and their quaternions, and the timestamps of a sequence: association and
interpolation (numpy only).

A trajectory file has one pose per line, ``timestamp tx ty tz qx qy qz qw`` (``#`` comments):
``T_world_cam``, metres, Hamilton quaternions (qx, qy, qz, qw) of the rotation of ``T_world_cam``
(docs/conventions.md). Timestamps are associated the way TUM's ``associate.py`` does and ground
truth is interpolated the way ``evo``'s ``SyncMethod.interpolation`` resamples a trajectory (the
rules: :mod:`gvnn_warp.datasets.tum`).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from .errors import DatasetError

__all__ = [
    "DEFAULT_MAX_DIFFERENCE",
    "associate",
    "interpolate_poses",
    "matrix_to_quaternion_xyzw",
    "quaternion_xyzw_to_matrix",
    "read_table",
    "read_trajectory",
    "write_trajectory",
]

#: Maximum time difference (s) for associating stamps, as TUM's associate.py and evaluate_ate.py.
DEFAULT_MAX_DIFFERENCE = 0.02


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


def read_table(path: Path, columns: int, what: str) -> tuple[np.ndarray, list[list[str]], list[int]]:
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
    stamps, rows, lines = read_table(path, 8, "trajectory")
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


def interpolate_poses(
    gt_times: np.ndarray, gt_poses: np.ndarray, times: np.ndarray, max_difference: float
) -> tuple[np.ndarray, np.ndarray]:
    """Ground-truth poses at ``times`` (the rule: :mod:`gvnn_warp.datasets.tum`): (poses (N, 4, 4)
    with NaN where invalid, valid (N,) bool). A time with no ground-truth stamp closer than
    ``max_difference`` is invalid; the others are interpolated between the two samples that bracket
    them (translation linearly, rotation by slerp), or take the nearest sample outside the range."""
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
