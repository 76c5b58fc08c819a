"""The thin kernels of the reprojection objective and the edge-aware smoothness (definitions: the
package docstring; the ``@wp.func`` s: :mod:`.ssim`).

Layouts (flat, batch-major): ``target`` (B, C, H, W); ``warped`` and ``sources`` (B, S, C, H, W);
``front`` (B, S, H, W), 1 where source s can see the target pixel's point (the warp of a constant
1), else 0; ``depth`` (B, H, W); per-pixel outputs (B, H, W).

- :data:`reprojection_choice` (forward only): each pixel's chosen candidate, ``choice`` = s for the
  reprojection of source s, S + s for its identity, -1 for an excluded pixel.
- :data:`reprojection_error` (differentiated by Warp): the chosen candidate's pe and a weight (1, or
  0 where excluded); its adjoint scatters into the 3x3 windows of target, warped and sources.
- :data:`per_item_mean`: the mean of the weighted pixels of each batch item, in pixel order.
- :data:`disparity_mean` and :data:`smoothness_rows`, :data:`rows_total`: Monodepth2's edge-aware
  smoothness of the mean-normalised disparity.

Each element writes only its own outputs and the reductions add in a fixed order, so results are
bitwise identical for every split over threads.
"""

from typing import Any

import warp as wp

from ..core.cache import float_overloads
from ..core.compat import func_grad
from ..core.kinds import LANES_MODULE_OPTIONS, FloatKernel
from ..geometry import camera, lie
from ..photometric.error_rows import rows_mean
from . import ssim

# a pixel-wise kernel: enough pixels per chunk to pay for a thread's start
_GRAIN = 4096


@wp.kernel(module="unique", enable_backward=False, module_options=LANES_MODULE_OPTIONS)
def _reprojection_choice(
    offset: int,
    target: wp.array(dtype=Any),
    warped: wp.array(dtype=Any),
    sources: wp.array(dtype=Any),
    front: wp.array(dtype=Any),
    depth: wp.array(dtype=Any),
    pose: wp.array(dtype=Any),
    K: wp.array(dtype=Any),
    S: int,
    C: int,
    H: int,
    W: int,
    alpha: wp.float64,
    automask: int,
    min_depth: wp.float64,
    use_front: int,
    choice: wp.array(dtype=Any),
    best: wp.array(dtype=Any),
    acc: wp.array(dtype=Any),
):
    # Element r = one target row (flat (b, y)): every candidate's pe along the row (ssim.row_errors,
    # into acc), then the running minimum into best and choice. Forward only. Whether source s sees
    # the pixel's point: front[(b S + s) H W + p] > 0.5 with use_front (a lens camera: the warp of a
    # constant 1), else the pinhole warp's own test, z > min_depth of the point moved by pose[b S + s]
    # (computed as warp_frame_depth computes it, through geometry.camera.row_rays).
    r = wp.tid() + offset
    hw = H * W
    b = r // H
    y = r - b * H
    row = r * W  # the row's first pixel, flat (b, y, x)
    r0, r1, r2, _, _, _ = ssim.window(0, y, H, W)  # (the rows; the columns slide in row_errors)
    a = best.dtype(alpha)
    t0 = b * C * hw
    for x in range(W):
        best[row + x] = best.dtype(1.0e30)
        choice[row + x] = wp.int32(-1)
    for s in range(S):
        ssim.row_errors(target, warped, acc, t0, (b * S + s) * C * hw, C, hw, W, r0, r1, r2, row, a)
        f0 = (b * S + s) * hw + y * W
        Tbs = pose[b * S + s]
        a0, ax = camera.row_rays(lie.pose_rotation(Tbs), K[b * S + s], best.dtype(y))
        tz = Tbs[2, 3]
        for x in range(W):
            e = acc[row + x]
            seen = False
            if use_front != 0:
                seen = front[f0 + x] > best.dtype(0.5)
            else:
                d = depth[row + x]
                seen = (a0[2] + ax[2] * best.dtype(x)) * d + tz > best.dtype(min_depth)
            if seen and e < best[row + x]:  # (a NaN error is never chosen)
                best[row + x] = e
                choice[row + x] = wp.int32(s)
    if automask != 0:
        for s in range(S):
            ssim.row_errors(target, sources, acc, t0, (b * S + s) * C * hw, C, hw, W, r0, r1, r2, row, a)
            for x in range(W):
                e = acc[row + x]
                if e < best[row + x]:
                    best[row + x] = e
                    choice[row + x] = wp.int32(S + s)
    zmin = best.dtype(min_depth)
    for x in range(W):
        d = depth[row + x]
        if not (d > zmin and d < best.dtype(1.0e30)):  # an invalid depth (NaN fails both): excluded
            choice[row + x] = wp.int32(-1)
        if choice[row + x] < 0:
            best[row + x] = best.dtype(0.0)


reprojection_choice = FloatKernel(
    _reprojection_choice, target="scalar", warped="scalar", sources="scalar", front="scalar", depth="scalar",
    pose="mat34", K="mat33", choice="int32", best="scalar", acc="scalar",
).set_parallel(scopes={}, forward=True, grain=lambda a: max(1, _GRAIN // max(1, a["W"] * a["C"])))


@wp.kernel(module="unique", module_options=LANES_MODULE_OPTIONS)
def _reprojection_error(
    offset: int,
    target: wp.array(dtype=Any),
    warped: wp.array(dtype=Any),
    sources: wp.array(dtype=Any),
    choice: wp.array(dtype=Any),
    best: wp.array(dtype=Any),
    S: int,
    C: int,
    H: int,
    W: int,
    alpha: wp.float64,
    pe: wp.array(dtype=Any),
    weight: wp.array(dtype=Any),
):
    # (best, the choice kernel's value of the chosen candidate, is not read here: see
    # reprojection_error_copy.) The channel terms are accumulated into pe[i] in place: a local sum
    # carried through a loop whose trip count is known only at run time is not differentiated by Warp.
    i = wp.tid() + offset
    hw = H * W
    b = i // hw
    p = i - b * hw
    y = p // W
    x = p - y * W
    zero = target[0] * type(target[0])(0.0)
    a = type(zero)(alpha)
    inv_c = type(zero)(1.0) / type(zero)(C)
    k = int(choice[i])
    r0, r1, r2, x0, x1, x2 = ssim.window(x, y, H, W)
    pe[i] = zero
    weight[i] = wp.where(k >= 0, type(zero)(1.0), zero)
    t0 = b * C * hw
    if k >= 0 and k < S:
        c0 = (b * S + k) * C * hw
        for c in range(C):
            pe[i] += inv_c * ssim.channel_error(target, warped, t0 + c * hw, c0 + c * hw, r0, r1, r2, x0, x1, x2, a)
    elif k >= S:
        c0 = (b * S + k - S) * C * hw
        for c in range(C):
            pe[i] += inv_c * ssim.channel_error(target, sources, t0 + c * hw, c0 + c * hw, r0, r1, r2, x0, x1, x2, a)


reprojection_error = FloatKernel(
    _reprojection_error, target="scalar", warped="scalar", sources="scalar", choice="int32", best="scalar",
    pe="scalar", weight="scalar",
).set_parallel(
    # a pixel's adjoint writes the 3x3 windows around it, in its own batch item's planes only
    segment=lambda a: a["H"] * a["W"],
    scopes={"target": "segment", "warped": "segment", "sources": "segment"},
    forward=True,
    grain=_GRAIN,
)


@wp.kernel(module="unique", enable_backward=False)
def _reprojection_error_copy(
    offset: int,
    target: wp.array(dtype=Any),
    warped: wp.array(dtype=Any),
    sources: wp.array(dtype=Any),
    choice: wp.array(dtype=Any),
    best: wp.array(dtype=Any),
    S: int,
    C: int,
    H: int,
    W: int,
    alpha: wp.float64,
    pe: wp.array(dtype=Any),
    weight: wp.array(dtype=Any),
):
    # The forward of reprojection_error from what the choice kernel computed already (its arguments;
    # bitwise the same values: ssim.window_sums adds the columns as ssim.row_errors slides them); the
    # backward is reprojection_error's.
    i = wp.tid() + offset
    pe[i] = best[i]
    weight[i] = wp.where(int(choice[i]) >= 0, best.dtype(1.0), best.dtype(0.0))


reprojection_error_copy = FloatKernel(
    _reprojection_error_copy, target="scalar", warped="scalar", sources="scalar", choice="int32", best="scalar",
    pe="scalar", weight="scalar",
).set_parallel(forward=True, grain=1 << 16)


@wp.kernel(module="unique")
def _per_item_mean(
    offset: int,
    value: wp.array(dtype=Any),
    weight: wp.array(dtype=Any),
    n: int,
    mean: wp.array(dtype=Any),
    count: wp.array(dtype=Any),
):
    # element b: mean[b] = sum of value[b n:(b + 1) n] / (the sum of weight there), in order; 0 if none
    b = wp.tid() + offset
    m, c = rows_mean(value, weight, b * n, n, 1)
    mean[b] = m
    count[b] = c


per_item_mean = FloatKernel(
    _per_item_mean, value="scalar", weight="scalar", mean="scalar", count="scalar"
).set_parallel(scopes={"value": "element", "weight": "element"}, forward=True, grain=1 << 30)


def _plane_mean(T):
    """float type ``T`` overload of plane_mean (custom adjoints need concrete types)."""

    @wp.func
    def plane_mean(values: wp.array(dtype=T), start: int, n: int):
        """The mean of values[start:start + n], added in order (in float64)."""
        s = wp.float64(0.0)
        for k in range(n):
            s += wp.float64(values[start + k])
        return T(s / wp.float64(n))

    @func_grad(plane_mean)
    def adj_plane_mean(values: wp.array(dtype=T), start: int, n: int, adj_ret: T):
        g = wp.adjoint[values]
        if g.shape[0] > 0:
            share = adj_ret / T(n)
            for k in range(n):
                g[start + k] += share

    return plane_mean


plane_mean = float_overloads(_plane_mean)


@wp.kernel(module="unique")
def _disparity_mean(offset: int, disparity: wp.array(dtype=Any), n: int, mean: wp.array(dtype=Any)):
    b = wp.tid() + offset
    mean[b] = plane_mean(disparity, b * n, n)


disparity_mean = FloatKernel(_disparity_mean, disparity="scalar", mean="scalar").set_parallel(
    scopes={"disparity": "element"}, forward=True, grain=1 << 30
)


def _mean_abs_diff(T):
    """float type ``T`` overload of mean_abs_diff (custom adjoints need concrete types)."""

    @wp.func
    def mean_abs_diff(image: wp.array(dtype=T), i: int, step: int, C: int, hw: int):
        """mean over the C planes (``hw`` apart) of |image[i + c hw] - image[i + c hw + step]|."""
        g = T(0.0)
        for c in range(C):
            g += wp.abs(image[i + c * hw] - image[i + c * hw + step])
        return g / T(C)

    @func_grad(mean_abs_diff)
    def adj_mean_abs_diff(image: wp.array(dtype=T), i: int, step: int, C: int, hw: int, adj_ret: T):
        # (written by hand: Warp does not differentiate the sum carried through the channel loop)
        g = wp.adjoint[image]
        if g.shape[0] > 0:
            share = adj_ret / T(C)
            for c in range(C):
                k = i + c * hw
                e = wp.sign(image[k] - image[k + step]) * share
                g[k] += e
                g[k + step] -= e

    return mean_abs_diff


mean_abs_diff = float_overloads(_mean_abs_diff)


@wp.kernel(module="unique")
def _smoothness_rows(
    offset: int,
    disparity: wp.array(dtype=Any),
    image: wp.array(dtype=Any),
    mean: wp.array(dtype=Any),
    C: int,
    H: int,
    W: int,
    row_sum: wp.array(dtype=Any),
):
    # Element r = row y of item b: row_sum[r] = its share of the smoothness, the x-differences of
    # the row over H (W - 1) and the y-differences to the next row over (H - 1) W, with the
    # disparity divided by (its mean + 1e-7) and each difference weighted by exp(-mean_c |dI|).
    # Accumulated in place (see _reprojection_error).
    r = wp.tid() + offset
    b = r // H
    y = r - b * H
    hw = H * W
    m = mean[b]
    inv = type(m)(1.0) / (m + type(m)(1.0e-7))
    wx = type(m)(1.0) / type(m)(H * (W - 1))
    wy = type(m)(1.0) / type(m)((H - 1) * W)
    d0 = b * hw + y * W
    i0 = b * C * hw + y * W
    row_sum[r] = type(m)(0.0)
    for x in range(W - 1):
        g = mean_abs_diff(image, i0 + x, 1, C, hw)
        row_sum[r] += wx * wp.abs(disparity[d0 + x] - disparity[d0 + x + 1]) * inv * wp.exp(-g)
    if y < H - 1:
        for x in range(W):
            g = mean_abs_diff(image, i0 + x, W, C, hw)
            row_sum[r] += wy * wp.abs(disparity[d0 + x] - disparity[d0 + x + W]) * inv * wp.exp(-g)


smoothness_rows = FloatKernel(
    _smoothness_rows, disparity="scalar", image="scalar", mean="scalar", row_sum="scalar"
).set_parallel(
    segment=lambda a: a["H"],  # the rows of one batch item
    scopes={"disparity": "segment", "image": "segment", "mean": "segment"},
    forward=True,
    grain=lambda a: max(1, 16384 // max(1, a["W"] * a["C"])),
)


@wp.kernel(module="unique")
def _rows_total(offset: int, row_sum: wp.array(dtype=Any), H: int, total: wp.array(dtype=Any)):
    # element b: total[b] = the sum of its H rows (H times their mean, added in order in float64)
    b = wp.tid() + offset
    total[b] = plane_mean(row_sum, b * H, H) * type(total[b])(H)


rows_total = FloatKernel(_rows_total, row_sum="scalar", total="scalar").set_parallel(
    scopes={"row_sum": "element"}, forward=True, grain=1 << 30
)


@wp.kernel(module="unique")
def _repeat(offset: int, src: wp.array(dtype=Any), n: int, S: int, out: wp.array(dtype=Any)):
    # element i of (B, S, n): out[i] = src[b, :] (each item's n values once per source). Its
    # adjoint adds the S copies' gradients into src: for the pure-Warp pipeline (one thread).
    i = wp.tid() + offset
    b = i // (S * n)
    out[i] = src[b * n + i % n]


repeat_scalar = FloatKernel(_repeat, src="scalar", out="scalar").set_parallel(forward=True)
repeat_mat33 = FloatKernel(_repeat, src="mat33", out="mat33").set_parallel(forward=True)
repeat_vec8 = FloatKernel(_repeat, src="vec8", out="vec8").set_parallel(forward=True)
