"""The self-supervised objective as layers (:func:`gvnn_warp.functional.reprojection_loss`,
:func:`gvnn_warp.functional.edge_aware_smoothness`)."""

from __future__ import annotations

from torch import Tensor, nn

from ..cameras.base import Camera
from ..functional.reprojection import edge_aware_smoothness, reprojection_loss
from ..kernels.geometry.camera import MIN_DEPTH

__all__ = ["EdgeAwareSmoothness", "ReprojectionLoss"]


class ReprojectionLoss(nn.Module):
    """:func:`reprojection_loss` as a layer: forward(target (B, C, H, W), sources (B, S, C, H, W),
    depth (B, 1, H, W), poses (B, S, 3|4, 4), camera) -> loss (B,)."""

    def __init__(self, alpha: float = 0.85, automask: bool = True, min_depth: float = MIN_DEPTH):
        super().__init__()
        self.alpha, self.automask, self.min_depth = alpha, automask, min_depth

    def forward(self, target: Tensor, sources: Tensor, depth: Tensor, poses: Tensor, camera: Tensor | Camera) -> Tensor:
        return reprojection_loss(target, sources, depth, poses, camera, alpha=self.alpha, automask=self.automask,
                                 min_depth=self.min_depth)


class EdgeAwareSmoothness(nn.Module):
    """:func:`edge_aware_smoothness` as a layer: forward(disparity (B, 1, H, W), image (B, C, H, W)) -> (B,)."""

    def forward(self, disparity: Tensor, image: Tensor) -> Tensor:
        return edge_aware_smoothness(disparity, image)
