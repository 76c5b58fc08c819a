"""Pose vectors of the VO network and their algebra: ``(B, 3)`` omega (``so3`` motion) or ``(B, 6)``
``[omega, t]`` (``se3``), read as :func:`gvnn_warp.se3_to_matrix` reads them (``R = exp(omega)``,
``t = t``), and the reference depth that scales depth-normalised translations.

The network (:mod:`.model`), its cost (:mod:`.loss`) and the odometry front end (:mod:`.frontend`)
all use them.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..functional.lie import so3_exp, so3_log

__all__ = ["compose_pose", "full_xi", "invert_pose", "median_depth", "mirror_pose"]


def full_xi(pred: Tensor) -> Tensor:
    """(B, 3) omega -> (B, 6) [omega, 0]; (B, 6) passes through."""
    if pred.shape[-1] == 6:
        return pred
    return torch.cat([pred, torch.zeros_like(pred)], dim=-1)


def median_depth(depth: Tensor) -> Tensor:
    """(B,) median of the valid (finite, > 1e-3 m) depths of each (B, 1, H, W) map (1 if none)."""
    d = depth.flatten(1)
    d = torch.where(torch.isfinite(d) & (d > 1e-3), d, torch.full_like(d, float("nan")))
    med = d.nanmedian(dim=1).values
    return torch.nan_to_num(med, nan=1.0)


def compose_pose(a: Tensor, b: Tensor) -> Tensor:
    """Pose vector of the product ``T(a) T(b)`` (both (B, 3) omega or (B, 6) [omega, t], as
    :func:`gvnn_warp.se3_to_matrix` reads them: ``R = exp(omega)``, ``t = t``).

    ``omega = so3_log(exp(a_omega) exp(b_omega))`` and ``t = exp(a_omega) b_t + a_t``; differentiable
    in both (gvnn_warp's Warp ops)."""
    R_a = so3_exp(a[:, :3])
    omega = so3_log((R_a @ so3_exp(b[:, :3])).contiguous())
    if a.shape[1] == 3:
        return omega
    t = (R_a @ b[:, 3:, None])[:, :, 0] + a[:, 3:]
    return torch.cat([omega, t], dim=1)


def invert_pose(xi: Tensor) -> Tensor:
    """Pose vector of ``T^-1`` for ``T`` = (omega) or ([omega, t]): ``-omega`` and ``-R^T t``."""
    if xi.shape[1] == 3:
        return -xi
    R = so3_exp(xi[:, :3].contiguous())
    return torch.cat([-xi[:, :3], -(R.transpose(1, 2) @ xi[:, 3:, None])[:, :, 0]], dim=1)


def mirror_pose(xi: Tensor, axis: int) -> Tensor:
    """Pose vector of ``M T M`` with M the reflection of camera axis ``axis`` (0: x, left-right; 1: y,
    upside-down): the pose of a pair whose images are both mirrored along that axis. The rotation
    axis of ``M R M`` is ``det(M) M a = -M a``, so omega keeps its ``axis`` component and negates the
    other two; t negates its ``axis`` component."""
    sign = torch.full((xi.shape[1],), -1.0, dtype=xi.dtype)
    sign[axis] = 1.0
    if xi.shape[1] == 6:
        sign[3:] = 1.0
        sign[3 + axis] = -1.0
    return xi * sign
