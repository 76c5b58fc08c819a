"""A camera as the fused ops take it (the 3D spatial transformer and the photometric objective,
:mod:`gvnn_warp.functional`): :class:`FusedCamera`, and the undistorted rays of its pixels,
computed once per camera value and image size for cameras without gradients."""

from __future__ import annotations

import torch
from torch import Tensor

from ..ops import sampling as _sampling_ops
from ..ops.checks import ArgCheck
from .base import Camera, camera_args

__all__: list[str] = []  # (used by gvnn_warp.functional; not part of the public API)

RAYS_CACHE: dict = {}  # (model, dtype, H, W, K bytes, dist bytes) -> rays, for cameras without gradients
RAYS_CACHE_SIZE = 8


class FusedCamera:
    """A camera as the fused kernels take it: ``model`` id, ``K`` (B, 3, 3), ``dist`` (B, 8) (see
    ``gvnn_warp.kernels.geometry.lens``), and the camera's own ``K_cam`` (Bc, 3, 3), ``dist_cam``
    (Bc, 8), Bc = 1 when one camera serves the whole batch (its rays are then computed once).
    ``camera``: a (3, 3) / (B, 3, 3) K tensor (the pinhole: model 0, nothing else made, so the
    calls stay as cheap) or a camera of :mod:`gvnn_warp.cameras`."""

    def __init__(self, chk: ArgCheck, camera):
        if isinstance(camera, Tensor):
            chk.tensor("K", camera, "3 3 or B 3 3")
            K = (camera.expand(chk.dim("B"), 3, 3) if camera.dim() == 2 else camera).contiguous()
            self.model, self.K, self.dist, self.K_cam, self.dist_cam = 0, K, None, None, None
            return
        self.model, self.K, self.dist = camera_args(chk, camera)
        shared = not isinstance(camera, Camera) or camera.batch_size is None
        self.K_cam = self.K[:1] if shared else self.K
        self.dist_cam = self.dist[:1] if shared else self.dist

    def detached(self) -> FusedCamera:
        """The same camera with its tensors detached (for ops that are not differentiable)."""
        out = object.__new__(FusedCamera)
        out.model = self.model
        out.K, out.dist, out.K_cam, out.dist_cam = (t.detach() for t in (self.K, self.dist, self.K_cam, self.dist_cam))
        return out

    def rays(self, H: int, W: int) -> tuple[Tensor, int]:
        """The undistorted rays (Bc*H*W, 3) of an H x W image's pixels (the op ``pixel_rays``) and
        the ray stride of the fused kernels (H * W per batch item, or 0: one camera shared by the
        batch). Cached by value for cameras whose K and dist need no gradient (the common, fixed
        camera): Newton's method then runs once per camera and image size."""
        Kc, dc = self.K_cam, self.dist_cam
        stride = 0 if Kc.shape[0] == 1 else H * W
        if Kc.requires_grad or dc.requires_grad or torch.compiler.is_compiling():
            return _sampling_ops.pixel_rays(Kc, dc, H, W, self.model), stride
        key = (self.model, Kc.dtype, H, W, Kc.numpy().tobytes(), dc.numpy().tobytes())
        rays = RAYS_CACHE.pop(key, None)
        if rays is None:
            rays = _sampling_ops.pixel_rays(Kc, dc, H, W, self.model)
            if len(RAYS_CACHE) >= RAYS_CACHE_SIZE:
                RAYS_CACHE.pop(next(iter(RAYS_CACHE)))
        RAYS_CACHE[key] = rays
        return rays, stride
