"""Building blocks of the fused photometric objective as ``@wp.func`` (no launches here).

The objective compares a reference image with a live image sampled where the reference pixels
land after a rigid motion (see :mod:`.error_rows`); this module holds its per-residual
pieces: the penalties ("l1", "l2" and the M-estimators of :mod:`.robust`), their derivative and
IRLS weight, and the bilinear interpolant with its exact derivative at the sample point.

Penalty kinds are integer codes: :data:`.robust.KINDS` (huber 0, cauchy 1, geman_mcclure 2,
tukey 3) plus :data:`L2` (``r^2 / 2``) and :data:`L1` (``|r|``); ``scale`` is used by the
M-estimators only.
"""

from typing import Any

import warp as wp

from .. import robust
from ..core import lanes
from ..core.cache import float_overloads
from ..core.compat import func_grad

L2 = wp.constant(4)
L1 = wp.constant(5)
#: penalty name -> the integer code the kernels take
KINDS = {"l1": 5, "l2": 4, **robust.KINDS}
#: fewest pixels worth a separate chunk of a threaded launch of the row kernels (a chunk costs ~15-20 us)
GRAIN_PIXELS = 16384


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


# ----------------------------------------------------------------------------- one pixel's penalty


# Channels handled by straight-line code in pixel_penalty and its adjoint (the rest by a loop).
UNROLLED_CHANNELS = 4


@wp.func
def channel_penalty(
    live: wp.array(dtype=Any), ref: wp.array(dtype=Any), base: int, ref_c: int,
    i00: int, i10: int, i01: int, i11: int, k00: bool, k10: bool, k01: bool, k11: bool, wx1: Any, wy1: Any,
    kind: int, c: Any,
):
    """rho(live(taps of plane ``base``) - ref[ref_c]) for one channel; 0 where not finite."""
    val, dx, dy = interpolate(
        read_tap(live, base + i00, k00), read_tap(live, base + i10, k10),
        read_tap(live, base + i01, k01), read_tap(live, base + i11, k11), wx1, wy1,
    )
    r = val - ref[ref_c]
    return wp.where(wp.abs(r) + wp.abs(dx) + wp.abs(dy) < type(wx1)(1.0e30), penalty(r, kind, c), type(wx1)(0.0))


@wp.func
def channel_grad(
    live: wp.array(dtype=Any), g_live: wp.array(dtype=Any), ref: wp.array(dtype=Any), g_ref: wp.array(dtype=Any),
    base: int, ref_c: int, i00: int, i10: int, i01: int, i11: int, k00: bool, k10: bool, k01: bool, k11: bool,
    wx1: Any, wy1: Any, kind: int, c: Any, adj: Any, scatter: bool, to_ref: bool,
):
    """The adjoint of :func:`channel_penalty` (see :func:`pixel_penalty_grad`): scatters into
    ``g_live`` / ``g_ref`` when asked, returns (d/du, d/dv)."""
    one = type(wx1)(1.0)
    val, dx, dy = interpolate(
        read_tap(live, base + i00, k00), read_tap(live, base + i10, k10),
        read_tap(live, base + i01, k01), read_tap(live, base + i11, k11), wx1, wy1,
    )
    r = val - ref[ref_c]
    gu = type(wx1)(0.0)
    gv = type(wx1)(0.0)
    if wp.abs(r) + wp.abs(dx) + wp.abs(dy) < type(wx1)(1.0e30):  # finite residual and derivatives
        g = adj * penalty_grad(r, kind, c)
        gu = g * dx
        gv = g * dy
        if scatter:
            wx0 = one - wx1
            wy0 = one - wy1
            if k00:
                g_live[base + i00] += g * (wx0 * wy0)
            if k10:
                g_live[base + i10] += g * (wx1 * wy0)
            if k01:
                g_live[base + i01] += g * (wx0 * wy1)
            if k11:
                g_live[base + i11] += g * (wx1 * wy1)
        if to_ref:
            g_ref[ref_c] -= g
    return gu, gv


@wp.func
def pixel_penalty_grad(
    live: wp.array(dtype=Any),
    g_live: wp.array(dtype=Any),
    ref: wp.array(dtype=Any),
    g_ref: wp.array(dtype=Any),
    live0: int,
    ref_i: int,
    C: int,
    hw: int,
    H: int,
    W: int,
    u: Any,
    v: Any,
    kind: int,
    c: Any,
    adj: Any,
):
    """The adjoint of :func:`pixel_penalty` where active: given ``adj`` = d loss / d (its value),
    adds d loss / d live (the four taps of every channel) into ``g_live`` and d loss / d ref into
    ``g_ref`` (null arrays, with no elements, are left alone) and returns (d loss / du, d loss / dv):
    with g = adj rho'(r_c), d/du = g d live_c/du (the bilinear interpolant's derivative)."""
    i00, i10, i01, i11, k00, k10, k01, k11, wx1, wy1 = taps(u, v, H, W)
    scatter = g_live.shape[0] > 0
    to_ref = g_ref.shape[0] > 0
    # each its own variable: `gu = zero` would alias zero, and `+=` would update every alias
    gu = type(u)(0.0)
    gv = type(u)(0.0)
    # channels unrolled up to UNROLLED_CHANNELS (constant trip count), the rest in a loop
    for ch in range(wp.static(UNROLLED_CHANNELS)):
        if ch < C:
            cu, cv = channel_grad(live, g_live, ref, g_ref, live0 + ch * hw, ref_i + ch * hw, i00, i10, i01, i11,
                                  k00, k10, k01, k11, wx1, wy1, kind, c, adj, scatter, to_ref)
            gu += cu
            gv += cv
    for ch in range(UNROLLED_CHANNELS, C):
        cu, cv = channel_grad(live, g_live, ref, g_ref, live0 + ch * hw, ref_i + ch * hw, i00, i10, i01, i11,
                              k00, k10, k01, k11, wx1, wy1, kind, c, adj, scatter, to_ref)
        gu += cu
        gv += cv
    return gu, gv


def _pixel_penalty(T):
    """float type ``T`` overload of pixel_penalty (Warp custom adjoints need concrete types)."""

    @wp.func
    def pixel_penalty(
        live: wp.array(dtype=T),
        ref: wp.array(dtype=T),
        live0: int,
        ref_i: int,
        C: int,
        hw: int,
        H: int,
        W: int,
        u: T,
        v: T,
        kind: int,
        c: T,
        active: wp.bool,
    ):
        """sum over channels ch of rho(live_ch(u, v) - ref[ref_i + ch hw]) where ``active``, else 0.

        ``live`` and ``ref`` are flat (B, C, H, W); ``live0`` is the flat offset of the batch
        item's first live plane, ``ref_i`` that of the reference pixel in its first plane. When
        active, the caller guarantees -1 < u < W and -1 < v < H. Residuals that are not finite
        (NaN/inf intensities) count 0. Gradients (hand-written adjoint, below): to u, v, live
        (scattered to the four taps) and ref; none to the rest.
        """
        total = T(0.0)
        if active:
            i00, i10, i01, i11, k00, k10, k01, k11, wx1, wy1 = taps(u, v, H, W)
            for ch in range(wp.static(UNROLLED_CHANNELS)):
                if ch < C:
                    total += channel_penalty(live, ref, live0 + ch * hw, ref_i + ch * hw, i00, i10, i01, i11,
                                             k00, k10, k01, k11, wx1, wy1, kind, c)
            for ch in range(UNROLLED_CHANNELS, C):
                total += channel_penalty(live, ref, live0 + ch * hw, ref_i + ch * hw, i00, i10, i01, i11,
                                         k00, k10, k01, k11, wx1, wy1, kind, c)
        return total

    @func_grad(pixel_penalty)
    def adj_pixel_penalty(
        live: wp.array(dtype=T),
        ref: wp.array(dtype=T),
        live0: int,
        ref_i: int,
        C: int,
        hw: int,
        H: int,
        W: int,
        u: T,
        v: T,
        kind: int,
        c: T,
        active: wp.bool,
        adj_ret: T,
    ):
        if active:
            gu, gv = pixel_penalty_grad(
                live, wp.adjoint[live], ref, wp.adjoint[ref], live0, ref_i, C, hw, H, W, u, v, kind, c, adj_ret
            )
            wp.adjoint[u] += gu
            wp.adjoint[v] += gv

    @wp.func_replay(pixel_penalty)
    def replay_pixel_penalty(
        live: wp.array(dtype=T),
        ref: wp.array(dtype=T),
        live0: int,
        ref_i: int,
        C: int,
        hw: int,
        H: int,
        W: int,
        u: T,
        v: T,
        kind: int,
        c: T,
        active: wp.bool,
    ):
        # the backward pass needs no value of it: skip re-sampling every channel
        return T(0.0)

    return pixel_penalty


pixel_penalty = float_overloads(_pixel_penalty)


# ----------------------------------------------------------------------------- 8 pixels at a time
#
# The penalties and weights on 8 lanes (the lane helpers: :mod:`..core.lanes`).


@wp.func
def weight8(r: Any, kind: int, c: Any):
    """:func:`irls_weight` on 8 lanes, in closed forms without branches: Huber c / max(|r|, c);
    Cauchy 1 / (1 + u^2); Geman-McClure its square; Tukey (1 - min(u^2, 1))^2 (u = r / c)."""
    one = type(c)(1.0)
    ones = lanes.splat8(one)
    w = ones
    if kind == robust.HUBER:
        w = wp.cw_div(lanes.splat8(c), wp.max(wp.max(r, -r), lanes.splat8(c)))
    elif kind != L2:
        u2 = wp.cw_mul(r, r) * (one / (c * c))
        w = wp.cw_div(ones, ones + u2)
        if kind == robust.GEMAN_MCCLURE:
            w = wp.cw_mul(w, w)
        elif kind == robust.TUKEY:
            z = ones - wp.min(u2, ones)
            w = wp.cw_mul(z, z)
    return w


@wp.func
def penalty8(r: Any, kind: int, c: Any):
    """:func:`penalty` on 8 lanes (Huber, Geman-McClure, Tukey, L2 in closed forms without
    branches; Cauchy per lane through :func:`.robust.rho`)."""
    one = type(c)(1.0)
    half = type(c)(0.5)
    ones = lanes.splat8(one)
    p = wp.cw_mul(r, r) * half
    if kind == robust.HUBER:
        a = wp.max(r, -r)
        m = wp.min(a, lanes.splat8(c))
        p = wp.cw_mul(m, a - m * half)  # r^2 / 2 inside, c (|r| - c / 2) beyond
    elif kind == robust.CAUCHY:
        p = wp.vector(
            robust.rho(r[0], kind, c), robust.rho(r[1], kind, c), robust.rho(r[2], kind, c),
            robust.rho(r[3], kind, c), robust.rho(r[4], kind, c), robust.rho(r[5], kind, c),
            robust.rho(r[6], kind, c), robust.rho(r[7], kind, c),
        )
    elif kind == robust.GEMAN_MCCLURE:
        u2 = wp.min(wp.cw_mul(r, r) * (one / (c * c)), lanes.splat8(type(c)(1.0e30)))  # no inf / inf
        p = wp.cw_div(u2, ones + u2) * (c * c * half)  # (c^2 / 2) u^2 / (1 + u^2) = (r^2 / 2) / (1 + u^2)
    elif kind == robust.TUKEY:
        z = wp.min(wp.cw_mul(r, r) * (one / (c * c)), ones)
        three = lanes.splat8(type(c)(3.0))
        p = wp.cw_mul(z, three - wp.cw_mul(z, three - z)) * (c * c / type(c)(6.0))
    return p
