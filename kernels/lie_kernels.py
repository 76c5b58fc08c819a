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

from . import lie
from .launch import FloatKernel

mat34d = wp.types.matrix(shape=(3, 4), dtype=wp.float64)


@wp.kernel
def _so3_exp(offset: int, omega: wp.array(dtype=Any), R: wp.array(dtype=Any)):
    i = wp.tid() + offset
    R[i] = R.dtype(lie.so3_exp(wp.vec3d(omega[i])))


@wp.kernel
def _so3_log(offset: int, R: wp.array(dtype=Any), omega: wp.array(dtype=Any)):
    i = wp.tid() + offset
    omega[i] = omega.dtype(lie.so3_log(wp.mat33d(R[i])))


@wp.kernel
def _quaternion_to_matrix(offset: int, q: wp.array(dtype=Any), R: wp.array(dtype=Any)):
    i = wp.tid() + offset
    R[i] = R.dtype(lie.quat_wxyz_to_matrix(wp.vec4d(q[i])))


@wp.kernel
def _euler_to_matrix(
    offset: int, angles: wp.array(dtype=Any), a0: int, a1: int, a2: int, R: wp.array(dtype=Any)
):
    i = wp.tid() + offset
    R[i] = R.dtype(lie.euler_to_matrix(wp.vec3d(angles[i]), a0, a1, a2))


@wp.kernel
def _se3_to_matrix(offset: int, omega: wp.array(dtype=Any), t: wp.array(dtype=Any), T: wp.array(dtype=Any)):
    i = wp.tid() + offset
    T[i] = T.dtype(lie.se3_to_pose(wp.vec3d(omega[i]), wp.vec3d(t[i])))


@wp.kernel
def _sim3_to_matrix(
    offset: int,
    omega: wp.array(dtype=Any),
    t: wp.array(dtype=Any),
    sigma: wp.array(dtype=Any),
    T: wp.array(dtype=Any),
):
    i = wp.tid() + offset
    T[i] = T.dtype(lie.sim3_to_pose(wp.vec3d(omega[i]), wp.vec3d(t[i]), wp.float64(sigma[i])))


@wp.kernel
def _se3_exp(offset: int, omega: wp.array(dtype=Any), u: wp.array(dtype=Any), T: wp.array(dtype=Any)):
    i = wp.tid() + offset
    T[i] = T.dtype(lie.se3_exp(wp.vec3d(omega[i]), wp.vec3d(u[i])))


@wp.kernel
def _se3_log(offset: int, T: wp.array(dtype=Any), omega: wp.array(dtype=Any), u: wp.array(dtype=Any)):
    i = wp.tid() + offset
    Ti = mat34d(T[i])
    w = lie.se3_log_omega(Ti)
    omega[i] = omega.dtype(w)
    u[i] = u.dtype(lie.se3_log_u(Ti, w))


so3_exp = FloatKernel(_so3_exp, omega="vec3", R="mat33")
so3_log = FloatKernel(_so3_log, R="mat33", omega="vec3")
quaternion_to_matrix = FloatKernel(_quaternion_to_matrix, q="vec4", R="mat33")
euler_to_matrix = FloatKernel(_euler_to_matrix, angles="vec3", R="mat33")
se3_to_matrix = FloatKernel(_se3_to_matrix, omega="vec3", t="vec3", T="mat34")
sim3_to_matrix = FloatKernel(_sim3_to_matrix, omega="vec3", t="vec3", sigma="scalar", T="mat34")
se3_exp = FloatKernel(_se3_exp, omega="vec3", u="vec3", T="mat34")
se3_log = FloatKernel(_se3_log, T="mat34", omega="vec3", u="vec3")
