"""The fisheye model (cv2.fisheye's equidistant, Kannala-Brandt) in float64: the distortion with and
without its Jacobian, its gradient to the coefficients, and the Newton iterations of its inverse,
evaluated without atan where it can (:func:`atan_ratio`). The formulas are the contract's
(:mod:`gvnn_warp.kernels.geometry.lens`); ``d`` is ``dist`` as float64, (k1, k2, k3, k4) = d[0:4].
:mod:`.dispatch` calls these on the model id.
"""

import math

import warp as wp

from ...core.kinds import vec8d
from .constants import LIMIT, NEWTON_ITERS, NEWTON_STEP_TOL, mat22d

_SMALL_R2 = wp.constant(1.0e-10)  # undistort: below, the series for tan(theta) / theta_d
_HALF_PI = wp.constant(wp.float64(math.pi / 2.0))

# c(z) = atan(sqrt(z)) / sqrt(z) without atan, sqrt or division on z in [0, 1]: the degree-20
# Chebyshev interpolant of c in w = 2 z - 1 (values computed in 40-digit arithmetic, converted to
# monomials of w in the same precision, then rounded). Its error is below one float64 ulp of c over
# [0, 1] (c's singularities at z = -1 and infinity are far: the coefficients fall ~3x per degree);
# tests/cameras/test_models.py checks it against 40-digit arithmetic. Evaluated by Estrin's scheme (depth 5,
# not Horner's 20 dependent steps, which measured no faster than the atan). The coefficients (lowest
# first) of c (ATAN_H) and of its derivative dc/dw (ATAN_G, degree 19), evaluated by estrin20's
# functions below and by their 8-lane twins in :mod:`.lanes`.
ATAN_H = (
    0.8704197513671031,
    -0.10187654235021822,
    0.020851851207106812,
    -0.005030863660249582,
    0.0013155859496792606,
    -0.0003609820870445124,
    0.00010227656045777358,
    -2.9650040909502615e-05,
    8.744943112043329e-06,
    -2.614071510996734e-06,
    7.898472870792878e-07,
    -2.4080334783259967e-07,
    7.398624793710959e-08,
    -2.2799632063639697e-08,
    7.027992040035036e-09,
    -2.2748635121767786e-09,
    7.602916554637715e-10,
    -1.7481491269961626e-10,
    3.2623164374142435e-11,
    -3.868471560201312e-11,
    1.6823203344941825e-11,
)
ATAN_G = (
    -0.10187654235021822,
    0.041703702414213624,
    -0.015092590980748746,
    0.005262343798717042,
    -0.001804910435222562,
    0.0006136593627466414,
    -0.0002075502863665183,
    6.995954489634663e-05,
    -2.3526643598970608e-05,
    7.898472870792878e-06,
    -2.6488368261585962e-06,
    8.878349752453151e-07,
    -2.963952168273161e-07,
    9.83918885604905e-08,
    -3.412295268265168e-08,
    1.2164666487420344e-08,
    -2.9718535158934765e-09,
    5.872169587345639e-10,
    -7.350095964382493e-10,
    3.3646406689883653e-10,
    0.0,  # degree 19: padded to the evaluator's 21 coefficients (the term adds exactly 0)
)


def estrin20(coeffs):
    """A ``@wp.func`` (w: float64) -> the degree-20 polynomial with these 21 coefficients (lowest
    first), by Estrin's scheme (pairs, then w^2, w^4, w^8 and w^16: not Horner's 20 dependent steps).

    A plain generator, not an entry of the cache of generated functions (``core.cache``): it runs
    twice, at import, for the two fixed tables above (the functions below name its results), and a
    key of 21 coefficients would name nothing a reader could use."""

    @wp.func
    def estrin20(w: wp.float64):
        w2 = w * w
        w4 = w2 * w2
        w8 = w4 * w4
        w16 = w8 * w8
        h0_0 = wp.float64(wp.static(coeffs[0])) + wp.float64(wp.static(coeffs[1])) * w
        h0_1 = wp.float64(wp.static(coeffs[2])) + wp.float64(wp.static(coeffs[3])) * w
        h0_2 = wp.float64(wp.static(coeffs[4])) + wp.float64(wp.static(coeffs[5])) * w
        h0_3 = wp.float64(wp.static(coeffs[6])) + wp.float64(wp.static(coeffs[7])) * w
        h0_4 = wp.float64(wp.static(coeffs[8])) + wp.float64(wp.static(coeffs[9])) * w
        h0_5 = wp.float64(wp.static(coeffs[10])) + wp.float64(wp.static(coeffs[11])) * w
        h0_6 = wp.float64(wp.static(coeffs[12])) + wp.float64(wp.static(coeffs[13])) * w
        h0_7 = wp.float64(wp.static(coeffs[14])) + wp.float64(wp.static(coeffs[15])) * w
        h0_8 = wp.float64(wp.static(coeffs[16])) + wp.float64(wp.static(coeffs[17])) * w
        h0_9 = wp.float64(wp.static(coeffs[18])) + wp.float64(wp.static(coeffs[19])) * w
        h1_0 = h0_0 + h0_1 * w2
        h1_1 = h0_2 + h0_3 * w2
        h1_2 = h0_4 + h0_5 * w2
        h1_3 = h0_6 + h0_7 * w2
        h1_4 = h0_8 + h0_9 * w2
        h2_0 = h1_0 + h1_1 * w4
        h2_1 = h1_2 + h1_3 * w4
        h2_2 = h1_4 + wp.float64(wp.static(coeffs[20])) * w4
        h3_0 = h2_0 + h2_1 * w8
        return h3_0 + h2_2 * w16

    return estrin20


atan_ratio_poly_value = estrin20(ATAN_H)  # c at w = 2 z - 1, z in [0, 1] (see atan_ratio)
atan_ratio_dpoly = estrin20(ATAN_G)  # dc/dw


@wp.func
def atan_ratio_poly(w: wp.float64):
    """(c, dc/dw) of c = atan(sqrt(z)) / sqrt(z) at w = 2 z - 1, z in [0, 1] (see atan_ratio)."""
    return atan_ratio_poly_value(w), atan_ratio_dpoly(w)


@wp.func
def atan_ratio_value(z: wp.float64):
    """c = atan(sqrt(z)) / sqrt(z) for z >= 0 (c(0) = 1): the polynomial on [0, 1], beyond it
    atan(r) = pi/2 - atan(1/r), i.e. c(z) = pi / (2 sqrt(z)) - c(1/z) / z."""
    one = wp.float64(1.0)
    c = one
    if z <= one:
        c = atan_ratio_poly_value(wp.float64(2.0) * z - one)
    else:
        iz = one / z
        c = _HALF_PI * wp.sqrt(z) * iz - atan_ratio_poly_value(wp.float64(2.0) * iz - one) * iz
    return c


@wp.func
def atan_ratio(z: wp.float64):
    """(c, dc/dz) of :func:`atan_ratio_value` (dc/dz = -1/3 at z = 0)."""
    one = wp.float64(1.0)
    two = wp.float64(2.0)
    c = one
    dc = wp.float64(0.0)
    if z <= one:
        h, g = atan_ratio_poly(two * z - one)
        c = h
        dc = two * g
    else:
        iz = one / z
        h, g = atan_ratio_poly(two * iz - one)
        a = _HALF_PI * wp.sqrt(z) * iz  # pi / (2 sqrt(z))
        c = a - h * iz
        dc = (-wp.float64(0.5) * a + (h + two * g * iz) * iz) * iz
    return c, dc


@wp.func
def poly(d: vec8d, t: wp.float64):
    """theta_d / theta = 1 + k1 t + k2 t^2 + k3 t^3 + k4 t^4 at t = theta^2."""
    return wp.float64(1.0) + t * (d[0] + t * (d[1] + t * (d[2] + t * d[3])))


@wp.func
def dpoly(d: vec8d, t: wp.float64):
    """d theta_d / d theta = 1 + 3 k1 t + 5 k2 t^2 + 7 k3 t^3 + 9 k4 t^4 at t = theta^2."""
    c3 = wp.float64(3.0)
    c5 = wp.float64(5.0)
    c7 = wp.float64(7.0)
    c9 = wp.float64(9.0)
    return wp.float64(1.0) + t * (c3 * d[0] + t * (c5 * d[1] + t * (c7 * d[2] + t * c9 * d[3])))


@wp.func
def terms(d: vec8d, r2: wp.float64):
    """For r^2: (s, q, c, t) with s = theta_d / r, q = (ds/dr) / r = 2 ds/d(r^2), c = theta / r,
    t = theta^2 (no atan, sqrt or division for r <= 1: :func:`atan_ratio`)."""
    two = wp.float64(2.0)
    c, dc = atan_ratio(r2)
    t = r2 * c * c
    p = poly(d, t)
    dpoly_dt = d[0] + t * (two * d[1] + t * (wp.float64(3.0) * d[2] + t * wp.float64(4.0) * d[3]))
    s = c * p
    # ds/d(r^2) = c' poly + c poly'(t) dt/d(r^2), dt/d(r^2) = c^2 + 2 r^2 c c'
    q = two * (dc * p + c * dpoly_dt * (c * c + two * r2 * c * dc))
    return s, q, c, t


@wp.func
def distort(d: vec8d, x: wp.float64, y: wp.float64):
    """Distorted (xd, yd) = (theta_d / r) (x, y) of normalized (x, y) and the Jacobian d(xd, yd)/d(x, y)."""
    s, q, c, t = terms(d, x * x + y * y)
    return s * x, s * y, mat22d(s + q * x * x, q * x * y, q * x * y, s + q * y * y)


@wp.func
def distort_value(d: vec8d, x: wp.float64, y: wp.float64):
    """(xd, yd) of :func:`distort` without the Jacobian (forward passes)."""
    r2 = x * x + y * y
    c = atan_ratio_value(r2)
    s = c * poly(d, r2 * c * c)
    return s * x, s * y


@wp.func
def vjp_dist(d: vec8d, x: wp.float64, y: wp.float64, gx: wp.float64, gy: wp.float64):
    """(d(xd, yd)/d dist)^T (gx, gy): the gradient to the coefficients (entries 4..7 zero)."""
    r2 = x * x + y * y
    c = atan_ratio_value(r2)
    t = r2 * c * c
    a = (gx * x + gy * y) * c * t
    z = wp.float64(0.0)
    return vec8d(a, a * t, a * t * t, a * t * t * t, z, z, z, z)


@wp.func
def undistort_newton(d: vec8d, xd: wp.float64, yd: wp.float64):
    """The 1-D Newton iterations on theta_d(theta) = |xd| from theta = |xd|, kept inside
    [0, theta_max]: returns (x, y) (:func:`.dispatch.undistort64` judges the result)."""
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    rd2 = xd * xd + yd * yd
    rd = wp.sqrt(rd2)
    theta_max = wp.atan(wp.sqrt(d[LIMIT]))
    theta = wp.min(rd, theta_max)
    for _it in range(NEWTON_ITERS):
        t = theta * theta
        f = theta * poly(d, t) - rd
        fp = dpoly(d, t)
        if not (fp > zero):
            break
        new = wp.clamp(theta - f / fp, zero, theta_max)
        step = new - theta
        theta = new
        if not (wp.abs(step) > NEWTON_STEP_TOL):
            break
    scale = one
    if rd2 < _SMALL_R2:
        scale = one - (d[0] - one / wp.float64(3.0)) * rd2
    else:
        scale = wp.tan(theta) / rd
    return xd * scale, yd * scale


__all__ = [
    "ATAN_G", "ATAN_H", "atan_ratio", "atan_ratio_dpoly", "atan_ratio_poly", "atan_ratio_poly_value",
    "atan_ratio_value", "distort", "distort_value", "dpoly", "estrin20", "poly", "terms", "undistort_newton",
    "vjp_dist",
]
