"""The fused photometric objective as a layer (:func:`gvnn_warp.functional.photometric_error`)."""

from __future__ import annotations

from torch import Tensor, nn

from ..cameras.base import Camera
from ..functional.photometric import ERROR_KINDS, photometric_error
from ..kernels.geometry.camera import MIN_DEPTH
from ..ops.checks import ArgCheck

__all__ = ["PhotometricLoss"]


class PhotometricLoss(nn.Module):
    """:func:`photometric_error` as a layer: forward(ref_image (B, C, H, W), ref_depth (B, 1, H,
    W), live_image (B, C, H, W), pose (B, 3|4, 4), K (B, 3, 3) or (3, 3)) -> error (B,)
    (the count is dropped; call the function to get it)."""

    def __init__(self, robust: str = "l1", scale: float = 1.0, min_depth: float = MIN_DEPTH):
        super().__init__()
        chk = ArgCheck("PhotometricLoss")
        self.robust = chk.option("robust", robust, ERROR_KINDS)
        self.scale = chk.positive("scale", scale)
        self.min_depth = chk.positive("min_depth", min_depth)

    def forward(
        self, ref_image: Tensor, ref_depth: Tensor, live_image: Tensor, pose: Tensor, K: Tensor | Camera
    ) -> Tensor:
        return photometric_error(
            ref_image, ref_depth, live_image, pose, K, robust=self.robust, scale=self.scale, min_depth=self.min_depth
        )[0]

    def extra_repr(self) -> str:
        return f"robust={self.robust!r}, scale={self.scale}, min_depth={self.min_depth}"

