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
as 0 and its pixel's depth becomes missing, so it is never used as a reference pixel. A depth that
differs from a valid 4-neighbour's by more than the relative ``tolerance`` (``|d - e| > tolerance
min(d, e)``: the two lie on different surfaces) is written as 0 too, on both sides of such a depth
edge: there a pixel's colour mixes both surfaces (anti-aliasing, blur, the sensor's footprint) while
its depth is one of them, so it moves inconsistently between views. Used as reference pixels, the
mixed pixels at the top edges of objects standing in front of a background biased the photometric
optimum (issue 15: +0.004 cm in y per pair at 640x480 with the occlusion test, removed by this);
used as live depths, they fail the occlusion test of samples next to an edge. The coarser levels
inherit the gaps through the downsampling.

Shapes: images (B, C, H, W), depths (B, 1, H, W), float32 or float64 (one type per call).
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import warp as wp

from .core import lanes
from .core.kinds import LANES_MODULE_OPTIONS
from .core.launch import FloatKernel, launch

wp.set_module_options({"enable_backward": False})

#: default relative depth tolerance of the depth downsampling (see the module docstring)
DEPTH_TOLERANCE = 0.05

__all__ = [
    "DEPTH_TOLERANCE",
    "downsample",
    "downsample_kernel",
    "downsample_lanes_kernel",
    "level0_kernel",
    "level0_lanes_kernel",
    "prepare_level0",
    "pyramid_shapes",
    "scale_intrinsics",
]


@wp.func
def _valid_depth(d: Any):
    """d is a finite positive depth (NaN fails both comparisons)."""
    return d > type(d)(0.0) and d < type(d)(3.0e38)


@wp.func
def _depth_jump(d: Any, e: Any, inside: bool, tolerance: Any):
    """A valid neighbour depth ``e`` (``inside`` the image) more than ``tolerance`` (relative) from ``d``."""
    return inside and _valid_depth(e) and wp.abs(d - e) > tolerance * wp.min(d, e)


@wp.func
def _at_depth_edge(depth: wp.array(dtype=Any), q: int, x: int, y: int, H: int, W: int, tolerance: Any):
    """Pixel ``q`` (at ``x, y`` of an H x W image) has a depth edge to a 4-neighbour (indices clamped
    into the image; outside ones ignored)."""
    d = depth[q]
    return (
        _depth_jump(d, depth[q - wp.where(x > 0, 1, 0)], x > 0, tolerance)
        or _depth_jump(d, depth[q + wp.where(x < W - 1, 1, 0)], x < W - 1, tolerance)
        or _depth_jump(d, depth[q - wp.where(y > 0, W, 0)], y > 0, tolerance)
        or _depth_jump(d, depth[q + wp.where(y < H - 1, W, 0)], y < H - 1, tolerance)
    )


@wp.func
def _block_depth(d0: Any, d1: Any, d2: Any, d3: Any, tolerance: Any):
    """The downsampled depth of a 2x2 block (see the module docstring), branch-free."""
    zero = type(d0)(0.0)
    one = type(d0)(1.0)
    big = type(d0)(3.0e38)
    v0 = _valid_depth(d0)
    v1 = _valid_depth(d1)
    v2 = _valid_depth(d2)
    v3 = _valid_depth(d3)
    e0 = wp.where(v0, d0, big)
    e1 = wp.where(v1, d1, big)
    e2 = wp.where(v2, d2, big)
    e3 = wp.where(v3, d3, big)
    limit = wp.min(wp.min(e0, e1), wp.min(e2, e3)) * (one + tolerance)
    n0 = wp.where(v0 and e0 <= limit, one, zero)
    n1 = wp.where(v1 and e1 <= limit, one, zero)
    n2 = wp.where(v2 and e2 <= limit, one, zero)
    n3 = wp.where(v3 and e3 <= limit, one, zero)
    n = n0 + n1 + n2 + n3
    s = n0 * wp.where(v0, d0, zero) + n1 * wp.where(v1, d1, zero) + n2 * wp.where(v2, d2, zero)
    s = s + n3 * wp.where(v3, d3, zero)
    return wp.where(n > zero, s / wp.max(n, one), zero)


# Kernels are row-blocked: element k is the image row k (b = k // H, y = k % H) and loops over its
# pixels, which amortises Warp's per-element cost on the CPU (a launch calls the kernel function
# once per element) and keeps the inner loop's index arithmetic trivial.


def _make_level0(C: int, Co: int):
    """The base-level kernel for C input and Co output channels (loops over constants: unrolled)."""

    def level0(
        offset: int,
        image: wp.array(dtype=Any),
        weights: wp.array(dtype=Any),
        depth: wp.array(dtype=Any),
        H: int,
        W: int,
        has_depth: int,
        tolerance: float,
        out_image: wp.array(dtype=Any),
        out_depth: wp.array(dtype=Any),
    ):
        row = wp.tid() + offset  # flat (b, y)
        b = row // H
        y = row - b * H
        HW = H * W
        p0 = y * W
        tol = out_image.dtype(tolerance)
        for x in range(W):
            p = p0 + x
            finite = bool(True)  # noqa: UP018 - a typed variable Warp may reassign inside the loop
            for co in range(Co):
                v = out_image.dtype(0.0)
                for c in range(C):
                    v += weights[co * C + c] * image[(b * C + c) * HW + p]
                ok = wp.isfinite(v)
                finite = finite and ok
                out_image[(b * Co + co) * HW + p] = wp.where(ok, v, out_image.dtype(0.0))
            if has_depth != 0:
                q = b * HW + p
                d = depth[q]
                edge = _at_depth_edge(depth, q, x, y, H, W, tol)
                out_depth[q] = wp.where(finite and _valid_depth(d) and not edge, d, type(d)(0.0))

    kernel = wp.kernel(level0, module="unique", enable_backward=False)
    # Forward-only: every element writes its own row's output pixels. Inputs are read at other
    # indices (every channel, a whole row), so their adjoint scope would be "any" (no adjoint is built).
    return FloatKernel(
        kernel, image="scalar", weights="scalar", depth="scalar", out_image="scalar", out_depth="scalar"
    ).set_parallel(scopes={"image": "any", "weights": "any", "depth": "any"}, grain=_row_grain)


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
        row = wp.tid() + offset  # flat (b, y') of the output
        b = row // Ho
        yo = row - b * Ho
        HW = H * W
        HWo = Ho * Wo
        quarter = out_image.dtype(0.25)
        for c in range(C):
            src = (b * C + c) * HW + 2 * yo * W
            dst = (b * C + c) * HWo + yo * Wo
            for xo in range(Wo):
                p = src + 2 * xo
                out_image[dst + xo] = quarter * (image[p] + image[p + 1] + image[p + W] + image[p + W + 1])
        if has_depth != 0:
            src = b * HW + 2 * yo * W
            dst = b * HWo + yo * Wo
            tol = out_image.dtype(tolerance)
            for xo in range(Wo):
                p = src + 2 * xo
                out_depth[dst + xo] = _block_depth(depth[p], depth[p + 1], depth[p + W], depth[p + W + 1], tol)

    kernel = wp.kernel(downsample, module="unique", enable_backward=False)
    # Forward-only: every element writes its own output row; inputs are read at 2x2 blocks ("any").
    return FloatKernel(kernel, image="scalar", depth="scalar", out_image="scalar", out_depth="scalar").set_parallel(
        scopes={"image": "any", "depth": "any"}, grain=_row_grain
    )


# 8-lane twins of the kernels above for the common sizes (one output channel, widths a multiple of 8):
# 8 pixels of a row per step as length-8 vectors (LLVM vectorises their arithmetic; see
# photometric.py), results stored as whole vectors through a vec8 view of the output. The same
# operations as the scalar kernels: bitwise the same pyramids (tested), ~6x faster. Every value is
# read as straight vectors (lanes.row8; the downsampling's even and odd columns are shuffled out of 16
# straight values) and every test is a per-lane mask, with no branch: LLVM's SLP vectoriser then
# turns them into SIMD code (gathers of strided values, a per-lane finiteness test and a branch to a
# scalar depth-edge test ran 1.7-2.2x slower). Compiled with the other 8-lane kernels' flags
# (kinds.LANES_MODULE_OPTIONS).


@wp.func
def _le8(a: Any, b: Any):
    """1 where a <= b, else 0 (NaN: 0), per lane."""
    one = type(a[0])(1.0)
    return type(a)(
        lanes.flag(a[0] <= b[0], one), lanes.flag(a[1] <= b[1], one), lanes.flag(a[2] <= b[2], one),
        lanes.flag(a[3] <= b[3], one), lanes.flag(a[4] <= b[4], one), lanes.flag(a[5] <= b[5], one),
        lanes.flag(a[6] <= b[6], one), lanes.flag(a[7] <= b[7], one),
    )


@wp.func
def _valid8(d: Any):
    """:func:`_valid_depth` per lane, as 1/0."""
    return lanes.open_mask8(d, type(d[0])(0.0), type(d[0])(3.0e38))


@wp.func
def _block_depth8(d0: Any, d1: Any, d2: Any, d3: Any, tolerance: Any):
    """:func:`_block_depth` on 8 lanes (the same operations in the same order)."""
    zero = type(tolerance)(0.0)
    one = type(tolerance)(1.0)
    zeros = lanes.splat8(zero)
    ones = lanes.splat8(one)
    bigs = lanes.splat8(type(tolerance)(3.0e38))
    v0 = _valid8(d0)
    v1 = _valid8(d1)
    v2 = _valid8(d2)
    v3 = _valid8(d3)
    e0 = lanes.select8(v0, d0, bigs)
    e1 = lanes.select8(v1, d1, bigs)
    e2 = lanes.select8(v2, d2, bigs)
    e3 = lanes.select8(v3, d3, bigs)
    limit = wp.min(wp.min(e0, e1), wp.min(e2, e3)) * (one + tolerance)
    n0 = wp.cw_mul(v0, _le8(e0, limit))
    n1 = wp.cw_mul(v1, _le8(e1, limit))
    n2 = wp.cw_mul(v2, _le8(e2, limit))
    n3 = wp.cw_mul(v3, _le8(e3, limit))
    n = n0 + n1 + n2 + n3
    s = wp.cw_mul(n0, lanes.select8(v0, d0, zeros)) + wp.cw_mul(n1, lanes.select8(v1, d1, zeros)) + wp.cw_mul(
        n2, lanes.select8(v2, d2, zeros))
    s = s + wp.cw_mul(n3, lanes.select8(v3, d3, zeros))
    return lanes.select8(lanes.open_mask8(n, zero, type(tolerance)(3.0e38)), wp.cw_div(s, wp.max(n, ones)), zeros)


@wp.func
def _no_jump8(d: Any, e: Any, tolerance: Any):
    """1 - :func:`_depth_jump` per lane, for neighbours ``e`` inside the image (one outside is
    passed as the pixel itself, never a jump). The same results bit for bit: max(t, -t) is |t|
    (Warp's min and max return NaN only when both operands are; -0 and +0 compare equal) and
    the product's operands are swapped (exact either way)."""
    t = d - e
    a = wp.max(t, -t)
    lim = wp.min(d, e) * tolerance
    gt = type(d)(lanes.above(a[0], lim[0]), lanes.above(a[1], lim[1]), lanes.above(a[2], lim[2]),
                 lanes.above(a[3], lim[3]), lanes.above(a[4], lim[4]), lanes.above(a[5], lim[5]),
                 lanes.above(a[6], lim[6]), lanes.above(a[7], lim[7]))
    return lanes.splat8(type(tolerance)(1.0)) - wp.cw_mul(_valid8(e), gt)


@wp.func
def _pairs8(a: wp.array(dtype=Any), p: int):
    """(a[p], a[p + 2], ..., a[p + 14]) and (a[p + 1], a[p + 3], ..., a[p + 15]) from 16 straight
    values."""
    u = lanes.row8(a, p)
    w = lanes.row8(a, p + 8)
    return (type(u)(u[0], u[2], u[4], u[6], w[0], w[2], w[4], w[6]),
            type(u)(u[1], u[3], u[5], u[7], w[1], w[3], w[5], w[7]))


def _make_level0_lanes(C: int):
    """:func:`_make_level0`'s kernel for one output channel, 8 pixels per step (W % 8 == 0); the
    outputs are vec8 views (element k = pixels [8k, 8k + 8) of the flat (B, 1, H, W) array)."""

    def level0_lanes(
        offset: int,
        image: wp.array(dtype=Any),
        weights: wp.array(dtype=Any),
        depth: wp.array(dtype=Any),
        depth8: wp.array(dtype=Any),
        H: int,
        W: int,
        has_depth: int,
        tolerance: float,
        out_image: wp.array(dtype=Any),
        out_depth: wp.array(dtype=Any),
    ):
        row = wp.tid() + offset  # flat (b, y)
        b = row // H
        y = row - b * H
        HW = H * W
        p0 = y * W
        zero = weights.dtype(0.0)
        one = weights.dtype(1.0)
        tol = weights.dtype(tolerance)
        zeros = lanes.splat8(zero)
        for k8 in range(W // 8):
            p = p0 + k8 * 8
            v = lanes.splat8(zero)
            for c in range(C):
                v = v + lanes.row8(image, (b * C + c) * HW + p) * weights[c]
            finite = lanes.open_mask8(wp.max(v, -v), -one, weights.dtype(wp.inf))  # |v| < inf: finite, not NaN
            q = (b * HW + p) // 8
            out_image[q] = lanes.select8(finite, v, zeros)
            if has_depth != 0:
                d = depth8[q]
                # the scalar kernel's depth-edge test (1 = no edge), lane by lane as vectors: the
                # left and right neighbours are the block shifted by one lane, with the pixels
                # either side of it; the rows above and below are read as vec8 (W % 8 == 0: one
                # array access each). A neighbour outside the image is read as the pixel itself,
                # which is never a jump.
                x = k8 * 8
                e = b * HW + p
                up = depth8[q - wp.where(y > 0, W // 8, 0)]
                down = depth8[q + wp.where(y < H - 1, W // 8, 0)]
                side_l = depth[e - wp.where(x > 0, 1, 0)]
                side_r = depth[e + 7 + wp.where(x + 8 < W, 1, 0)]
                left = type(d)(side_l, d[0], d[1], d[2], d[3], d[4], d[5], d[6])
                right = type(d)(d[1], d[2], d[3], d[4], d[5], d[6], d[7], side_r)
                smooth = wp.cw_mul(
                    wp.cw_mul(_no_jump8(d, left, tol), _no_jump8(d, right, tol)),
                    wp.cw_mul(_no_jump8(d, up, tol), _no_jump8(d, down, tol)),
                )
                out_depth[q] = lanes.select8(wp.cw_mul(wp.cw_mul(finite, _valid8(d)), smooth), d, zeros)

    kernel = wp.kernel(level0_lanes, module="unique", enable_backward=False, module_options=LANES_MODULE_OPTIONS)
    return FloatKernel(
        kernel, image="scalar", weights="scalar", depth="scalar", depth8="vec8", out_image="vec8", out_depth="vec8"
    ).set_parallel(scopes={"image": "any", "weights": "any", "depth": "any", "depth8": "any"}, grain=_row_grain)


def _make_downsample_lanes(C: int):
    """:func:`_make_downsample`'s kernel, 8 output pixels per step (Wo % 8 == 0); the outputs are
    vec8 views as in :func:`_make_level0_lanes`."""

    def downsample_lanes(
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
        row = wp.tid() + offset  # flat (b, y') of the output
        b = row // Ho
        yo = row - b * Ho
        HW = H * W
        HWo = Ho * Wo
        quarter = image.dtype(0.25)
        for c in range(C):
            src = (b * C + c) * HW + 2 * yo * W
            dst = ((b * C + c) * HWo + yo * Wo) // 8
            for k8 in range(Wo // 8):
                p = src + 16 * k8
                t0, t1 = _pairs8(image, p)
                b0, b1 = _pairs8(image, p + W)
                out_image[dst + k8] = (t0 + t1 + b0 + b1) * quarter
        if has_depth != 0:
            src = b * HW + 2 * yo * W
            dst = (b * HWo + yo * Wo) // 8
            tol = image.dtype(tolerance)
            for k8 in range(Wo // 8):
                p = src + 16 * k8
                t0, t1 = _pairs8(depth, p)
                b0, b1 = _pairs8(depth, p + W)
                out_depth[dst + k8] = _block_depth8(t0, t1, b0, b1, tol)

    kernel = wp.kernel(downsample_lanes, module="unique", enable_backward=False, module_options=LANES_MODULE_OPTIONS)
    return FloatKernel(kernel, image="scalar", depth="scalar", out_image="vec8", out_depth="vec8").set_parallel(
        scopes={"image": "any", "depth": "any"}, grain=_row_grain
    )


def _row_grain(args: dict) -> int:
    """Fewest rows worth a chunk of a threaded launch: ~32k pixels."""
    return max(1, 32768 // max(1, int(args.get("Wo", args["W"]))))


_KERNELS: dict[tuple, FloatKernel] = {}
_KERNELS_LOCK = threading.Lock()


def level0_kernel(C: int, Co: int) -> FloatKernel:
    """The (cached) base-level kernel for C input and Co output channels, one element per image row
    (B * H); its arguments: (offset, image, weights, depth, H, W, has_depth, tolerance, out_image,
    out_depth), flat arrays (``tolerance``: the depth-edge test's, see the module docstring)."""
    with _KERNELS_LOCK:
        k = _KERNELS.get(("level0", C, Co))
        if k is None:
            k = _KERNELS["level0", C, Co] = _make_level0(C, Co)
        return k


def downsample_kernel(C: int) -> FloatKernel:
    """The (cached) downsampling kernel for C channels, one element per output row (B * Ho); its
    arguments: (offset, image, depth, H, W, Ho, Wo, tolerance, has_depth, out_image, out_depth),
    flat arrays."""
    with _KERNELS_LOCK:
        k = _KERNELS.get(("down", C))
        if k is None:
            k = _KERNELS["down", C] = _make_downsample(C)
        return k


def level0_lanes_kernel(C: int) -> FloatKernel:
    """The (cached) 8-lane base-level kernel for C input channels and one output channel (W % 8
    == 0); arguments as :func:`level0_kernel`'s, the outputs as vec8 views."""
    with _KERNELS_LOCK:
        k = _KERNELS.get(("level0_lanes", C))
        if k is None:
            k = _KERNELS["level0_lanes", C] = _make_level0_lanes(C)
        return k


def downsample_lanes_kernel(C: int) -> FloatKernel:
    """The (cached) 8-lane downsampling kernel for C channels (Wo % 8 == 0); arguments as
    :func:`downsample_kernel`'s, the outputs as vec8 views."""
    with _KERNELS_LOCK:
        k = _KERNELS.get(("down_lanes", C))
        if k is None:
            k = _KERNELS["down_lanes", C] = _make_downsample_lanes(C)
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
    *,
    tolerance: float = DEPTH_TOLERANCE,
) -> None:
    """Write the base level of a pyramid: ``out_image[b, o] = sum_c weights[o, c] image[b, c]``
    and ``out_depth`` = ``depth`` cleaned (0 where missing or at a depth edge, with the relative
    ``tolerance`` >= 0, ``inf`` for no edge test), see the module docstring.

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
        B * Ho,
        [image.flatten(), depth.flatten() if depth is not None else empty, H, W, Ho, Wo, float(tolerance),
         int(depth is not None)],
        [out_image.flatten(), out_depth.flatten() if out_depth is not None else empty],
    )
