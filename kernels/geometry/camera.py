"""Pinhole camera building blocks as generic ``@wp.func`` (no launches here).

K is read as ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` (``s`` the skew, usually 0); its lower
row is never read. Pixels are (x, y) = (column, row) with pixel centres at integer coordinates
starting from 0 (see ``docs/conventions.md``).

:func:`project_moved_ray` is the per-pixel move -> project step of the 3D spatial transformer
(with :func:`row_rays` computed once per image row) with a hand-shaped Warp adjoint
(``@wp.func_grad``); so is :func:`project_clamped` (no gradient from clamped points); the other
functions are differentiated by Warp automatically.
"""

from typing import Any

import warp as wp

from ..core.cache import float_overloads
from ..core.compat import func_grad

# Points (and depths) must have z above this many metres to be projected / used; below it a
# warp marks the pixel invalid. The paper notes gradients of the projection degrade as z -> 0.
MIN_DEPTH = 1.0e-3


@wp.func
def pixel_ray(K: Any, x: Any, y: Any):
    """K^-1 [x, y, 1]: the ray through pixel (x, y), scaled to z = 1."""
    ry = (y - K[1, 2]) / K[1, 1]
    rx = (x - K[0, 2] - K[0, 1] * ry) / K[0, 0]
    return wp.vector(rx, ry, type(x)(1.0))


@wp.func
def unproject(K: Any, x: Any, y: Any, depth: Any):
    """The 3D point at z = depth seen at pixel (x, y): depth * K^-1 [x, y, 1]."""
    return pixel_ray(K, x, y) * depth


@wp.func
def project(K: Any, p: Any):
    """Pinhole projection (fx X/Z + s Y/Z + cx, fy Y/Z + cy). The caller guarantees Z > 0."""
    inv_z = type(p[2])(1.0) / p[2]
    xn = p[0] * inv_z
    yn = p[1] * inv_z
    return wp.vector(K[0, 0] * xn + K[0, 1] * yn + K[0, 2], K[1, 1] * yn + K[1, 2])


@wp.func
def project_grad(K: Any, p: Any, adj_ret: Any):
    """The adjoint of :func:`project`: given ``adj_ret`` = d loss / d (u, v), returns
    d loss / d (K, p). For hand-written adjoints; the caller guarantees Z > 0."""
    zero = type(p[2])(0.0)
    inv_z = type(p[2])(1.0) / p[2]
    xn = p[0] * inv_z
    yn = p[1] * inv_z
    gu = adj_ret[0]
    gv = adj_ret[1]
    gxn = K[0, 0] * gu
    gyn = K[0, 1] * gu + K[1, 1] * gv
    g_K = wp.matrix_from_rows(
        wp.vector(gu * xn, gu * yn, gu), wp.vector(zero, gv * yn, gv), wp.vector(zero, zero, zero)
    )
    return g_K, wp.vector(gxn * inv_z, gyn * inv_z, -(xn * gxn + yn * gyn) * inv_z)


def _project_clamped(T):
    """project_clamped's float type ``T`` overload (Warp custom adjoints need concrete types)."""
    vec2 = wp.types.vector(2, T)
    vec3 = wp.types.vector(3, T)
    mat33 = wp.types.matrix((3, 3), T)

    @wp.func
    def project_clamped(K: mat33, p: vec3, min_depth: T):
        """project() with Z replaced by min_depth where Z <= min_depth (or is NaN): always finite
        (for finite X, Y). Such a value only stands in for a point the caller rejects: no gradient
        flows from it (to p or K); elsewhere the gradient is project()'s."""
        z = wp.where(p[2] > min_depth, p[2], min_depth)
        return project(K, wp.vector(p[0], p[1], z))

    @func_grad(project_clamped)
    def adj_project_clamped(K: mat33, p: vec3, min_depth: T, adj_ret: vec2):
        front = p[2] > min_depth
        g_K, g_p = project_grad(K, wp.vector(p[0], p[1], wp.where(front, p[2], T(1.0))), adj_ret)
        wp.adjoint[K] += wp.where(front, g_K, mat33())
        wp.adjoint[p] += wp.where(front, g_p, vec3())

    return project_clamped


project_clamped = float_overloads(_project_clamped)


@wp.func
def project_point(K: Any, p: Any, min_depth: Any):
    """The projection layer's rule (``gvnn_warp.project_points``): :func:`project_clamped` where
    Z is finite (no gradient where Z <= min_depth), NaN where Z is NaN or infinite (no pixel;
    no gradient)."""
    nan = type(min_depth)(wp.nan)
    return wp.where(wp.isfinite(p[2]), project_clamped(K, p, min_depth), wp.vector(nan, nan))


@wp.func
def row_rays(R: Any, K: Any, y: Any):
    """Rays of image row ``y`` rotated by R: R K^-1 [x, y, 1] = a0 + x ax, returns (a0, ax).

    K^-1 e_x = (1 / fx, 0, 0) since K is upper triangular; used with :func:`project_moved_ray`
    so that a row's per-pixel work is a few multiply-adds.
    """
    zero = type(y)(0.0)
    a0 = R * pixel_ray(K, zero, y)
    ax = R * wp.vector(type(y)(1.0) / K[0, 0], zero, zero)
    return a0, ax


@wp.func
def project_moved_ray_grad(a0: Any, ax: Any, t: Any, K: Any, x: Any, depth: Any, min_depth: Any, adj_ret: Any):
    """The adjoint of :func:`project_moved_ray`: given ``adj_ret`` = d loss / d (u, v, q_z),
    returns d loss / d (a0, ax, t, K, x, depth). For hand-written adjoints."""
    zero = type(x)(0.0)
    one = type(x)(1.0)
    r0 = a0[0] + ax[0] * x
    r1 = a0[1] + ax[1] * x
    r2 = a0[2] + ax[2] * x
    q0 = r0 * depth + t[0]
    q1 = r1 * depth + t[1]
    q2 = r2 * depth + t[2]
    front = q2 > min_depth
    inv_z = one / wp.where(front, q2, one)
    xn = q0 * inv_z
    yn = q1 * inv_z
    gu = adj_ret[0]
    gv = adj_ret[1]
    # u = fx xn + s yn + cx, v = fy yn + cy
    gxn = K[0, 0] * gu
    gyn = K[0, 1] * gu + K[1, 1] * gv
    # xn = q0 / q2, yn = q1 / q2 (behind min_depth the substitute 1 is a constant)
    g0 = gxn * inv_z
    g1 = gyn * inv_z
    g2 = adj_ret[2] - wp.where(front, (xn * gxn + yn * gyn) * inv_z, zero)
    gq = wp.vector(g0, g1, g2)
    gr = gq * depth
    g_K = wp.matrix_from_rows(
        wp.vector(gu * xn, gu * yn, gu), wp.vector(zero, gv * yn, gv), wp.vector(zero, zero, zero)
    )
    return gr, gr * x, gq, g_K, wp.dot(gr, ax), g0 * r0 + g1 * r1 + g2 * r2


def _project_moved_ray(T):
    """project_moved_ray's float type ``T`` overload (Warp custom adjoints need concrete types)."""
    vec3 = wp.types.vector(3, T)
    mat33 = wp.types.matrix((3, 3), T)

    @wp.func
    def project_moved_ray(a0: vec3, ax: vec3, t: vec3, K: mat33, x: T, depth: T, min_depth: T):
        """Project q = depth (a0 + x ax) + t: returns (u, v, q_z).

        With (a0, ax) = :func:`row_rays` (R, K, y), q is pixel (x, y) at ``depth`` moved by
        [R | t]. Where q_z <= min_depth (u, v) are computed with q_z replaced by 1 (finite, for
        the caller to reject); q_z is returned so it can.
        """
        q0 = (a0[0] + ax[0] * x) * depth + t[0]
        q1 = (a0[1] + ax[1] * x) * depth + t[1]
        q2 = (a0[2] + ax[2] * x) * depth + t[2]
        inv_z = T(1.0) / wp.where(q2 > min_depth, q2, T(1.0))
        xn = q0 * inv_z
        yn = q1 * inv_z
        return wp.vector(K[0, 0] * xn + K[0, 1] * yn + K[0, 2], K[1, 1] * yn + K[1, 2], q2)

    @func_grad(project_moved_ray)
    def adj_project_moved_ray(
        a0: vec3, ax: vec3, t: vec3, K: mat33, x: T, depth: T, min_depth: T, adj_ret: vec3
    ):
        g_a0, g_ax, g_t, g_K, g_x, g_depth = project_moved_ray_grad(a0, ax, t, K, x, depth, min_depth, adj_ret)
        wp.adjoint[a0] += g_a0
        wp.adjoint[ax] += g_ax
        wp.adjoint[t] += g_t
        wp.adjoint[K] += g_K
        wp.adjoint[x] += g_x
        wp.adjoint[depth] += g_depth

    return project_moved_ray


project_moved_ray = float_overloads(_project_moved_ray)
