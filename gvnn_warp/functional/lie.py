"""Rotations, rigid motions and similarities as torch functions: so(3) and SE(3) exponential and
logarithm, quaternions, Euler angles, gvnn's SE3 and Sim3 layers' maps.

Every function takes float32 or float64 CPU tensors of shape (..., k) (any leading dimensions),
returns gradients for every floating argument through Warp's adjoints, validates its arguments
with a clear error, and never modifies its inputs. Conventions (``[omega, t]`` order, quaternion
order, units) are in ``docs/conventions.md``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..ops import geometry as _ops
from ..ops.checks import ArgCheck, flat

__all__ = [
    "euler_to_matrix",
    "quaternion_to_matrix",
    "se3_exp",
    "se3_log",
    "se3_to_matrix",
    "sim3_to_matrix",
    "so3_exp",
    "so3_log",
]

_AXES = {"X": 0, "Y": 1, "Z": 2}
EULER_CONVENTIONS = tuple(
    a + b + c for a in "XYZ" for b in "XYZ" for c in "XYZ" if a != b and b != c
)  # 6 Tait-Bryan ("XYZ", ...) and 6 proper Euler ("ZYZ", ...) orders


# ----------------------------------------------------------------------------- rotations


def so3_exp(omega: Tensor) -> Tensor:
    """Exponential map so(3) -> SO(3) (Rodrigues' formula), the paper's SO3 layer.

    Args:
        omega: (..., 3) rotation vectors, axis * angle in radians.

    Returns:
        (..., 3, 3) rotation matrices. Exact values and finite, exact gradients at omega = 0
        (Taylor branch below |omega| = 1e-2) and for every angle, including near and beyond pi.
    """
    ArgCheck("so3_exp").tensor("omega", omega, "... 3")
    return _ops.so3_exp(flat(omega, 1)).reshape(*omega.shape[:-1], 3, 3)


def so3_log(R: Tensor) -> Tensor:
    """Logarithm SO(3) -> so(3), the inverse of :func:`so3_exp` (angle in [0, pi]).

    Args:
        R: (..., 3, 3) rotation matrices. A matrix that is not one (|R^T R - I|_F > 1e-5 or
            det R <= 0: scaled, sheared, a reflection, 0) stands for its nearest rotation in the
            Frobenius norm (U V^T from the SVD, the last singular value signed); where several
            are equally near (an orthogonal reflection) one of them, for 0 the identity. Finite
            values and gradients for every finite R; the gradient is that of the nearest
            rotation's log (its terms are left out where the nearest rotation is not unique).
            Matrices within 1e-5 of a rotation are used as they are (no projection, no cost).

    Returns:
        (..., 3) rotation vectors. Stable near 0 (series) and near pi (axis from the symmetric
        part); at exactly pi the sign of the axis is the one for which the antisymmetric part
        of R is non-negative along it (either is a valid logarithm).
    """
    ArgCheck("so3_log").tensor("R", R, "... 3 3")
    return _ops.so3_log(flat(R, 2)).reshape(*R.shape[:-2], 3)


def quaternion_to_matrix(q: Tensor) -> Tensor:
    """Quaternion -> rotation matrix.

    Args:
        q: (..., 4) quaternions in (w, x, y, z) order, of any norm with |q|^2 in (1e-30, dtype
            max) (normalised inside; the gradient is that of q / |q|). Below that (a zero
            quaternion) the identity, with zero gradient.

    Returns:
        (..., 3, 3) rotation matrices.
    """
    ArgCheck("quaternion_to_matrix").tensor("q", q, "... 4")
    return _ops.quaternion_to_matrix(flat(q, 1)).reshape(*q.shape[:-1], 3, 3)


def euler_to_matrix(angles: Tensor, convention: str = "XYZ") -> Tensor:
    """Euler angles -> rotation matrix, R = R_c0(a0) @ R_c1(a1) @ R_c2(a2) for convention "c0c1c2".

    Args:
        angles: (..., 3) angles in radians, in the order of ``convention``.
        convention: three axes from "X", "Y", "Z", no two consecutive equal: the six
            Tait-Bryan orders ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX") and the six proper
            Euler orders ("XYX", ..., "ZYZ"). R_X, R_Y, R_Z are right-handed rotations about
            the fixed axes, e.g. R_Z(a) = [[cos a, -sin a, 0], [sin a, cos a, 0], [0, 0, 1]].

    Returns:
        (..., 3, 3) rotation matrices.
    """
    chk = ArgCheck("euler_to_matrix")
    chk.tensor("angles", angles, "... 3")
    chk.option("convention", convention, EULER_CONVENTIONS)
    a0, a1, a2 = (_AXES[c] for c in convention)
    return _ops.euler_to_matrix(flat(angles, 1), a0, a1, a2).reshape(*angles.shape[:-1], 3, 3)


# ----------------------------------------------------------------------------- rigid motions


def se3_to_matrix(xi: Tensor) -> Tensor:
    """The paper's SE3 layer: xi = [omega, t] -> [so3_exp(omega) | t].

    Note t is used as is (not V(omega) t as in the Lie exponential, :func:`se3_exp`), and not
    gvnn's original [R | R t].

    Args:
        xi: (..., 6) with omega = xi[..., :3] (radians) and t = xi[..., 3:] (metres).

    Returns:
        (..., 3, 4) poses acting on points as p -> R p + t.
    """
    ArgCheck("se3_to_matrix").tensor("xi", xi, "... 6")
    x = flat(xi, 1)
    return _ops.se3_to_matrix(x[:, :3].contiguous(), x[:, 3:].contiguous()).reshape(*xi.shape[:-1], 3, 4)


def sim3_to_matrix(xi: Tensor) -> Tensor:
    """The Sim3 layer: xi = [omega, t, sigma] -> [exp(sigma) so3_exp(omega) | t].

    Args:
        xi: (..., 7): omega = xi[..., :3], t = xi[..., 3:6], log-scale sigma = xi[..., 6].

    Returns:
        (..., 3, 4) similarity transforms p -> s R p + t with s = exp(sigma).
    """
    ArgCheck("sim3_to_matrix").tensor("xi", xi, "... 7")
    x = flat(xi, 1)
    T = _ops.sim3_to_matrix(x[:, :3].contiguous(), x[:, 3:6].contiguous(), x[:, 6].contiguous())
    return T.reshape(*xi.shape[:-1], 3, 4)


def se3_exp(xi: Tensor) -> Tensor:
    """The SE(3) Lie-group exponential: xi = [omega, u] -> [so3_exp(omega) | V(omega) u].

    Args:
        xi: (..., 6) twists, omega = xi[..., :3], u = xi[..., 3:].

    Returns:
        (..., 3, 4) poses. V(omega) = I + B [omega]x + C [omega]x^2 (series near 0).
    """
    ArgCheck("se3_exp").tensor("xi", xi, "... 6")
    x = flat(xi, 1)
    return _ops.se3_exp(x[:, :3].contiguous(), x[:, 3:].contiguous()).reshape(*xi.shape[:-1], 3, 4)


def se3_log(T: Tensor) -> Tensor:
    """The SE(3) Lie-group logarithm, inverse of :func:`se3_exp`.

    Args:
        T: (..., 3, 4) or (..., 4, 4) poses (a 4x4's last row is ignored). A rotation block
            that is not a rotation is replaced by its nearest rotation, as in :func:`so3_log`.

    Returns:
        (..., 6) twists [omega, u] with |omega| in [0, pi] and u = V(omega)^-1 t.
    """
    T34 = ArgCheck("se3_log").pose("T", T, "... 3|4 4")
    omega, u = _ops.se3_log(flat(T34, 2))
    return torch.cat([omega, u], dim=-1).reshape(*T.shape[:-2], 6)
