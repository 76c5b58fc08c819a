"""Sampling as torch functions: the bilinear sampler of spatial transformer networks and the
fused 3D spatial transformer (``warp_frame_depth``), pinhole or through a camera's lens model.

Every function takes float32 or float64 CPU tensors (all arguments of one call in the same
dtype), returns gradients for every floating argument through Warp's adjoints, validates its
arguments with a clear error, and never modifies its inputs. Conventions (pixel centres, (x, y)
order, units, valid masks) are in ``docs/conventions.md``.
"""

from __future__ import annotations

from torch import Tensor

from ..cameras.base import Camera
from ..cameras.fused import FusedCamera
from ..kernels.geometry.camera import MIN_DEPTH
from ..kernels.sampling import kernels as sampling_kernels
from ..kernels.sampling.sampler import PADDING_MODES as _PADDING
from ..ops import sampling as _ops
from ..ops.checks import ArgCheck, flat

__all__ = ["bilinear_sample", "warp_frame_depth"]


def bilinear_sample(
    image: Tensor, grid: Tensor, *, align_corners: bool = False, padding_mode: str = "zeros"
) -> Tensor:
    """Bilinear sampler of spatial transformer networks, implemented in Warp.

    Same semantics as ``torch.nn.functional.grid_sample(image, grid, mode="bilinear",
    padding_mode=padding_mode, align_corners=align_corners)``: ``grid[b, i, j] = (gx, gy)`` in
    [-1, 1], gx along the width. With ``align_corners=False`` -1 and 1 are the outer edges of the
    image: for W = 4, gx = -1 is pixel x = -0.5, gx = 0 is x = 1.5. With ``align_corners=True``
    they are the centres of the corner pixels: gx = -1 is x = 0, gx = 1 is x = W - 1.
    ``padding_mode="zeros"`` reads 0 outside; ``"border"`` clamps the position into the image.
    NaN grid values sample 0 with zero gradient; so do +-inf with "zeros", while "border" clamps
    them to the edge (as ``grid_sample`` does).

    Args:
        image: (B, C, H, W).
        grid: (B, h, w, 2) normalised (x, y) positions.

    Returns:
        (B, C, h, w) samples; gradients for image and grid.
    """
    chk = ArgCheck("bilinear_sample")
    chk.tensor("image", image, "B C H W", image=True)
    chk.tensor("grid", grid, "B h w 2")
    pad = _PADDING[chk.option("padding_mode", padding_mode, tuple(_PADDING))]
    B, C, H, W = image.shape
    h, w = grid.shape[1:3]
    if H * W == 0 and B * h * w > 0:
        chk.fail(ValueError, f"argument 'image' has no pixels to sample from (shape {tuple(image.shape)})")
    # 8 output locations per thread where they tile the output (SIMD weights; same results)
    op = _ops.bilinear_sample_lanes if sampling_kernels.fits_lanes(h * w, H, W) else _ops.bilinear_sample
    out = op(image.contiguous(), flat(grid, 1), C, H, W, h * w, int(bool(align_corners)), pad)
    return out.reshape(B, C, h, w)


def warp_frame_depth(
    image: Tensor,
    depth: Tensor,
    pose: Tensor,
    K: Tensor | Camera,
    *,
    padding_mode: str = "zeros",
    min_depth: float = MIN_DEPTH,
) -> tuple[Tensor, Tensor]:
    """The 3D spatial transformer: warp ``image`` into the frame of ``depth``.

    For every pixel u = (x, y) of the depth's frame, warped(u) = image sampled bilinearly at
    project(K, pose * (depth(u) K^-1 [x, y, 1])), i.e. ``pose`` maps points from the depth's
    frame into the image's frame. One fused Warp pass (and one adjoint pass); same values as
    ``kornia.geometry.depth.warp_frame_depth(image, depth, pose_4x4, K)`` wherever valid.

    Args:
        image: (B, C, H, W) source image.
        depth: (B, 1, H, W) depth (z, metres) of the target frame.
        pose: (B, 3, 4) or (B, 4, 4) target-to-source transform (a 4x4's last row ignored).
        K: (B, 3, 3) or (3, 3) intrinsics, shared by both views; or a camera from
            ``gvnn_warp.cameras`` (both views taken by it): then u = (x, y) is a pixel of the
            distorted image, its ray is undistort(K^-1 [x, y, 1]) and the moved point is
            projected through the model (``camera.project``); gradients reach K and every
            distortion coefficient too. A pixel without a ray (outside the model's domain) counts
            as an invalid depth, a moved point outside the domain as one behind the camera. The
            rays are computed once per call, or once per camera value and image size when the
            camera needs no gradient (a small cache). ``PinholeCamera(K)`` is exactly ``K``.
        padding_mode: "zeros" or "border", how samples outside the image read.
        min_depth: depths and moved points must have z > min_depth (metres) to be used.

    Returns:
        warped: (B, C, H, W); 0 where the depth or the moved point is invalid; where the
            projection falls outside the image, the padded sample (as ``grid_sample``).
        valid: (B, 1, H, W) bool, true where the depth is finite and > min_depth, the moved point
            has z > min_depth, and its projection lies inside the image (within 1e-3 px of the
            pixel-centre rectangle [0, W-1] x [0, H-1]). Identity pose: all true, warped == image.

    Gradients flow to image, depth, pose and K; they are finite for every finite pose and
    every depth value (0, negative, NaN, inf included). Pixels with an invalid depth or moved
    point pass no gradient; pixels projecting outside the image pass the padded sample's (as
    ``grid_sample`` does), though ``valid`` is false there: mask the loss with ``valid``.
    """
    chk = ArgCheck("warp_frame_depth")
    chk.tensor("image", image, "B C H W", image=True)
    chk.tensor("depth", depth, "B 1 H W")
    pose34 = chk.pose("pose", pose, "B 3|4 4")
    cam = FusedCamera(chk, K)
    pad = _PADDING[chk.option("padding_mode", padding_mode, tuple(_PADDING))]
    min_depth = chk.positive("min_depth", min_depth)
    _, C, H, W = image.shape
    if cam.model == 0:  # the pinhole: its own kernel (the row-linear fast path; 8 pixels at a time where rows allow)
        op = _ops.warp_frame_depth_lanes if sampling_kernels.fits_row_lanes(H, W) else _ops.warp_frame_depth
        return op(image.contiguous(), depth.contiguous(), pose34.contiguous(), cam.K, C, H, W, min_depth, pad)
    rays, stride = cam.rays(H, W)
    return _ops.warp_frame_depth_lens(
        image.contiguous(), depth.contiguous(), pose34.contiguous(), cam.K, cam.dist, rays,
        C, H, W, min_depth, pad, cam.model, stride,
    )
