"""Figures of the VO demo (matplotlib, Agg): the training curve and the registration panel."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..functional.lie import se3_to_matrix
from .data import PairSet
from .loss import pose_errors, warp_live
from .pose import full_xi

__all__ = ["panel_figure", "plot_panel", "plot_training_curve", "training_curve_figure"]


def _plt():
    import matplotlib  # (on first use: only the figures need it, and it is slow to import)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


RESIDUAL_MAX = 0.3  # colour scale of the residual tiles (intensities are in [0, 1])
FONT = 10  # points: the smallest text in the figures


def training_curve_figure(history: list[float], title: str = "training loss"):
    """Loss per step and, from 100 steps on, its running mean over ~2% of the steps; log scale."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 3.6), dpi=110, layout="constrained")
    h = np.asarray(history, dtype=np.float64)
    steps = np.arange(1, len(h) + 1)
    k = len(h) // 50
    if k >= 2:  # a running mean of at least 2 steps; shorter runs show the raw curve only
        ax.plot(steps, h, color="tab:blue", alpha=0.3, lw=0.8, label="per step")
        smooth = np.convolve(h, np.ones(k) / k, mode="valid")
        ax.plot(steps[k - 1 :], smooth, color="tab:blue", lw=1.8, label=f"running mean over {k} steps")
        ax.legend(fontsize=FONT)
    else:
        ax.plot(steps, h, color="tab:blue", lw=1.2, marker="." if len(h) < 50 else None)
    if len(h) and np.all(h > 0):
        ax.set_yscale("log")
    ax.set_xlabel("step", fontsize=FONT)
    ax.set_ylabel("photometric loss", fontsize=FONT)
    ax.set_title(title, fontsize=FONT + 1)
    ax.grid(alpha=0.3, which="both")
    return fig


def plot_training_curve(history: list[float], path: Path, title: str = "training loss") -> None:
    """Writes :func:`training_curve_figure` to ``path``."""
    _save(training_curve_figure(history, title), path)


def panel_figure(
    ps: PairSet,
    gt_warp: Tensor,
    gt_valid: Tensor,
    idx: Tensor,
    stages: dict[int, Tensor],
    motion: str = "",
):
    """Like the paper's figures: for each training step (row) and held-out pair, the prediction
    (live warped with the predicted pose, its pose error below), the ground truth (live warped with
    the true pose) and |prediction - ground truth| (mean over RGB, 0 where either warp is invalid),
    with one colour bar for the residuals."""
    plt = _plt()
    steps = sorted(stages)
    n_rows, n_pairs = len(steps), len(idx)
    _, live, ref_d, _, pose, _ = ps.batch(idx)
    H, W = live.shape[-2:]
    # A fixed layout, in inches (matplotlib's constrained layout took 1-2 s a figure on 28 axes)
    tile, tile_h = 2.3, 2.3 * H / W  # inches per tile: titles at FONT points fit
    left, right, top, row_pad, gap = 0.35, 1.15, 0.45, 0.25, 0.08  # ylabels; colour bar; suptitle; titles, xlabels
    fig_w = left + 3 * n_pairs * tile + (3 * n_pairs - 1) * gap + right
    fig_h = top + n_rows * (tile_h + 2 * row_pad)
    fig, axes = plt.subplots(
        n_rows, 3 * n_pairs, figsize=(fig_w, fig_h), dpi=100, squeeze=False,
        gridspec_kw=dict(left=left / fig_w, right=1 - right / fig_w, top=1 - (top + row_pad) / fig_h,
                         bottom=row_pad / fig_h, wspace=gap / tile, hspace=2 * row_pad / tile_h),
    )
    im = None
    for r, s in enumerate(steps):
        with torch.no_grad():
            pred_w, pred_v = warp_live(live, ref_d, se3_to_matrix(full_xi(stages[s]).float()), ps.K)
        for j in range(n_pairs):
            g = idx[j]
            res = ((pred_w[j] - gt_warp[g]).abs().mean(0) * (pred_v[j, 0] & gt_valid[g, 0])).numpy()
            err = _pose_err_text(stages[s][j : j + 1], pose[j : j + 1])
            tiles = [
                (pred_w[j].permute(1, 2, 0).clamp(0, 1).numpy(), f"pair {j + 1}: prediction", f"pose error {err}"),
                (gt_warp[g].permute(1, 2, 0).clamp(0, 1).numpy(), "ground truth", ""),
                (res, "|prediction - truth|", ""),
            ]
            for c, (img, label, below) in enumerate(tiles):
                ax = axes[r, 3 * j + c]
                if img.ndim == 2:
                    im = ax.imshow(img, cmap="inferno", vmin=0.0, vmax=RESIDUAL_MAX)
                else:
                    ax.imshow(img)
                ax.set_xticks([])
                ax.set_yticks([])
                if r == 0 or c == 0:
                    ax.set_title(label if r == 0 else "", fontsize=FONT)
                if below:
                    ax.set_xlabel(below, fontsize=FONT)
        axes[r, 0].set_ylabel(f"step {s}", fontsize=FONT + 1)
    if im is not None:
        grid_h = fig_h - top - 2 * row_pad  # (inches, the tiles' rows)
        bar_h = grid_h * min(1.0, 0.9 / n_rows + 0.3)
        cax = fig.add_axes(((fig_w - right + 0.2) / fig_w, (row_pad + (grid_h - bar_h) / 2) / fig_h,
                            0.15 / fig_w, bar_h / fig_h), label="<colorbar>")  # (the name matplotlib gives its own)
        bar = fig.colorbar(im, cax=cax, extend="max")
        bar.set_label("|residual|, mean over RGB (intensity, 0-1)", fontsize=FONT)
        bar.ax.tick_params(labelsize=FONT - 1)
    fig.suptitle(f"VO {motion}: held-out pairs over training (rows: training step)", fontsize=FONT + 2,
                 y=1 - 0.12 / fig_h, va="top")
    return fig


def plot_panel(
    ps: PairSet,
    gt_warp: Tensor,
    gt_valid: Tensor,
    idx: Tensor,
    stages: dict[int, Tensor],
    path: Path,
    motion: str = "",
) -> None:
    """Writes :func:`panel_figure` to ``path``."""
    _save(panel_figure(ps, gt_warp, gt_valid, idx, stages, motion), path)


def _save(fig, path: Path) -> None:
    fig.savefig(path)
    _plt().close(fig)


def _pose_err_text(pred: Tensor, pose: Tensor) -> str:
    rot, trans = pose_errors(pred, pose)
    text = f"{float(rot[0]):.2f} deg"
    if pred.shape[-1] == 6:
        text += f", {100 * float(trans[0]):.1f} cm"
    return text
