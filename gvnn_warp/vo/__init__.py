"""End-to-end visual odometry through the 3D spatial transformer (the paper's application).

- :mod:`.model`: the siamese pose-regression network (:class:`SiameseVO`) and the coarse-to-fine
  cascade of them that refines the pose on the live image warped by the pose so far (:class:`CascadeVO`);
- :mod:`.pose`: pose vectors (omega or [omega, t]) and their algebra;
- :mod:`.data`: rendered synthetic RGB-D trajectories and frame pairs;
- :mod:`.loss`: the photometric cost between the live image warped with the predicted and with the
  ground-truth pose, and pose-error metrics;
- :mod:`.config`: a run's configuration (:class:`VOConfig`), its defaults and checks;
- :mod:`.train`: training (DDP-aware); :mod:`.checkpoint`: checkpoints and the trained network they
  hold; :mod:`.evaluation`: evaluation, ``metrics.json``; :mod:`.plots`: figures;
- :mod:`.frontend`: the trained network as an odometry front end (``gvnn-warp track --method vo``).

The command line is ``gvnn-warp vo`` (:mod:`gvnn_warp.cli`).
"""
from __future__ import annotations

from .config import VOConfig, default_config
from .loss import DEFAULT_LOSS, LOSSES, photometric_loss, pose_errors
from .model import SYMMETRIES, CascadeVO, SiameseVO, pose_dim
from .pose import compose_pose, invert_pose, mirror_pose
from .train import train

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
