"""End-to-end visual odometry through the 3D spatial transformer (the paper's application).

- :mod:`.model`: the siamese pose-regression network (:class:`SiameseVO`) and the coarse-to-fine
  cascade of them that refines the pose on the live image warped by the pose so far (:class:`CascadeVO`);
- :mod:`.data`: rendered synthetic RGB-D trajectories and frame pairs;
- :mod:`.loss`: the photometric cost between the live image warped with the predicted and with the
  ground-truth pose, and pose-error metrics;
- :mod:`.train`: training (DDP-aware), checkpoints, evaluation, ``metrics.json``, figures.

The command line is ``gvnn-warp vo`` (:mod:`gvnn_warp.demos.vo`).
"""

from __future__ import annotations

from .loss import DEFAULT_LOSS, LOSSES, photometric_loss, pose_errors
from .model import SYMMETRIES, CascadeVO, SiameseVO, compose_pose, invert_pose, mirror_pose, pose_dim
from .train import VOConfig, default_config, train

__all__ = [
    "DEFAULT_LOSS",
    "LOSSES",
    "SYMMETRIES",
    "CascadeVO",
    "SiameseVO",
    "VOConfig",
    "compose_pose",
    "default_config",
    "invert_pose",
    "mirror_pose",
    "photometric_loss",
    "pose_dim",
    "pose_errors",
    "train",
]
