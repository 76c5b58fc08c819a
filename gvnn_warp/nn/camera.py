"""``nn.Module`` layers of the pinhole camera (gvnn's 3D grid generator and projection layer) over
:mod:`gvnn_warp.functional.camera`, and :class:`Intrinsics`, the base of every layer that holds
intrinsics or a camera. Shapes and conventions are those of the functions (see
``docs/conventions.md``).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from ..cameras.base import Camera
from ..functional import camera as F
from ..kernels.geometry.camera import MIN_DEPTH

__all__ = ["GridGenerator3D", "PinholeProjection"]


class Intrinsics(nn.Module):
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


class GridGenerator3D(Intrinsics):
    """The 3D grid generator: depth (B, 1, H, W) -> points (B, H, W, 3), optionally moved by a
    pose (B, 3, 4) / (B, 4, 4): ``depth_to_points`` then ``transform_points``."""

    def forward(self, depth: Tensor, pose: Tensor | None = None) -> Tensor:
        points = F.depth_to_points(depth, self.K)
        return points if pose is None else F.transform_points(pose, points)


class PinholeProjection(Intrinsics):
    """The projection layer: points (B, ..., 3) -> pixels (B, ..., 2); ``learnable=True`` makes
    K a parameter (gradients reach fx, fy, cx, cy and the skew)."""

    def __init__(self, K: Tensor, learnable: bool = False, min_depth: float = MIN_DEPTH):
        super().__init__(K, learnable)
        self.min_depth = min_depth

    def forward(self, points: Tensor) -> Tensor:
        return F.project_points(points, self.K, min_depth=self.min_depth)
