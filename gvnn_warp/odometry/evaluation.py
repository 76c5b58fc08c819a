"""Trajectory metrics (computed by ``evo``) and figures for odometry runs (numpy, evo, matplotlib; no torch).

- ATE: ``evo``'s APE of the translation part after an SE(3) Umeyama alignment of the estimate
  to the ground truth (``evo_ape tum gt.txt est.txt -a``), RMSE in metres. Where the ground
  truth's camera centres do not determine that alignment (rotation-only or straight-line motion:
  evo refuses a degenerate Umeyama problem), the estimate's first pose is aligned to the ground
  truth's instead (``evo_ape --align_origin``); ``TrajectoryMetrics.ate_alignment`` says which.
  With ``correct_scale`` (a monocular estimate, whose scale is arbitrary) the alignment is a
  similarity, Sim(3) (``evo_ape -as``), and the RPE is that of the scaled estimate (``evo_rpe -as``).
- RPE: ``evo``'s RPE over consecutive 1-frame steps (``evo_rpe ... --delta 1 --delta_unit f``),
  translation part (metres) and rotation angle (degrees), RMSE; per pair
  ``E = inv(inv(Q_i) Q_j) inv(P_i) P_j`` with ground truth Q and estimate P.
- A pair *fails* when its RPE exceeds ``FAIL_TRANS_M`` (1 cm) or ``FAIL_ROT_DEG`` (0.25 deg).
- Ground truth at the frames: :func:`nearest_groundtruth` takes, for each frame, the ground-truth
  pose with the nearest stamp (within a maximum difference), as evo's tools and TUM's scripts
  associate a trajectory file with ``groundtruth.txt``, so the numbers are those they print for the
  files written; ``TUMSequence.gt_poses`` (interpolated at the frames' stamps) is the alternative.
- RPE per second: :func:`rpe_per_second`, the drift over 1-second steps as TUM's
  ``evaluate_rpe.py --fixed_delta --delta 1 --delta_unit s`` defines it (evo has no time delta). On
  real data the per-frame RPE is dominated by the motion capture's own noise; this is not.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = [
    "ATE_ALIGNMENT",
    "ATE_ALIGNMENT_ORIGIN",
    "ATE_ALIGNMENT_SIM3",
    "FAIL_ROT_DEG",
    "FAIL_TRANS_M",
    "TrajectoryMetrics",
    "evaluate_trajectory",
    "nearest_groundtruth",
    "rpe_per_second",
    "pose_error",
    "plot_errors",
    "plot_top_view",
]

FAIL_TRANS_M = 0.01
FAIL_ROT_DEG = 0.25
ATE_ALIGNMENT = "SE(3) Umeyama (evo_ape -a: rotation and translation, no scale)"
ATE_ALIGNMENT_SIM3 = "Sim(3) Umeyama (evo_ape -as: rotation, translation and scale)"
ATE_ALIGNMENT_ORIGIN = ("first pose (evo_ape --align_origin; the positions of the ground truth or of the estimate are "
                        "degenerate for Umeyama)")


def pose_error(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(translation error (m), rotation error (deg)) of estimated relative poses (..., 4, 4) against
    true ones: the translation norm and rotation angle of ``inv(T_gt) @ T_est``."""
    T_est = np.asarray(T_est, dtype=np.float64)
    T_gt = np.asarray(T_gt, dtype=np.float64)
    R_gt_t = np.swapaxes(T_gt[..., :3, :3], -1, -2)
    R = R_gt_t @ T_est[..., :3, :3]
    t = (R_gt_t @ (T_est[..., :3, 3] - T_gt[..., :3, 3])[..., None])[..., 0]
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    return np.linalg.norm(t, axis=-1), np.degrees(np.arccos(cos))


@dataclass
class TrajectoryMetrics:
    """What :func:`evaluate_trajectory` returns.

    Attributes:
        ate_rmse_m, rpe_trans_rmse_m, rpe_rot_rmse_deg: the RMSEs (see the module docstring).
        ate_alignment: how the estimate was aligned for the ATE (``ATE_ALIGNMENT``,
            ``ATE_ALIGNMENT_SIM3`` or ``ATE_ALIGNMENT_ORIGIN``).
        scale: the scale of the similarity alignment (1.0 without ``correct_scale``).
        frames: frame indices (into the estimate) that had ground truth.
        pair_frames: (P, 2) frame indices of the consecutive RPE pairs.
        rpe_trans_m, rpe_rot_deg: (P,) per-pair errors.
        ape_trans_m: (F,) per-frame ATE errors after the alignment.
        aligned: (F, 4, 4) the estimate after the SE(3) alignment; ground_truth: (F, 4, 4).
    """

    ate_rmse_m: float
    rpe_trans_rmse_m: float
    rpe_rot_rmse_deg: float
    ate_alignment: str
    frames: np.ndarray
    pair_frames: np.ndarray
    rpe_trans_m: np.ndarray
    rpe_rot_deg: np.ndarray
    ape_trans_m: np.ndarray
    aligned: np.ndarray
    ground_truth: np.ndarray
    scale: float = 1.0

    @property
    def failed(self) -> np.ndarray:
        """(P,) bool: pairs whose RPE exceeds 1 cm or 0.25 deg."""
        return (self.rpe_trans_m > FAIL_TRANS_M) | (self.rpe_rot_deg > FAIL_ROT_DEG)


def evaluate_trajectory(
    timestamps: np.ndarray,
    poses: np.ndarray,
    gt_poses: np.ndarray,
    gt_valid: np.ndarray | None = None,
    *,
    correct_scale: bool = False,
) -> TrajectoryMetrics:
    """ATE and 1-frame RPE of an estimated trajectory against ground truth at the same frames, by ``evo``.

    Args:
        timestamps: (N,) frame timestamps (s).
        poses: (N, 4, 4) estimated ``T_world_cam``.
        gt_poses: (N, 4, 4) ground-truth ``T_world_cam`` at the same frames (e.g.
            ``TUMSequence.gt_poses``).
        gt_valid: (N,) bool, frames that have ground truth (default: all). Frames without it are
            left out; RPE pairs are then consecutive frames *with* ground truth.
        correct_scale: align with a similarity (the estimate's scale is free; see the module
            docstring).
    """
    # evo on first use: it imports scipy (about a second), which pose_error and the figures do not need
    from evo.core import metrics, sync
    from evo.core.geometry import GeometryException
    from evo.core.trajectory import PoseTrajectory3D

    timestamps = np.asarray(timestamps, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    gt_poses = np.asarray(gt_poses, dtype=np.float64)
    valid = np.ones(timestamps.shape[0], bool) if gt_valid is None else np.asarray(gt_valid, bool)
    frames = np.flatnonzero(valid)
    if frames.size < 2:
        raise ValueError(f"evaluate_trajectory: need at least 2 frames with ground truth, got {frames.size}")
    ref = PoseTrajectory3D(poses_se3=list(gt_poses[frames]), timestamps=timestamps[frames])
    est = PoseTrajectory3D(poses_se3=list(poses[frames]), timestamps=timestamps[frames])
    # identical stamps: the association keeps every frame (done anyway, as evo's tools do)
    ref, est = sync.associate_trajectories(ref, est, max_diff=1e-4)
    if ref.num_poses != frames.size:
        raise RuntimeError("evaluate_trajectory: evo dropped frames while associating identical timestamps")

    aligned = PoseTrajectory3D(poses_se3=list(poses[frames]), timestamps=timestamps[frames])
    scale = 1.0
    try:
        rotation, translation, scale = aligned.align(ref, correct_scale=correct_scale)
        alignment = ATE_ALIGNMENT_SIM3 if correct_scale else ATE_ALIGNMENT
    except GeometryException:  # degenerate positions: rotation-only or collinear motion
        aligned = PoseTrajectory3D(poses_se3=list(poses[frames]), timestamps=timestamps[frames])
        aligned.align_origin(ref)
        alignment = ATE_ALIGNMENT_ORIGIN
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, aligned))
    # the RPE does not change under a rigid alignment, but does under a scale (evo_rpe -as scales first)
    moved = aligned if correct_scale else est
    rpe_t = metrics.RPE(metrics.PoseRelation.translation_part, delta=1, delta_unit=metrics.Unit.frames)
    rpe_t.process_data((ref, moved))
    rpe_r = metrics.RPE(metrics.PoseRelation.rotation_angle_deg, delta=1, delta_unit=metrics.Unit.frames)
    rpe_r.process_data((ref, moved))

    pair_frames = np.stack([frames[:-1], frames[1:]], axis=1)
    return TrajectoryMetrics(
        ate_rmse_m=float(ape.get_statistic(metrics.StatisticsType.rmse)),
        rpe_trans_rmse_m=float(rpe_t.get_statistic(metrics.StatisticsType.rmse)),
        rpe_rot_rmse_deg=float(rpe_r.get_statistic(metrics.StatisticsType.rmse)),
        ate_alignment=alignment,
        frames=frames,
        pair_frames=pair_frames,
        rpe_trans_m=np.asarray(rpe_t.error, dtype=np.float64),
        rpe_rot_deg=np.asarray(rpe_r.error, dtype=np.float64),
        ape_trans_m=np.asarray(ape.error, dtype=np.float64),
        aligned=np.stack(aligned.poses_se3),
        ground_truth=np.stack(ref.poses_se3),
        scale=float(scale),
    )


def nearest_groundtruth(timestamps: np.ndarray, gt_timestamps: np.ndarray, gt_poses: np.ndarray,
                        max_difference: float) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth at the frames by nearest stamp, as ``evo_ape``/``evo_rpe`` associate
    (``evo.core.sync``: each stamp of the shorter trajectory takes the nearest stamp of the other,
    within ``max_difference`` s). Returns (poses (N, 4, 4), NaN where none; valid (N,) bool) for the
    frames' ``timestamps`` (N,) and the ground truth's ``gt_timestamps`` (M,), ``gt_poses`` (M, 4, 4)."""
    from evo.core.sync import matching_time_indices

    timestamps = np.asarray(timestamps, dtype=np.float64)
    gt_timestamps = np.asarray(gt_timestamps, dtype=np.float64)
    poses = np.full((timestamps.size, 4, 4), np.nan)
    valid = np.zeros(timestamps.size, bool)
    if timestamps.size <= gt_timestamps.size:  # evo matches the shorter trajectory's stamps
        frames, rows = matching_time_indices(timestamps, gt_timestamps, max_difference)
    else:
        rows, frames = matching_time_indices(gt_timestamps, timestamps, max_difference)
    frames, rows = np.asarray(frames, np.int64), np.asarray(rows, np.int64)
    poses[frames] = np.asarray(gt_poses, dtype=np.float64)[rows]
    valid[frames] = True
    return poses, valid


def rpe_per_second(timestamps: np.ndarray, poses: np.ndarray, gt_timestamps: np.ndarray, gt_poses: np.ndarray,
                   delta: float = 1.0, scale: float = 1.0) -> tuple[float, float, int] | None:
    """Translational (m) and rotational (deg) RMSE of the relative pose error over steps of
    ``delta`` seconds, and the number of steps, as TUM's ``evaluate_rpe.py --fixed_delta --delta
    <delta> --delta_unit s [--scale <scale>]`` computes them; None if no step has ground truth.

    The definition (written from that script): for each estimate stamp t_i, its partner j is the
    estimate stamp nearest to t_i + delta, and the step is kept unless j is the last estimate (the
    script's rule: a step running off the end is dropped). Each end takes the ground-truth pose of
    nearest stamp, and the step is skipped if that stamp is more than twice the ground truth's median
    interval away. The error of a step is ``inv(A) B`` with ``A = inv(E_j) E_i`` (its translation
    multiplied by ``scale``) and ``B = inv(G_j) G_i`` for estimate poses E and ground-truth poses G
    (the script's ``ominus``): its translation norm and rotation angle.
    """
    t = np.asarray(timestamps, dtype=np.float64)
    E = np.asarray(poses, dtype=np.float64)
    gt_t = np.asarray(gt_timestamps, dtype=np.float64)
    G = np.asarray(gt_poses, dtype=np.float64)
    if t.size < 2 or gt_t.size < 2:
        return None

    def nearest(stamps: np.ndarray, query: np.ndarray) -> np.ndarray:
        k = np.clip(np.searchsorted(stamps, query), 1, stamps.size - 1)
        return np.where(np.abs(stamps[k - 1] - query) <= np.abs(stamps[k] - query), k - 1, k)

    i = np.arange(t.size)
    j = nearest(t, t + delta)
    keep = j != t.size - 1
    i, j = i[keep], j[keep]
    gi, gj = nearest(gt_t, t[i]), nearest(gt_t, t[j])
    limit = 2.0 * float(np.median(np.diff(gt_t)))
    near = (np.abs(gt_t[gi] - t[i]) <= limit) & (np.abs(gt_t[gj] - t[j]) <= limit)
    i, j, gi, gj = i[near], j[near], gi[near], gj[near]
    if i.size == 0:
        return None
    rel_est = np.linalg.inv(E[j]) @ E[i]
    rel_est[:, :3, 3] *= scale
    err = np.linalg.inv(rel_est) @ (np.linalg.inv(G[gj]) @ G[gi])
    trans = np.linalg.norm(err[:, :3, 3], axis=1)
    cos = np.clip((np.trace(err[:, :3, :3], axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    rot = np.degrees(np.arccos(cos))
    return float(np.sqrt(np.mean(trans**2))), float(np.sqrt(np.mean(rot**2))), int(i.size)


def _top_view_axes(positions: np.ndarray) -> tuple[int, int]:
    """The two world axes of largest extent (the top view drops the one the camera moved least
    along: y for this project's y-down rooms, z for TUM's z-up motion capture)."""
    extent = np.ptp(positions, axis=0)
    a, b = sorted(np.argsort(extent)[1:])
    return int(a), int(b)


def plot_top_view(path: str | Path, estimate: np.ndarray, ground_truth: np.ndarray | None = None,
                  title: str = "trajectory (top view)") -> None:
    """PNG of camera positions seen from above: estimate (after alignment, if given so) and ground truth."""
    import matplotlib  # (on first use: only the figures need it, and it is slow to import)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    est = np.asarray(estimate)[:, :3, 3]
    both = est if ground_truth is None else np.concatenate([est, np.asarray(ground_truth)[:, :3, 3]])
    a, b = _top_view_axes(both)
    fig, ax = plt.subplots(figsize=(6, 5.5))
    if ground_truth is not None:
        gt = np.asarray(ground_truth)[:, :3, 3]
        ax.plot(gt[:, a], gt[:, b], "-", color="0.35", lw=2.0, label="ground truth")
    ax.plot(est[:, a], est[:, b], "-", color="tab:red", lw=1.2, label="estimate")
    ax.plot(est[:1, a], est[:1, b], "o", color="tab:red", ms=5, label="start")
    names = "xyz"
    ax.set_xlabel(f"{names[a]} (m)")
    ax.set_ylabel(f"{names[b]} (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_errors(path: str | Path, m: TrajectoryMetrics, unconverged: np.ndarray | None = None,
                title: str = "per-frame relative pose error (1-frame RPE)") -> None:
    """PNG of the per-pair translation (cm) and rotation (deg) errors against the frame index, with
    the failure thresholds and the frames whose alignment did not converge marked."""
    import matplotlib  # (on first use: only the figures need it, and it is slow to import)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = m.pair_frames[:, 1]
    fig, axes = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    series = [(m.rpe_trans_m * 100.0, FAIL_TRANS_M * 100.0, "translation error (cm)"),
              (m.rpe_rot_deg, FAIL_ROT_DEG, "rotation error (deg)")]
    for ax, (err, limit, label) in zip(axes, series):
        ax.plot(x, err, "-", color="tab:blue", lw=1.0)
        ax.axhline(limit, color="tab:red", ls="--", lw=1.0, label="failure threshold")
        bad = m.failed
        if bad.any():
            ax.plot(x[bad], err[bad], "x", color="tab:red", ms=6, label="failed pair")
        if unconverged is not None and len(unconverged):
            for k, f in enumerate(unconverged):
                ax.axvline(f, color="tab:orange", alpha=0.5, lw=1.0, label="not converged" if k == 0 else None)
        ax.set_ylabel(label)
        ax.set_ylim(bottom=0.0, top=max(1.2 * limit, 1.05 * float(np.max(err, initial=0.0))))
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[1].set_xlabel("frame")
    axes[0].set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

