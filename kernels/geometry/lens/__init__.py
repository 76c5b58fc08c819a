"""Camera lens models as ``@wp.func`` (no launches here): pinhole, radial-tangential, fisheye.

The contract, for kernels that project or unproject through any of the models
============================================================================

A camera is three things per batch item: ``K`` (a ``mat33`` as in :mod:`.camera`, lower row
never read), ``dist`` (one distortion vector, ``vec8`` of the kernel's float type, the same
layout for every model) and ``model`` (an ``int``, one of the ids below). ``model`` is read at
run time, typically one value for a whole launch: one kernel serves every model (no compiled
variant per model), the branch on it is predictable, and PINHOLE costs only the validity tests
(the distorting code is out of line and never entered; see the costs under ``project``).

Model ids and ``dist`` layout (:func:`pack_dist` builds it on the host; ``gvnn_warp.cameras``
does it for torch)::

    PINHOLE = 0   dist ignored (all zeros)
    RADTAN  = 1   dist[0:5] = (k1, k2, p1, p2, k3)   OpenCV's 5 coefficients
    FISHEYE = 2   dist[0:4] = (k1, k2, k3, k4)       cv2.fisheye's equidistant (Kannala-Brandt)
    dist[5] = LIMIT: the model's domain, an upper bound on r^2 = (X/Z)^2 + (Y/Z)^2 (inf if none)
    dist[6], dist[7] = 0 (reserved)

On normalized coordinates (x, y) = (X/Z, Y/Z), r^2 = x^2 + y^2:

- RADTAN: R = 1 + k1 r^2 + k2 r^4 + k3 r^6,
  xd = x R + 2 p1 x y + p2 (r^2 + 2 x^2),  yd = y R + p1 (r^2 + 2 y^2) + 2 p2 x y.
- FISHEYE: theta = atan(r), theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8),
  (xd, yd) = (theta_d / r) (x, y).
- then pixels u = fx xd + s yd + cx, v = fy yd + cy (the skew s is cv2.fisheye's fx * alpha).

Domain. A point counts (``valid``) when X, Y, Z are finite, Z > min_depth, and, for RADTAN and
FISHEYE, r^2 < dist[LIMIT]: the radius up to which the radial distortion keeps increasing
(RADTAN: d(r R)/dr > 0 on [0, r]; FISHEYE: d theta_d / d theta > 0 on [0, theta], theta < pi/2;
the tangential terms are not part of the rule). :func:`domain_limit` computes it once per
camera on the host. Outside the domain every function returns a finite stand-in (documented per
function) with zero gradient to every input, never NaN.

Functions (``T`` = float32 or float64; distorted models compute in float64 inside and round the
results, so float32 values and gradients are float64's rounded):

- ``distort(model, dist, xn: vec2) -> (xd: vec2, valid: bool)``: normalized ideal -> distorted.
  Invalid (r^2 >= LIMIT or non-finite): returns xn (non-finite entries as 0).
- ``distort_pixel(model, K, dist, uv: vec2) -> (uv': vec2, valid: bool)``: the pixel of the
  ideal pinhole image (intrinsics K) -> the distorted image's, K distort(K^-1 [u, v, 1]); and
  ``undistort_pixel`` (the inverse, K undistort(K^-1 [u, v, 1])). Invalid (or PINHOLE): uv itself
  (non-finite entries as 0); for PINHOLE valid with gradient 1 to uv, otherwise zero gradient.
- ``undistort(model, dist, xd: vec2) -> (xn: vec2, valid: bool)``: the inverse, by Newton's
  method (RADTAN: 2-D Newton on the distortion map from xn = xd; FISHEYE: 1-D Newton on
  theta_d(theta) = |xd| from theta = |xd|, kept inside [0, theta_max]), at most NEWTON_ITERS = 20
  iterations, stopping after a step below 1e-13 (normalized units / radians). Valid where the
  solution is finite, inside the domain, and its residual |distort(xn) - xd| (max norm) is at
  most UNDISTORT_TOL = 1e-10 (about 5e-8 px at f = 500). Invalid: returns xd (non-finite as 0).
  The gradient (to xd and dist) is the implicit-function-theorem one through the converged
  solution, d xn = J^-1 (d xd - dD/d dist d dist), J the distortion's Jacobian at xn; the
  iterations are not differentiated.
- ``project(model, K, dist, p: vec3, min_depth: T) -> (uv: vec2, valid: bool)``. Invalid: the
  pinhole projection of p with Z clamped to min_depth and non-finite coordinates taken as 0 (for a
  point with Z > min_depth outside the domain, simply its pinhole projection), with zero gradient
  to p, K and dist. For PINHOLE with a valid point the value is bitwise :func:`.camera.project`
  (and its gradient :func:`.camera.project_grad`). Cost (isolated projection kernel, float32, a
  loaded 2-core host): PINHOLE ~1.2-1.6x :func:`.camera.project_clamped`'s ~3-5 ns per point
  (the validity tests), RADTAN ~4.6x, FISHEYE ~11x; backward 1.1x, 2.8x, 8x (FISHEYE measured
  with the float64 atan, since replaced by a polynomial about 1.6x cheaper: see _atan_ratio).
- ``unproject(model, K, dist, x: T, y: T, depth: T) -> (p: vec3, valid: bool)``:
  p = depth * (undistort(K^-1 [x, y, 1]), 1); ``valid`` is the undistortion's (the depth is
  passed through, as :func:`.camera.unproject` does). Invalid: depth * K^-1 [x, y, 1] with the
  non-finite entries as 0, zero gradient. For PINHOLE: bitwise :func:`.camera.unproject`, always
  valid.

Every function has a hand-written adjoint (``@wp.func_grad``) for all its floating arguments
(K, dist, p / x, y, depth), so callers get gradients for intrinsics and every coefficient
through Warp's adjoint launches or ``wp.Tape``. Adjoint of dist[LIMIT:] is always 0.

Float64 building blocks for kernels with their own hand-written adjoints (kernels.lens_rays uses
them; their signatures are kept stable): ``_to64(dist) -> vec8d``, ``_from64(g: vec8d, ref)``
(rounded to ``ref``'s float type), ``_distort64(model, d, x, y) -> (xd, yd, J: mat22d)``,
``_distort_value64(model, d, x, y) -> (xd, yd)``, ``_distort_vjp_dist64(model, d, x, y, gx, gy)
-> vec8d`` (the gradient to dist of gx xd + gy yd), ``_undistort64(model, d, xd, yd) -> (x, y,
valid)`` and ``_undistort_grad64(model, d, x, y, gx, gy) -> (lx, ly, g_dist)`` (the
implicit-function adjoint at the solution (x, y)).
"""

import math
import threading
from typing import Any

import numpy as np
import warp as wp

from ...core.kinds import vec8d, vec8f
from .. import camera

PINHOLE = wp.constant(0)
RADTAN = wp.constant(1)
FISHEYE = wp.constant(2)
MODEL_IDS = {"pinhole": 0, "radtan": 1, "fisheye": 2}
N_COEFFS = {0: 0, 1: 5, 2: 4}  # coefficients each model reads from dist[0:5]
DIST_SIZE = 8
LIMIT = wp.constant(5)  # dist[LIMIT] = the domain's bound on r^2

NEWTON_ITERS = wp.constant(20)
NEWTON_STEP_TOL = wp.constant(1.0e-13)
UNDISTORT_TOL = wp.constant(1.0e-10)
_SMALL_R2 = wp.constant(1.0e-10)  # undistort: below, the series for tan(theta) / theta_d
_TINY_DET = wp.constant(1.0e-12)
_HALF_PI = wp.constant(wp.float64(math.pi / 2.0))

mat22d = wp.types.matrix((2, 2), wp.float64)


# ----------------------------------------------------------------------------- host side


def _first_positive_root(coeffs_low_to_high) -> float:
    """The smallest positive real root of the polynomial, inf if none (a root where the polynomial
    only touches 0 counts: the derivative is 0 there)."""
    c = np.trim_zeros(np.asarray(coeffs_low_to_high, dtype=np.float64), "b")
    if len(c) <= 1:
        return math.inf
    roots = np.roots(c[::-1])
    real = [r.real for r in roots if abs(r.imag) <= 1e-7 * max(1.0, abs(r.real)) and r.real > 0]
    return min(real) if real else math.inf


def domain_limit(model: int, coeffs) -> float:
    """dist[LIMIT] for a model and its coefficients: the bound on r^2 = (X/Z)^2 + (Y/Z)^2 below
    which the radial distortion increases monotonically (inf if it always does)."""
    model = int(model)
    if model == 0:
        return math.inf
    k = [float(v) for v in coeffs]
    if model == 1:  # d(r R)/dr = 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3, s = r^2
        return _first_positive_root([1.0, 3 * k[0], 5 * k[1], 7 * k[4]])
    if model == 2:  # d theta_d / d theta = 1 + 3 k1 t + 5 k2 t^2 + 7 k3 t^3 + 9 k4 t^4, t = theta^2
        t = _first_positive_root([1.0, 3 * k[0], 5 * k[1], 7 * k[2], 9 * k[3]])
        if t >= (math.pi / 2) ** 2:
            return math.inf
        return math.tan(math.sqrt(t)) ** 2
    raise ValueError(f"gvnn_warp.kernels.lens: unknown model id {model!r} (expected one of {sorted(N_COEFFS)})")


def pack_dist(model: int, coeffs=()) -> np.ndarray:
    """The length-8 ``dist`` vector (float64 numpy) for a model and its coefficients (5 for
    RADTAN, 4 for FISHEYE, none for PINHOLE)."""
    model = int(model)
    if model not in N_COEFFS:
        raise ValueError(f"gvnn_warp.kernels.lens.pack_dist: unknown model id {model!r}")
    coeffs = np.asarray(coeffs, dtype=np.float64).reshape(-1)
    if len(coeffs) != N_COEFFS[model]:
        raise ValueError(
            f"gvnn_warp.kernels.lens.pack_dist: model {model} takes {N_COEFFS[model]} coefficients, got {len(coeffs)}"
        )
    d = np.zeros(DIST_SIZE)
    d[: len(coeffs)] = coeffs
    d[5] = domain_limit(model, d[:5] if model == 1 else coeffs)
    return d


# ----------------------------------------------------------------------------- float64 core


# c(z) = atan(sqrt(z)) / sqrt(z) without atan, sqrt or division on z in [0, 1]: the degree-20
# Chebyshev interpolant of c in w = 2 z - 1 (values computed in 40-digit arithmetic, converted to
# monomials of w in the same precision, then rounded). Its error is below one float64 ulp of c over
# [0, 1] (c's singularities at z = -1 and infinity are far: the coefficients fall ~3x per degree);
# tests/test_cameras.py checks it against 40-digit arithmetic. Evaluated by Estrin's scheme (depth 5,
# not Horner's 20 dependent steps, which measured no faster than the atan). The fisheye's distortion
# in a loop over 614k points (one thread, interleaved in one process, a lightly loaded host): 16 ->
# 10 ns per point, with its Jacobian 24 -> 14.5 ns (was: sqrt, atan and two or three divisions).
# The coefficients (lowest first) of c (_ATAN_H) and of its derivative dc/dw (_ATAN_G, degree 19),
# evaluated by _make_estrin20's functions below and by their 8-lane twins in kernels.lens_rays.
_ATAN_H = (
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
_ATAN_G = (
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


def _make_estrin20(coeffs):
    """A ``@wp.func`` (w: float64) -> the degree-20 polynomial with these 21 coefficients (lowest
    first), by Estrin's scheme (pairs, then w^2, w^4, w^8 and w^16: not Horner's 20 dependent steps)."""

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


_atan_ratio_poly_value = _make_estrin20(_ATAN_H)  # c at w = 2 z - 1, z in [0, 1] (see _atan_ratio)
_atan_ratio_dpoly = _make_estrin20(_ATAN_G)  # dc/dw


@wp.func
def _atan_ratio_poly(w: wp.float64):
    """(c, dc/dw) of c = atan(sqrt(z)) / sqrt(z) at w = 2 z - 1, z in [0, 1] (see _atan_ratio)."""
    return _atan_ratio_poly_value(w), _atan_ratio_dpoly(w)


@wp.func
def _atan_ratio_value(z: wp.float64):
    """c = atan(sqrt(z)) / sqrt(z) for z >= 0 (c(0) = 1): the polynomial on [0, 1], beyond it
    atan(r) = pi/2 - atan(1/r), i.e. c(z) = pi / (2 sqrt(z)) - c(1/z) / z."""
    one = wp.float64(1.0)
    c = one
    if z <= one:
        c = _atan_ratio_poly_value(wp.float64(2.0) * z - one)
    else:
        iz = one / z
        c = _HALF_PI * wp.sqrt(z) * iz - _atan_ratio_poly_value(wp.float64(2.0) * iz - one) * iz
    return c


@wp.func
def _atan_ratio(z: wp.float64):
    """(c, dc/dz) of :func:`_atan_ratio_value` (dc/dz = -1/3 at z = 0)."""
    one = wp.float64(1.0)
    two = wp.float64(2.0)
    c = one
    dc = wp.float64(0.0)
    if z <= one:
        h, g = _atan_ratio_poly(two * z - one)
        c = h
        dc = two * g
    else:
        iz = one / z
        h, g = _atan_ratio_poly(two * iz - one)
        a = _HALF_PI * wp.sqrt(z) * iz  # pi / (2 sqrt(z))
        c = a - h * iz
        dc = (-wp.float64(0.5) * a + (h + two * g * iz) * iz) * iz
    return c, dc


@wp.func
def _fisheye_poly(d: vec8d, t: wp.float64):
    """theta_d / theta = 1 + k1 t + k2 t^2 + k3 t^3 + k4 t^4 at t = theta^2."""
    return wp.float64(1.0) + t * (d[0] + t * (d[1] + t * (d[2] + t * d[3])))


@wp.func
def _fisheye_dpoly(d: vec8d, t: wp.float64):
    """d theta_d / d theta = 1 + 3 k1 t + 5 k2 t^2 + 7 k3 t^3 + 9 k4 t^4 at t = theta^2."""
    c3 = wp.float64(3.0)
    c5 = wp.float64(5.0)
    c7 = wp.float64(7.0)
    c9 = wp.float64(9.0)
    return wp.float64(1.0) + t * (c3 * d[0] + t * (c5 * d[1] + t * (c7 * d[2] + t * c9 * d[3])))


@wp.func
def _fisheye_terms(d: vec8d, r2: wp.float64):
    """For r^2: (s, q, c, t) with s = theta_d / r, q = (ds/dr) / r = 2 ds/d(r^2), c = theta / r,
    t = theta^2 (no atan, sqrt or division for r <= 1: :func:`_atan_ratio`)."""
    two = wp.float64(2.0)
    c, dc = _atan_ratio(r2)
    t = r2 * c * c
    poly = _fisheye_poly(d, t)
    dpoly_dt = d[0] + t * (two * d[1] + t * (wp.float64(3.0) * d[2] + t * wp.float64(4.0) * d[3]))
    s = c * poly
    # ds/d(r^2) = c' poly + c poly'(t) dt/d(r^2), dt/d(r^2) = c^2 + 2 r^2 c c'
    q = two * (dc * poly + c * dpoly_dt * (c * c + two * r2 * c * dc))
    return s, q, c, t


@wp.func
def _distort64(model: int, d: vec8d, x: wp.float64, y: wp.float64):
    """Distorted (xd, yd) of normalized (x, y) and the Jacobian d(xd, yd)/d(x, y)."""
    one = wp.float64(1.0)
    two = wp.float64(2.0)
    zero = wp.float64(0.0)
    r2 = x * x + y * y
    xd = x
    yd = y
    J = mat22d(one, zero, zero, one)
    if model == RADTAN:
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
    elif model == FISHEYE:
        s, q, c, t = _fisheye_terms(d, r2)
        xd = s * x
        yd = s * y
        J = mat22d(s + q * x * x, q * x * y, q * x * y, s + q * y * y)
    return xd, yd, J


@wp.func
def _distort_value64(model: int, d: vec8d, x: wp.float64, y: wp.float64):
    """(xd, yd) of :func:`_distort64` without the Jacobian (forward passes)."""
    one = wp.float64(1.0)
    two = wp.float64(2.0)
    r2 = x * x + y * y
    xd = x
    yd = y
    if model == RADTAN:
        R = one + r2 * (d[0] + r2 * (d[1] + r2 * d[4]))
        xd = x * R + two * d[2] * x * y + d[3] * (r2 + two * x * x)
        yd = y * R + d[2] * (r2 + two * y * y) + two * d[3] * x * y
    elif model == FISHEYE:
        c = _atan_ratio_value(r2)
        s = c * _fisheye_poly(d, r2 * c * c)
        xd = s * x
        yd = s * y
    return xd, yd


@wp.func
def _distort_vjp_dist64(model: int, d: vec8d, x: wp.float64, y: wp.float64, gx: wp.float64, gy: wp.float64):
    """(d(xd, yd)/d dist)^T (gx, gy): the gradient to the coefficients (entries 5..7 zero)."""
    two = wp.float64(2.0)
    r2 = x * x + y * y
    g = vec8d()
    if model == RADTAN:
        a = gx * x + gy * y
        g = vec8d(
            a * r2,
            a * r2 * r2,
            gx * two * x * y + gy * (r2 + two * y * y),
            gx * (r2 + two * x * x) + gy * two * x * y,
            a * r2 * r2 * r2,
            wp.float64(0.0),
            wp.float64(0.0),
            wp.float64(0.0),
        )
    elif model == FISHEYE:
        c = _atan_ratio_value(r2)
        t = r2 * c * c
        a = (gx * x + gy * y) * c * t
        z = wp.float64(0.0)
        g = vec8d(a, a * t, a * t * t, a * t * t * t, z, z, z, z)
    return g


@wp.func
def _undistort64(model: int, d: vec8d, xd: wp.float64, yd: wp.float64):
    """(x, y, valid): the ideal normalized point whose distortion is (xd, yd) (see the module doc)."""
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    x = xd
    y = yd
    if model == RADTAN:
        for _it in range(NEWTON_ITERS):
            fx, fy, J = _distort64(model, d, x, y)
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
    elif model == FISHEYE:
        rd2 = xd * xd + yd * yd
        rd = wp.sqrt(rd2)
        theta_max = wp.atan(wp.sqrt(d[LIMIT]))
        theta = wp.min(rd, theta_max)
        for _it in range(NEWTON_ITERS):
            t = theta * theta
            f = theta * _fisheye_poly(d, t) - rd
            fp = _fisheye_dpoly(d, t)
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
        x = xd * scale
        y = yd * scale
    fx, fy = _distort_value64(model, d, x, y)
    res = wp.max(wp.abs(fx - xd), wp.abs(fy - yd))
    valid = res <= UNDISTORT_TOL and (x * x + y * y) < d[LIMIT]
    return x, y, valid


@wp.func
def _undistort_grad64(model: int, d: vec8d, x: wp.float64, y: wp.float64, gx: wp.float64, gy: wp.float64):
    """Implicit-function adjoint at the solution (x, y): lambda = J^-T (gx, gy) is the gradient to
    (xd, yd); the gradient to dist is -(dD/d dist)^T lambda. Returns (lx, ly, g_dist)."""
    fx, fy, J = _distort64(model, d, x, y)
    det = J[0, 0] * J[1, 1] - J[0, 1] * J[1, 0]
    lx = (J[1, 1] * gx - J[1, 0] * gy) / det
    ly = (J[0, 0] * gy - J[0, 1] * gx) / det
    return lx, ly, -_distort_vjp_dist64(model, d, x, y, lx, ly)


@wp.func
def _in_domain64(model: int, d: vec8d, x: wp.float64, y: wp.float64):
    inf = wp.float64(wp.inf)
    return wp.abs(x) < inf and wp.abs(y) < inf and (model == PINHOLE or x * x + y * y < d[LIMIT])


@wp.func
def _finite(v: Any):
    """wp.isfinite(v) as one comparison (false for NaN and +-inf); isfinite costs ~14 ns."""
    return wp.abs(v) < type(v)(wp.inf)


@wp.func
def _to64(d: Any):
    return vec8d(
        wp.float64(d[0]), wp.float64(d[1]), wp.float64(d[2]), wp.float64(d[3]),
        wp.float64(d[4]), wp.float64(d[5]), wp.float64(d[6]), wp.float64(d[7]),
    )


@wp.func
def _from64(g: vec8d, ref: Any):
    """g rounded to the float type of ``ref`` (a scalar)."""
    return wp.vector(
        type(ref)(g[0]), type(ref)(g[1]), type(ref)(g[2]), type(ref)(g[3]),
        type(ref)(g[4]), type(ref)(g[5]), type(ref)(g[6]), type(ref)(g[7]),
    )


@wp.func
def _finite_or_zero(v: Any):
    return wp.where(_finite(v), v, type(v)(0.0))


@wp.func
def _project_distorted64(model: int, K: Any, d: vec8d, p: Any):
    """(u, v, in domain) of a point with Z > 0 through a distorting model, in float64."""
    z = wp.float64(p[2])
    x = wp.float64(p[0]) / z
    y = wp.float64(p[1]) / z
    u = wp.float64(0.0)
    v = wp.float64(0.0)
    ok = x * x + y * y < d[LIMIT]
    if ok:
        xd, yd = _distort_value64(model, d, x, y)
        u = wp.float64(K[0, 0]) * xd + wp.float64(K[0, 1]) * yd + wp.float64(K[0, 2])
        v = wp.float64(K[1, 1]) * yd + wp.float64(K[1, 2])
    return u, v, ok


# ----------------------------------------------------------------------------- typed front


def _make(T, distort=None, undistort=None, project=None, unproject=None, distort_pixel=None, undistort_pixel=None):
    """float type ``T`` overloads of the public functions (Warp custom adjoints need concrete
    types); the parameters named like the functions are the overloads made before (see sampler.py)."""
    f64 = wp.float64
    vec2 = wp.types.vector(2, T)
    vec3 = wp.types.vector(3, T)
    mat33 = wp.types.matrix((3, 3), T)
    vec8 = vec8f if T == wp.float32 else vec8d

    @wp.func
    def distort(model: int, dist: vec8, xn: vec2):
        d = _to64(dist)
        x = f64(xn[0])
        y = f64(xn[1])
        ok = _in_domain64(model, d, x, y)
        out = vec2(_finite_or_zero(xn[0]), _finite_or_zero(xn[1]))
        if ok:
            xd, yd = _distort_value64(model, d, x, y)
            out = vec2(T(xd), T(yd))
        return out, ok

    @wp.func_grad(distort)
    def adj_distort(model: int, dist: vec8, xn: vec2, adj_ret0: vec2, adj_ret1: bool):
        d = _to64(dist)
        x = f64(xn[0])
        y = f64(xn[1])
        if _in_domain64(model, d, x, y):
            gx = f64(adj_ret0[0])
            gy = f64(adj_ret0[1])
            xd, yd, J = _distort64(model, d, x, y)
            wp.adjoint[xn] += vec2(T(J[0, 0] * gx + J[1, 0] * gy), T(J[0, 1] * gx + J[1, 1] * gy))
            wp.adjoint[dist] += _from64(_distort_vjp_dist64(model, d, x, y, gx, gy), xn[0])

    @wp.func
    def undistort(model: int, dist: vec8, xd: vec2):
        out = vec2(_finite_or_zero(xd[0]), _finite_or_zero(xd[1]))
        ok = _finite(xd[0]) and _finite(xd[1])
        if model != PINHOLE and ok:
            x, y, ok = _undistort64(model, _to64(dist), f64(xd[0]), f64(xd[1]))
            if ok:
                out = vec2(T(x), T(y))
        return out, ok

    @wp.func_grad(undistort)
    def adj_undistort(model: int, dist: vec8, xd: vec2, adj_ret0: vec2, adj_ret1: bool):
        if _finite(xd[0]) and _finite(xd[1]):
            if model == PINHOLE:
                wp.adjoint[xd] += adj_ret0
            else:
                d = _to64(dist)
                x, y, ok = _undistort64(model, d, f64(xd[0]), f64(xd[1]))
                if ok:
                    lx, ly, gd = _undistort_grad64(model, d, x, y, f64(adj_ret0[0]), f64(adj_ret0[1]))
                    wp.adjoint[xd] += vec2(T(lx), T(ly))
                    wp.adjoint[dist] += _from64(gd, xd[0])

    @wp.func
    def project(model: int, K: mat33, dist: vec8, p: vec3, min_depth: T):
        # finite X, Y, Z (a sum of finite coordinates above ~1e38 counts as not: irrelevant) and Z > min_depth
        ok = p[2] > min_depth and _finite(p[0] + p[1] + p[2])
        q = p
        if not ok:
            q = vec3(_finite_or_zero(p[0]), _finite_or_zero(p[1]), wp.max(_finite_or_zero(p[2]), min_depth))
        out = camera.project(K, q)  # the pinhole projection, or the stand-in
        if model != PINHOLE and ok:  # out of line, so that the pinhole path stays small
            u, v, ok = _project_distorted64(model, K, _to64(dist), p)
            if ok:
                out = vec2(T(u), T(v))
        return out, ok

    @wp.func_grad(project)
    def adj_project(model: int, K: mat33, dist: vec8, p: vec3, min_depth: T, adj_ret0: vec2, adj_ret1: bool):
        # finite X, Y, Z (a sum of finite coordinates above ~1e38 counts as not: irrelevant) and Z > min_depth
        ok = p[2] > min_depth and _finite(p[0] + p[1] + p[2])
        if ok:
            if model == PINHOLE:
                g_K, g_p = camera.project_grad(K, p, adj_ret0)
                wp.adjoint[K] += g_K
                wp.adjoint[p] += g_p
            else:
                z = f64(p[2])
                x = f64(p[0]) / z
                y = f64(p[1]) / z
                d = _to64(dist)
                if x * x + y * y < d[LIMIT]:
                    gu = f64(adj_ret0[0])
                    gv = f64(adj_ret0[1])
                    xd, yd, J = _distort64(model, d, x, y)
                    gxd = f64(K[0, 0]) * gu
                    gyd = f64(K[0, 1]) * gu + f64(K[1, 1]) * gv
                    gx = J[0, 0] * gxd + J[1, 0] * gyd
                    gy = J[0, 1] * gxd + J[1, 1] * gyd
                    wp.adjoint[p] += vec3(T(gx / z), T(gy / z), T(-(x * gx + y * gy) / z))
                    wp.adjoint[K] += mat33(
                        T(gu * xd), T(gu * yd), T(gu), T(0.0), T(gv * yd), T(gv), T(0.0), T(0.0), T(0.0)
                    )
                    wp.adjoint[dist] += _from64(_distort_vjp_dist64(model, d, x, y, gxd, gyd), p[0])

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
                out = vec3(_finite_or_zero(ray[0]), _finite_or_zero(ray[1]), T(1.0)) * _finite_or_zero(depth)
        return out, ok

    @wp.func_grad(unproject)
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
            d = _to64(dist)
            ok = _finite(rx) and _finite(ry)
            xn = f64(0.0)
            yn = f64(0.0)
            if ok:
                xn, yn, ok = _undistort64(model, d, rx, ry)
            if ok:
                dep = f64(depth)
                wp.adjoint[depth] += T(f64(g[0]) * xn + f64(g[1]) * yn + f64(g[2]))
                lx, ly, gd = _undistort_grad64(model, d, xn, yn, f64(g[0]) * dep, f64(g[1]) * dep)
                wp.adjoint[dist] += _from64(gd, x)
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
        ok = _finite(uv[0] + uv[1])
        out = vec2(_finite_or_zero(uv[0]), _finite_or_zero(uv[1]))
        if model != PINHOLE and ok:
            rx, ry = _k_inv64(K, uv)
            d = _to64(dist)
            ok = _in_domain64(model, d, rx, ry)
            if ok:
                xd, yd = _distort_value64(model, d, rx, ry)
                out = vec2(T(f64(K[0, 0]) * xd + f64(K[0, 1]) * yd + f64(K[0, 2])), T(f64(K[1, 1]) * yd + f64(K[1, 2])))
        return out, ok

    @wp.func_grad(distort_pixel)
    def adj_distort_pixel(model: int, K: mat33, dist: vec8, uv: vec2, adj_ret0: vec2, adj_ret1: bool):
        if _finite(uv[0] + uv[1]):
            if model == PINHOLE:
                wp.adjoint[uv] += adj_ret0
            else:
                rx, ry = _k_inv64(K, uv)
                d = _to64(dist)
                if _in_domain64(model, d, rx, ry):
                    gu = f64(adj_ret0[0])
                    gv = f64(adj_ret0[1])
                    xd, yd, J = _distort64(model, d, rx, ry)
                    gxd = f64(K[0, 0]) * gu
                    gyd = f64(K[0, 1]) * gu + f64(K[1, 1]) * gv
                    lx = J[0, 0] * gxd + J[1, 0] * gyd
                    ly = J[0, 1] * gxd + J[1, 1] * gyd
                    g_uv, g_K = _pixel_grads(K, rx, ry, xd, yd, gu, gv, lx, ly)
                    wp.adjoint[uv] += g_uv
                    wp.adjoint[K] += g_K
                    wp.adjoint[dist] += _from64(_distort_vjp_dist64(model, d, rx, ry, gxd, gyd), uv[0])

    @wp.func
    def undistort_pixel(model: int, K: mat33, dist: vec8, uv: vec2):
        ok = _finite(uv[0] + uv[1])
        out = vec2(_finite_or_zero(uv[0]), _finite_or_zero(uv[1]))
        if model != PINHOLE and ok:
            rx, ry = _k_inv64(K, uv)
            x, y, ok = _undistort64(model, _to64(dist), rx, ry)
            if ok:
                out = vec2(T(f64(K[0, 0]) * x + f64(K[0, 1]) * y + f64(K[0, 2])), T(f64(K[1, 1]) * y + f64(K[1, 2])))
        return out, ok

    @wp.func_grad(undistort_pixel)
    def adj_undistort_pixel(model: int, K: mat33, dist: vec8, uv: vec2, adj_ret0: vec2, adj_ret1: bool):
        if _finite(uv[0] + uv[1]):
            if model == PINHOLE:
                wp.adjoint[uv] += adj_ret0
            else:
                rx, ry = _k_inv64(K, uv)
                d = _to64(dist)
                x, y, ok = _undistort64(model, d, rx, ry)
                if ok:
                    gu = f64(adj_ret0[0])
                    gv = f64(adj_ret0[1])
                    gx = f64(K[0, 0]) * gu
                    gy = f64(K[0, 1]) * gu + f64(K[1, 1]) * gv
                    lx, ly, gd = _undistort_grad64(model, d, x, y, gx, gy)
                    g_uv, g_K = _pixel_grads(K, rx, ry, x, y, gu, gv, lx, ly)
                    wp.adjoint[uv] += g_uv
                    wp.adjoint[K] += g_K
                    wp.adjoint[dist] += _from64(gd, uv[0])

    return distort, undistort, project, unproject, distort_pixel, undistort_pixel


# The typed fronts are made on first use (PEP 562): Warp builds a function with a custom adjoint
# when the adjoint is defined, to learn its return types, which costs ~1.5 s here; importing this
# module for its constants (the torch cameras, the aligner) should not. A kernel or function that
# names ``lens.project`` makes them when it is defined (Warp resolves the names then), i.e. when
# its module is imported: the modules with such kernels are imported on first use of a lens.
_FRONTS = ("distort", "undistort", "project", "unproject", "distort_pixel", "undistort_pixel")
distort: Any
undistort: Any
project: Any
unproject: Any
distort_pixel: Any
undistort_pixel: Any
_FRONTS_LOCK = threading.Lock()


def __getattr__(name: str):
    if name in _FRONTS:
        with _FRONTS_LOCK:
            if _FRONTS[0] not in globals():
                globals().update(zip(_FRONTS, _make(wp.float64, *_make(wp.float32))))
        return globals()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_FRONTS))


__all__ = [
    "DIST_SIZE",
    "FISHEYE",
    "LIMIT",
    "MODEL_IDS",
    "NEWTON_ITERS",
    "NEWTON_STEP_TOL",
    "N_COEFFS",
    "PINHOLE",
    "RADTAN",
    "UNDISTORT_TOL",
    "distort",
    "distort_pixel",
    "domain_limit",
    "pack_dist",
    "project",
    "undistort",
    "undistort_pixel",
    "unproject",
]
