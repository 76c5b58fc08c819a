"""Synthetic RGB-D frame pairs for the visual-odometry demo, rendered once and kept in memory.

A split is a set of camera trajectories in one room (``gvnn_warp.synthetic``), each rendered
into images and depths; a *pair* is (reference frame k, live frame k + g) for every gap g in
``gaps``, in both temporal directions (k -> k + g and k + g -> k) when ``both_directions``. The
ground-truth pose of a pair is ``T_live_ref = relative_pose(T_world_live, T_world_ref)``: it maps
points of the reference camera frame into the live one, so ``warp_frame_depth(live, ref_depth,
T_live_ref, K)`` reproduces the reference image wherever it is valid.

Training and evaluation splits use different trajectory seeds (see :func:`split_seeds`).
:func:`read_split` makes the same pairs from TUM-format folders (``gvnn-warp render`` writes them;
TUM RGB-D and ICL-NUIM downloads are read the same way), resized to the network's size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..datasets.errors import DatasetError
from ..datasets.tum import read_tum
from ..functional.lie import so3_log
from ..synthetic.render import render_rgbd
from ..synthetic.scene import make_room_scene
from ..synthetic.trajectories import default_intrinsics, relative_pose, rotation_trajectory, smooth_se3_trajectory
from .frontend import resize_frame, scale_intrinsics

__all__ = ["PairSet", "make_pairs", "read_split", "render_split", "split_seeds", "tum_frames"]


@dataclass
class PairSet:
    """Rendered frames and the pairs drawn from them (all torch float32 tensors).

    Attributes:
        images: (F, 3, H, W) RGB in [0, 1].
        depths: (F, 1, H, W) depth (camera z, metres).
        ref, live: (N,) int64 frame indices of each pair.
        pose: (N, 4, 4) ground truth ``T_live_ref``.
        xi: (N, 6) the same as [omega, t] (omega = so3_log(R)), the regression targets.
        K: (3, 3) intrinsics.
    """

    images: Tensor
    depths: Tensor
    ref: Tensor
    live: Tensor
    pose: Tensor
    xi: Tensor
    K: Tensor

    def __len__(self) -> int:
        return int(self.ref.shape[0])

    def batch(self, idx: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor]:
        """(ref image, live image, ref depth, live depth, T_live_ref (B, 4, 4), xi (B, 6)) of pairs ``idx``."""
        r, lv = self.ref[idx], self.live[idx]
        return self.images[r], self.images[lv], self.depths[r], self.depths[lv], self.pose[idx], self.xi[idx]


def split_seeds(seed: int, split: str, n: int) -> list[int]:
    """Trajectory seeds of a split: training and evaluation never share one."""
    base = {"train": 0, "eval": 500}[split]
    return [1000 * seed + base + i for i in range(n)]


def _trajectory(motion: str, n_frames: int, seed: int, **kwargs) -> np.ndarray:
    if motion == "so3":
        return rotation_trajectory(n_frames, seed, **kwargs)
    if motion == "se3":
        return smooth_se3_trajectory(n_frames, seed, **kwargs)
    raise ValueError(f"motion must be 'so3' or 'se3', got {motion!r}")


def make_pairs(T_world_cam: np.ndarray, gaps: tuple[int, ...], both_directions: bool) -> tuple[np.ndarray, ...]:
    """Index pairs (ref, live) within one trajectory and their poses ``T_live_ref`` (float64)."""
    n = T_world_cam.shape[0]
    ref, live = [], []
    for g in gaps:
        k = np.arange(n - g)
        ref.append(k)
        live.append(k + g)
        if both_directions:
            ref.append(k + g)
            live.append(k)
    ref_a, live_a = np.concatenate(ref), np.concatenate(live)
    return ref_a, live_a, relative_pose(T_world_cam[live_a], T_world_cam[ref_a])


def render_split(
    motion: str,
    seeds: list[int],
    n_frames: int,
    size: tuple[int, int],
    gaps: tuple[int, ...] = (1,),
    both_directions: bool = True,
    scene_seed: int = 0,
    supersample: int = 2,
    n_threads: int = 2,
    n_boxes: int = 6,
    trajectory_kwargs: dict | None = None,
) -> PairSet:
    """Render ``len(seeds)`` trajectories of ``n_frames`` frames at ``size`` = (W, H) and pair them up.

    ``motion`` picks the trajectory family: ``so3`` = ``rotation_trajectory`` (pure rotation,
    several degrees per frame), ``se3`` = ``smooth_se3_trajectory`` (6-DoF, a few cm per frame).
    """
    W, H = size
    K = default_intrinsics(W, H)
    scene = make_room_scene(seed=scene_seed, n_boxes=n_boxes)
    images, depths, refs, lives, poses = [], [], [], [], []
    offset = 0
    for s in seeds:
        T = _trajectory(motion, n_frames, s, **(trajectory_kwargs or {}))
        img, dep = render_rgbd(scene, T, K, W, H, supersample=supersample, n_threads=n_threads)
        r, lv, P = make_pairs(T, gaps, both_directions)
        images.append(img)
        depths.append(dep)
        refs.append(r + offset)
        lives.append(lv + offset)
        poses.append(P)
        offset += T.shape[0]
    return _pair_set(images, depths, refs, lives, poses, K)


def tum_frames(root, max_frames: int | None = None):
    """The TUM sequence in folder ``root`` (``gvnn_warp.datasets.tum.read_tum``) and the indices of
    its first ``max_frames`` frames that have ground truth; ``DatasetError`` if it has none."""
    seq = read_tum(root)
    if seq.gt_poses is None:
        raise DatasetError(f"{seq.root / 'groundtruth.txt'}: missing (training and evaluation need ground truth)")
    n = len(seq) if max_frames is None else min(max_frames, len(seq))
    frames = np.flatnonzero(seq.gt_valid[:n])
    if frames.size < 2:
        raise DatasetError(f"{seq.root / 'groundtruth.txt'}: fewer than 2 frames with ground truth")
    return seq, frames


def read_split(
    roots: list,
    size: tuple[int, int],
    gaps: tuple[int, ...] = (1,),
    both_directions: bool = True,
    max_frames: int | None = None,
) -> PairSet:
    """Frame pairs of the TUM-format folders ``roots``, resized to ``size`` = (W, H) (colour:
    antialiased bilinear; depth: nearest pixel centre; the intrinsics scaled to match, see
    :func:`gvnn_warp.vo.frontend.resize_frame`). A pair is (frame k, frame k + g) of one folder
    for g in ``gaps`` (in both directions when ``both_directions``), among its first ``max_frames``
    frames with ground truth; its pose is ``T_live_ref`` from the ground truth. The folders must
    have the same intrinsics once resized (the network is trained for one camera).
    """
    images, depths, refs, lives, poses = [], [], [], [], []
    K = None
    offset = 0
    for root in roots:
        seq, frames = tum_frames(root, max_frames)
        K_seq = scale_intrinsics(seq.K, (seq.width, seq.height), size)
        if K is None:
            K, K_root = K_seq, seq.root
        elif not np.allclose(K_seq, K, rtol=1e-4, atol=1e-3):
            raise DatasetError(f"{seq.root}: intrinsics {K_seq[0, 0]:.6g}, {K_seq[1, 1]:.6g}, {K_seq[0, 2]:.6g}, "
                               f"{K_seq[1, 2]:.6g} at {size[0]}x{size[1]} differ from {K_root}'s {K[0, 0]:.6g}, "
                               f"{K[1, 1]:.6g}, {K[0, 2]:.6g}, {K[1, 2]:.6g} (train on one camera)")
        for i in frames:
            img, dep = resize_frame(seq.image(int(i)), seq.depth(int(i)), size)
            images.append(img[0].numpy())
            depths.append(dep[0].numpy())
        r, lv, P = make_pairs(seq.gt_poses[frames], gaps, both_directions)
        refs.append(r + offset)
        lives.append(lv + offset)
        poses.append(P)
        offset += frames.size
    return _pair_set(images, depths, refs, lives, poses, K)


def _pair_set(images, depths, refs, lives, poses, K) -> PairSet:
    pose = torch.from_numpy(np.concatenate(poses))
    omega = so3_log(pose[:, :3, :3].contiguous())
    xi = torch.cat([omega, pose[:, :3, 3]], dim=1)
    return PairSet(
        images=torch.from_numpy(np.stack(images) if images[0].ndim == 3 else np.concatenate(images)).float(),
        depths=torch.from_numpy(np.stack(depths) if depths[0].ndim == 3 else np.concatenate(depths)).float(),
        ref=torch.from_numpy(np.concatenate(refs)).long(),
        live=torch.from_numpy(np.concatenate(lives)).long(),
        pose=pose.float(),
        xi=xi.float(),
        K=torch.from_numpy(np.asarray(K)).float(),
    )
