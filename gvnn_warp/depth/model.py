"""The depth and pose networks (random initialisation; nothing is downloaded).

:class:`DepthNet`: a U-Net (five stride-2 stages of two 3x3 convolutions, each followed by batch
normalisation and an ELU; a decoder with skip connections) whose heads give a sigmoid disparity
at four scales (full, 1/2, 1/4, 1/8 resolution), mapped to depth in [min_depth, max_depth] by
:func:`disp_to_depth` as Monodepth2 does. ``norm="none"`` leaves the normalisation out (the first
version; measured in benchmarks/RESULTS.md: it generalised far worse to unseen rooms).
:class:`PoseNet`: the frame pair stacked (6 channels), five stride-2 stages, a 1x1 convolution to
six numbers averaged over the image and scaled by 0.01 (Monodepth2's), read as [omega, t] (axis-angle
and translation) and made a (B, 3, 4) pose by ``gvnn_warp.se3_to_matrix``: the motion that maps
points of the first frame's camera into the second's (the ``pose`` of ``warp_frame_depth``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..functional.lie import se3_to_matrix

__all__ = ["NORMS", "DepthNet", "PoseNet", "disp_to_depth"]

MEAN, STD = 0.45, 0.225  # input normalisation (Monodepth2's)


NORMS = ("batch", "none")


def _block(c_in: int, c_out: int, stride: int = 1, norm: str = "batch") -> nn.Sequential:
    """Two 3x3 convolutions (the first with ``stride``), each followed by ``norm`` and an ELU."""
    if norm not in NORMS:
        raise ValueError(f"DepthNet: argument 'norm' must be one of {list(NORMS)}, got {norm!r}")

    def normalise(c: int) -> nn.Module:
        return nn.BatchNorm2d(c) if norm == "batch" else nn.Identity()

    return nn.Sequential(
        nn.Conv2d(c_in, c_out, 3, stride, 1), normalise(c_out), nn.ELU(inplace=True),
        nn.Conv2d(c_out, c_out, 3, 1, 1), normalise(c_out), nn.ELU(inplace=True),
    )


def disp_to_depth(disp: Tensor, min_depth: float, max_depth: float) -> Tensor:
    """Sigmoid output in [0, 1] -> depth in [min_depth, max_depth] (linear in inverse depth)."""
    lo, hi = 1.0 / max_depth, 1.0 / min_depth
    return 1.0 / (lo + (hi - lo) * disp)


class DepthNet(nn.Module):
    """image (B, 3, H, W) in [0, 1], H and W multiples of 32 -> disparities, a list of four
    (B, 1, H / 2^s, W / 2^s) in [0, 1] for s = 0, 1, 2, 3."""

    def __init__(self, widths: tuple[int, ...] = (16, 32, 64, 128, 256), min_depth: float = 0.1,
                 max_depth: float = 10.0, norm: str = "batch"):
        super().__init__()
        self.widths, self.min_depth, self.max_depth = tuple(widths), float(min_depth), float(max_depth)
        self.norm = norm
        c = [3, *widths]
        self.encoder = nn.ModuleList(_block(c[i], c[i + 1], 2, norm) for i in range(len(widths)))
        dec = [widths[-1], *reversed(widths[:-1]), widths[0]]  # 256 -> 128 -> 64 -> 32 -> 16 -> 16
        self.up = nn.ModuleList(_block(dec[i], dec[i + 1], 1, norm) for i in range(len(widths)))
        skips = [*reversed(widths[:-1]), 0]
        self.fuse = nn.ModuleList(_block(dec[i + 1] + skips[i], dec[i + 1], 1, norm) for i in range(len(widths)))
        self.heads = nn.ModuleList(nn.Conv2d(dec[i + 1], 1, 3, 1, 1)
                                   for i in range(len(widths) - 4, len(widths)))
        self.to(memory_format=torch.channels_last)  # (torch's CPU convolutions: ~12% faster a step)

    def forward(self, image: Tensor) -> list[Tensor]:
        x = ((image - MEAN) / STD).contiguous(memory_format=torch.channels_last)
        feats = []
        for stage in self.encoder:
            x = stage(x)
            feats.append(x)
        x = feats.pop()
        disps = []
        n = len(self.up)
        for i in range(n):
            x = F.interpolate(self.up[i](x), scale_factor=2, mode="nearest")
            if feats:
                x = torch.cat([x, feats.pop()], 1)
            x = self.fuse[i](x)
            if i >= n - 4:
                disps.append(torch.sigmoid(self.heads[i - (n - 4)](x)))
        return disps[::-1]  # full resolution first

    def depth(self, image: Tensor) -> Tensor:
        """(B, 1, H, W) depth of ``image`` (the full-resolution head)."""
        return disp_to_depth(self(image)[0], self.min_depth, self.max_depth)


class PoseNet(nn.Module):
    """(first (B, 3, H, W), second (B, 3, H, W)) -> (B, 3, 4) pose mapping points of the first
    frame's camera into the second's."""

    def __init__(self, widths: tuple[int, ...] = (16, 32, 64, 128, 256), norm: str = "batch"):
        super().__init__()
        self.widths = tuple(widths)
        c = [6, *widths]
        self.encoder = nn.Sequential(*(_block(c[i], c[i + 1], 2, norm) for i in range(len(widths))))
        self.head = nn.Conv2d(widths[-1], 6, 1)

    def xi(self, first: Tensor, second: Tensor) -> Tensor:
        """(B, 6) [omega, t] of the motion (see the class docstring)."""
        x = self.encoder((torch.cat([first, second], 1) - MEAN) / STD)
        return 0.01 * self.head(x).mean((2, 3))

    def forward(self, first: Tensor, second: Tensor) -> Tensor:
        return se3_to_matrix(self.xi(first, second))
