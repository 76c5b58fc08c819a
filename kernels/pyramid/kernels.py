"""The pyramid's kernels, one pixel at a time: the base level and the 2x2 downsampling (see the
package docstring for what they compute), each made on first use for its channel counts.

Kernels are row-blocked: element k is the image row k (b = k // H, y = k % H) and loops over its
pixels, which amortises Warp's per-element cost on the CPU (a launch calls the kernel function
once per element) and keeps the inner loop's index arithmetic trivial. Forward only.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ..core.cache import specialise
from ..core.kinds import FloatKernel

wp.set_module_options({"enable_backward": False})


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
    """The downsampled depth of a 2x2 block (see the package docstring), branch-free."""
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


def row_grain(args: dict) -> int:
    """Fewest rows worth a chunk of a threaded launch: ~32k pixels."""
    return max(1, 32768 // max(1, int(args.get("Wo", args["W"]))))


@specialise("pyramid.level0")
def level0_kernel(C: int, Co: int) -> FloatKernel:
    """The base-level kernel for C input and Co output channels (loops over constants: unrolled),
    one element per image row (B * H); its arguments: (offset, image, weights, depth, H, W,
    has_depth, tolerance, out_image, out_depth), flat arrays (``tolerance``: the depth-edge test's,
    see the package docstring). Made on first use."""

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
    ).set_parallel(scopes={"image": "any", "weights": "any", "depth": "any"}, grain=row_grain)


@wp.func
def _nearest_depth(depth: wp.array(dtype=Any), index: wp.array(dtype=wp.int32), q0: int, p: int):
    """The source depth at ``index[p]`` (of the item starting at ``q0``); 0 where there is none."""
    i = index[p]
    return wp.where(i >= 0, depth[q0 + wp.max(i, 0)], depth.dtype(0.0))


@specialise("pyramid.level0_remap")
def level0_remap_kernel(C: int, Co: int) -> FloatKernel:
    """:func:`level0_kernel` (C input and Co output channels) for a frame resampled through a fixed table in
    the same pass (a lens image into its ideal pinhole image, see
    :class:`gvnn_warp.kernels.sampling.remap.RemapTable`): output pixel p's channels are bilinear
    between the source pixels ``base[p]``, +1, +Ws, +Ws + 1 with weights (``wx[p]``, ``wy[p]``) (0
    where base[p] < 0), its depth the source's at ``index[p]`` (the nearest pixel; none where < 0);
    then the base level's rules, the depth-edge test among the resampled depths. One element per
    output row (B * H); arguments: (offset, image, weights, depth, base, wx, wy, index, H, W, Ws, HWs,
    has_depth, tolerance, out_image, out_depth), flat arrays, the source items HWs pixels apart
    (``wx``, ``wy`` of the kernel's float type).
    Made on first use."""

    def level0_remap(
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
        o0 = b * H * W  # (the item's first pixel of the depth; of the image, o0 * Co)
        q0 = b * HWs
        zero = out_image.dtype(0.0)
        one = out_image.dtype(1.0)
        tol = out_image.dtype(tolerance)
        # the depths of the row's pixels x - 1, x, x + 1 slide along the row (0: none, or outside)
        left = out_depth.dtype(0.0)
        here = out_depth.dtype(0.0)
        if has_depth != 0:
            here = _nearest_depth(depth, index, q0, p0)
        for x in range(W):
            p = p0 + x
            k = base[p]
            fx = wx[p]
            fy = wy[p]
            finite = bool(True)  # noqa: UP018 - a typed variable Warp may reassign inside the loop
            for co in range(Co):
                v = out_image.dtype(0.0)
                if k >= 0:
                    for c in range(C):
                        o = (b * C + c) * HWs + k
                        top = (one - fx) * image[o] + fx * image[o + 1]
                        bottom = (one - fx) * image[o + Ws] + fx * image[o + Ws + 1]
                        v += weights[co * C + c] * ((one - fy) * top + fy * bottom)
                ok = wp.isfinite(v)
                finite = finite and ok
                out_image[o0 * Co + co * H * W + p] = wp.where(ok, v, zero)
            if has_depth != 0:
                right = out_depth.dtype(0.0)
                if x < W - 1:
                    right = _nearest_depth(depth, index, q0, p + 1)
                up = out_depth.dtype(0.0)
                if y > 0:
                    up = _nearest_depth(depth, index, q0, p - W)
                down = out_depth.dtype(0.0)
                if y < H - 1:
                    down = _nearest_depth(depth, index, q0, p + W)
                d = here
                edge = (_depth_jump(d, left, True, tol) or _depth_jump(d, right, True, tol)
                        or _depth_jump(d, up, True, tol) or _depth_jump(d, down, True, tol))
                out_depth[o0 + p] = wp.where(finite and _valid_depth(d) and not edge, d, zero)
                left = here
                here = right

    kernel = wp.kernel(level0_remap, module="unique", enable_backward=False)
    return FloatKernel(
        kernel, image="scalar", weights="scalar", depth="scalar", wx="scalar", wy="scalar", out_image="scalar",
        out_depth="scalar"
    ).set_parallel(scopes={"image": "any", "weights": "any", "depth": "any", "wx": "any", "wy": "any"}, grain=row_grain)


@specialise("pyramid.downsample")
def downsample_kernel(C: int) -> FloatKernel:
    """The 2x2 downsampling kernel for C channels (see the package docstring), one element per
    output row (B * Ho); its arguments: (offset, image, depth, H, W, Ho, Wo, tolerance, has_depth,
    out_image, out_depth), flat arrays. Made on first use."""

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
        scopes={"image": "any", "depth": "any"}, grain=row_grain
    )
