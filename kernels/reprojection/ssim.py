"""``@wp.func`` library of the reprojection objective (definitions: the package docstring).
No launches here."""

from typing import Any

import warp as wp

from ..core.cache import float_overloads
from ..core.compat import func_grad

SSIM_C1 = 0.01**2  # (in the kernels as 1/10000 and 9/10000 in the kernel's float type: a Python
SSIM_C2 = 0.03**2  # float constant would reach a float64 kernel rounded to float32)


@wp.func
def reflect(i: int, n: int):
    """Index ``i`` in [-1, n] reflected into [0, n) as ``nn.ReflectionPad2d`` does (n >= 2)."""
    if i < 0:
        return -i
    if i >= n:
        return 2 * n - 2 - i
    return i


@wp.func
def dssim(sx: Any, sy: Any, sxx: Any, syy: Any, sxy: Any):
    """clamp((1 - SSIM) / 2, 0, 1) of a 3x3 window from its sums (of x, y, x^2, y^2, x y)."""
    ninth = type(sx)(1.0) / type(sx)(9.0)
    mx = sx * ninth
    my = sy * ninth
    vx = sxx * ninth - mx * mx
    vy = syy * ninth - my * my
    cxy = sxy * ninth - mx * my
    c1 = type(sx)(1.0) / type(sx)(10000.0)
    c2 = type(sx)(9.0) / type(sx)(10000.0)
    num = (type(sx)(2.0) * mx * my + c1) * (type(sx)(2.0) * cxy + c2)
    den = (mx * mx + my * my + c1) * (vx + vy + c2)  # >= c1 c2 > 0 (vx, vy >= 0 up to rounding)
    return wp.clamp((type(sx)(1.0) - num / den) * type(sx)(0.5), type(sx)(0.0), type(sx)(1.0))


@wp.func
def window(x: int, y: int, H: int, W: int):
    """The offsets of the 3x3 window around pixel (x, y) with reflection: the three row offsets
    (multiples of W) and the three columns, as one ``vec``-free 6-tuple."""
    return reflect(y - 1, H) * W, y * W, reflect(y + 1, H) * W, reflect(x - 1, W), x, reflect(x + 1, W)


@wp.func
def tap(k: int, k0: int, k1: int, k2: int):
    """Element ``k`` (0, 1, 2; a static loop index) of (k0, k1, k2)."""
    out = k0
    if k == 1:
        out = k1
    if k == 2:
        out = k2
    return out


def _channel_error(T):
    """float type ``T`` overload of channel_error (custom adjoints need concrete types)."""

    @wp.func
    def channel_error(
        target: wp.array(dtype=T),
        cand: wp.array(dtype=T),
        t0: int,
        c0: int,
        r0: int,
        r1: int,
        r2: int,
        x0: int,
        x1: int,
        x2: int,
        alpha: T,
    ):
        """One channel's share of pe at the pixel whose window is rows (r0, r1, r2) x columns
        (x0, x1, x2) (:func:`window`): alpha clamp((1 - SSIM) / 2) + (1 - alpha) |t - c|, for the
        planes starting at ``t0`` in ``target`` and ``c0`` in ``cand``."""
        sx, sy, sxx, syy, sxy = window_sums(target, cand, t0, c0, r0, r1, r2, x0, x1, x2)
        k = r1 + x1
        l1 = wp.abs(target[t0 + k] - cand[c0 + k])
        return alpha * dssim(sx, sy, sxx, syy, sxy) + (T(1.0) - alpha) * l1

    @func_grad(channel_error)
    def adj_channel_error(
        target: wp.array(dtype=T),
        cand: wp.array(dtype=T),
        t0: int,
        c0: int,
        r0: int,
        r1: int,
        r2: int,
        x0: int,
        x1: int,
        x2: int,
        alpha: T,
        adj_ret: T,
    ):
        # Written by hand (Warp's own adjoint replays the nine taps and is ~2x slower). With
        # m = mean, v = variance, c = covariance of the window and SSIM = N / D,
        # N = (2 mx my + C1)(2 cxy + C2), D = (mx^2 + my^2 + C1)(vx + vy + C2), the gradient of tap j
        # of the candidate is g (dS/dmy + 2 dS/dvy (y_j - my) + dS/dcxy (x_j - mx)) / 9 with
        # g = adj * alpha * d clamp((1 - S) / 2) / dS (-1/2 inside the clamp's range, bounds
        # included, as torch.clamp; 0 outside), and symmetrically for the target.
        gt = wp.adjoint[target]
        gc = wp.adjoint[cand]
        if gt.shape[0] == 0 and gc.shape[0] == 0:
            return  # (e.g. an identity candidate, whose images need no gradient)
        sx, sy, sxx, syy, sxy = window_sums(target, cand, t0, c0, r0, r1, r2, x0, x1, x2)
        ninth = T(1.0) / T(9.0)
        c1 = T(1.0) / T(10000.0)
        c2 = T(9.0) / T(10000.0)
        mx = sx * ninth
        my = sy * ninth
        vx = sxx * ninth - mx * mx
        vy = syy * ninth - my * my
        cxy = sxy * ninth - mx * my
        a1 = T(2.0) * mx * my + c1
        a2 = T(2.0) * cxy + c2
        b1 = mx * mx + my * my + c1
        b2 = vx + vy + c2
        den = b1 * b2
        ssim = a1 * a2 / den
        h = (T(1.0) - ssim) * T(0.5)
        g = T(0.0)
        if h >= T(0.0) and h <= T(1.0):
            g = -adj_ret * alpha * T(0.5) / den
        # d SSIM / d (mx, my, vx, vy, cxy), each times den
        d_mx = T(2.0) * my * a2 - ssim * T(2.0) * mx * b2
        d_my = T(2.0) * mx * a2 - ssim * T(2.0) * my * b2
        d_v = -ssim * b1
        d_c = T(2.0) * a1
        k = r1 + x1
        s1 = wp.sign(target[t0 + k] - cand[c0 + k]) * adj_ret * (T(1.0) - alpha)
        if gt.shape[0] > 0:
            for dy in range(3):
                row = tap(dy, r0, r1, r2)
                for dx in range(3):
                    j = row + tap(dx, x0, x1, x2)
                    a = target[t0 + j]
                    b = cand[c0 + j]
                    gt[t0 + j] += g * ninth * (d_mx + T(2.0) * d_v * (a - mx) + d_c * (b - my))
            gt[t0 + k] += s1
        if gc.shape[0] > 0:
            for dy in range(3):
                row = tap(dy, r0, r1, r2)
                for dx in range(3):
                    j = row + tap(dx, x0, x1, x2)
                    a = target[t0 + j]
                    b = cand[c0 + j]
                    gc[c0 + j] += g * ninth * (d_my + T(2.0) * d_v * (b - my) + d_c * (a - mx))
            gc[c0 + k] -= s1

    @wp.func_replay(channel_error)
    def replay_channel_error(
        target: wp.array(dtype=T),
        cand: wp.array(dtype=T),
        t0: int,
        c0: int,
        r0: int,
        r1: int,
        r2: int,
        x0: int,
        x1: int,
        x2: int,
        alpha: T,
    ):
        # The forward replayed in an adjoint launch: kernels only accumulate the value into their
        # output (whose adjoint needs no value), so the nine taps are not summed twice.
        return T(0.0)

    return channel_error


@wp.func
def column(target: wp.array(dtype=Any), cand: wp.array(dtype=Any), t: int, c: int, r0: int, r1: int, r2: int):
    """Sums over the window's three rows of one column: (x, y, x^2, y^2, x y) for target element
    ``t`` and candidate element ``c`` (the column's offsets in their planes) plus the row offsets."""
    a0 = target[t + r0]
    a1 = target[t + r1]
    a2 = target[t + r2]
    b0 = cand[c + r0]
    b1 = cand[c + r1]
    b2 = cand[c + r2]
    return (a0 + a1 + a2, b0 + b1 + b2, a0 * a0 + a1 * a1 + a2 * a2, b0 * b0 + b1 * b1 + b2 * b2,
            a0 * b0 + a1 * b1 + a2 * b2)


@wp.func
def window_sums(
    target: wp.array(dtype=Any),
    cand: wp.array(dtype=Any),
    t0: int,
    c0: int,
    r0: int,
    r1: int,
    r2: int,
    x0: int,
    x1: int,
    x2: int,
):
    """Sums of (x, y, x^2, y^2, x y) over the 3x3 window (rows r0..r2, columns x0..x2) of the
    target plane at ``t0`` and the candidate plane at ``c0``: the three columns' sums
    (:func:`column`), added as :func:`row_errors` adds them."""
    lx, ly, lxx, lyy, lxy = column(target, cand, t0 + x0, c0 + x0, r0, r1, r2)
    mx, my, mxx, myy, mxy = column(target, cand, t0 + x1, c0 + x1, r0, r1, r2)
    rx, ry, rxx, ryy, rxy = column(target, cand, t0 + x2, c0 + x2, r0, r1, r2)
    return lx + mx + rx, ly + my + ry, lxx + mxx + rxx, lyy + myy + ryy, lxy + mxy + rxy


channel_error = float_overloads(_channel_error)


@wp.func
def row_errors(
    target: wp.array(dtype=Any),
    cand: wp.array(dtype=Any),
    acc: wp.array(dtype=Any),
    t0: int,
    c0: int,
    C: int,
    hw: int,
    W: int,
    r0: int,
    r1: int,
    r2: int,
    out0: int,
    alpha: Any,
):
    """pe of one candidate for every pixel of one row, into acc[out0:out0 + W] (overwritten):
    the window sums slide along the row (each column's sums computed once, not three times).
    Forward only (locals carried through dynamic loops)."""
    inv_c = type(alpha)(1.0) / type(alpha)(C)
    for x in range(W):
        acc[out0 + x] = type(alpha)(0.0)
    for ch in range(C):
        tp = t0 + ch * hw
        cp = c0 + ch * hw
        # columns x - 1, x, x + 1 of the window (reflected: column -1 is column 1)
        lx, ly, lxx, lyy, lxy = column(target, cand, tp + 1, cp + 1, r0, r1, r2)
        mx, my, mxx, myy, mxy = column(target, cand, tp, cp, r0, r1, r2)
        rx, ry, rxx, ryy, rxy = column(target, cand, tp + 1, cp + 1, r0, r1, r2)  # (not "= lx, ...": an alias)
        for x in range(W):
            e = dssim(lx + mx + rx, ly + my + ry, lxx + mxx + rxx, lyy + myy + ryy, lxy + mxy + rxy)
            l1 = wp.abs(target[tp + r1 + x] - cand[cp + r1 + x])
            acc[out0 + x] += inv_c * (alpha * e + (type(alpha)(1.0) - alpha) * l1)
            nxt = reflect(wp.min(x + 2, W), W)  # (column x + 2 of the next window; unused after the last)
            lx, ly, lxx, lyy, lxy = mx, my, mxx, myy, mxy
            mx, my, mxx, myy, mxy = rx, ry, rxx, ryy, rxy
            rx, ry, rxx, ryy, rxy = column(target, cand, tp + nxt, cp + nxt, r0, r1, r2)
