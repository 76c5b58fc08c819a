"""The radial-tangential model (OpenCV's 5 coefficients) in float64: the distortion with and
without its Jacobian, its gradient to the coefficients, and the Newton iterations of its inverse.
The formulas are the contract's (:mod:`gvnn_warp.kernels.geometry.lens`); ``d`` is ``dist`` as
float64, (k1, k2, p1, p2, k3) = d[0:5]. :mod:`.dispatch` calls these on the model id.
"""

import warp as wp

from ...core.kinds import vec8d
from .constants import NEWTON_ITERS, NEWTON_STEP_TOL, mat22d

_TINY_DET = wp.constant(1.0e-12)  # Newton stops where the Jacobian's determinant is below this


@wp.func
def distort(d: vec8d, x: wp.float64, y: wp.float64):
    """Distorted (xd, yd) of normalized (x, y) and the Jacobian d(xd, yd)/d(x, y)."""
    one = wp.float64(1.0)
    two = wp.float64(2.0)
    r2 = x * x + y * y
    k1 = d[0]
    k2 = d[1]
    p1 = d[2]
    p2 = d[3]
    k3 = d[4]
    R = one + r2 * (k1 + r2 * (k2 + r2 * k3))
    dR = k1 + r2 * (two * k2 + r2 * wp.float64(3.0) * k3)
    xd = x * R + two * p1 * x * y + p2 * (r2 + two * x * x)
    yd = y * R + p1 * (r2 + two * y * y) + two * p2 * x * y
    off = two * x * y * dR + two * p1 * x + two * p2 * y
    J = mat22d(
        R + two * x * x * dR + two * p1 * y + wp.float64(6.0) * p2 * x,
        off,
        off,
        R + two * y * y * dR + wp.float64(6.0) * p1 * y + two * p2 * x,
    )
    return xd, yd, J


@wp.func
def distort_value(d: vec8d, x: wp.float64, y: wp.float64):
    """(xd, yd) of :func:`distort` without the Jacobian (forward passes)."""
    one = wp.float64(1.0)
    two = wp.float64(2.0)
    r2 = x * x + y * y
    R = one + r2 * (d[0] + r2 * (d[1] + r2 * d[4]))
    xd = x * R + two * d[2] * x * y + d[3] * (r2 + two * x * x)
    yd = y * R + d[2] * (r2 + two * y * y) + two * d[3] * x * y
    return xd, yd


@wp.func
def vjp_dist(d: vec8d, x: wp.float64, y: wp.float64, gx: wp.float64, gy: wp.float64):
    """(d(xd, yd)/d dist)^T (gx, gy): the gradient to the coefficients (entries 5..7 zero)."""
    two = wp.float64(2.0)
    r2 = x * x + y * y
    a = gx * x + gy * y
    return vec8d(
        a * r2,
        a * r2 * r2,
        gx * two * x * y + gy * (r2 + two * y * y),
        gx * (r2 + two * x * x) + gy * two * x * y,
        a * r2 * r2 * r2,
        wp.float64(0.0),
        wp.float64(0.0),
        wp.float64(0.0),
    )


@wp.func
def undistort_newton(d: vec8d, xd: wp.float64, yd: wp.float64):
    """The 2-D Newton iterations on the distortion map from (x, y) = (xd, yd): returns (x, y)
    (:func:`.dispatch.undistort64` judges the result)."""
    x = xd
    y = yd
    for _it in range(NEWTON_ITERS):
        fx, fy, J = distort(d, x, y)
        ex = fx - xd
        ey = fy - yd
        det = J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0]
        if not (wp.abs(det) > _TINY_DET):
            break
        sx = (J[1, 1] * ex - J[0, 1] * ey) / det
        sy = (J[0, 0] * ey - J[1, 0] * ex) / det
        x = x - sx
        y = y - sy
        if not (wp.max(wp.abs(sx), wp.abs(sy)) > NEWTON_STEP_TOL):
            break
    return x, y


__all__ = ["distort", "distort_value", "undistort_newton", "vjp_dist"]
