"""Pixel rays through a lens model, for the fused kernels (``@wp.func``, no launches here).

A lens model (``model``, ``K``, ``dist``: the contract of :mod:`.lens`) cannot use the pinhole's
row linearity (:func:`.camera.row_rays`): the ray of pixel (x, y) is ``undistort(K^-1 [x, y, 1])``,
found by Newton's method. The fused kernels therefore read precomputed rays (:func:`pixel_ray`,
launched once per camera and image size, its gradient by the implicit function theorem through
:func:`.lens.undistort`) and move and project them with :func:`project_ray`, whose hand-written
adjoint computes the projection's Jacobian once per pixel (Warp's automatic adjoint would
re-derive it term by term), in float64 inside as :mod:`.lens` does.

The spatial transformer's kernel instead works in blocks of 8 pixels (:func:`warp_block`): the
block's rays are moved and projected as 8-lane vectors in the kernel's own float type
(:func:`block_lanes`, SIMD code), and only then sampled, so that the image reads of the block are
not each held up by its own projection. For float32 that projection is float32 arithmetic (within
~1e-4 px of :func:`project_ray`'s), for float64 it is exact to rounding.

A ray is stored as ``(xn, yn, w)``: the ideal normalized coordinates of the pixel (its point at
depth d is ``d (xn, yn, 1)``) and ``w = 1`` where the undistortion converged inside the model's
domain, 0 where it did not (the pixel has no ray: treated as an invalid depth).
"""

import math
from typing import Any

import warp as wp

from ...core import lanes
from ...core.kinds import vec8d, vec8f
from ...sampling import sampler
from .. import camera, lens


@wp.func
def pixel_ray(model: int, K: Any, dist: Any, x: Any, y: Any):
    """The stored ray ``(xn, yn, w)`` of pixel (x, y) (see the module docstring). Gradients (to
    K and dist) through :func:`.lens.undistort`'s implicit-function adjoint; none where w = 0."""
    r = camera.pixel_ray(K, x, y)
    xn, ok = lens.undistort(model, dist, wp.vector(r[0], r[1]))
    return wp.vector(xn[0], xn[1], wp.where(ok, type(x)(1.0), type(x)(0.0)))


def _make_project_ray(T, project_ray=None):
    """float type ``T`` overload of project_ray (Warp custom adjoints need concrete types); the
    parameter named like the function is the overload made before (see sampler.py)."""
    f64 = wp.float64
    vec3 = wp.types.vector(3, T)
    mat33 = wp.types.matrix((3, 3), T)
    vec8 = vec8f if T == wp.float32 else vec8d

    @wp.func
    def project_ray(model: int, R: mat33, t: vec3, K: mat33, dist: vec8, ray: vec3, depth: T, min_depth: T):
        """Move the point ``depth (ray_x, ray_y, 1)`` by [R | t] and project it through the lens:
        returns ((u, v, q_z), ok) with q the moved point; ``ok``: q_z > min_depth and q inside the
        model's domain (r^2 < dist[LIMIT]). Where not ok, (u, v) is a finite stand-in (the
        principal point) for the caller to reject, and no gradient flows from it. The lens is
        evaluated as :func:`.lens.project` does (in float64, rounded; X/Z as X * (1/Z)), so (u, v)
        equals ``lens.project(model, K, dist, q)`` to rounding. Gradients (hand-written adjoint): to R, t, K, dist,
        the ray's (x, y) and depth; q_z passes its own gradient."""
        q = R * vec3(ray[0] * depth, ray[1] * depth, depth) + t
        front = q[2] > min_depth
        iz = f64(1.0) / f64(wp.where(front, q[2], T(1.0)))  # one division (two cost more than the lens)
        x = f64(q[0]) * iz
        y = f64(q[1]) * iz
        d = lens._to64(dist)
        ok = front and x * x + y * y < d[lens.LIMIT]
        xd, yd = lens._distort_value64(model, d, wp.where(ok, x, f64(0.0)), wp.where(ok, y, f64(0.0)))
        u = T(f64(K[0, 0]) * xd + f64(K[0, 1]) * yd + f64(K[0, 2]))
        v = T(f64(K[1, 1]) * yd + f64(K[1, 2]))
        return vec3(u, v, q[2]), ok

    @wp.func_grad(project_ray)
    def adj_project_ray(
        model: int, R: mat33, t: vec3, K: mat33, dist: vec8, ray: vec3, depth: T, min_depth: T,
        adj_ret0: vec3, adj_ret1: bool,
    ):
        P = vec3(ray[0] * depth, ray[1] * depth, depth)
        q = R * P + t
        front = q[2] > min_depth
        iz = f64(1.0) / f64(wp.where(front, q[2], T(1.0)))
        x = f64(q[0]) * iz
        y = f64(q[1]) * iz
        d = lens._to64(dist)
        gq = vec3(T(0.0), T(0.0), adj_ret0[2])
        if front and x * x + y * y < d[lens.LIMIT]:
            xd, yd, J = lens._distort64(model, d, x, y)
            gu = f64(adj_ret0[0])
            gv = f64(adj_ret0[1])
            # u = fx xd + s yd + cx, v = fy yd + cy; (xd, yd) = D(x, y); x = q0 / q2, y = q1 / q2
            gxd = f64(K[0, 0]) * gu
            gyd = f64(K[0, 1]) * gu + f64(K[1, 1]) * gv
            gx = J[0, 0] * gxd + J[1, 0] * gyd
            gy = J[0, 1] * gxd + J[1, 1] * gyd
            gq = vec3(T(gx * iz), T(gy * iz), T(f64(adj_ret0[2]) - (x * gx + y * gy) * iz))
            wp.adjoint[K] += mat33(
                T(gu * xd), T(gu * yd), T(gu), T(0.0), T(gv * yd), T(gv), T(0.0), T(0.0), T(0.0)
            )
            wp.adjoint[dist] += lens._from64(lens._distort_vjp_dist64(model, d, x, y, gxd, gyd), depth)
        wp.adjoint[t] += gq
        wp.adjoint[R] += wp.outer(gq, P)
        gP = wp.transpose(R) * gq
        wp.adjoint[ray] += vec3(gP[0] * depth, gP[1] * depth, T(0.0))
        wp.adjoint[depth] += gP[0] * ray[0] + gP[1] * ray[1] + gP[2]

    return project_ray


project_ray = _make_project_ray(wp.float64, _make_project_ray(wp.float32))



@wp.func
def project_ray_jacobian(model: int, R: Any, t: Any, K: Any, dist: Any, ray: Any, depth: Any, min_depth: Any):
    """:func:`project_ray`'s values with the projection's Jacobian, for Gauss-Newton (no adjoint):
    returns (u, v, q, ok, du/dq, dv/dq), q the moved point, du/dq and dv/dq (vec3) the rows of
    d(u, v)/dq = [[fx, s], [0, fy]] J_D (1 / q_z) [[1, 0, -x], [0, 1, -y]] (J_D the distortion's
    Jacobian at (x, y) = (q_x, q_y) / q_z). Where not ok the Jacobian is that of the stand-in."""
    q = R * wp.vector(ray[0] * depth, ray[1] * depth, depth) + t
    front = q[2] > min_depth
    iz = wp.float64(1.0) / wp.float64(wp.where(front, q[2], type(depth)(1.0)))
    x = wp.float64(q[0]) * iz
    y = wp.float64(q[1]) * iz
    d = lens._to64(dist)
    ok = front and x * x + y * y < d[lens.LIMIT]
    xs = wp.where(ok, x, wp.float64(0.0))
    ys = wp.where(ok, y, wp.float64(0.0))
    xd, yd, J = lens._distort64(model, d, xs, ys)
    fx = wp.float64(K[0, 0])
    s = wp.float64(K[0, 1])
    fy = wp.float64(K[1, 1])
    a00 = fx * J[0, 0] + s * J[1, 0]
    a01 = fx * J[0, 1] + s * J[1, 1]
    a10 = fy * J[1, 0]
    a11 = fy * J[1, 1]
    du = wp.vector(type(depth)(a00 * iz), type(depth)(a01 * iz), type(depth)(-(a00 * xs + a01 * ys) * iz))
    dv = wp.vector(type(depth)(a10 * iz), type(depth)(a11 * iz), type(depth)(-(a10 * xs + a11 * ys) * iz))
    u = type(depth)(fx * xd + s * yd + wp.float64(K[0, 2]))
    v = type(depth)(fy * yd + wp.float64(K[1, 2]))
    return u, v, q, ok, du, dv


# ----------------------------------------------------------------------------- 8 lanes
# The projection through the lens for 8 pixels at once, as length-8 vectors of the kernel's float
# type (LLVM turns them into SIMD code; see photometric.py's lane helpers): warp_block computes a
# block's projections with these before its samples. Unlike project_ray (float64 inside, rounded),
# the lanes evaluate the lens in the kernel's float type: for float32, (u, v) within ~1e-4 px of
# project_ray's (relative rounding ~1e-7 of coordinates up to ~1e3 px), for float64 equal to rounding.
# Each function exists with the projection's Jacobian (the backward) and without it (the forward:
# the lane functions are too large to be inlined, so unused results would still be computed).


@wp.func
def _poly_pair8(w: Any, c0: Any, c1: Any):
    """c0 + c1 w per lane (c0, c1 scalars)."""
    return lanes.splat8(c0) + w * c1


def _make_estrin20_lanes(coeffs):
    """:func:`.lens._make_estrin20` per lane: w (8 lanes) -> the polynomial, in the lanes' float type."""

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


_atan_ratio_h8 = _make_estrin20_lanes(lens._ATAN_H)  # c of lens._atan_ratio_poly per lane
_atan_ratio_g8 = _make_estrin20_lanes(lens._ATAN_G)  # dc/dw


@wp.func
def load_rays8(rays: wp.array(dtype=Any), base: int, last: int):
    """The rays rays[base + min(k, last)], k = 0..7, as lanes (x, y, w) (see :func:`.photometric.load8`)."""
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


def _make_lanes(jacobian: bool):
    """The lane functions with (``jacobian``) or without the projection's Jacobian (then returned
    as zeros): (distort8, project_rays8, block_lanes)."""

    @wp.func
    def atan_ratio8(z: Any, one: Any):
        """(c, dc/dz) of :func:`.lens._atan_ratio` per lane (z >= 0; dc only with the Jacobian),
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
        h = _atan_ratio_h8(w, one)
        root = wp.vector(
            wp.sqrt(zb[0]), wp.sqrt(zb[1]), wp.sqrt(zb[2]), wp.sqrt(zb[3]),
            wp.sqrt(zb[4]), wp.sqrt(zb[5]), wp.sqrt(zb[6]), wp.sqrt(zb[7]),
        )
        a = wp.cw_mul(root, iz) * type(one)(wp.static(math.pi / 2.0))
        c = wp.cw_mul(small, h) + wp.cw_mul(big, a - wp.cw_mul(h, iz))
        dc = lanes.splat8(type(one)(0.0))
        if wp.static(jacobian):
            g = _atan_ratio_g8(w, one)
            dc_big = wp.cw_mul(a * type(one)(-0.5) + wp.cw_mul(h + wp.cw_mul(g, iz) * two, iz), iz)
            dc = wp.cw_mul(small, g * two) + wp.cw_mul(big, dc_big)
        return c, dc

    @wp.func
    def distort8(model: int, dist: Any, x: Any, y: Any, one: Any):
        """The distortion of 8 lanes of normalized (x, y) and its Jacobian: (xd, yd, J00, J01, J10,
        J11), the formulas of :func:`.lens._distort64` per lane in the float type of ``one``."""
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
        if model == lens.RADTAN:
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
        elif model == lens.FISHEYE:
            # s = theta_d / r and q = 2 ds/d(r^2), as lens._fisheye_terms
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
        """:func:`project_ray_jacobian` for 8 lanes of rays (rx, ry) and depths d: returns (u, v, ok,
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
        ok = wp.cw_mul(front, lanes.open_mask8(wp.cw_mul(x, x) + wp.cw_mul(y, y), -one, dist[lens.LIMIT]))
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
        """The n <= 8 pixels of a block of :func:`warp_block` read and projected as lanes (lanes past n
        repeat the last pixel): (u, v, ok, du0, du1, du2, dv0, dv1, dv2) of :func:`project_rays8`, ok
        also 0 where the depth is invalid (<= min, NaN, inf; depth 1 stands in) or the pixel has no ray."""
        one = type(min_depth)(1.0)
        d = lanes.load8(depth, i0, 0, n - 1)
        rx, ry, rw = load_rays8(rays, ray0, n - 1)
        has_ray = lanes.open_mask8(rw, type(one)(0.0), type(one)(2.0))
        depth_ok = wp.cw_mul(lanes.open_mask8(d, min_depth, type(one)(1.0e30)), has_ray)
        u, v, ok, du0, du1, du2, dv0, dv1, dv2 = project_rays8(
            model, R, t, K, dist, rx, ry, lanes.select8(depth_ok, d, lanes.splat8(one)), min_depth
        )
        return u, v, wp.cw_mul(ok, depth_ok), du0, du1, du2, dv0, dv1, dv2

    return distort8, project_rays8, block_lanes


distort8, project_rays8, block_lanes = _make_lanes(True)
_, _, block_values = _make_lanes(False)  # the forward's: no Jacobian


# pixels per block of warp_block: the projections of a block are computed before any of its
# samples, so the block's image reads are issued together instead of each waiting for its own
# projection's division and lens polynomial (the one-pixel-at-a-time loop was latency-bound: the
# kernel took ~1.4x the time per pixel of the two-phase block; measured in the issue-19 notes of
# benchmarks/RESULTS.md)
BLOCK = wp.constant(8)


def _make_warp_block(T, warp_block=None):
    """float type ``T`` overload of warp_block (see _make_project_ray)."""
    f64 = wp.float64
    vec3 = wp.types.vector(3, T)
    mat33 = wp.types.matrix((3, 3), T)
    vec8 = vec8f if T == wp.float32 else vec8d

    @wp.func
    def warp_block(
        image: wp.array(dtype=T), depth: wp.array(dtype=T), rays: wp.array(dtype=vec3), out: wp.array(dtype=T),
        valid: wp.array(dtype=wp.bool), K: wp.array(dtype=mat33), dist: wp.array(dtype=vec8), i0: int, ray0: int,
        n: int, b: int, src: int, dst0: int, C: int, H: int, W: int, padding: int, model: int, R: mat33, t: vec3,
        Kb: mat33, db: vec8, min_depth: T, tol: T,
    ):
        """``n`` <= BLOCK consecutive pixels of one row of the 3D spatial transformer through the lens:
        pixel k (flat index ``i0 + k`` of ``depth`` and ``valid``, ray ``rays[ray0 + k]``) is the point
        ``depth (ray_x, ray_y, 1)`` moved by [R | t] and projected (the lanes of :func:`block_values`,
        :func:`project_ray`'s formulas in the kernel's float type); ``valid``
        (valid depth, a ray, in the domain, inside the image within ``tol``) and the bilinear samples
        of the C channels of ``image`` (plane ``src``) into ``out[dst0 + k + c H W]``: 0 where the
        pixel is not active (valid depth, a ray, the moved point in front and in the domain); an
        active pixel that lands just outside the image reads zeros there (or the border, with border
        padding) as grid_sample does. Invalid depth (<= min, NaN, inf) or a pixel without a ray: depth
        1 stands in before any arithmetic, so neither the values nor the adjoint see it.

        All n projections come first, then the samples (see BLOCK). Hand-written adjoint in two
        phases: the projections with their Jacobians (lanes, :func:`block_lanes`), then per pixel the
        sampler's gradient (:func:`.sampler.sample_channels_grad`) and through the Jacobian the
        gradients to R, t, depth, the ray, and to ``K[b]`` and ``dist[b]`` only when their adjoint
        arrays exist (a wanted gradient); the backward pass does not replay it (nothing the kernel
        computes after it reads its results)."""
        u8, v8, ok8, du0, du1, du2, dv0, dv1, dv2 = block_values(
            depth, rays, i0, ray0, n, model, R, t, Kb, db, min_depth
        )
        umax = T(W - 1) + tol
        vmax = T(H - 1) + tol
        for k in range(n):
            u = u8[k]
            v = v8[k]
            ok = ok8[k] > T(0.0)
            valid[wp.max(i0 + k, 0)] = ok and u >= -tol and u <= umax and v >= -tol and v <= vmax
            xs, ys, reachable = sampler.sample_position(u, v, H, W, padding)
            sampler.sample_channels(image, out, src, dst0 + k, C, H * W, H * W, H, W, xs, ys, ok and reachable)

    @wp.func_grad(warp_block)
    def adj_warp_block(
        image: wp.array(dtype=T), depth: wp.array(dtype=T), rays: wp.array(dtype=vec3), out: wp.array(dtype=T),
        valid: wp.array(dtype=wp.bool), K: wp.array(dtype=mat33), dist: wp.array(dtype=vec8), i0: int, ray0: int,
        n: int, b: int, src: int, dst0: int, C: int, H: int, W: int, padding: int, model: int, R: mat33, t: vec3,
        Kb: mat33, db: vec8, min_depth: T, tol: T,
    ):
        zero = T(0.0)
        # phase 1: the projections and their Jacobians d(u, v)/dq (rows du, dv)
        u8, v8, ok8, du0, du1, du2, dv0, dv1, dv2 = block_lanes(
            depth, rays, i0, ray0, n, model, R, t, Kb, db, min_depth
        )
        # phase 2, per pixel: the sampler's gradient d loss / d(u, v), then through the projection
        # (the lanes' Jacobian) and the motion to pose, depth and ray, K and coefficients if wanted
        g_depth = wp.adjoint[depth]
        g_rays = wp.adjoint[rays]
        gK = wp.adjoint[K]
        gd = wp.adjoint[dist]
        lens_wanted = gK.shape[0] > 0 or gd.shape[0] > 0
        # the block's pose gradients summed in registers, added to the kernel's once
        g_t = vec3()
        g_R = mat33()
        for k in range(n):
            if ok8[k] > zero:  # active: a valid depth (read raw below), a ray, in front, in the domain
                u = u8[k]
                v = v8[k]
                xs, ys, reachable = sampler.sample_position(u, v, H, W, padding)
                if reachable:
                    gu, gv = sampler.sample_channels_grad(
                        image, wp.adjoint[image], wp.adjoint[out], src, dst0 + k, C, H * W, H * W, H, W, xs, ys
                    )
                    # the border padding's clamp passes no gradient where it clamps (grid_sample's rule)
                    if padding == sampler.PADDING_BORDER:
                        gu = wp.where(u <= zero or u >= T(W - 1), zero, gu)
                        gv = wp.where(v <= zero or v >= T(H - 1), zero, gv)
                    depth_i = depth[wp.max(i0 + k, 0)]
                    ray = rays[wp.max(ray0 + k, 0)]
                    P = vec3(ray[0] * depth_i, ray[1] * depth_i, depth_i)
                    gq = vec3(du0[k] * gu + dv0[k] * gv, du1[k] * gu + dv1[k] * gv, du2[k] * gu + dv2[k] * gv)
                    g_t = g_t + gq
                    g_R = g_R + wp.outer(gq, P)
                    gP = wp.transpose(R) * gq
                    if g_rays.shape[0] > 0:
                        j = wp.max(ray0 + k, 0)
                        g_rays[j] = g_rays[j] + vec3(gP[0] * depth_i, gP[1] * depth_i, zero)
                    if g_depth.shape[0] > 0:
                        j = wp.max(i0 + k, 0)
                        g_depth[j] = g_depth[j] + gP[0] * ray[0] + gP[1] * ray[1] + gP[2]
                    if lens_wanted:
                        # u = fx xd + s yd + cx, v = fy yd + cy, (xd, yd) = D(x, y), (x, y) = (q0, q1) / q2
                        d64 = lens._to64(db)
                        q = R * P + t
                        iz = f64(1.0) / f64(q[2])
                        x = f64(q[0]) * iz
                        y = f64(q[1]) * iz
                        xd, yd = lens._distort_value64(model, d64, x, y)
                        gu64 = f64(gu)
                        gv64 = f64(gv)
                        if gK.shape[0] > 0:
                            gK[b] = gK[b] + mat33(
                                T(gu64 * xd), T(gu64 * yd), gu, zero, T(gv64 * yd), gv, zero, zero, zero
                            )
                        if gd.shape[0] > 0:
                            gxd = f64(Kb[0, 0]) * gu64
                            gyd = f64(Kb[0, 1]) * gu64 + f64(Kb[1, 1]) * gv64
                            gd[b] = gd[b] + lens._from64(
                                lens._distort_vjp_dist64(model, d64, x, y, gxd, gyd), depth_i
                            )
        wp.adjoint[t] += g_t
        wp.adjoint[R] += g_R

    @wp.func_replay(warp_block)
    def replay_warp_block(
        image: wp.array(dtype=T), depth: wp.array(dtype=T), rays: wp.array(dtype=vec3), out: wp.array(dtype=T),
        valid: wp.array(dtype=wp.bool), K: wp.array(dtype=mat33), dist: wp.array(dtype=vec8), i0: int, ray0: int,
        n: int, b: int, src: int, dst0: int, C: int, H: int, W: int, padding: int, model: int, R: mat33, t: vec3,
        Kb: mat33, db: vec8, min_depth: T, tol: T,
    ):
        # the backward pass needs nothing the forward stored: skip projecting and sampling again
        pass

    return warp_block


warp_block = _make_warp_block(wp.float64, _make_warp_block(wp.float32))


__all__ = [
    "BLOCK", "block_lanes", "block_values", "distort8", "load_rays8", "pixel_ray", "project_ray",
    "project_ray_jacobian", "project_rays8", "warp_block",
]
