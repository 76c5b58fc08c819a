"""Thin per-element kernels over the rotation / rigid-motion functions of :mod:`.lie`.

Each kernel: element index -> load -> one ``@wp.func`` call -> store. Arrays are 1-D (one
element per batch item); see :mod:`.launch` for the ``offset`` convention and overloads.

The functions are evaluated in float64 for every array type (loads are converted to float64,
results rounded to the output's type on store): a float32 op's values and gradients are then
the float64 ones rounded to float32, for every angle (float32 arithmetic alone loses up to ~1e-5
of the gradients' relative accuracy near 0 and pi: sums of large terms that cancel). Converting
costs little next to the loads and stores.
"""

from typing import Any

import warp as wp

from ..core.kinds import FloatKernel
from . import lie

mat34d = wp.types.matrix(shape=(3, 4), dtype=wp.float64)


@wp.func
def _vec3_as(v: Any, x: Any):
    """v as a 3-vector of the float type of the scalar x."""
    return wp.vector(v, length=3, dtype=type(x))


@wp.func
def _mat33_as(M: Any, x: Any):
    """M (3x3) as a matrix of the float type of the scalar x."""
    return wp.matrix(M, shape=(3, 3), dtype=type(x))


@wp.func
def _mat34_as(M: Any, x: Any):
    """M (3x4) as a matrix of the float type of the scalar x."""
    return wp.matrix(M, shape=(3, 4), dtype=type(x))


@wp.kernel
def _so3_exp(offset: int, omega: wp.array(dtype=Any), R: wp.array(dtype=Any)):
    i = wp.tid() + offset
    w = omega[i]
    R[i] = _mat33_as(lie.so3_exp(wp.vec3d(w)), w[0])


@wp.kernel
def _so3_log(offset: int, R: wp.array(dtype=Any), omega: wp.array(dtype=Any)):
    i = wp.tid() + offset
    Ri = R[i]
    omega[i] = _vec3_as(lie.so3_log(wp.mat33d(Ri)), Ri[0, 0])


@wp.kernel
def _quaternion_to_matrix(offset: int, q: wp.array(dtype=Any), R: wp.array(dtype=Any)):
    i = wp.tid() + offset
    qi = q[i]
    R[i] = _mat33_as(lie.quat_wxyz_to_matrix(wp.vec4d(qi)), qi[0])


@wp.kernel
def _euler_to_matrix(
    offset: int, angles: wp.array(dtype=Any), a0: int, a1: int, a2: int, R: wp.array(dtype=Any)
):
    i = wp.tid() + offset
    a = angles[i]
    R[i] = _mat33_as(lie.euler_to_matrix(wp.vec3d(a), a0, a1, a2), a[0])


@wp.kernel
def _se3_to_matrix(offset: int, omega: wp.array(dtype=Any), t: wp.array(dtype=Any), T: wp.array(dtype=Any)):
    i = wp.tid() + offset
    w = omega[i]
    T[i] = _mat34_as(lie.se3_to_pose(wp.vec3d(w), wp.vec3d(t[i])), w[0])


@wp.kernel
def _sim3_to_matrix(
    offset: int,
    omega: wp.array(dtype=Any),
    t: wp.array(dtype=Any),
    sigma: wp.array(dtype=Any),
    T: wp.array(dtype=Any),
):
    i = wp.tid() + offset
    w = omega[i]
    T[i] = _mat34_as(lie.sim3_to_pose(wp.vec3d(w), wp.vec3d(t[i]), wp.float64(sigma[i])), w[0])


@wp.kernel
def _se3_exp(offset: int, omega: wp.array(dtype=Any), u: wp.array(dtype=Any), T: wp.array(dtype=Any)):
    i = wp.tid() + offset
    w = omega[i]
    T[i] = _mat34_as(lie.se3_exp(wp.vec3d(w), wp.vec3d(u[i])), w[0])


@wp.kernel
def _se3_log(offset: int, T: wp.array(dtype=Any), omega: wp.array(dtype=Any), u: wp.array(dtype=Any)):
    i = wp.tid() + offset
    Tf = T[i]
    Ti = mat34d(Tf)
    w = lie.se3_log_omega(Ti)
    omega[i] = _vec3_as(w, Tf[0, 0])
    u[i] = _vec3_as(lie.se3_log_u(Ti, w), Tf[0, 0])


# Every element reads and writes only its own batch item: any split is exact.
so3_exp = FloatKernel(_so3_exp, omega="vec3", R="mat33").set_parallel(scopes={"omega": "element"})
so3_log = FloatKernel(_so3_log, R="mat33", omega="vec3").set_parallel(scopes={"R": "element"})
quaternion_to_matrix = FloatKernel(_quaternion_to_matrix, q="vec4", R="mat33").set_parallel(scopes={"q": "element"})
euler_to_matrix = FloatKernel(_euler_to_matrix, angles="vec3", R="mat33").set_parallel(scopes={"angles": "element"})
se3_to_matrix = FloatKernel(_se3_to_matrix, omega="vec3", t="vec3", T="mat34").set_parallel(
    scopes={"omega": "element", "t": "element"}
)
sim3_to_matrix = FloatKernel(_sim3_to_matrix, omega="vec3", t="vec3", sigma="scalar", T="mat34").set_parallel(
    scopes={"omega": "element", "t": "element", "sigma": "element"}
)
se3_exp = FloatKernel(_se3_exp, omega="vec3", u="vec3", T="mat34").set_parallel(
    scopes={"omega": "element", "u": "element"}
)
se3_log = FloatKernel(_se3_log, T="mat34", omega="vec3", u="vec3").set_parallel(scopes={"T": "element"})
