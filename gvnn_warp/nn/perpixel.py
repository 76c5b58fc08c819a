"""``nn.Module`` wrappers of :mod:`gvnn_warp.functional.perpixel`: each forward is one call of the function.

Options are validated when the layer is built (same messages as the functions, naming the layer).
"""

from __future__ import annotations

from torch import Tensor, nn

from ..functional import perpixel as P
from ..kernels.sampling.sampler import PADDING_MODES
from ..ops.checks import ArgCheck

__all__ = [
    "AffineFlow",
    "AffineFlowWarp",
    "AffineGridGenerator",
    "DisparityWarp",
    "FlowWarp",
    "HomographyFlow",
    "PointwiseSE3",
    "PointwiseSim3",
    "PointwiseTransform10",
    "RobustLoss",
    "SE2Flow",
    "SlantedPlaneDisparity",
    "SmoothnessLoss",
]

_PADDING_MODES = tuple(PADDING_MODES)
_REDUCTIONS = ("mean", "sum", "none")


class _Sampler(nn.Module):
    def __init__(self, padding_mode: str = "zeros"):
        super().__init__()
        self.padding_mode = ArgCheck(type(self).__name__).option("padding_mode", padding_mode, _PADDING_MODES)

    def extra_repr(self) -> str:
        return f"padding_mode={self.padding_mode!r}"


class FlowWarp(_Sampler):
    """:func:`gvnn_warp.functional.perpixel.flow_warp`: forward(image (B, C, H, W), flow (B, 2, H, W))
    -> (B, C, H, W)."""

    def forward(self, image: Tensor, flow: Tensor) -> Tensor:
        return P.flow_warp(image, flow, padding_mode=self.padding_mode)


class DisparityWarp(_Sampler):
    """:func:`gvnn_warp.functional.perpixel.disparity_warp`: forward(image (B, C, H, W), disparity (B, 1, H, W))
    -> (B, C, H, W), the image sampled at (x - d, y)."""

    def forward(self, image: Tensor, disparity: Tensor) -> Tensor:
        return P.disparity_warp(image, disparity, padding_mode=self.padding_mode)


class AffineFlowWarp(_Sampler):
    """:func:`gvnn_warp.functional.perpixel.affine_flow_warp` (fused): forward(image (B, C, H, W),
    params (B, 6, H, W)) -> (B, C, H, W)."""

    def forward(self, image: Tensor, params: Tensor) -> Tensor:
        return P.affine_flow_warp(image, params, padding_mode=self.padding_mode)


class AffineFlow(nn.Module):
    """:func:`gvnn_warp.functional.perpixel.affine_flow`: forward(params (B, 6, H, W)) -> flow (B, 2, H, W)."""

    def forward(self, params: Tensor) -> Tensor:
        return P.affine_flow(params)


class SE2Flow(nn.Module):
    """:func:`gvnn_warp.functional.perpixel.se2_flow`: forward(params (B, 3, H, W) [theta, tx, ty])
    -> flow (B, 2, H, W)."""

    def forward(self, params: Tensor) -> Tensor:
        return P.se2_flow(params)


class HomographyFlow(nn.Module):
    """:func:`gvnn_warp.functional.perpixel.homography_flow`: forward(params (B, 9, H, W)) -> flow (B, 2, H, W)."""

    def forward(self, params: Tensor) -> Tensor:
        return P.homography_flow(params)


class SlantedPlaneDisparity(nn.Module):
    """:func:`gvnn_warp.functional.perpixel.slanted_plane_disparity`: forward(params (B, 3, H, W) [a, b, c])
    -> disparity (B, 1, H, W) = a x + b y + c."""

    def forward(self, params: Tensor) -> Tensor:
        return P.slanted_plane_disparity(params)


class PointwiseSE3(nn.Module):
    """:func:`gvnn_warp.functional.perpixel.pointwise_se3`: forward(points (B, H, W, 3), params (B, 6, H, W))
    -> (B, H, W, 3)."""

    def forward(self, points: Tensor, params: Tensor) -> Tensor:
        return P.pointwise_se3(points, params)


class PointwiseSim3(nn.Module):
    """:func:`gvnn_warp.functional.perpixel.pointwise_sim3`: forward(points (B, H, W, 3), params (B, 7, H, W))
    -> (B, H, W, 3)."""

    def forward(self, points: Tensor, params: Tensor) -> Tensor:
        return P.pointwise_sim3(points, params)


class PointwiseTransform10(nn.Module):
    """:func:`gvnn_warp.functional.perpixel.pointwise_transform10`: forward(points (B, H, W, 3),
    params (B, 10, H, W)) -> (B, H, W, 3)."""

    def forward(self, points: Tensor, params: Tensor) -> Tensor:
        return P.pointwise_transform10(points, params)


class AffineGridGenerator(nn.Module):
    """:func:`gvnn_warp.functional.perpixel.affine_grid` (the STN grid generator): forward(theta (B, 2, 3),
    size (B, C, H, W)) -> grid (B, H, W, 2)."""

    def __init__(self, align_corners: bool = False):
        super().__init__()
        self.align_corners = bool(align_corners)

    def forward(self, theta: Tensor, size) -> Tensor:
        return P.affine_grid(theta, size, self.align_corners)

    def extra_repr(self) -> str:
        return f"align_corners={self.align_corners}"


class _Robust(nn.Module):
    def __init__(self, kind: str, scale: float):
        super().__init__()
        chk = ArgCheck(type(self).__name__)
        self.kind = chk.option("kind", kind, P.ROBUST_KINDS)
        self.scale = chk.positive("scale", scale)


class RobustLoss(_Robust):
    """M-estimator loss: forward(x (any shape)) -> rho(x) (:func:`gvnn_warp.functional.perpixel.robust_rho`)
    reduced by ``reduction``: "mean" or "sum" (0-dim tensor) or "none" (same shape as x)."""

    def __init__(self, kind: str, scale: float = 1.0, reduction: str = "mean"):
        super().__init__(kind, scale)
        self.reduction = ArgCheck("RobustLoss").option("reduction", reduction, _REDUCTIONS)

    def forward(self, x: Tensor) -> Tensor:
        r = P.robust_rho(x, self.kind, self.scale)
        return r.mean() if self.reduction == "mean" else r.sum() if self.reduction == "sum" else r

    def extra_repr(self) -> str:
        return f"kind={self.kind!r}, scale={self.scale}, reduction={self.reduction!r}"


class SmoothnessLoss(_Robust):
    """:func:`gvnn_warp.functional.perpixel.smoothness_loss`: forward(field (B, K, H, W)) -> 0-dim tensor."""

    def __init__(self, kind: str = "huber", scale: float = 1.0):
        super().__init__(kind, scale)

    def forward(self, field: Tensor) -> Tensor:
        return P.smoothness_loss(field, self.kind, self.scale)

    def extra_repr(self) -> str:
        return f"kind={self.kind!r}, scale={self.scale}"
