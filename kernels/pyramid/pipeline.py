"""The pyramid's host functions on ``wp.array`` s (no torch): the base level, the next level, and
the shapes and intrinsics of every level (see the package docstring)."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..core.launch import launch
from .kernels import downsample_kernel, level0_kernel

#: default relative depth tolerance of the depth downsampling (see the package docstring)
DEPTH_TOLERANCE = 0.05


def pyramid_shapes(H: int, W: int, levels: int) -> list[tuple[int, int]]:
    """(H_l, W_l) of levels 0..levels-1: each level halves the previous one (``H // 2``)."""
    shapes = [(int(H), int(W))]
    for _ in range(1, levels):
        h, w = shapes[-1]
        shapes.append((h // 2, w // 2))
    return shapes


def scale_intrinsics(K: np.ndarray, level: int) -> np.ndarray:
    """Intrinsics (..., 3, 3) of pyramid level ``level`` (float64 numpy): ``fx, fy, s`` divided by
    ``2^level``, ``c' = (c + 0.5) / 2^level - 0.5`` (pixel centres at integers, see the package)."""
    K = np.array(K, dtype=np.float64)
    f = 0.5**level
    K[..., 0, 0] *= f
    K[..., 0, 1] *= f
    K[..., 1, 1] *= f
    K[..., 0, 2] = (K[..., 0, 2] + 0.5) * f - 0.5
    K[..., 1, 2] = (K[..., 1, 2] + 0.5) * f - 0.5
    return K


def _expect(fn: str, name: str, cond: bool, what: str, got, exc: type[Exception] = ValueError) -> None:
    if not cond:
        raise exc(f"gvnn_warp.kernels.pyramid.{fn}: argument '{name}' must be {what}, got {got}")


def _check_float(fn: str, name: str, a, ft=None) -> None:
    _expect(fn, name, isinstance(a, wp.array), "a wp.array", type(a).__name__, TypeError)
    ok = a.dtype in (wp.float32, wp.float64) if ft is None else a.dtype is ft
    want = "float32 or float64" if ft is None else ft.__name__
    _expect(fn, name, ok, f"of dtype {want}", getattr(a.dtype, "__name__", a.dtype), TypeError)
    _expect(fn, name, a.is_contiguous, "contiguous", "a strided array")


def prepare_level0(
    image: wp.array,
    weights: wp.array,
    depth: wp.array | None,
    out_image: wp.array,
    out_depth: wp.array | None,
    *,
    tolerance: float = DEPTH_TOLERANCE,
) -> None:
    """Write the base level of a pyramid: ``out_image[b, o] = sum_c weights[o, c] image[b, c]``
    and ``out_depth`` = ``depth`` cleaned (0 where missing or at a depth edge, with the relative
    ``tolerance`` >= 0, ``inf`` for no edge test), see the package docstring.

    image (B, C, H, W); weights (Co, C); depth and out_depth (B, 1, H, W) or both None;
    out_image (B, Co, H, W); one float type.
    """
    fn = "prepare_level0"
    _check_float(fn, "image", image)
    ft = image.dtype
    _expect(fn, "image", image.ndim == 4, "a 4-D (B, C, H, W) array", image.shape)
    B, C, H, W = image.shape
    _check_float(fn, "weights", weights, ft)
    _expect(fn, "weights", weights.ndim == 2 and weights.shape[1] == C, f"of shape (Co, {C})", weights.shape)
    Co = weights.shape[0]
    _check_float(fn, "out_image", out_image, ft)
    _expect(fn, "out_image", tuple(out_image.shape) == (B, Co, H, W), f"of shape {(B, Co, H, W)}", out_image.shape)
    _expect(fn, "out_depth", (depth is None) == (out_depth is None), "given exactly when depth is", out_depth)
    if depth is not None:
        for name, a in (("depth", depth), ("out_depth", out_depth)):
            _check_float(fn, name, a, ft)
            _expect(fn, name, tuple(a.shape) == (B, 1, H, W), f"of shape {(B, 1, H, W)}", a.shape)
    _expect(fn, "tolerance", tolerance >= 0.0, "a number >= 0 (inf: no edge test)", repr(tolerance))
    empty = out_image.flatten()[:0]
    launch(
        level0_kernel(C, Co)[ft],
        B * H,
        [image.flatten(), weights.flatten(), depth.flatten() if depth is not None else empty, H, W,
         int(depth is not None), float(tolerance)],
        [out_image.flatten(), out_depth.flatten() if out_depth is not None else empty],
    )


def downsample(
    image: wp.array,
    depth: wp.array | None,
    out_image: wp.array,
    out_depth: wp.array | None,
    *,
    tolerance: float = DEPTH_TOLERANCE,
) -> None:
    """Write the next pyramid level of ``image`` (and ``depth``) into ``out_image`` (``out_depth``),
    as described in the package docstring.

    image (B, C, H, W) -> out_image (B, C, H // 2, W // 2); depth (B, 1, H, W) -> out_depth
    (B, 1, H // 2, W // 2), or both None; one float type; ``tolerance`` >= 0.
    """
    fn = "downsample"
    _check_float(fn, "image", image)
    ft = image.dtype
    _expect(fn, "image", image.ndim == 4, "a 4-D (B, C, H, W) array", image.shape)
    B, C, H, W = image.shape
    Ho, Wo = H // 2, W // 2
    _expect(fn, "image", Ho >= 1 and Wo >= 1, "at least 2x2 pixels", image.shape)
    _check_float(fn, "out_image", out_image, ft)
    _expect(fn, "out_image", tuple(out_image.shape) == (B, C, Ho, Wo), f"of shape {(B, C, Ho, Wo)}", out_image.shape)
    _expect(fn, "out_depth", (depth is None) == (out_depth is None), "given exactly when depth is", out_depth)
    if depth is not None:
        _check_float(fn, "depth", depth, ft)
        _expect(fn, "depth", tuple(depth.shape) == (B, 1, H, W), f"of shape {(B, 1, H, W)}", depth.shape)
        _check_float(fn, "out_depth", out_depth, ft)
        _expect(fn, "out_depth", tuple(out_depth.shape) == (B, 1, Ho, Wo), f"of shape {(B, 1, Ho, Wo)}",
                out_depth.shape)
    _expect(fn, "tolerance", 0.0 <= tolerance < float("inf"), "a finite number >= 0", repr(tolerance))
    empty = out_image.flatten()[:0]
    launch(
        downsample_kernel(C)[ft],
        B * Ho,
        [image.flatten(), depth.flatten() if depth is not None else empty, H, W, Ho, Wo, float(tolerance),
         int(depth is not None)],
        [out_image.flatten(), out_depth.flatten() if out_depth is not None else empty],
    )
