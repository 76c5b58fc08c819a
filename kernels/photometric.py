"""Building blocks of the fused photometric objective as ``@wp.func`` (no launches here).

The objective compares a reference image with a live image sampled where the reference pixels
land after a rigid motion (see :mod:`.photometric_kernels`); this module holds its per-residual
pieces: the penalties ("l1", "l2" and the M-estimators of :mod:`.robust`), their derivative and
IRLS weight, and the bilinear interpolant with its exact derivative at the sample point.

Penalty kinds are integer codes: :data:`.robust.KINDS` (huber 0, cauchy 1, geman_mcclure 2,
tukey 3) plus :data:`L2` (``r^2 / 2``) and :data:`L1` (``|r|``); ``scale`` is used by the
M-estimators only.
"""

from typing import Any

import warp as wp

from . import robust

L2 = wp.constant(4)
L1 = wp.constant(5)
#: penalty name -> the integer code the kernels take
KINDS = {"l1": 5, "l2": 4, **robust.KINDS}


@wp.func
def penalty(r: Any, kind: int, c: Any):
    """rho(r): |r| (L1), r^2 / 2 (L2), or the M-estimator ``kind`` with scale ``c``."""
    p = r * r * type(r)(0.5)
    if kind == L1:
        p = wp.abs(r)
    elif kind != L2:
        p = robust.rho(r, kind, c)
    return p


@wp.func
def penalty_grad(r: Any, kind: int, c: Any):
    """d rho / dr: sign(r) (L1, 0 at r = 0), r (L2), or psi(r) of the M-estimator."""
    zero = type(r)(0.0)
    g = r
    if kind == L1:
        g = wp.where(r > zero, type(r)(1.0), wp.where(r < zero, type(r)(-1.0), zero))
    elif kind != L2:
        g = robust.psi(r, kind, c)
    return g


@wp.func
def irls_weight(r: Any, kind: int, c: Any):
    """The IRLS weight psi(r) / r (1 for L2; at r = 0 its limit, rho''(0) = 1 for every
    M-estimator). Not defined for L1 (unbounded at 0): callers reject it."""
    one = type(r)(1.0)
    w = one
    if kind != L2:
        nz = r != type(r)(0.0)
        w = wp.where(nz, robust.psi(r, kind, c) / wp.where(nz, r, one), one)
    return w


@wp.func
def taps(x: Any, y: Any, H: int, W: int):
    """Bilinear set-up at pixel position (x, y) with -1 < x < W, -1 < y < H: the flat in-plane
    offsets of the four taps (00, 10, 01, 11; clamped into the image, so always readable), their
    masks (the tap lies in the image: outside ones read 0, zeros padding) and the weights
    (wx1, wy1) = (x - floor x, y - floor y), as grid_sample computes them."""
    fx0 = wp.floor(x)
    fy0 = wp.floor(y)
    x0 = int(fx0)
    y0 = int(fy0)
    kx0 = x0 >= 0
    kx1 = x0 < W - 1
    ky0 = y0 >= 0
    ky1 = y0 < H - 1
    ra = wp.max(y0, 0) * W
    rb = wp.min(y0 + 1, H - 1) * W
    xa = wp.max(x0, 0)
    xb = wp.min(x0 + 1, W - 1)
    return (
        ra + xa, ra + xb, rb + xa, rb + xb,
        ky0 and kx0, ky0 and kx1, ky1 and kx0, ky1 and kx1,
        x - fx0, y - fy0,
    )


@wp.func
def interpolate(v00: Any, v10: Any, v01: Any, v11: Any, wx1: Any, wy1: Any):
    """The bilinear interpolant of four tap values and its exact derivatives along x and y at the
    sample point: (value, d/dx, d/dy). floor() contributes nothing, as in grid_sample's backward."""
    one = type(wx1)(1.0)
    wx0 = one - wx1
    wy0 = one - wy1
    value = (v00 * wx0 + v10 * wx1) * wy0 + (v01 * wx0 + v11 * wx1) * wy1
    gx = (v10 - v00) * wy0 + (v11 - v01) * wy1
    gy = (v01 - v00) * wx0 + (v11 - v10) * wx1
    return value, gx, gy


@wp.func
def read_tap(a: wp.array(dtype=Any), index: int, inside: bool):
    """a[index] where the tap is inside the image, else 0 (a select: a NaN behind it gives 0)."""
    return wp.where(inside, a[wp.max(index, 0)], a.dtype(0.0))


@wp.func
def projection_gradient(gu: Any, gv: Any, fx: Any, fy: Any, s: Any, inv_z: Any, xn: Any, yn: Any):
    """(gu, gv) d(u, v)/dP for the pinhole projection u = fx X/Z + s Y/Z + cx, v = fy Y/Z + cy
    at P with 1/Z = inv_z, X/Z = xn, Y/Z = yn: the gradient of a function of (u, v) w.r.t. P."""
    return wp.vector(
        gu * fx * inv_z,
        (gu * s + gv * fy) * inv_z,
        -(gu * (fx * xn + s * yn) + gv * fy * yn) * inv_z,
    )


@wp.func
def twist_jacobian(p: Any, gp: Any):
    """d f / d delta at delta = 0 for f(exp(delta) P) with gradient ``gp`` = df/dP and
    delta = [omega, t]: dP/domega = -[P]x, dP/dt = I, so J = [P x gp, gp]."""
    c = wp.cross(p, gp)
    return c[0], c[1], c[2], gp[0], gp[1], gp[2]
