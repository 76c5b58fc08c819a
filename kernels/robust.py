"""M-estimators (robust penalties) as ``@wp.func`` (no launches here): rho(x) and psi(x) = rho'(x).

The table of the gvnn paper ("M-estimators"), with a scale ``c`` (``eps`` for Huber):

=============  ===========================================  ==================================
kind           rho(x)                                       psi(x) = d rho / dx
=============  ===========================================  ==================================
Huber          x^2 / 2 if |x| <= eps, else eps (|x| - eps/2) x if |x| <= eps, else eps sign(x)
Cauchy         c^2 / 2 log(1 + (x/c)^2)                     x / (1 + (x/c)^2)
Geman-McClure  (x^2 / 2) / (1 + (x/c)^2)                    x / (1 + (x/c)^2)^2
Tukey          c^2/6 (1 - (1 - (x/c)^2)^3) if |x| <= c,     x (1 - (x/c)^2)^2 if |x| <= c,
               else c^2 / 6                                 else 0
=============  ===========================================  ==================================

(The paper's Geman-McClure row is the c = 1 case.) Every rho is written so that Warp's automatic
adjoint *is* psi to rounding: Tukey's ``1 - (1 - z)^3`` is expanded as ``z (3 - 3 z + z^2)`` (no
cancellation for small x), and Cauchy uses :func:`log1p`, accurate for tiny arguments, whose
gradient ``1 / (1 + z)`` is given explicitly with ``@wp.func_grad``. All functions are generic
over float32/float64 except the two concrete :func:`log1p` overloads (custom gradients cannot
be generic in Warp 1.19).
"""

from typing import Any

import warp as wp

HUBER = wp.constant(0)
CAUCHY = wp.constant(1)
GEMAN_MCCLURE = wp.constant(2)
TUKEY = wp.constant(3)
#: kind name -> the integer code the kernels take
KINDS = {"huber": 0, "cauchy": 1, "geman_mcclure": 2, "tukey": 3}


# ----------------------------------------------------------------------------- log1p
# log(1 + z) for z > -1 without losing the low bits of a small z (Kahan's trick: with u = fl(1 + z),
# u - 1 is exact and log(u) z / (u - 1) is accurate to a few ulps). The trick's automatic adjoint
# would cancel, so the gradient 1 / (1 + z) is supplied explicitly.


@wp.func
def log1p(z: wp.float32):
    u = wp.float32(1.0) + z
    r = z
    if u != wp.float32(1.0):
        r = wp.log(u) * z / (u - wp.float32(1.0))
    return r


@wp.func_grad(log1p)
def adj_log1p(z: wp.float32, adj_ret: wp.float32):
    wp.adjoint[z] += adj_ret / (wp.float32(1.0) + z)


@wp.func
def log1p(z: wp.float64):  # noqa: F811 (the float64 overload)
    u = wp.float64(1.0) + z
    r = z
    if u != wp.float64(1.0):
        r = wp.log(u) * z / (u - wp.float64(1.0))
    return r


@wp.func_grad(log1p)
def adj_log1p(z: wp.float64, adj_ret: wp.float64):  # noqa: F811 (the float64 overload)
    wp.adjoint[z] += adj_ret / (wp.float64(1.0) + z)


# ----------------------------------------------------------------------------- rho


@wp.func
def huber_rho(x: Any, eps: Any):
    ax = wp.abs(x)
    r = x * x * type(x)(0.5)
    if ax > eps:
        r = eps * (ax - eps * type(x)(0.5))
    return r


@wp.func
def cauchy_rho(x: Any, c: Any):
    u = x / c
    return c * c * type(x)(0.5) * log1p(u * u)


@wp.func
def geman_mcclure_rho(x: Any, c: Any):
    u = x / c
    return x * x * type(x)(0.5) / (type(x)(1.0) + u * u)


@wp.func
def tukey_rho(x: Any, c: Any):
    k = c * c / type(x)(6.0)
    r = k
    if wp.abs(x) <= c:
        u = x / c
        z = u * u
        # 1 - (1 - z)^3 = z (3 - 3 z + z^2), without the cancellation of the closed form
        r = k * z * (type(x)(3.0) - z * (type(x)(3.0) - z))
    return r


@wp.func
def rho(x: Any, kind: int, c: Any):
    """The M-estimator ``kind`` (HUBER, CAUCHY, GEMAN_MCCLURE, TUKEY) with scale ``c`` at ``x``."""
    r = huber_rho(x, c)
    if kind == CAUCHY:
        r = cauchy_rho(x, c)
    elif kind == GEMAN_MCCLURE:
        r = geman_mcclure_rho(x, c)
    elif kind == TUKEY:
        r = tukey_rho(x, c)
    return r


# ----------------------------------------------------------------------------- psi


@wp.func
def huber_psi(x: Any, eps: Any):
    r = x
    if x > eps:
        r = eps
    elif x < -eps:
        r = -eps
    return r


@wp.func
def cauchy_psi(x: Any, c: Any):
    u = x / c
    return x / (type(x)(1.0) + u * u)


@wp.func
def geman_mcclure_psi(x: Any, c: Any):
    u = x / c
    d = type(x)(1.0) + u * u
    return x / (d * d)


@wp.func
def tukey_psi(x: Any, c: Any):
    r = type(x)(0.0)
    if wp.abs(x) <= c:
        u = x / c
        w = type(x)(1.0) - u * u
        r = x * w * w
    return r


@wp.func
def psi(x: Any, kind: int, c: Any):
    """d rho(x, kind, c) / dx, in closed form (its own adjoint is rho'')."""
    r = huber_psi(x, c)
    if kind == CAUCHY:
        r = cauchy_psi(x, c)
    elif kind == GEMAN_MCCLURE:
        r = geman_mcclure_psi(x, c)
    elif kind == TUKEY:
        r = tukey_psi(x, c)
    return r
