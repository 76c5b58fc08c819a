"""Camera intrinsics of TUM-format sequences: the published presets, ``intrinsics.txt`` files, and
the rule that picks a sequence's (numpy only).

``intrinsics.txt`` (not part of TUM's own format) holds one line ``fx fy cx cy`` for a pinhole, or
``fx fy cx cy k1 k2 p1 p2 k3`` with the radial-tangential distortion of OpenCV's model when the
images are distorted; ``#`` lines are comments.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from .errors import DatasetError

__all__ = ["DISTORTION_PRESETS", "INTRINSICS_PRESETS", "intrinsics_preset", "resolve_intrinsics"]

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


def resolve_intrinsics(root: Path, intrinsics, width: int, height: int):
    """(K, source, dist or None, override) of a sequence folder ``root`` of ``width`` x ``height``
    images, from ``intrinsics`` (see :func:`gvnn_warp.datasets.tum.read_tum`), else
    ``root/intrinsics.txt``, else the Freiburg preset named by the folder. ``override``: None, or,
    when given intrinsics replace the folder's ``intrinsics.txt``, a sentence saying so and whether
    the two differ (a warning for the user: the wrong camera costs far more than a wrong option)."""
    K, source, dist = _resolve(root, intrinsics, width, height)
    path = root / "intrinsics.txt"
    override = None
    if intrinsics is not None and path.exists():
        try:
            K_file, dist_file = _read_intrinsics_file(path)
        except DatasetError:
            return K, source, dist, f"the intrinsics given replace {path}, which cannot be read"
        same = np.allclose(K, K_file, rtol=1e-6, atol=1e-9) and (
            (dist is None and dist_file is None) or (dist is not None and dist_file is not None
                                                     and np.allclose(dist, dist_file, rtol=1e-6, atol=1e-12)))
        if same:
            override = f"the intrinsics given replace {path}, which has the same values"
        else:
            def text(K_, d_):
                return (f"fx {K_[0, 0]:g} fy {K_[1, 1]:g} cx {K_[0, 2]:g} cy {K_[1, 2]:g}"
                        + ("" if d_ is None else " with radial-tangential distortion"))
            override = (f"the intrinsics given ({text(K, dist)}) replace {path}, which differs "
                        f"({text(K_file, dist_file)}): check that they are this camera's")
    return K, source, dist, override


def _resolve(root: Path, intrinsics, width: int, height: int):
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
