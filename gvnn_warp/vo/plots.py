"""Figures of the VO demo (matplotlib, Agg): the training curve and the registration panel."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .data import PairSet
from .loss import full_xi, warp_live

__all__ = ["plot_panel", "plot_training_curve"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_training_curve(history: list[float], path: Path, title: str = "training loss") -> None:
    """Loss per step (light) and its running mean over ~2% of the steps (dark), log scale."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 3.6), dpi=110)
    h = np.asarray(history, dtype=np.float64)
    steps = np.arange(1, len(h) + 1)
    ax.plot(steps, h, color="tab:blue", alpha=0.3, lw=0.8, label="per step")
    k = max(1, len(h) // 50)
    if len(h) >= k:
        smooth = np.convolve(h, np.ones(k) / k, mode="valid")
        ax.plot(steps[k - 1 :], smooth, color="tab:blue", lw=1.8, label=f"mean of {k}")
    if len(h) and np.all(h > 0):
        ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("photometric loss")
    ax.set_title(title)
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_panel(
    ps: PairSet,
    gt_warp: Tensor,
    gt_valid: Tensor,
    idx: Tensor,
    stages: dict[int, Tensor],
    path: Path,
    motion: str = "",
) -> None:
    """Like the paper's figures: for each training stage (row) and held-out pair, the prediction
    (live warped with the predicted pose), the ground truth (live warped with the true pose) and
    the residual |prediction - ground truth| (mean over RGB, 0 where either warp is invalid)."""
    plt = _plt()
    steps = sorted(stages)
    n_rows, n_pairs = len(steps), len(idx)
    _, live, ref_d, _, pose, _ = ps.batch(idx)
    H, W = live.shape[-2:]
    fig, axes = plt.subplots(
        n_rows, 3 * n_pairs, figsize=(3 * n_pairs * 1.9, n_rows * 1.9 * H / W + 0.6), dpi=100, squeeze=False
    )
    for r, s in enumerate(steps):
        from gvnn_warp import se3_to_matrix

        with torch.no_grad():
            pred_w, pred_v = warp_live(live, ref_d, se3_to_matrix(full_xi(stages[s]).float()), ps.K)
        for j in range(n_pairs):
            g = idx[j]
            res = ((pred_w[j] - gt_warp[g]).abs().mean(0) * (pred_v[j, 0] & gt_valid[g, 0])).numpy()
            err = _pose_err_text(stages[s][j : j + 1], pose[j : j + 1])
            tiles = [
                (pred_w[j].permute(1, 2, 0).clamp(0, 1).numpy(), f"prediction (step {s})"),
                (gt_warp[g].permute(1, 2, 0).clamp(0, 1).numpy(), "ground truth"),
                (res, f"residual {err}"),
            ]
            for c, (img, label) in enumerate(tiles):
                ax = axes[r, 3 * j + c]
                if img.ndim == 2:
                    ax.imshow(img, cmap="inferno", vmin=0.0, vmax=0.3)
                else:
                    ax.imshow(img)
                ax.set_xticks([])
                ax.set_yticks([])
                ax.set_title(label, fontsize=7)
    fig.suptitle(f"VO {motion}: held-out pairs over training (rows: training step)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _pose_err_text(pred: Tensor, pose: Tensor) -> str:
    from .loss import pose_errors

    rot, trans = pose_errors(pred, pose)
    text = f"{float(rot[0]):.2f} deg"
    if pred.shape[-1] == 6:
        text += f", {100 * float(trans[0]):.1f} cm"
    return text
