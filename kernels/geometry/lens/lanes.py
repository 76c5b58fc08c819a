"""The projection through a lens of 8 pixels at once, as length-8 vectors of the kernel's float type
(LLVM turns them into SIMD code; see :mod:`gvnn_warp.kernels.core.lanes`): the 3D spatial
transformer's block (``sampling.lens_block``) computes a block's projections with these before its
samples. Unlike :mod:`.rays`' ``project_ray`` (float64 inside, rounded), the lanes evaluate the lens
in the kernel's float type: for float32, (u, v) within ~1e-4 px of ``project_ray``'s (relative
rounding ~1e-7 of coordinates up to ~1e3 px), for float64 equal to rounding. Each function exists
with the projection's Jacobian (the backward) and without it (the forward: the lane functions are
too large to be inlined, so unused results would still be computed): :func:`functions`.
"""

import math
from typing import Any, NamedTuple

import warp as wp

from ...core import lanes
from ...core.cache import specialise
from . import fisheye
from .constants import FISHEYE, LIMIT, RADTAN


class Lanes(NamedTuple):
    """The lane functions of one variant (with or without the Jacobian)."""

    distort8: wp.Function
    project_rays8: wp.Function
    block_lanes: wp.Function


@wp.func
def _poly_pair8(w: Any, c0: Any, c1: Any):
    """c0 + c1 w per lane (c0, c1 scalars)."""
    return lanes.splat8(c0) + w * c1


def estrin20_lanes(coeffs):
    """:func:`.fisheye.estrin20` per lane: w (8 lanes) -> the polynomial, in the lanes' float type (a
    plain generator as that one, called once per table by :func:`atan_ratio_lanes`)."""

    @wp.func
    def estrin20(w: Any, one: Any):
        w2 = wp.cw_mul(w, w)
        w4 = wp.cw_mul(w2, w2)
        w8 = wp.cw_mul(w4, w4)
        w16 = wp.cw_mul(w8, w8)
        h0 = _poly_pair8(w, type(one)(wp.static(coeffs[0])), type(one)(wp.static(coeffs[1])))
        h1 = _poly_pair8(w, type(one)(wp.static(coeffs[2])), type(one)(wp.static(coeffs[3])))
        h2 = _poly_pair8(w, type(one)(wp.static(coeffs[4])), type(one)(wp.static(coeffs[5])))
        h3 = _poly_pair8(w, type(one)(wp.static(coeffs[6])), type(one)(wp.static(coeffs[7])))
        h4 = _poly_pair8(w, type(one)(wp.static(coeffs[8])), type(one)(wp.static(coeffs[9])))
        h5 = _poly_pair8(w, type(one)(wp.static(coeffs[10])), type(one)(wp.static(coeffs[11])))
        h6 = _poly_pair8(w, type(one)(wp.static(coeffs[12])), type(one)(wp.static(coeffs[13])))
        h7 = _poly_pair8(w, type(one)(wp.static(coeffs[14])), type(one)(wp.static(coeffs[15])))
        h8 = _poly_pair8(w, type(one)(wp.static(coeffs[16])), type(one)(wp.static(coeffs[17])))
        h9 = _poly_pair8(w, type(one)(wp.static(coeffs[18])), type(one)(wp.static(coeffs[19])))
        a0 = h0 + wp.cw_mul(h1, w2)
        a1 = h2 + wp.cw_mul(h3, w2)
        a2 = h4 + wp.cw_mul(h5, w2)
        a3 = h6 + wp.cw_mul(h7, w2)
        a4 = h8 + wp.cw_mul(h9, w2)
        b0 = a0 + wp.cw_mul(a1, w4)
        b1 = a2 + wp.cw_mul(a3, w4)
        b2 = a4 + w4 * type(one)(wp.static(coeffs[20]))
        return b0 + wp.cw_mul(b1, w8) + wp.cw_mul(b2, w16)

    return estrin20


@specialise("geometry.lens_atan_ratio_lanes")
def atan_ratio_lanes() -> tuple[wp.Function, wp.Function]:
    """(c, dc/dw) of :func:`.fisheye.atan_ratio_poly` per lane: its two polynomials' evaluators,
    made with the lane functions (defining them takes ~10 ms each, which importing this module,
    done by the pinhole spatial transformer's, should not)."""
    return estrin20_lanes(fisheye.ATAN_H), estrin20_lanes(fisheye.ATAN_G)


@wp.func
def load_rays8(rays: wp.array(dtype=Any), base: int, last: int):
    """The rays rays[base + min(k, last)], k = 0..7, as lanes (x, y, w) (see :func:`.core.lanes.load8`)."""
    i = wp.max(base, 0)
    n = wp.max(wp.min(last, 7), 0)
    r0 = rays[i]
    r1 = rays[i + wp.min(1, n)]
    r2 = rays[i + wp.min(2, n)]
    r3 = rays[i + wp.min(3, n)]
    r4 = rays[i + wp.min(4, n)]
    r5 = rays[i + wp.min(5, n)]
    r6 = rays[i + wp.min(6, n)]
    r7 = rays[i + wp.min(7, n)]
    return (
        wp.vector(r0[0], r1[0], r2[0], r3[0], r4[0], r5[0], r6[0], r7[0]),
        wp.vector(r0[1], r1[1], r2[1], r3[1], r4[1], r5[1], r6[1], r7[1]),
        wp.vector(r0[2], r1[2], r2[2], r3[2], r4[2], r5[2], r6[2], r7[2]),
    )


@specialise("geometry.lens_lanes")
def functions(jacobian: bool) -> Lanes:
    """The lane functions with (``jacobian``) or without the projection's Jacobian (then returned
    as zeros)."""
    atan_ratio_h8, atan_ratio_g8 = atan_ratio_lanes()

    @wp.func
    def atan_ratio8(z: Any, one: Any):
        """(c, dc/dz) of :func:`.fisheye.atan_ratio` per lane (z >= 0; dc only with the Jacobian),
        the same formulas: the polynomial at w = 2 z - 1 on z <= 1, and beyond (more than 45
        degrees off the axis) c(z) = pi / (2 sqrt(z)) - c(1/z) / z with the polynomial at
        w = 2 / z - 1. One polynomial evaluation for both and no branch (a branch on "any lane
        beyond" cost the block ~4 ns per pixel, taken or not)."""
        ones = lanes.splat8(one)
        two = type(one)(2.0)
        big = lanes.open_mask8(z, one, type(one)(wp.inf))  # 1 where z > 1 (z is finite here)
        small = ones - big
        zb = wp.max(z, ones)
        iz = wp.cw_div(ones, zb)
        # w exact in both cases: the masks are 0 or 1 and both terms are in [-1, 1] (z up to the
        # float type's largest: 2 z - 1 would overflow, 2 min(z, 1) - 1 does not)
        w = wp.cw_mul(small, wp.min(z, ones) * two - ones) + wp.cw_mul(big, iz * two - ones)
        h = atan_ratio_h8(w, one)
        root = wp.vector(
            wp.sqrt(zb[0]), wp.sqrt(zb[1]), wp.sqrt(zb[2]), wp.sqrt(zb[3]),
            wp.sqrt(zb[4]), wp.sqrt(zb[5]), wp.sqrt(zb[6]), wp.sqrt(zb[7]),
        )
        a = wp.cw_mul(root, iz) * type(one)(wp.static(math.pi / 2.0))
        c = wp.cw_mul(small, h) + wp.cw_mul(big, a - wp.cw_mul(h, iz))
        dc = lanes.splat8(type(one)(0.0))
        if wp.static(jacobian):
            g = atan_ratio_g8(w, one)
            dc_big = wp.cw_mul(a * type(one)(-0.5) + wp.cw_mul(h + wp.cw_mul(g, iz) * two, iz), iz)
            dc = wp.cw_mul(small, g * two) + wp.cw_mul(big, dc_big)
        return c, dc

    @wp.func
    def distort8(model: int, dist: Any, x: Any, y: Any, one: Any):
        """The distortion of 8 lanes of normalized (x, y) and its Jacobian: (xd, yd, J00, J01, J10,
        J11), the formulas of :func:`.dispatch.distort64` per lane in the float type of ``one``."""
        two = type(one)(2.0)
        xx = wp.cw_mul(x, x)
        yy = wp.cw_mul(y, y)
        xy = wp.cw_mul(x, y)
        r2 = xx + yy
        ones = lanes.splat8(one)
        xd = x
        yd = y
        J00 = ones
        J01 = lanes.splat8(type(one)(0.0))
        J10 = J01
        J11 = ones
        if model == RADTAN:
            k1 = dist[0]
            k2 = dist[1]
            p1 = dist[2]
            p2 = dist[3]
            k3 = dist[4]
            R = ones + wp.cw_mul(r2, lanes.splat8(k1) + wp.cw_mul(r2, lanes.splat8(k2) + r2 * k3))
            xd = wp.cw_mul(x, R) + xy * (two * p1) + (r2 + xx * two) * p2
            yd = wp.cw_mul(y, R) + (r2 + yy * two) * p1 + xy * (two * p2)
            if wp.static(jacobian):
                dR = lanes.splat8(k1) + wp.cw_mul(r2, lanes.splat8(two * k2) + r2 * (type(one)(3.0) * k3))
                off = wp.cw_mul(xy * two, dR) + x * (two * p1) + y * (two * p2)
                J00 = R + wp.cw_mul(xx * two, dR) + y * (two * p1) + x * (type(one)(6.0) * p2)
                J01 = off
                J10 = off
                J11 = R + wp.cw_mul(yy * two, dR) + y * (type(one)(6.0) * p1) + x * (two * p2)
        elif model == FISHEYE:
            # s = theta_d / r and q = 2 ds/d(r^2), as fisheye.terms
            c, dc = atan_ratio8(r2, one)
            cc = wp.cw_mul(c, c)
            t = wp.cw_mul(r2, cc)
            poly = ones + wp.cw_mul(t, lanes.splat8(dist[0]) + wp.cw_mul(t, lanes.splat8(dist[1]) + wp.cw_mul(
                t, lanes.splat8(dist[2]) + t * dist[3])))
            s = wp.cw_mul(c, poly)
            xd = wp.cw_mul(s, x)
            yd = wp.cw_mul(s, y)
            if wp.static(jacobian):
                dpoly = lanes.splat8(dist[0]) + wp.cw_mul(t, lanes.splat8(two * dist[1]) + wp.cw_mul(
                    t, lanes.splat8(type(one)(3.0) * dist[2]) + t * (type(one)(4.0) * dist[3])))
                dt = cc + wp.cw_mul(r2 * two, wp.cw_mul(c, dc))  # dt/d(r^2)
                q = (wp.cw_mul(dc, poly) + wp.cw_mul(wp.cw_mul(c, dpoly), dt)) * two
                qxy = wp.cw_mul(q, xy)
                J00 = s + wp.cw_mul(q, xx)
                J01 = qxy
                J10 = qxy
                J11 = s + wp.cw_mul(q, yy)
        return xd, yd, J00, J01, J10, J11

    @wp.func
    def project_rays8(
        model: int, R: Any, t: Any, K: Any, dist: Any, rx: Any, ry: Any, d: Any, min_depth: Any
    ):
        """:func:`.rays.project_ray_jacobian` for 8 lanes of rays (rx, ry) and depths d: returns (u, v, ok,
        du0, du1, du2, dv0, dv1, dv2), ok 1 or 0 per lane (q_z > min_depth and inside the domain),
        (du0, du1, du2) and (dv0, dv1, dv2) the rows d(u, v)/dq (zeros without the Jacobian).
        Where not ok: the principal point and the Jacobian there, for the caller to reject."""
        one = type(min_depth)(1.0)
        ones = lanes.splat8(one)
        zeros = lanes.splat8(type(one)(0.0))
        P0 = wp.cw_mul(rx, d)
        P1 = wp.cw_mul(ry, d)
        q0 = P0 * R[0, 0] + P1 * R[0, 1] + d * R[0, 2] + lanes.splat8(t[0])
        q1 = P0 * R[1, 0] + P1 * R[1, 1] + d * R[1, 2] + lanes.splat8(t[1])
        q2 = P0 * R[2, 0] + P1 * R[2, 1] + d * R[2, 2] + lanes.splat8(t[2])
        front = lanes.open_mask8(q2, min_depth, type(one)(3.0e38))
        iz = wp.cw_div(ones, lanes.select8(front, q2, ones))
        x = wp.cw_mul(q0, iz)
        y = wp.cw_mul(q1, iz)
        ok = wp.cw_mul(front, lanes.open_mask8(wp.cw_mul(x, x) + wp.cw_mul(y, y), -one, dist[LIMIT]))
        x = lanes.select8(ok, x, zeros)
        y = lanes.select8(ok, y, zeros)
        xd, yd, J00, J01, J10, J11 = distort8(model, dist, x, y, one)
        fx = K[0, 0]
        s = K[0, 1]
        fy = K[1, 1]
        u = xd * fx + yd * s + lanes.splat8(K[0, 2])
        v = yd * fy + lanes.splat8(K[1, 2])
        du0 = zeros
        du1 = zeros
        du2 = zeros
        dv0 = zeros
        dv1 = zeros
        dv2 = zeros
        if wp.static(jacobian):
            a00 = J00 * fx + J10 * s
            a01 = J01 * fx + J11 * s
            a10 = J10 * fy
            a11 = J11 * fy
            du0 = wp.cw_mul(a00, iz)
            du1 = wp.cw_mul(a01, iz)
            du2 = -wp.cw_mul(wp.cw_mul(a00, x) + wp.cw_mul(a01, y), iz)
            dv0 = wp.cw_mul(a10, iz)
            dv1 = wp.cw_mul(a11, iz)
            dv2 = -wp.cw_mul(wp.cw_mul(a10, x) + wp.cw_mul(a11, y), iz)
        return u, v, ok, du0, du1, du2, dv0, dv1, dv2

    @wp.func
    def block_lanes(
        depth: wp.array(dtype=Any), rays: wp.array(dtype=Any), i0: int, ray0: int, n: int, model: int, R: Any,
        t: Any, K: Any, dist: Any, min_depth: Any,
    ):
        """The n <= 8 pixels of a block of the spatial transformer (``sampling.lens_block``) read and
        projected as lanes (lanes past n repeat the last pixel): (u, v, ok, du0, du1, du2, dv0, dv1,
        dv2) of :func:`project_rays8`, ok also 0 where the depth is invalid (<= min, NaN, inf; depth 1
        stands in) or the pixel has no ray."""
        one = type(min_depth)(1.0)
        d = lanes.load8(depth, i0, 0, n - 1)
        rx, ry, rw = load_rays8(rays, ray0, n - 1)
        has_ray = lanes.open_mask8(rw, type(one)(0.0), type(one)(2.0))
        depth_ok = wp.cw_mul(lanes.open_mask8(d, min_depth, type(one)(1.0e30)), has_ray)
        u, v, ok, du0, du1, du2, dv0, dv1, dv2 = project_rays8(
            model, R, t, K, dist, rx, ry, lanes.select8(depth_ok, d, lanes.splat8(one)), min_depth
        )
        return u, v, wp.cw_mul(ok, depth_ok), du0, du1, du2, dv0, dv1, dv2

    return Lanes(distort8, project_rays8, block_lanes)


__all__ = ["Lanes", "atan_ratio_lanes", "estrin20_lanes", "functions", "load_rays8"]
