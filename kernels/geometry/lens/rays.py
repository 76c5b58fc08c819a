"""Pixel rays through a lens model, for the fused kernels (``@wp.func``, no launches here).

A lens model (``model``, ``K``, ``dist``: the contract of :mod:`gvnn_warp.kernels.geometry.lens`)
cannot use the pinhole's row linearity (:func:`.camera.row_rays`): the ray of pixel (x, y) is
``undistort(K^-1 [x, y, 1])``, found by Newton's method. The fused kernels therefore read
precomputed rays (``pixel_ray``, launched once per camera and image size, its gradient by the
implicit function theorem through the lens ``undistort``) and move and project them with
``project_ray``, whose hand-written adjoint computes the projection's Jacobian once per pixel
(Warp's automatic adjoint would re-derive it term by term), in float64 inside as the lens models
do. The 3D spatial transformer's kernel projects 8 rays at a time instead (:mod:`.lanes`, used by
:mod:`gvnn_warp.kernels.sampling.lens_block`).

A ray is stored as ``(xn, yn, w)``: the ideal normalized coordinates of the pixel (its point at
depth d is ``d (xn, yn, 1)``) and ``w = 1`` where the undistortion converged inside the model's
domain, 0 where it did not (the pixel has no ray: treated as an invalid depth).

``pixel_ray`` (it names the lens fronts) and ``project_ray`` (a custom adjoint) are made on first
use, through the cache (:func:`functions`), and read as module attributes
(``lens_rays.project_ray`` in a kernel) like the lens fronts.
"""

from typing import Any, NamedTuple

import warp as wp

from ...core.cache import float_overloads, specialise
from ...core.compat import func_grad
from ...core.kinds import vec8d, vec8f
from .. import camera
from . import dispatch, fronts
from .constants import LIMIT


class Rays(NamedTuple):
    """The rays' functions made on first use (see the module docstring)."""

    pixel_ray: wp.Function
    project_ray: wp.Function


@specialise("geometry.lens_rays")
def functions() -> Rays:
    """``pixel_ray`` and ``project_ray``, made once (this makes the lens fronts too)."""
    undistort = fronts.functions().undistort

    @wp.func
    def pixel_ray(model: int, K: Any, dist: Any, x: Any, y: Any):
        """The stored ray ``(xn, yn, w)`` of pixel (x, y) (see the module docstring). Gradients (to
        K and dist) through the lens ``undistort``'s implicit-function adjoint; none where w = 0."""
        r = camera.pixel_ray(K, x, y)
        xn, ok = undistort(model, dist, wp.vector(r[0], r[1]))
        return wp.vector(xn[0], xn[1], wp.where(ok, type(x)(1.0), type(x)(0.0)))

    return Rays(pixel_ray, float_overloads(_project_ray))


def _project_ray(T):
    """project_ray's float type ``T`` overload (Warp custom adjoints need concrete types)."""
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
        evaluated as the lens ``project`` does (in float64, rounded; X/Z as X * (1/Z)), so (u, v)
        equals ``lens.project(model, K, dist, q)`` to rounding. Gradients (hand-written adjoint): to R, t, K, dist,
        the ray's (x, y) and depth; q_z passes its own gradient."""
        q = R * vec3(ray[0] * depth, ray[1] * depth, depth) + t
        front = q[2] > min_depth
        iz = f64(1.0) / f64(wp.where(front, q[2], T(1.0)))  # one division (two cost more than the lens)
        x = f64(q[0]) * iz
        y = f64(q[1]) * iz
        d = dispatch.to64(dist)
        ok = front and x * x + y * y < d[LIMIT]
        xd, yd = dispatch.distort_value64(model, d, wp.where(ok, x, f64(0.0)), wp.where(ok, y, f64(0.0)))
        u = T(f64(K[0, 0]) * xd + f64(K[0, 1]) * yd + f64(K[0, 2]))
        v = T(f64(K[1, 1]) * yd + f64(K[1, 2]))
        return vec3(u, v, q[2]), ok

    @func_grad(project_ray)
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
        d = dispatch.to64(dist)
        gq = vec3(T(0.0), T(0.0), adj_ret0[2])
        if front and x * x + y * y < d[LIMIT]:
            xd, yd, J = dispatch.distort64(model, d, x, y)
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
            wp.adjoint[dist] += dispatch.from64(dispatch.distort_vjp_dist64(model, d, x, y, gxd, gyd), depth)
        wp.adjoint[t] += gq
        wp.adjoint[R] += wp.outer(gq, P)
        gP = wp.transpose(R) * gq
        wp.adjoint[ray] += vec3(gP[0] * depth, gP[1] * depth, T(0.0))
        wp.adjoint[depth] += gP[0] * ray[0] + gP[1] * ray[1] + gP[2]

    return project_ray


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
    d = dispatch.to64(dist)
    ok = front and x * x + y * y < d[LIMIT]
    xs = wp.where(ok, x, wp.float64(0.0))
    ys = wp.where(ok, y, wp.float64(0.0))
    xd, yd, J = dispatch.distort64(model, d, xs, ys)
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


pixel_ray: Any
project_ray: Any


def __getattr__(name: str):
    if name in Rays._fields:
        globals().update(functions()._asdict())  # (the same objects every time: later lookups skip this)
        return globals()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(Rays._fields))


__all__ = ["functions", "pixel_ray", "project_ray", "project_ray_jacobian"]
