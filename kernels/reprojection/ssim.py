"""``@wp.func`` library of the reprojection objective (definitions: the package docstring).
No launches here."""

from typing import Any

import warp as wp

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
def channel_error(
    target: wp.array(dtype=Any),
    cand: wp.array(dtype=Any),
    t0: int,
    c0: int,
    W: int,
    H: int,
    x: int,
    y: int,
    alpha: Any,
):
    """One channel's share of pe at pixel (x, y): alpha clamp((1 - SSIM) / 2) + (1 - alpha) |t - c|,
    for the planes starting at ``t0`` in ``target`` and ``c0`` in ``cand``."""
    sx = type(alpha)(0.0)
    sy = type(alpha)(0.0)
    sxx = type(alpha)(0.0)
    syy = type(alpha)(0.0)
    sxy = type(alpha)(0.0)
    for dy in range(3):
        row = reflect(y + dy - 1, H) * W
        for dx in range(3):
            k = row + reflect(x + dx - 1, W)
            a = target[t0 + k]
            b = cand[c0 + k]
            sx += a
            sy += b
            sxx += a * a
            syy += b * b
            sxy += a * b
    k = y * W + x
    l1 = wp.abs(target[t0 + k] - cand[c0 + k])
    return alpha * dssim(sx, sy, sxx, syy, sxy) + (type(alpha)(1.0) - alpha) * l1


@wp.func
def candidate_error(
    target: wp.array(dtype=Any),
    cand: wp.array(dtype=Any),
    t0: int,
    c0: int,
    C: int,
    H: int,
    W: int,
    x: int,
    y: int,
    alpha: Any,
):
    """pe of one candidate at pixel (x, y) (mean over the C channels); forward only (a dynamic
    loop carrying a local sum: the differentiated kernel accumulates into its output instead)."""
    hw = H * W
    e = type(alpha)(0.0)
    for c in range(C):
        e += channel_error(target, cand, t0 + c * hw, c0 + c * hw, W, H, x, y, alpha)
    return e / type(alpha)(C)
