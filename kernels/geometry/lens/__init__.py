"""Camera lens models as ``@wp.func`` (no launches here): pinhole, radial-tangential, fisheye.

The contract, for kernels that project or unproject through any of the models
============================================================================

A camera is three things per batch item: ``K`` (a ``mat33`` as in :mod:`.camera`, lower row
never read), ``dist`` (one distortion vector, ``vec8`` of the kernel's float type, the same
layout for every model) and ``model`` (an ``int``, one of the ids below). ``model`` is read at
run time, typically one value for a whole launch: one kernel serves every model (no compiled
variant per model), the branch on it is predictable, and PINHOLE costs only the validity tests
(the distorting code is out of line and never entered).

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
  (and its gradient :func:`.camera.project_grad`).
- ``unproject(model, K, dist, x: T, y: T, depth: T) -> (p: vec3, valid: bool)``:
  p = depth * (undistort(K^-1 [x, y, 1]), 1); ``valid`` is the undistortion's (the depth is
  passed through, as :func:`.camera.unproject` does). Invalid: depth * K^-1 [x, y, 1] with the
  non-finite entries as 0, zero gradient. For PINHOLE: bitwise :func:`.camera.unproject`, always
  valid.

Every function has a hand-written adjoint (``compat.func_grad``: Warp's ``@wp.func_grad`` without
its build) for all its floating arguments (K, dist, p / x, y, depth), so callers get gradients for
intrinsics and every coefficient through Warp's adjoint launches or ``wp.Tape``. Adjoint of
dist[LIMIT:] is always 0.

The typed fronts are :mod:`.fronts` (made on first use);
the float64 building blocks for kernels with their own hand-written adjoints (:mod:`.rays`, the
fused warps) are :mod:`.dispatch` (``to64``, ``from64``, ``distort64``, ``distort_value64``,
``distort_vjp_dist64``, ``undistort64``, ``undistort_grad64``; also here under their earlier names
``_to64``, ``_distort64``...), over the models :mod:`.radtan` and :mod:`.fisheye`; the pixel rays
of the fused kernels are :mod:`.rays` (8 lanes at a time: :mod:`.lanes`).
"""

import math
from typing import Any

import numpy as np

from . import dispatch, fisheye, fronts
from .constants import (
    DIST_SIZE,
    FISHEYE,
    LIMIT,
    MODEL_IDS,
    N_COEFFS,
    NEWTON_ITERS,
    NEWTON_STEP_TOL,
    PINHOLE,
    RADTAN,
    UNDISTORT_TOL,
)

# the float64 building blocks under their earlier names (documented as stable for users' own kernels)
_to64 = dispatch.to64
_from64 = dispatch.from64
_distort64 = dispatch.distort64
_distort_value64 = dispatch.distort_value64
_distort_vjp_dist64 = dispatch.distort_vjp_dist64
_undistort64 = dispatch.undistort64
_undistort_grad64 = dispatch.undistort_grad64
_in_domain64 = dispatch.in_domain64
_project_distorted64 = dispatch.project_distorted64
_finite = dispatch.finite
_finite_or_zero = dispatch.finite_or_zero
_atan_ratio = fisheye.atan_ratio
_atan_ratio_value = fisheye.atan_ratio_value
_ATAN_H = fisheye.ATAN_H
_ATAN_G = fisheye.ATAN_G


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

# ----------------------------------------------------------------------------- typed fronts

# Made on first use through the cache (:func:`.fronts.functions`), and
# named by kernels as module attributes (``lens.project``): Warp resolves such a name when the
# kernel is defined, so defining a kernel that names one makes them.
_FRONTS = fronts.Fronts._fields
distort: Any
undistort: Any
project: Any
unproject: Any
distort_pixel: Any
undistort_pixel: Any


def __getattr__(name: str):
    if name in _FRONTS:
        globals().update(fronts.functions()._asdict())  # (the same objects every time: later lookups skip this)
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
