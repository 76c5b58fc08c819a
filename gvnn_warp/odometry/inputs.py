"""The aligner's arguments: numpy arrays or CPU torch tensors as numpy views, numbers, cameras and
initial poses, checked with one-line errors that name the method and the argument.

Import needs no torch; torch is imported only when a tensor comes in.
"""

from __future__ import annotations

import math
import numbers
import warnings

import numpy as np

from ..kernels.geometry import lens as _lens

__all__ = [
    "INTENSITY_LIMIT", "as_numpy", "colour_values", "dist_array", "fail", "initial_pose", "is_torch", "lens_camera",
    "real_number", "rigid_pose",
]

INTENSITY_LIMIT = 1.5  # above this an image is taken for [0, 255] intensities (warned once per aligner or volume)

MIN_SIDE = 4  # smallest side (pixels) of an image the aligner takes, and of a pyramid level
RIGID_TOLERANCE = 1e-3  # an init's |R^T R - I| and last-row deviation (chained float32 poses: ~1e-6)


def fail(fn: str, exc: type[Exception], msg: str):
    """Raise ``exc`` naming the method: ``fn`` relative to gvnn_warp.odometry, or a full name."""
    raise exc(f"{fn if fn.startswith('gvnn_warp.') else 'gvnn_warp.odometry.' + fn}: {msg}")


def real_number(v) -> float:
    """``v`` as a float if it is a real number (Python, numpy, or a one-element numpy array or torch
    tensor), else NaN (which every range check refuses)."""
    if (isinstance(v, np.ndarray) and v.size == 1) or (hasattr(v, "numel") and callable(v.numel) and v.numel() == 1):
        v = v.item()
    return float(v) if isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_)) else math.nan


def is_torch(x) -> bool:
    return type(x).__module__.split(".")[0] == "torch"


def _integer_hint(name: str, integer: bool) -> str:
    """What to do with integer pixels (an image or depth as read from a PNG), for an error message."""
    if not integer:
        return ""
    if "depth" in name:
        return " (depth in metres: divide a depth PNG's values by its depth scale, 5000 in TUM RGB-D)"
    if any(word in name for word in ("image", "rgb", "colour", "color", "gray", "grey")):
        return " (images in [0, 1]: divide 8-bit ones by 255)"
    return ""


def as_numpy(fn: str, name: str, x, ndims: tuple[int, ...]) -> np.ndarray:
    """numpy float32/float64 view of a numpy array or CPU torch tensor with one of ``ndims``."""
    if is_torch(x):
        import torch  # (only when a tensor comes in: the odometry never needs torch otherwise)

        if not isinstance(x, torch.Tensor):
            fail(fn, TypeError, f"argument '{name}' must be a numpy array or torch tensor, got {type(x).__name__}")
        if x.device.type != "cpu":
            fail(fn, ValueError, f"argument '{name}' must be on the CPU, got device {x.device}")
        if x.dtype not in (torch.float32, torch.float64):
            hint = _integer_hint(name, not (x.dtype.is_floating_point or x.dtype.is_complex or x.dtype == torch.bool))
            fail(fn, TypeError, f"argument '{name}' must be float32 or float64, got {x.dtype}{hint}")
        x = x.detach().numpy()
    elif not isinstance(x, np.ndarray):
        fail(fn, TypeError, f"argument '{name}' must be a numpy array or torch tensor, got {type(x).__name__}")
    elif x.dtype not in (np.float32, np.float64):
        hint = _integer_hint(name, np.issubdtype(x.dtype, np.integer))
        fail(fn, TypeError, f"argument '{name}' must be float32 or float64, got {x.dtype}{hint}")
    if x.ndim not in ndims:
        want = " or ".join(f"{d}-D" for d in ndims)
        fail(fn, ValueError, f"argument '{name}' must be {want}, got shape {tuple(x.shape)}")
    return x


def dist_array(fn: str, name: str, dist) -> np.ndarray | None:
    """Distortion coefficients as a float64 numpy array (a list, tuple, numpy array or CPU torch
    tensor of one dimension; None stays None); their number and values are the caller's to check."""
    if dist is None:
        return None
    if isinstance(dist, (list, tuple)):
        dist = np.asarray(dist, dtype=np.float64)
    return as_numpy(fn, name, dist, (1,)).astype(np.float64)


def lens_camera(fn: str, K, model, dist, name: str = "K"):
    """(K (3, 3) float64, model name, packed dist (8,) float64 or None for the pinhole) from K and
    the ``model`` / ``dist`` arguments, or from a camera of ``gvnn_warp.cameras``; ``name``: the
    argument's name in the caller's errors."""
    if hasattr(K, "model") and hasattr(K, "K") and hasattr(K, "dist") and not isinstance(K, np.ndarray):
        if model is not None or dist is not None:
            fail(fn, ValueError, "arguments 'model' and 'dist' must not be given with a camera object")
        cam = K
        if cam.K.dim() != 2 or (cam.dist is not None and cam.dist.dim() != 1):
            fail(fn, ValueError, f"argument '{name}' must be an unbatched camera (K (3, 3), dist (n,))")
        model = {v: k for k, v in _lens.MODEL_IDS.items()}[int(cam.model)]
        K, dist = cam.K, cam.dist
    # (whole-pixel intrinsics written as integers: exact as floats)
    if is_torch(K) and str(K.dtype).startswith(("torch.int", "torch.uint")):
        K = K.double()
    elif isinstance(K, np.ndarray) and np.issubdtype(K.dtype, np.integer):
        K = K.astype(np.float64)
    K = as_numpy(fn, name, K, (2,)).astype(np.float64)
    if model is None:
        model = "pinhole" if dist is None else "radtan"
    if model not in _lens.MODEL_IDS:
        fail(fn, ValueError, f"argument 'model' must be one of {list(_lens.MODEL_IDS)}, got {model!r}")
    mid = _lens.MODEL_IDS[model]
    if mid == _lens.PINHOLE:
        if dist is not None:
            fail(fn, ValueError, "argument 'dist' must be None for the pinhole model")
        return K, model, None
    n = _lens.N_COEFFS[mid]
    coeffs = dist_array(fn, "dist", dist)
    if coeffs is None or coeffs.shape != (n,) or not np.all(np.isfinite(coeffs)):
        got = None if coeffs is None else coeffs.tolist()
        fail(fn, ValueError, f"argument 'dist' must be {n} finite coefficients for the {model} model, got {got}")
    return K, model, _lens.pack_dist(mid, coeffs)


def initial_pose(fn: str, init, B: int, batched: bool) -> np.ndarray:
    """(B, 4, 4) float64 starting poses from ``init`` ((4, 4) / (B, 4, 4), or 3x4 rows [R | t]), a
    rigid transform each; the identity for None."""
    if init is None:
        return np.broadcast_to(np.eye(4), (B, 4, 4)).copy()
    T = as_numpy(fn, "init", init, (3,) if batched else (2,)).astype(np.float64)
    if not batched:
        T = T[None]
    if T.shape[0] != B or T.shape[1:] not in ((4, 4), (3, 4)):
        want = f"({B}, 4, 4)" if batched else "(4, 4)"
        fail(fn, ValueError, f"argument 'init' must have shape {want} (or 3x4 rows), got {tuple(np.shape(init))}")
    if not np.all(np.isfinite(T)):
        fail(fn, ValueError, "argument 'init' must be finite")
    R = T[:, :3, :3]
    off = np.abs(np.einsum("bji,bjk->bik", R, R) - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((off > RIGID_TOLERANCE) | (np.linalg.det(R) < 0))
    if T.shape[1] == 4:
        bad = np.union1d(bad, np.flatnonzero(np.abs(T[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) > RIGID_TOLERANCE))
    if bad.size:
        b = int(bad[0])
        fail(fn, ValueError, f"argument 'init' must be rigid transforms [R | t] (R a rotation: R^T R = I within "
                             f"{RIGID_TOLERANCE:g}, det +1; a 4x4's last row 0 0 0 1), but "
                             f"{'item ' + str(b) if batched else 'it'} is not: "
                             f"{np.array2string(T[b], precision=4, separator=', ').replace(chr(10), '')}")
    out = np.broadcast_to(np.eye(4), (B, 4, 4)).copy()
    out[:, :3, :] = T[:, :3, :]
    return out


def rigid_pose(fn: str, name: str, T) -> np.ndarray:
    """Argument ``name`` of function ``fn`` (its full name) as a float64 (4, 4) rigid transform
    (``T_world_cam``): finite, an orthonormal rotation, last row 0 0 0 1; ValueError otherwise."""
    T = as_numpy(fn, name, T, (2,)).astype(np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        fail(fn, ValueError, f"argument '{name}' must be a finite (4, 4) pose, got shape {T.shape}")
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-3 or np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-6:
        fail(fn, ValueError, f"argument '{name}' must be a rigid transform (orthonormal rotation, last row 0 0 0 1)")
    return T


def colour_values(fn: str, name: str, c: np.ndarray, warned: set, consequence: str = "") -> np.ndarray:
    """Colour image ``c`` (C, H, W) with NaN and infinite values taken as 0 (black: what is made of it
    stays finite; a copy, the input untouched), warning once each, as recorded in ``warned``, about
    those and about values beyond [0, 1] (8-bit ones; ``consequence`` ends that warning)."""
    finite = np.isfinite(c)
    if not finite.all():
        c = np.where(finite, c, 0.0).astype(c.dtype)
        if "non-finite" not in warned:
            warned.add("non-finite")
            warnings.warn(f"{fn}: argument '{name}' has NaN or infinite values; they are taken as 0 (black)",
                          UserWarning, stacklevel=3)
    top = float(np.max(c[..., ::7, ::7], initial=0.0))  # (1/49 of the pixels: cheap beside the caller's work)
    if top > INTENSITY_LIMIT and "8-bit" not in warned:
        warned.add("8-bit")
        warnings.warn(f"{fn}: argument '{name}' has values up to {top:g}; colours are expected in [0, 1] (divide "
                      f"8-bit images by 255){consequence}", UserWarning, stacklevel=3)
    return c
