"""``nn.Module`` layers over :mod:`gvnn_warp.functional`; each ``forward`` is one functional call.

Shapes and conventions are those of the functions (see ``docs/conventions.md``).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from ..cameras.models import Camera
from ..functional import geometry as F

__all__ = ["SO3", "SE3", "Sim3", "GridGenerator3D", "PinholeProjection", "BilinearSampler", "SpatialTransformer3D"]


class SO3(nn.Module):
    """so(3) vector (..., 3) -> rotation matrix (..., 3, 3) by the exponential map."""

    def forward(self, omega: Tensor) -> Tensor:
        return F.so3_exp(omega)


class SE3(nn.Module):
    """[omega, t] (..., 6) -> [so3_exp(omega) | t] (..., 3, 4), the paper's SE3 layer."""

    def forward(self, xi: Tensor) -> Tensor:
        return F.se3_to_matrix(xi)


class Sim3(nn.Module):
    """[omega, t, sigma] (..., 7) -> [exp(sigma) so3_exp(omega) | t] (..., 3, 4)."""

    def forward(self, xi: Tensor) -> Tensor:
        return F.sim3_to_matrix(xi)


class _Intrinsics(nn.Module):
    """Holds K (3, 3) or (B, 3, 3) as a buffer, or as a learnable parameter; or a camera from
    :mod:`gvnn_warp.cameras`, whose K and distortion coefficients ``dist`` become the buffers (or
    parameters) and which :attr:`camera` rebuilds over them.

    K keeps the dtype it is given (a tensor's or NumPy array's; anything else, e.g. a list,
    becomes float32), never torch's default dtype: give it the dtype of the data, or convert the
    layer with ``.to(dtype)``."""

    def __init__(self, K, learnable: bool = False):
        super().__init__()
        self._camera_type = None
        if isinstance(K, Camera):
            self._camera_type = type(K)
            dist = K.dist
            K = K.K
        typed = isinstance(K, (torch.Tensor, np.ndarray))
        K = (torch.as_tensor(K) if typed else torch.as_tensor(K, dtype=torch.float32)).clone()
        if learnable:
            self.K = nn.Parameter(K)
        else:
            self.register_buffer("K", K)
        if self._camera_type is not None and dist is not None:
            dist = dist.detach().clone()
            if learnable:
                self.dist = nn.Parameter(dist)
            else:
                self.register_buffer("dist", dist)

    @property
    def camera(self):
        """What the functions take: the camera over this layer's K (and dist), or K itself."""
        if self._camera_type is None:
            return self.K
        if "dist" in self._parameters or "dist" in self._buffers:
            return self._camera_type(self.K, self.dist)
        return self._camera_type(self.K)


class GridGenerator3D(_Intrinsics):
    """The 3D grid generator: depth (B, 1, H, W) -> points (B, H, W, 3), optionally moved by a
    pose (B, 3, 4) / (B, 4, 4): ``depth_to_points`` then ``transform_points``."""

    def forward(self, depth: Tensor, pose: Tensor | None = None) -> Tensor:
        points = F.depth_to_points(depth, self.K)
        return points if pose is None else F.transform_points(pose, points)


class PinholeProjection(_Intrinsics):
    """The projection layer: points (B, ..., 3) -> pixels (B, ..., 2); ``learnable=True`` makes
    K a parameter (gradients reach fx, fy, cx, cy and the skew)."""

    def __init__(self, K: Tensor, learnable: bool = False, min_depth: float = F.MIN_DEPTH):
        super().__init__(K, learnable)
        self.min_depth = min_depth

    def forward(self, points: Tensor) -> Tensor:
        return F.project_points(points, self.K, min_depth=self.min_depth)


class BilinearSampler(nn.Module):
    """The STN bilinear sampler: image (B, C, H, W), grid (B, h, w, 2) -> (B, C, h, w)."""

    def __init__(self, align_corners: bool = False, padding_mode: str = "zeros"):
        super().__init__()
        self.align_corners = align_corners
        self.padding_mode = padding_mode

    def forward(self, image: Tensor, grid: Tensor) -> Tensor:
        return F.bilinear_sample(image, grid, align_corners=self.align_corners, padding_mode=self.padding_mode)


class SpatialTransformer3D(_Intrinsics):
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
        min_depth: float = F.MIN_DEPTH,
    ):
        super().__init__(K, learnable_intrinsics)
        self.padding_mode = padding_mode
        self.min_depth = min_depth

    def forward(self, image: Tensor, depth: Tensor, xi: Tensor) -> tuple[Tensor, Tensor]:
        return F.warp_frame_depth(
            image, depth, F.se3_to_matrix(xi), self.camera, padding_mode=self.padding_mode, min_depth=self.min_depth
        )
