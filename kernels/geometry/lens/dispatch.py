"""The float64 core of the lens models, dispatched on the model id at run time (``@wp.func``).

For kernels with their own hand-written adjoints (:mod:`.fronts`, :mod:`.rays`, the fused warps):
``to64(dist) -> vec8d``, ``from64(g: vec8d, ref)`` (rounded to ``ref``'s float type),
``distort64(model, d, x, y) -> (xd, yd, J: mat22d)``, ``distort_value64(model, d, x, y) -> (xd,
yd)``, ``distort_vjp_dist64(model, d, x, y, gx, gy) -> vec8d`` (the gradient to dist of gx xd +
gy yd), ``undistort64(model, d, xd, yd) -> (x, y, valid)`` and ``undistort_grad64(model, d, x, y,
gx, gy) -> (lx, ly, g_dist)`` (the implicit-function adjoint at the solution (x, y)). PINHOLE is
the identity throughout. The models themselves are :mod:`.radtan` and :mod:`.fisheye`.
"""

from typing import Any

import warp as wp

from ...core.kinds import vec8d
from . import fisheye, radtan
from .constants import FISHEYE, LIMIT, PINHOLE, RADTAN, UNDISTORT_TOL, mat22d


@wp.func
def distort64(model: int, d: vec8d, x: wp.float64, y: wp.float64):
    """Distorted (xd, yd) of normalized (x, y) and the Jacobian d(xd, yd)/d(x, y)."""
    one = wp.float64(1.0)
    zero = wp.float64(0.0)
    xd = x
    yd = y
    J = mat22d(one, zero, zero, one)
    if model == RADTAN:
        xd, yd, J = radtan.distort(d, x, y)
    elif model == FISHEYE:
        xd, yd, J = fisheye.distort(d, x, y)
    return xd, yd, J


@wp.func
def distort_value64(model: int, d: vec8d, x: wp.float64, y: wp.float64):
    """(xd, yd) of :func:`distort64` without the Jacobian (forward passes)."""
    xd = x
    yd = y
    if model == RADTAN:
        xd, yd = radtan.distort_value(d, x, y)
    elif model == FISHEYE:
        xd, yd = fisheye.distort_value(d, x, y)
    return xd, yd


@wp.func
def distort_vjp_dist64(model: int, d: vec8d, x: wp.float64, y: wp.float64, gx: wp.float64, gy: wp.float64):
    """(d(xd, yd)/d dist)^T (gx, gy): the gradient to the coefficients (entries 5..7 zero)."""
    g = vec8d()
    if model == RADTAN:
        g = radtan.vjp_dist(d, x, y, gx, gy)
    elif model == FISHEYE:
        g = fisheye.vjp_dist(d, x, y, gx, gy)
    return g


@wp.func
def undistort64(model: int, d: vec8d, xd: wp.float64, yd: wp.float64):
    """(x, y, valid): the ideal normalized point whose distortion is (xd, yd) (see the contract)."""
    x = xd
    y = yd
    if model == RADTAN:
        x, y = radtan.undistort_newton(d, xd, yd)
    elif model == FISHEYE:
        x, y = fisheye.undistort_newton(d, xd, yd)
    fx, fy = distort_value64(model, d, x, y)
    res = wp.max(wp.abs(fx - xd), wp.abs(fy - yd))
    valid = res <= UNDISTORT_TOL and (x * x + y * y) < d[LIMIT]
    return x, y, valid


@wp.func
def undistort_grad64(model: int, d: vec8d, x: wp.float64, y: wp.float64, gx: wp.float64, gy: wp.float64):
    """Implicit-function adjoint at the solution (x, y): lambda = J^-T (gx, gy) is the gradient to
    (xd, yd); the gradient to dist is -(dD/d dist)^T lambda. Returns (lx, ly, g_dist)."""
    fx, fy, J = distort64(model, d, x, y)
    det = J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0]
    lx = (J[1, 1] * gx - J[1, 0] * gy) / det
    ly = (J[0, 0] * gy - J[0, 1] * gx) / det
    return lx, ly, -distort_vjp_dist64(model, d, x, y, lx, ly)


@wp.func
def in_domain64(model: int, d: vec8d, x: wp.float64, y: wp.float64):
    inf = wp.float64(wp.inf)
    return wp.abs(x) < inf and wp.abs(y) < inf and (model == PINHOLE or x * x + y * y < d[LIMIT])


@wp.func
def finite(v: Any):
    """wp.isfinite(v) as one comparison (false for NaN and +-inf); isfinite costs ~14 ns."""
    return wp.abs(v) < type(v)(wp.inf)


@wp.func
def to64(d: Any):
    return vec8d(
        wp.float64(d[0]), wp.float64(d[1]), wp.float64(d[2]), wp.float64(d[3]),
        wp.float64(d[4]), wp.float64(d[5]), wp.float64(d[6]), wp.float64(d[7]),
    )


@wp.func
def from64(g: vec8d, ref: Any):
    """g rounded to the float type of ``ref`` (a scalar)."""
    return wp.vector(
        type(ref)(g[0]), type(ref)(g[1]), type(ref)(g[2]), type(ref)(g[3]),
        type(ref)(g[4]), type(ref)(g[5]), type(ref)(g[6]), type(ref)(g[7]),
    )


@wp.func
def finite_or_zero(v: Any):
    return wp.where(finite(v), v, type(v)(0.0))


@wp.func
def project_distorted64(model: int, K: Any, d: vec8d, p: Any):
    """(u, v, in domain) of a point with Z > 0 through a distorting model, in float64."""
    z = wp.float64(p[2])
    x = wp.float64(p[0]) / z
    y = wp.float64(p[1]) / z
    u = wp.float64(0.0)
    v = wp.float64(0.0)
    ok = x * x + y * y < d[LIMIT]
    if ok:
        xd, yd = distort_value64(model, d, x, y)
        u = wp.float64(K[0, 0]) * xd + wp.float64(K[0, 1]) * yd + wp.float64(K[0, 2])
        v = wp.float64(K[1, 1]) * yd + wp.float64(K[1, 2])
    return u, v, ok


__all__ = [
    "distort64", "distort_value64", "distort_vjp_dist64", "finite", "finite_or_zero", "from64", "in_domain64",
    "project_distorted64", "to64", "undistort64", "undistort_grad64",
]
