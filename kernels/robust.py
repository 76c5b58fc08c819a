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
over float32/float64 except :func:`log1p`, whose float32 and float64 overloads are made by
:func:`.core.cache.float_overloads` (custom gradients cannot be generic in Warp 1.19).

Huge residuals. ``(x/c)^2`` overflows once |x/c| > ~1.8e19 (float32), so where |x/c| > 1 Cauchy and
Geman-McClure are evaluated in ``w = c/x`` (``log(1 + u^2) = 2 log|u| + log(1 + w^2)``, ``u^2 / (1
+ u^2) = 1 / (1 + w^2)``): finite for every finite x and correct at x = +-inf (rho = inf, c^2/2,
psi = 0). Each branch is evaluated on an input replaced by a harmless value where the other branch
is taken (:func:`_keep`), and the branches are joined by ``wp.where``, whose adjoint sends nothing
to the side not taken: the unused branch can neither overflow nor put ``0 * inf = NaN`` into the
gradient.
"""

from typing import Any

import warp as wp

from .core.cache import float_overloads
from .core.compat import func_grad

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


def _log1p(T):
    """float type ``T`` overload of log1p (custom adjoints need concrete types)."""

    @wp.func
    def log1p(z: T):
        u = T(1.0) + z
        r = z
        if u != T(1.0):
            r = wp.log(u) * (z / (u - T(1.0)))  # z / (u - 1) first: log(u) z overflows for z ~ 1e37
        return r

    @func_grad(log1p)
    def adj_log1p(z: T, adj_ret: T):
        wp.adjoint[z] += adj_ret / (T(1.0) + z)

    return log1p


log1p = float_overloads(_log1p)


# ----------------------------------------------------------------------------- rho


@wp.func
def _keep(take: bool, x: Any, other: Any):
    """x where ``take``, else ``other``: the input of a branch, made harmless where it is not taken."""
    return wp.where(take, x, other)


@wp.func
def _branches(x: Any, c: Any):
    """(inner, xi, u, w) for the two branches of Cauchy and Geman-McClure: ``inner`` = |x| <= c;
    there xi = x and u = x/c (0 elsewhere); beyond, w = c/x (1 elsewhere), with |w| < 1."""
    inner = wp.abs(x) <= c
    xi = _keep(inner, x, type(x)(0.0))
    return inner, xi, xi / c, c / _keep(inner, c, x)


@wp.func
def huber_rho(x: Any, eps: Any):
    inner = wp.abs(x) <= eps
    xi = _keep(inner, x, type(x)(0.0))
    ao = wp.abs(_keep(inner, eps, x))
    return wp.where(inner, xi * xi * type(x)(0.5), eps * (ao - eps * type(x)(0.5)))


@wp.func
def cauchy_rho(x: Any, c: Any):
    inner, _, u, w = _branches(x, c)  # w = 0 at x = +-inf
    xo = wp.abs(_keep(inner, c, x))
    # log(1 + u^2) for |u| <= 1, 2 log|x/c| + log(1 + w^2) beyond; log|x| - log c where x/c overflows
    uo = xo / c
    log_uo = wp.where(uo <= type(x)(3.0e38), wp.log(uo), wp.log(xo) - wp.log(c))
    h = c * c * type(x)(0.5)
    return wp.where(inner, h * log1p(u * u), h * (type(x)(2.0) * log_uo + log1p(w * w)))


@wp.func
def geman_mcclure_rho(x: Any, c: Any):
    inner, xi, u, w = _branches(x, c)
    half = type(x)(0.5)
    # (x^2/2) / (1 + u^2) = (c^2/2) / (1 + w^2) for |u| > 1
    return wp.where(inner, xi * xi * half / (type(x)(1.0) + u * u), c * c * half / (type(x)(1.0) + w * w))


@wp.func
def tukey_rho(x: Any, c: Any):
    k = c * c / type(x)(6.0)
    inner = wp.abs(x) <= c
    u = _keep(inner, x, type(x)(0.0)) / c
    z = u * u
    # 1 - (1 - z)^3 = z (3 - 3 z + z^2), without the cancellation of the closed form
    return wp.where(inner, k * z * (type(x)(3.0) - z * (type(x)(3.0) - z)), k)


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
    inner = wp.abs(x) <= eps
    return wp.where(inner, _keep(inner, x, type(x)(0.0)), wp.where(x < type(x)(0.0), -eps, eps))


@wp.func
def cauchy_psi(x: Any, c: Any):
    inner, xi, u, w = _branches(x, c)
    # x / (1 + u^2) = c w / (1 + w^2) for |u| > 1 (0 at x = +-inf)
    return wp.where(inner, xi / (type(x)(1.0) + u * u), c * w / (type(x)(1.0) + w * w))


@wp.func
def geman_mcclure_psi(x: Any, c: Any):
    inner, xi, u, w = _branches(x, c)
    d = type(x)(1.0) + u * u
    e = type(x)(1.0) + w * w
    # x / (1 + u^2)^2 = c w^3 / (1 + w^2)^2 for |u| > 1
    return wp.where(inner, xi / (d * d), c * w * w * w / (e * e))


@wp.func
def tukey_psi(x: Any, c: Any):
    inner = wp.abs(x) <= c
    xi = _keep(inner, x, type(x)(0.0))
    u = xi / c
    v = type(x)(1.0) - u * u
    return wp.where(inner, xi * v * v, type(x)(0.0))


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
