"""Image and depth pyramids for coarse-to-fine alignment (thin kernels and host functions, no torch).

Level ``l + 1`` halves level ``l``: output pixel ``(x', y')`` covers the 2x2 input pixels ``(2x' + i,
2y' + j)``, i, j in {0, 1}, so with the pixel-centre convention of ``docs/conventions.md`` a position
maps as ``x' = (x + 0.5) / 2 - 0.5`` and the intrinsics as ``fx' = fx / 2``, ``cx' = (cx + 0.5) / 2 -
0.5`` (:func:`scale_intrinsics`). Odd sizes drop the last row / column: ``H' = H // 2``.

- Intensities: the mean of the 2x2 block (per channel).
- Depths: 0, NaN, +-inf and negative values mean "no depth" and are written as 0. The output is the
  mean of the valid taps that lie on the nearest surface of the block, i.e. within a relative
  ``tolerance`` of the smallest valid depth (``d <= d_min (1 + tolerance)``); farther taps (the
  other side of a depth edge) are left out, so no depth is invented between a foreground and a
  background surface. A block with no valid tap gives 0.

:func:`prepare_level0` converts an input frame to the pyramid's base level: channels mixed by a
weight matrix (e.g. RGB to one intensity), depths cleaned as above; a non-finite intensity is read
as 0 and its pixel's depth becomes missing, so it is never used as a reference pixel.

Shapes: images (B, C, H, W), depths (B, 1, H, W), float32 or float64 (one type per call).
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import warp as wp

from .launch import FloatKernel, launch

wp.set_module_options({"enable_backward": False})

#: default relative depth tolerance of the depth downsampling (see the module docstring)
DEPTH_TOLERANCE = 0.05

__all__ = [
    "DEPTH_TOLERANCE",
    "downsample",
    "downsample_kernel",
    "level0_kernel",
    "prepare_level0",
    "pyramid_shapes",
    "scale_intrinsics",
]


@wp.func
def _clean_depth(d: Any):
    """d if it is a finite positive depth, else 0 (NaN fails both comparisons)."""
    r = type(d)(0.0)
    if d > type(d)(0.0) and d < type(d)(3.0e38):
        r = d
    return r


@wp.func
def _tap_sum(d: Any, limit: Any, s: Any):
    """s + d if d is a valid depth within ``limit`` (else s)."""
    r = s
    if d > type(d)(0.0) and d <= limit:
        r = s + d
    return r


@wp.func
def _tap_count(d: Any, limit: Any, n: Any):
    r = n
    if d > type(d)(0.0) and d <= limit:
        r = n + type(d)(1.0)
    return r


def _make_level0(C: int, Co: int):
    """The base-level kernel for C input and Co output channels (loops over constants: unrolled)."""

    def level0(
        offset: int,
        image: wp.array(dtype=Any),
        weights: wp.array(dtype=Any),
        depth: wp.array(dtype=Any),
        HW: int,
        has_depth: int,
        out_image: wp.array(dtype=Any),
        out_depth: wp.array(dtype=Any),
    ):
        i = wp.tid() + offset  # flat (b, pixel)
        b = i // HW
        p = i - b * HW
        finite = bool(True)  # noqa: UP018 - a typed variable Warp may reassign inside the loop
        for co in range(Co):
            v = out_image.dtype(0.0)
            for c in range(C):
                v += weights[co * C + c] * image[(b * C + c) * HW + p]
            if not wp.isfinite(v):
                v = out_image.dtype(0.0)
                finite = False
            out_image[(b * Co + co) * HW + p] = v
        if has_depth != 0:
            d = _clean_depth(depth[i])
            out_depth[i] = wp.where(finite, d, type(d)(0.0))

    kernel = wp.kernel(level0, module="unique", enable_backward=False)
    # Forward-only: every element writes its own output pixel(s). The image and weights are read at
    # other indices (every channel), so their adjoint scope would be "any" (no adjoint is built).
    return FloatKernel(
        kernel, image="scalar", weights="scalar", depth="scalar", out_image="scalar", out_depth="scalar"
    ).set_parallel(scopes={"image": "any", "weights": "any", "depth": "element"})


def _make_downsample(C: int):
    """The 2x2 downsampling kernel for C channels (see the module docstring)."""

    def downsample(
        offset: int,
        image: wp.array(dtype=Any),
        depth: wp.array(dtype=Any),
        H: int,
        W: int,
        Ho: int,
        Wo: int,
        tolerance: float,
        has_depth: int,
        out_image: wp.array(dtype=Any),
        out_depth: wp.array(dtype=Any),
    ):
        i = wp.tid() + offset  # flat (b, y', x') of the output
        HWo = Ho * Wo
        b = i // HWo
        r = i - b * HWo
        yo = r // Wo
        xo = r - yo * Wo
        p = (2 * yo) * W + 2 * xo  # top-left tap in its plane
        HW = H * W
        quarter = out_image.dtype(0.25)
        for c in range(C):
            base = (b * C + c) * HW + p
            block = image[base] + image[base + 1] + image[base + W] + image[base + W + 1]
            out_image[(b * C + c) * HWo + r] = quarter * block
        if has_depth != 0:
            base = b * HW + p
            d0 = _clean_depth(depth[base])
            d1 = _clean_depth(depth[base + 1])
            d2 = _clean_depth(depth[base + W])
            d3 = _clean_depth(depth[base + W + 1])
            dmin = type(d0)(3.0e38)
            if d0 > type(d0)(0.0):
                dmin = d0
            if d1 > type(d0)(0.0) and d1 < dmin:
                dmin = d1
            if d2 > type(d0)(0.0) and d2 < dmin:
                dmin = d2
            if d3 > type(d0)(0.0) and d3 < dmin:
                dmin = d3
            limit = dmin * (type(d0)(1.0) + type(d0)(tolerance))
            zero = type(d0)(0.0)
            s = _tap_sum(d3, limit, _tap_sum(d2, limit, _tap_sum(d1, limit, _tap_sum(d0, limit, zero))))
            n = _tap_count(d3, limit, _tap_count(d2, limit, _tap_count(d1, limit, _tap_count(d0, limit, zero))))
            out = zero
            if n > zero:
                out = s / n
            out_depth[i] = out

    kernel = wp.kernel(downsample, module="unique", enable_backward=False)
    # Forward-only: every element writes its own output pixel; inputs are read at 2x2 blocks ("any").
    return FloatKernel(kernel, image="scalar", depth="scalar", out_image="scalar", out_depth="scalar").set_parallel(
        scopes={"image": "any", "depth": "any"}
    )


_KERNELS: dict[tuple, FloatKernel] = {}
_KERNELS_LOCK = threading.Lock()


def level0_kernel(C: int, Co: int) -> FloatKernel:
    """The (cached) base-level kernel for C input and Co output channels; its arguments: (offset,
    image, weights, depth, HW, has_depth, out_image, out_depth), flat arrays."""
    with _KERNELS_LOCK:
        k = _KERNELS.get(("level0", C, Co))
        if k is None:
            k = _KERNELS["level0", C, Co] = _make_level0(C, Co)
        return k


def downsample_kernel(C: int) -> FloatKernel:
    """The (cached) downsampling kernel for C channels; its arguments: (offset, image, depth, H, W,
    Ho, Wo, tolerance, has_depth, out_image, out_depth), flat arrays."""
    with _KERNELS_LOCK:
        k = _KERNELS.get(("down", C))
        if k is None:
            k = _KERNELS["down", C] = _make_downsample(C)
        return k


def pyramid_shapes(H: int, W: int, levels: int) -> list[tuple[int, int]]:
    """(H_l, W_l) of levels 0..levels-1: each level halves the previous one (``H // 2``)."""
    shapes = [(int(H), int(W))]
    for _ in range(1, levels):
        h, w = shapes[-1]
        shapes.append((h // 2, w // 2))
    return shapes


def scale_intrinsics(K: np.ndarray, level: int) -> np.ndarray:
    """Intrinsics (..., 3, 3) of pyramid level ``level`` (float64 numpy): ``fx, fy, s`` divided by
    ``2^level``, ``c' = (c + 0.5) / 2^level - 0.5`` (pixel centres at integers, see the module)."""
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
) -> None:
    """Write the base level of a pyramid: ``out_image[b, o] = sum_c weights[o, c] image[b, c]``
    and ``out_depth`` = ``depth`` cleaned (0 where missing), see the module docstring.

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
    empty = out_image.flatten()[:0]
    launch(
        level0_kernel(C, Co)[ft],
        B * H * W,
        [image.flatten(), weights.flatten(), depth.flatten() if depth is not None else empty, H * W,
         int(depth is not None)],
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
    as described in the module docstring.

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
        B * Ho * Wo,
        [image.flatten(), depth.flatten() if depth is not None else empty, H, W, Ho, Wo, float(tolerance),
         int(depth is not None)],
        [out_image.flatten(), out_depth.flatten() if out_depth is not None else empty],
    )
