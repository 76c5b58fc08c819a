"""``nn.Module`` layers of sampling (the STN bilinear sampler, gvnn's 3D spatial transformer) over
:mod:`gvnn_warp.functional.sampling`. Shapes and conventions are those of the functions (see
``docs/conventions.md``).
"""

from __future__ import annotations

from torch import Tensor, nn

from ..functional import sampling as F
from ..functional.lie import se3_to_matrix
from ..kernels.geometry.camera import MIN_DEPTH
from ..ops.checks import ArgCheck
from .camera import Intrinsics

__all__ = ["BilinearSampler", "SpatialTransformer3D"]


class BilinearSampler(nn.Module):
    """The STN bilinear sampler: image (B, C, H, W), grid (B, h, w, 2) -> (B, C, h, w)."""

    def __init__(self, align_corners: bool = False, padding_mode: str = "zeros"):
        super().__init__()
        self.align_corners = align_corners
        self.padding_mode = padding_mode

    def forward(self, image: Tensor, grid: Tensor) -> Tensor:
        return F.bilinear_sample(image, grid, align_corners=self.align_corners, padding_mode=self.padding_mode)


class SpatialTransformer3D(Intrinsics):
    """The 3D spatial transformer: (image, depth, [omega, t] (B, 6)) -> (warped, valid).

    The 6-vector goes through the SE3 layer; the pose maps the depth's frame into the image's.
    ``K`` is the intrinsics tensor or a camera of :mod:`gvnn_warp.cameras` (a distorted lens);
    ``learnable_intrinsics=True`` makes K (and the camera's distortion coefficients) parameters.
    """

    def __init__(
        self,
        K,
        learnable_intrinsics: bool = False,
        padding_mode: str = "zeros",
        min_depth: float = MIN_DEPTH,
    ):
        super().__init__(K, learnable_intrinsics)
        self.padding_mode = padding_mode
        self.min_depth = min_depth

    def forward(self, image: Tensor, depth: Tensor, xi: Tensor) -> tuple[Tensor, Tensor]:
        chk = ArgCheck("nn.SpatialTransformer3D")  # (the layer's own argument named: xi, not the function's pose)
        chk.tensor("image", image, "B C H W", image=True)
        chk.tensor("xi", xi, "B 6")
        return F.warp_frame_depth(
            image, depth, se3_to_matrix(xi), self.camera, padding_mode=self.padding_mode, min_depth=self.min_depth
        )
