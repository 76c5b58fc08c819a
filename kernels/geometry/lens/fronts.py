"""The typed fronts of the lens models, with their hand-written adjoints: ``distort``,
``undistort``, ``project``, ``unproject``, ``distort_pixel`` and ``undistort_pixel`` (the contract
is the docstring of :mod:`gvnn_warp.kernels.geometry.lens`, which kernels name them through:
``lens.project``).

They are made on first use, through the cache of generated functions (:func:`functions`): Warp's
own ``@wp.func_grad`` built each function to check its adjoint, which took seconds for these six,
and importing the lens models for their constants (the torch cameras, the aligner, the pinhole
kernels) should not pay for functions it never calls. Registered through
:func:`gvnn_warp.kernels.core.compat.func_grad` (no such build), making them takes ~0.05 s.
"""

from typing import NamedTuple

import warp as wp

from ...core.cache import float_overloads, specialise
from ...core.compat import func_grad
from ...core.kinds import vec8d, vec8f
from .. import camera
from .constants import LIMIT, PINHOLE
from .dispatch import (
    distort64,
    distort_value64,
    distort_vjp_dist64,
    finite,
    finite_or_zero,
    from64,
    in_domain64,
    project_distorted64,
    to64,
    undistort64,
    undistort_grad64,
)


class Fronts(NamedTuple):
    """The six fronts, each a Warp function with float32 and float64 overloads."""

    distort: wp.Function
    undistort: wp.Function
    project: wp.Function
    unproject: wp.Function
    distort_pixel: wp.Function
    undistort_pixel: wp.Function


@specialise("geometry.lens_fronts")
def functions() -> Fronts:
    """The typed fronts, made once (on first use: see the module docstring)."""
    return Fronts(*float_overloads(_typed_fronts))


def _typed_fronts(T):
    """The fronts' float type ``T`` overloads (Warp custom adjoints need concrete types)."""
    f64 = wp.float64
    vec2 = wp.types.vector(2, T)
    vec3 = wp.types.vector(3, T)
    mat33 = wp.types.matrix((3, 3), T)
    vec8 = vec8f if T == wp.float32 else vec8d

    @wp.func
    def distort(model: int, dist: vec8, xn: vec2):
        d = to64(dist)
        x = f64(xn[0])
        y = f64(xn[1])
        ok = in_domain64(model, d, x, y)
        out = vec2(finite_or_zero(xn[0]), finite_or_zero(xn[1]))
        if ok:
            xd, yd = distort_value64(model, d, x, y)
            out = vec2(T(xd), T(yd))
        return out, ok

    @func_grad(distort)
    def adj_distort(model: int, dist: vec8, xn: vec2, adj_ret0: vec2, adj_ret1: bool):
        d = to64(dist)
        x = f64(xn[0])
        y = f64(xn[1])
        if in_domain64(model, d, x, y):
            gx = f64(adj_ret0[0])
            gy = f64(adj_ret0[1])
            xd, yd, J = distort64(model, d, x, y)
            wp.adjoint[xn] += vec2(T(J[0, 0] * gx + J[1, 0] * gy), T(J[0, 1] * gx + J[1, 1] * gy))
            wp.adjoint[dist] += from64(distort_vjp_dist64(model, d, x, y, gx, gy), xn[0])

    @wp.func
    def undistort(model: int, dist: vec8, xd: vec2):
        out = vec2(finite_or_zero(xd[0]), finite_or_zero(xd[1]))
        ok = finite(xd[0]) and finite(xd[1])
        if model != PINHOLE and ok:
            x, y, ok = undistort64(model, to64(dist), f64(xd[0]), f64(xd[1]))
            if ok:
                out = vec2(T(x), T(y))
        return out, ok

    @func_grad(undistort)
    def adj_undistort(model: int, dist: vec8, xd: vec2, adj_ret0: vec2, adj_ret1: bool):
        if finite(xd[0]) and finite(xd[1]):
            if model == PINHOLE:
                wp.adjoint[xd] += adj_ret0
            else:
                d = to64(dist)
                x, y, ok = undistort64(model, d, f64(xd[0]), f64(xd[1]))
                if ok:
                    lx, ly, gd = undistort_grad64(model, d, x, y, f64(adj_ret0[0]), f64(adj_ret0[1]))
                    wp.adjoint[xd] += vec2(T(lx), T(ly))
                    wp.adjoint[dist] += from64(gd, xd[0])

    @wp.func
    def project(model: int, K: mat33, dist: vec8, p: vec3, min_depth: T):
        # finite X, Y, Z (a sum of finite coordinates above ~1e38 counts as not: irrelevant) and Z > min_depth
        ok = p[2] > min_depth and finite(p[0] + p[1] + p[2])
        q = p
        if not ok:
            q = vec3(finite_or_zero(p[0]), finite_or_zero(p[1]), wp.max(finite_or_zero(p[2]), min_depth))
        out = camera.project(K, q)  # the pinhole projection, or the stand-in
        if model != PINHOLE and ok:  # out of line, so that the pinhole path stays small
            u, v, ok = project_distorted64(model, K, to64(dist), p)
            if ok:
                out = vec2(T(u), T(v))
        return out, ok

    @func_grad(project)
    def adj_project(model: int, K: mat33, dist: vec8, p: vec3, min_depth: T, adj_ret0: vec2, adj_ret1: bool):
        # finite X, Y, Z (a sum of finite coordinates above ~1e38 counts as not: irrelevant) and Z > min_depth
        ok = p[2] > min_depth and finite(p[0] + p[1] + p[2])
        if ok:
            if model == PINHOLE:
                g_K, g_p = camera.project_grad(K, p, adj_ret0)
                wp.adjoint[K] += g_K
                wp.adjoint[p] += g_p
            else:
                z = f64(p[2])
                x = f64(p[0]) / z
                y = f64(p[1]) / z
                d = to64(dist)
                if x * x + y * y < d[LIMIT]:
                    gu = f64(adj_ret0[0])
                    gv = f64(adj_ret0[1])
                    xd, yd, J = distort64(model, d, x, y)
                    gxd = f64(K[0, 0]) * gu
                    gyd = f64(K[0, 1]) * gu + f64(K[1, 1]) * gv
                    gx = J[0, 0] * gxd + J[1, 0] * gyd
                    gy = J[0, 1] * gxd + J[1, 1] * gyd
                    wp.adjoint[p] += vec3(T(gx / z), T(gy / z), T(-(x * gx + y * gy) / z))
                    wp.adjoint[K] += mat33(
                        T(gu * xd), T(gu * yd), T(gu), T(0.0), T(gv * yd), T(gv), T(0.0), T(0.0), T(0.0)
                    )
                    wp.adjoint[dist] += from64(distort_vjp_dist64(model, d, x, y, gxd, gyd), p[0])

    @wp.func
    def unproject(model: int, K: mat33, dist: vec8, x: T, y: T, depth: T):
        out = vec3()
        ok = True
        if model == PINHOLE:
            out = camera.unproject(K, x, y, depth)
        else:
            ray = camera.pixel_ray(K, x, y)
            xn, ok = undistort(model, dist, vec2(ray[0], ray[1]))
            out = vec3(xn[0], xn[1], T(1.0)) * depth
            if not ok:
                out = vec3(finite_or_zero(ray[0]), finite_or_zero(ray[1]), T(1.0)) * finite_or_zero(depth)
        return out, ok

    @func_grad(unproject)
    def adj_unproject(model: int, K: mat33, dist: vec8, x: T, y: T, depth: T, adj_ret0: vec3, adj_ret1: bool):
        g = adj_ret0
        if model == PINHOLE:
            # p = depth (rx, ry, 1), ry = (y - cy) / fy, rx = (x - cx - s ry) / fx
            ray = camera.pixel_ray(K, x, y)
            wp.adjoint[depth] += wp.dot(g, ray)
            grx = g[0] * depth
            gry = g[1] * depth
            fx = K[0, 0]
            fy = K[1, 1]
            gx = grx / fx
            gryt = gry - grx * K[0, 1] / fx
            gy = gryt / fy
            wp.adjoint[x] += gx
            wp.adjoint[y] += gy
            wp.adjoint[K] += mat33(
                -gx * ray[0], -gx * ray[1], -gx, T(0.0), -gy * ray[1], -gy, T(0.0), T(0.0), T(0.0)
            )
        else:
            fxd = f64(K[0, 0])
            fyd = f64(K[1, 1])
            sk = f64(K[0, 1])
            ry = (f64(y) - f64(K[1, 2])) / fyd
            rx = (f64(x) - f64(K[0, 2]) - sk * ry) / fxd
            d = to64(dist)
            ok = finite(rx) and finite(ry)
            xn = f64(0.0)
            yn = f64(0.0)
            if ok:
                xn, yn, ok = undistort64(model, d, rx, ry)
            if ok:
                dep = f64(depth)
                wp.adjoint[depth] += T(f64(g[0]) * xn + f64(g[1]) * yn + f64(g[2]))
                lx, ly, gd = undistort_grad64(model, d, xn, yn, f64(g[0]) * dep, f64(g[1]) * dep)
                wp.adjoint[dist] += from64(gd, x)
                gxd = lx / fxd
                gyd = (ly - lx * sk / fxd) / fyd
                wp.adjoint[x] += T(gxd)
                wp.adjoint[y] += T(gyd)
                wp.adjoint[K] += mat33(
                    T(-gxd * rx), T(-gxd * ry), T(-gxd), T(0.0), T(-gyd * ry), T(-gyd), T(0.0), T(0.0), T(0.0)
                )

    @wp.func
    def _k_inv64(K: mat33, uv: vec2):
        """K^-1 [u, v, 1] in float64: (rx, ry)."""
        ry = (f64(uv[1]) - f64(K[1, 2])) / f64(K[1, 1])
        rx = (f64(uv[0]) - f64(K[0, 2]) - f64(K[0, 1]) * ry) / f64(K[0, 0])
        return rx, ry

    @wp.func
    def _pixel_grads(K: mat33, rx: f64, ry: f64, mx: f64, my: f64, gu: f64, gv: f64, lx: f64, ly: f64):
        """Gradients of out = K (m(r)) with r = K^-1 uv, given d loss/d out = (gu, gv) and the
        gradient lambda = (lx, ly) that reached r: returns (g_uv, g_K)."""
        fx = f64(K[0, 0])
        fy = f64(K[1, 1])
        gx = lx / fx
        gy = (ly - lx * f64(K[0, 1]) / fx) / fy
        g_K = mat33(
            T(gu * mx - gx * rx), T(gu * my - gx * ry), T(gu - gx),
            T(0.0), T(gv * my - gy * ry), T(gv - gy),
            T(0.0), T(0.0), T(0.0),
        )
        return vec2(T(gx), T(gy)), g_K

    @wp.func
    def distort_pixel(model: int, K: mat33, dist: vec8, uv: vec2):
        ok = finite(uv[0] + uv[1])
        out = vec2(finite_or_zero(uv[0]), finite_or_zero(uv[1]))
        if model != PINHOLE and ok:
            rx, ry = _k_inv64(K, uv)
            d = to64(dist)
            ok = in_domain64(model, d, rx, ry)
            if ok:
                xd, yd = distort_value64(model, d, rx, ry)
                out = vec2(T(f64(K[0, 0]) * xd + f64(K[0, 1]) * yd + f64(K[0, 2])), T(f64(K[1, 1]) * yd + f64(K[1, 2])))
        return out, ok

    @func_grad(distort_pixel)
    def adj_distort_pixel(model: int, K: mat33, dist: vec8, uv: vec2, adj_ret0: vec2, adj_ret1: bool):
        if finite(uv[0] + uv[1]):
            if model == PINHOLE:
                wp.adjoint[uv] += adj_ret0
            else:
                rx, ry = _k_inv64(K, uv)
                d = to64(dist)
                if in_domain64(model, d, rx, ry):
                    gu = f64(adj_ret0[0])
                    gv = f64(adj_ret0[1])
                    xd, yd, J = distort64(model, d, rx, ry)
                    gxd = f64(K[0, 0]) * gu
                    gyd = f64(K[0, 1]) * gu + f64(K[1, 1]) * gv
                    lx = J[0, 0] * gxd + J[1, 0] * gyd
                    ly = J[0, 1] * gxd + J[1, 1] * gyd
                    g_uv, g_K = _pixel_grads(K, rx, ry, xd, yd, gu, gv, lx, ly)
                    wp.adjoint[uv] += g_uv
                    wp.adjoint[K] += g_K
                    wp.adjoint[dist] += from64(distort_vjp_dist64(model, d, rx, ry, gxd, gyd), uv[0])

    @wp.func
    def undistort_pixel(model: int, K: mat33, dist: vec8, uv: vec2):
        ok = finite(uv[0] + uv[1])
        out = vec2(finite_or_zero(uv[0]), finite_or_zero(uv[1]))
        if model != PINHOLE and ok:
            rx, ry = _k_inv64(K, uv)
            x, y, ok = undistort64(model, to64(dist), rx, ry)
            if ok:
                out = vec2(T(f64(K[0, 0]) * x + f64(K[0, 1]) * y + f64(K[0, 2])), T(f64(K[1, 1]) * y + f64(K[1, 2])))
        return out, ok

    @func_grad(undistort_pixel)
    def adj_undistort_pixel(model: int, K: mat33, dist: vec8, uv: vec2, adj_ret0: vec2, adj_ret1: bool):
        if finite(uv[0] + uv[1]):
            if model == PINHOLE:
                wp.adjoint[uv] += adj_ret0
            else:
                rx, ry = _k_inv64(K, uv)
                d = to64(dist)
                x, y, ok = undistort64(model, d, rx, ry)
                if ok:
                    gu = f64(adj_ret0[0])
                    gv = f64(adj_ret0[1])
                    gx = f64(K[0, 0]) * gu
                    gy = f64(K[0, 1]) * gu + f64(K[1, 1]) * gv
                    lx, ly, gd = undistort_grad64(model, d, x, y, gx, gy)
                    g_uv, g_K = _pixel_grads(K, rx, ry, x, y, gu, gv, lx, ly)
                    wp.adjoint[uv] += g_uv
                    wp.adjoint[K] += g_K
                    wp.adjoint[dist] += from64(gd, uv[0])

    return distort, undistort, project, unproject, distort_pixel, undistort_pixel
