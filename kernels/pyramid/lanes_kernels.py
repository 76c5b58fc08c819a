"""The pyramid's kernels, 8 pixels at a time, for the common sizes (one output channel, widths a
multiple of 8).

8-lane twins of :mod:`.kernels`: 8 pixels of a row per step as length-8 vectors (LLVM vectorises
their arithmetic), results stored as whole vectors through a vec8 view of the output. The same
operations as the scalar kernels: bitwise the same pyramids (tested). Every value is read as
straight vectors (:func:`..core.lanes.row8`; the downsampling's even and odd columns are shuffled
out of 16 straight values) and every test is a per-lane mask, with no branch: LLVM's SLP
vectoriser then turns them into SIMD code (gathers of strided values, a per-lane finiteness test
and a branch to a scalar depth-edge test were slower). Compiled with the other 8-lane kernels'
flags (:data:`..core.kinds.LANES_MODULE_OPTIONS`). Each made on first use for its channel count.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ..core import lanes
from ..core.cache import specialise
from ..core.kinds import LANES_MODULE_OPTIONS, FloatKernel
from .kernels import _nearest_depth, row_grain

wp.set_module_options({"enable_backward": False})


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
    """:func:`.kernels._valid_depth` per lane, as 1/0."""
    return lanes.open_mask8(d, type(d[0])(0.0), type(d[0])(3.0e38))


@wp.func
def _block_depth8(d0: Any, d1: Any, d2: Any, d3: Any, tolerance: Any):
    """:func:`.kernels._block_depth` on 8 lanes (the same operations in the same order)."""
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
    """1 - :func:`.kernels._depth_jump` per lane, for neighbours ``e`` inside the image (one outside is
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
def _no_edge8(d: Any, side_l: Any, side_r: Any, up: Any, down: Any, tolerance: Any):
    """1 - :func:`.kernels._at_depth_edge` per lane of the 8 depths ``d`` of a row: their left and
    right neighbours are ``d`` shifted by a lane, with ``side_l`` / ``side_r`` the pixels either
    side of the block; ``up``, ``down`` the 8 depths of the rows above and below (a neighbour
    outside the image passed as the pixel itself)."""
    left = type(d)(side_l, d[0], d[1], d[2], d[3], d[4], d[5], d[6])
    right = type(d)(d[1], d[2], d[3], d[4], d[5], d[6], d[7], side_r)
    return wp.cw_mul(
        wp.cw_mul(_no_jump8(d, left, tolerance), _no_jump8(d, right, tolerance)),
        wp.cw_mul(_no_jump8(d, up, tolerance), _no_jump8(d, down, tolerance)),
    )


@wp.func
def _pairs8(a: wp.array(dtype=Any), p: int):
    """(a[p], a[p + 2], ..., a[p + 14]) and (a[p + 1], a[p + 3], ..., a[p + 15]) from 16 straight
    values."""
    u = lanes.row8(a, p)
    w = lanes.row8(a, p + 8)
    return (type(u)(u[0], u[2], u[4], u[6], w[0], w[2], w[4], w[6]),
            type(u)(u[1], u[3], u[5], u[7], w[1], w[3], w[5], w[7]))


@specialise("pyramid.level0_lanes")
def level0_lanes_kernel(C: int) -> FloatKernel:
    """:func:`.kernels.level0_kernel` for C input channels and one output channel, 8 pixels per
    step (W % 8 == 0); its arguments as that kernel's, with a vec8 view ``depth8`` of ``depth``
    after it, and the outputs as vec8 views (element k = pixels [8k, 8k + 8) of the flat
    (B, 1, H, W) array). Made on first use."""

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
                smooth = _no_edge8(d, side_l, side_r, up, down, tol)
                out_depth[q] = lanes.select8(wp.cw_mul(wp.cw_mul(finite, _valid8(d)), smooth), d, zeros)

    kernel = wp.kernel(level0_lanes, module="unique", enable_backward=False, module_options=LANES_MODULE_OPTIONS)
    return FloatKernel(
        kernel, image="scalar", weights="scalar", depth="scalar", depth8="vec8", out_image="vec8", out_depth="vec8"
    ).set_parallel(scopes={"image": "any", "weights": "any", "depth": "any", "depth8": "any"}, grain=row_grain)


@wp.func
def _gather8(a: wp.array(dtype=Any), o: int, i: Any):
    """(a[o + i[0]], ..., a[o + i[7]]): 8 scalar reads (indices >= 0, the caller's guarantee)."""
    return wp.vector(a[o + i[0]], a[o + i[1]], a[o + i[2]], a[o + i[3]], a[o + i[4]], a[o + i[5]], a[o + i[6]],
                     a[o + i[7]])


@wp.func
def _nearest8(depth: wp.array(dtype=Any), index: wp.array(dtype=wp.int32), q0: int, p: int):
    """The source depths at index[p], ..., index[p + 7] (of the item starting at ``q0``); 0 where
    an index is negative (no source): :func:`.kernels._nearest_depth` per lane."""
    i = lanes.row8(index, p)
    zero = depth.dtype(0.0)
    d = _gather8(depth, q0, wp.max(i, lanes.splat8(0)))
    return wp.vector(wp.where(i[0] >= 0, d[0], zero), wp.where(i[1] >= 0, d[1], zero),
                     wp.where(i[2] >= 0, d[2], zero), wp.where(i[3] >= 0, d[3], zero),
                     wp.where(i[4] >= 0, d[4], zero), wp.where(i[5] >= 0, d[5], zero),
                     wp.where(i[6] >= 0, d[6], zero), wp.where(i[7] >= 0, d[7], zero))


@specialise("pyramid.level0_remap_lanes")
def level0_remap_lanes_kernel(C: int) -> FloatKernel:
    """:func:`.kernels.level0_remap_kernel` for C input channels and one output channel, 8 pixels
    per step (W % 8 == 0): the table's reads and the arithmetic as vectors, the source reads
    scalar; the same results bit for bit. Its arguments as that kernel's, the outputs as vec8
    views (as in :func:`level0_lanes_kernel`). Made on first use."""

    def level0_remap_lanes(
        offset: int,
        image: wp.array(dtype=Any),
        weights: wp.array(dtype=Any),
        depth: wp.array(dtype=Any),
        base: wp.array(dtype=wp.int32),
        wx: wp.array(dtype=Any),
        wy: wp.array(dtype=Any),
        index: wp.array(dtype=wp.int32),
        H: int,
        W: int,
        Ws: int,
        HWs: int,
        has_depth: int,
        tolerance: float,
        out_image: wp.array(dtype=Any),
        out_depth: wp.array(dtype=Any),
    ):
        row = wp.tid() + offset  # flat (b, y)
        b = row // H
        y = row - b * H
        p0 = y * W
        q0 = b * HWs
        zero = weights.dtype(0.0)
        one = weights.dtype(1.0)
        tol = weights.dtype(tolerance)
        zeros = lanes.splat8(zero)
        ones = lanes.splat8(one)
        for k8 in range(W // 8):
            p = p0 + k8 * 8
            k = lanes.row8(base, p)
            source = wp.vector(lanes.flag(k[0] >= 0, one), lanes.flag(k[1] >= 0, one), lanes.flag(k[2] >= 0, one),
                               lanes.flag(k[3] >= 0, one), lanes.flag(k[4] >= 0, one), lanes.flag(k[5] >= 0, one),
                               lanes.flag(k[6] >= 0, one), lanes.flag(k[7] >= 0, one))
            k = wp.max(k, lanes.splat8(0))  # (lanes with no source read pixel 0 and are dropped)
            fx = lanes.row8(wx, p)
            fy = lanes.row8(wy, p)
            gx = ones - fx
            gy = ones - fy
            v = lanes.splat8(zero)
            for c in range(C):
                o = (b * C + c) * HWs
                top = wp.cw_mul(gx, _gather8(image, o, k)) + wp.cw_mul(fx, _gather8(image, o + 1, k))
                bottom = wp.cw_mul(gx, _gather8(image, o + Ws, k)) + wp.cw_mul(fx, _gather8(image, o + Ws + 1, k))
                v = v + (wp.cw_mul(gy, top) + wp.cw_mul(fy, bottom)) * weights[c]
            v = lanes.select8(source, v, zeros)
            finite = lanes.open_mask8(wp.max(v, -v), -one, weights.dtype(wp.inf))  # |v| < inf: finite, not NaN
            q = (b * H * W + p) // 8
            out_image[q] = lanes.select8(finite, v, zeros)
            if has_depth != 0:
                d = _nearest8(depth, index, q0, p)
                # the neighbours (as the scalar kernel's; one outside the image is the pixel itself,
                # never a jump): the block shifted by a lane, the rows above and below
                x = k8 * 8
                side_l = d[0]
                if x > 0:
                    side_l = _nearest_depth(depth, index, q0, p - 1)
                side_r = d[7]
                if x + 8 < W:
                    side_r = _nearest_depth(depth, index, q0, p + 8)
                up = d
                if y > 0:
                    up = _nearest8(depth, index, q0, p - W)
                down = d
                if y < H - 1:
                    down = _nearest8(depth, index, q0, p + W)
                smooth = _no_edge8(d, side_l, side_r, up, down, tol)
                out_depth[q] = lanes.select8(wp.cw_mul(wp.cw_mul(finite, _valid8(d)), smooth), d, zeros)

    kernel = wp.kernel(level0_remap_lanes, module="unique", enable_backward=False,
                       module_options=LANES_MODULE_OPTIONS)
    return FloatKernel(
        kernel, image="scalar", weights="scalar", depth="scalar", wx="scalar", wy="scalar", out_image="vec8",
        out_depth="vec8"
    ).set_parallel(scopes={"image": "any", "weights": "any", "depth": "any", "wx": "any", "wy": "any"}, grain=row_grain)


@specialise("pyramid.downsample_lanes")
def downsample_lanes_kernel(C: int) -> FloatKernel:
    """:func:`.kernels.downsample_kernel`, 8 output pixels per step (Wo % 8 == 0); its arguments
    as that kernel's, the outputs as vec8 views as in :func:`level0_lanes_kernel`. Made on first
    use."""

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
        scopes={"image": "any", "depth": "any"}, grain=row_grain
    )
