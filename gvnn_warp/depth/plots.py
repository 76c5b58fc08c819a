"""Figures of the depth commands (matplotlib, Agg): a frame, its predicted depth, the true depth
when known, and the auto-mask or the error."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import Tensor

__all__ = ["depth_panel"]


def _plt():
    import matplotlib  # (on first use: only the figures need it, and it is slow to import)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def depth_panel(image: Tensor, depth: Tensor, true_depth: Tensor | None, last: Tensor | None, path: Path, *,
                title: str = "", last_title: str = "auto-mask (white: reprojection used)",
                last_cmap: str = "gray") -> None:
    """Writes a row of panels: ``image`` (3, H, W), predicted ``depth`` (H, W), the true depth
    (1, H, W) or (H, W) (0 = none) if given, and ``last`` (H, W) if given. With a true depth the
    prediction is shown times the ratio of the medians (a monocular network has no scale), on the
    true depth's colour scale; without one, in its own units and range."""
    plt = _plt()
    panels = 2 + (true_depth is not None) + (last is not None)
    fig, axes = plt.subplots(1, panels, figsize=(3.4 * panels, 3.0), dpi=100, squeeze=False)
    axes = axes[0]
    axes[0].imshow(np.clip(image.permute(1, 2, 0).numpy(), 0, 1))
    axes[0].set_title("input", fontsize=10)
    d = depth.numpy().astype(np.float64)
    lo, hi = float(np.percentile(d, 2)), float(np.percentile(d, 98))
    label = "predicted depth (network units)"
    if true_depth is not None:
        t = true_depth.reshape(d.shape).numpy()
        valid = t > 0
        if valid.any():
            d = d * float(np.median(t[valid]) / np.median(d[valid]))
            lo, hi = float(np.percentile(t[valid], 2)), float(np.percentile(t[valid], 98))
            label = "predicted depth (m, median-scaled)"
    im = axes[1].imshow(d, cmap="magma_r", vmin=lo, vmax=hi)
    axes[1].set_title(label, fontsize=10)
    fig.colorbar(im, ax=axes[1], fraction=0.046, pad=0.04)
    k = 2
    if true_depth is not None:
        im = axes[k].imshow(np.where(t > 0, t, np.nan), cmap="magma_r", vmin=lo, vmax=hi)
        axes[k].set_title("true depth (m; blank: none)", fontsize=10)
        fig.colorbar(im, ax=axes[k], fraction=0.046, pad=0.04)
        k += 1
    if last is not None:
        im = axes[k].imshow(last.float().numpy(), cmap=last_cmap)
        axes[k].set_title(last_title, fontsize=10)
        if last.dtype != torch.bool:  # (a mask needs no colour bar: its title says what white is)
            fig.colorbar(im, ax=axes[k], fraction=0.046, pad=0.04)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
