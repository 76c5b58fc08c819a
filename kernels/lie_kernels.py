"""Thin per-element kernels over the rotation / rigid-motion functions of :mod:`.lie`.

Each kernel: element index -> load -> one ``@wp.func`` call -> store. Arrays are 1-D (one
element per batch item); see :mod:`.launch` for the ``offset`` convention and overloads.
"""

from typing import Any

import warp as wp

from . import lie
from .kinds import FloatKernel


@wp.kernel
def _so3_exp(offset: int, omega: wp.array(dtype=Any), R: wp.array(dtype=Any)):
    i = wp.tid() + offset
    R[i] = lie.so3_exp(omega[i])


@wp.kernel
def _so3_log(offset: int, R: wp.array(dtype=Any), omega: wp.array(dtype=Any)):
    i = wp.tid() + offset
    omega[i] = lie.so3_log(R[i])


@wp.kernel
def _quaternion_to_matrix(offset: int, q: wp.array(dtype=Any), R: wp.array(dtype=Any)):
    i = wp.tid() + offset
    R[i] = lie.quat_wxyz_to_matrix(q[i])


@wp.kernel
def _euler_to_matrix(
    offset: int, angles: wp.array(dtype=Any), a0: int, a1: int, a2: int, R: wp.array(dtype=Any)
):
    i = wp.tid() + offset
    R[i] = lie.euler_to_matrix(angles[i], a0, a1, a2)


@wp.kernel
def _se3_to_matrix(offset: int, omega: wp.array(dtype=Any), t: wp.array(dtype=Any), T: wp.array(dtype=Any)):
    i = wp.tid() + offset
    T[i] = lie.se3_to_pose(omega[i], t[i])


@wp.kernel
def _sim3_to_matrix(
    offset: int,
    omega: wp.array(dtype=Any),
    t: wp.array(dtype=Any),
    sigma: wp.array(dtype=Any),
    T: wp.array(dtype=Any),
):
    i = wp.tid() + offset
    T[i] = lie.sim3_to_pose(omega[i], t[i], sigma[i])


@wp.kernel
def _se3_exp(offset: int, omega: wp.array(dtype=Any), u: wp.array(dtype=Any), T: wp.array(dtype=Any)):
    i = wp.tid() + offset
    T[i] = lie.se3_exp(omega[i], u[i])


@wp.kernel
def _se3_log(offset: int, T: wp.array(dtype=Any), omega: wp.array(dtype=Any), u: wp.array(dtype=Any)):
    i = wp.tid() + offset
    Ti = T[i]
    w = lie.se3_log_omega(Ti)
    omega[i] = w
    u[i] = lie.se3_log_u(Ti, w)


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
