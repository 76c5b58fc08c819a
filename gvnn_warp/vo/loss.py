"""The paper's visual-odometry cost and the pose-error metrics.

The cost compares the live image warped into the reference frame with the *predicted* pose against
the live image warped with the *ground-truth* pose, both through the 3D spatial transformer
``warp_frame_depth(live, ref_depth, se3_to_matrix(xi), K)`` and the reference depth, on the pixels
valid in both warps (so pixels that leave the image are excluded and, at the optimum, the two
warps have the same missing pixels). For ``so3`` motion the pose vector is [omega, 0, 0, 0].

Per-pixel penalties of the residual r (RGB, in [0, 1] units): ``l1`` = |r| (the default, see
``DEFAULT_LOSS``), ``l2`` = r^2, or an M-estimator of the paper's table via
``gvnn_warp.robust_rho(r, kind, scale)`` (``huber``, ``cauchy``, ``geman_mcclure``,
``tukey``; ``scale`` is the M-estimator's epsilon / c, in intensity units).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ..functional.lie import se3_to_matrix, so3_log
from ..functional.perpixel import robust_rho
from ..functional.sampling import warp_frame_depth
from ..synthetic.trajectories import pose_error
from .pose import full_xi, median_depth

# full_xi (now in .pose) stays importable from here
__all__ = [
    "DEFAULT_LOSS",
    "LOSSES",
    "ROBUST_LOSSES",
    "full_xi",
    "penalty",
    "photometric_loss",
    "pose_errors",
    "pose_loss",
    "warp_live",
]

ROBUST_LOSSES = ("huber", "cauchy", "geman_mcclure", "tukey")
LOSSES = ("l1", "l2", *ROBUST_LOSSES)
DEFAULT_LOSS = "l1"


def warp_live(live: Tensor, ref_depth: Tensor, pose: Tensor, K: Tensor) -> tuple[Tensor, Tensor]:
    """The live image warped into the reference frame by ``pose`` = T_live_ref ((B, 3|4, 4))."""
    return warp_frame_depth(live, ref_depth, pose, K)


def penalty(r: Tensor, kind: str = DEFAULT_LOSS, scale: float = 0.1) -> Tensor:
    """Per-element penalty of residuals ``r`` (see the module docstring)."""
    if kind == "l1":
        return r.abs()
    if kind == "l2":
        return r.square()
    if kind in ROBUST_LOSSES:
        return robust_rho(r, kind, scale)
    raise ValueError(f"loss must be one of {LOSSES}, got {kind!r}")


def photometric_loss(
    pred: Tensor,
    live: Tensor,
    ref_depth: Tensor,
    gt_warp: Tensor,
    gt_valid: Tensor,
    K: Tensor,
    kind: str = DEFAULT_LOSS,
    scale: float = 0.1,
    levels: int = 1,
) -> tuple[Tensor, Tensor, Tensor]:
    """Per-pair cost of predicted poses.

    Args:
        pred: (B, 3) or (B, 6) predicted pose vectors (``so3`` or ``se3``).
        live: (B, 3, H, W) live images; ref_depth: (B, 1, H, W) reference depths.
        gt_warp, gt_valid: ``warp_live(live, ref_depth, T_gt, K)``, precomputed (no gradient needed).
        K: (3, 3) intrinsics.

    Returns:
        loss (B,): the mean penalty over the channels of the pixels valid in both warps;
        pred_warp (B, 3, H, W): the live image warped with the prediction; valid (B, 1, H, W).
    """
    pred_warp, pred_valid = warp_live(live, ref_depth, se3_to_matrix(full_xi(pred)), K)
    valid = pred_valid & gt_valid
    m = valid.to(pred_warp.dtype)
    a, b = pred_warp, gt_warp
    total = 0.0
    for level in range(levels):
        if level:
            # 2x2 means of both warps, valid where all four pixels are valid in both
            a, b = F.avg_pool2d(a, 2), F.avg_pool2d(b, 2)
            m = -F.max_pool2d(-m, 2)
        per_pixel = penalty(a - b, kind, scale) * m
        n = (m.sum(dim=(1, 2, 3)) * live.shape[1]).clamp_min(1.0)
        total = total + per_pixel.sum(dim=(1, 2, 3)) / n
    return total / levels, pred_warp, valid


def pose_loss(pred: Tensor, T_gt: Tensor, ref_depth: Tensor, t_weight: float = 1.0) -> Tensor:
    """(B,) L1 distance of predicted pose vectors ``pred`` ((B, 3) omega or (B, 6) [omega, t]) from
    the ground truth ``T_gt`` (B, 4, 4): ``|omega - omega_gt|_1`` (radians) plus, for (B, 6),
    ``t_weight |t - t_gt|_1 / d`` with ``d`` the median reference depth (a translation's parallax,
    in radians).
    The ground-truth rotation vector is ``so3_log(R_gt)`` (no gradient needed)."""
    with torch.no_grad():
        omega_gt = so3_log(T_gt[:, :3, :3].contiguous().to(pred.dtype))
    out = (pred[:, :3] - omega_gt).abs().sum(1)
    if pred.shape[1] == 6:
        out = out + t_weight * (pred[:, 3:] - T_gt[:, :3, 3].to(pred.dtype)).abs().sum(1) / median_depth(ref_depth)
    return out


def pose_errors(pred: Tensor, T_gt: Tensor) -> tuple[Tensor, Tensor]:
    """Rotation error (degrees, geodesic angle of R_pred^T R_gt) and translation error (metres,
    |t_pred - t_gt|) per pair, computed in float64; ``pred`` as from the network ((B, 3) or (B, 6))."""
    T_pred = se3_to_matrix(full_xi(pred.detach()).double())
    rot, trans = pose_error(T_pred.numpy(), T_gt.detach().double().cpu().numpy())
    return torch.from_numpy(rot), torch.from_numpy(trans)
