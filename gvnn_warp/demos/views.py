"""The two views of the ``align`` demo (:mod:`.align`), rendered in the synthetic room a known motion
apart, their pose errors, and how many pyramid levels their size allows. numpy and Warp only (no
torch): the command line checks its arguments with :func:`max_levels` before torch loads.
"""

from __future__ import annotations

import math

import numpy as np

from ..synthetic import default_intrinsics, make_room_scene, relative_pose, render_rgbd, smooth_se3_trajectory
from ..synthetic import pose_error as _pose_errors

__all__ = ["MIN_LEVEL_SIZE", "make_views", "max_levels", "pose_error"]

MIN_LEVEL_SIZE = 4  # pixels along the shorter side of the coarsest pyramid level


def max_levels(width: int, height: int) -> int:
    """The most pyramid levels for images of ``width`` x ``height`` pixels: the coarsest level keeps
    >= ``MIN_LEVEL_SIZE`` pixels a side."""
    return int(math.log2(min(width, height) // MIN_LEVEL_SIZE)) + 1


def make_views(width: int, height: int, rotation_deg: float, translation_cm: float, seed: int):
    """Render a reference and a live view ``rotation_deg`` degrees about a random axis and
    ``translation_cm`` cm along a random direction apart; returns numpy (ref_img (3, H, W) in [0, 1],
    ref_depth (1, H, W) metres, live_img (3, H, W), K (3, 3) pixels, T_live_ref (4, 4) metres)."""
    rng = np.random.default_rng(seed)
    scene = make_room_scene(seed=seed)
    K = default_intrinsics(width, height)
    T_w_ref = smooth_se3_trajectory(2, seed=seed)[0]
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    angle = math.radians(rotation_deg)
    W = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    T_ref_live = np.eye(4)
    T_ref_live[:3, :3] = np.eye(3) + math.sin(angle) * W + (1 - math.cos(angle)) * W @ W
    T_ref_live[:3, 3] = direction * translation_cm / 100
    T_w_live = T_w_ref @ T_ref_live
    image, depth = render_rgbd(scene, np.stack([T_w_ref, T_w_live]), K, width, height)
    return image[0], depth[0], image[1], K, relative_pose(T_w_live, T_w_ref)


def pose_error(T_est, T_gt) -> tuple[float, float]:
    """(rotation error in degrees, translation error in metres) between two (3, 4) poses."""
    rot, trans = _pose_errors(T_est, T_gt)
    return float(rot), float(trans)
