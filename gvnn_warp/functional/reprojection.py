"""Learning depth and motion from video without labels: Monodepth2's reprojection objective and
edge-aware smoothness, as torch functions (Warp kernels). Definitions, stated once:
``gvnn_warp.kernels.reprojection`` (its package docstring); conventions: ``docs/conventions.md``.
The same objective on ``wp.array`` s, without torch: ``gvnn_warp.kernels.reprojection.pipeline``.
"""

from __future__ import annotations

import numbers

import torch
from torch import Tensor

from ..cameras.base import Camera
from ..kernels.geometry.camera import MIN_DEPTH
from ..ops import reprojection as _ops
from ..ops.checks import ArgCheck
from .sampling import warp_frame_depth

__all__ = ["edge_aware_smoothness", "reprojection_loss"]


def _per_source_camera(chk: ArgCheck, camera, B: int, S: int):
    """``camera`` for the B*S (target, source) pairs, item b's camera repeated S times."""
    if isinstance(camera, Tensor):
        chk.tensor("camera", camera, "3 3 or B 3 3")
        return camera if camera.dim() == 2 else camera.repeat_interleave(S, 0)
    if not isinstance(camera, Camera):
        chk.fail(TypeError, f"argument 'camera' must be a (3, 3) / (B, 3, 3) tensor or a gvnn_warp.cameras camera, "
                            f"got {type(camera).__name__}")
    if camera.batch_size is None:
        return camera
    if camera.batch_size != B:
        chk.fail(ValueError, f"argument 'camera' has batch size {camera.batch_size}, expected {B} (the target's)")

    def rep(t):
        return t if t is None or t.dim() < (3 if t is camera.K else 2) else t.repeat_interleave(S, 0)

    return type(camera)(rep(camera.K), *(() if camera.dist is None else (rep(camera.dist),)))


def reprojection_loss(
    target: Tensor,
    sources: Tensor,
    depth: Tensor,
    poses: Tensor,
    camera: Tensor | Camera,
    *,
    alpha: float = 0.85,
    automask: bool = True,
    min_depth: float = MIN_DEPTH,
    return_maps: bool = False,
):
    """Monodepth2's self-supervised objective: the per-pixel minimum over the neighbouring frames of
    the photometric error of each frame warped into the target through depth and pose.

    Per pixel p of the target with a valid depth, each source gives a candidate error pe (alpha
    times the SSIM term, 1 - alpha times the L1 term, mean over channels) of the source sampled
    where p's 3D point lands (``warp_frame_depth``, border padding); with ``automask``, the
    unwarped sources join as candidates (a pixel a static source explains better passes no
    gradient to depth or pose). The pixel's error is the minimum; ties go to reprojections, then
    to the lower source index. Exact definitions: ``gvnn_warp.kernels.reprojection``.

    Args:
        target: (B, C, H, W) target frame, H, W >= 2.
        sources: (B, S, C, H, W) neighbouring frames, S >= 1.
        depth: (B, 1, H, W) the target's depth (z, metres); pixels whose depth is not finite and
            > min_depth are excluded.
        poses: (B, S, 4, 4) or (B, S, 3, 4): target-camera points -> source s's camera (the
            ``pose`` of ``warp_frame_depth``).
        camera: (3, 3) / (B, 3, 3) intrinsics, or a camera of ``gvnn_warp.cameras`` (lens models).
        alpha: weight of the SSIM term, in [0, 1] (Monodepth2: 0.85).
        automask: add the identity candidates (Monodepth2's auto-masking).
        min_depth: depths and moved points must have z > min_depth.
        return_maps: also return the per-pixel maps.

    Returns:
        loss: (B,), each item's mean of the per-pixel minimum over its counted pixels (0 if none).
        With ``return_maps``, also ``maps``, a dict of ``error`` (B, 1, H, W) (the per-pixel
        minimum, 0 where excluded), ``automask`` (B, 1, H, W) bool (a reprojection was chosen),
        ``source`` (B, 1, H, W) int64 (the index of the chosen source, -1 where excluded).

    Gradients flow to target, sources, depth, poses and the camera (K and distortion), through the
    chosen candidate of each pixel; they are finite for every depth value (0, negative, NaN).
    """
    chk = ArgCheck("reprojection_loss")
    chk.tensor("target", target, "B C H W", image=True)
    chk.tensor("sources", sources, "B S C H W", image=True)
    B, S, C, H, W = sources.shape
    if S < 1:
        chk.fail(ValueError, "argument 'sources' must hold at least one source frame (S >= 1), got S = 0")
    chk.tensor("depth", depth, "B 1 H W")
    poses34 = chk.pose("poses", poses, "B S 3|4 4")
    if H < 2 or W < 2:
        chk.fail(ValueError, f"images must be at least 2x2 (the 3x3 SSIM window reflects at the border), got {H}x{W}")
    if isinstance(alpha, bool) or not isinstance(alpha, numbers.Real) or not 0.0 <= alpha <= 1.0:
        chk.fail(ValueError, f"argument 'alpha' must be a number in [0, 1], got {alpha!r}")
    if not isinstance(automask, bool):
        chk.fail(TypeError, f"argument 'automask' must be a bool, got {type(automask).__name__}")
    min_depth = chk.positive("min_depth", min_depth)
    cam = _per_source_camera(chk, camera, B, S)

    # every source warped into the target (B*S pairs; the depth repeated per source)
    depth_s = depth.repeat_interleave(S, 0)
    flat_sources = sources.reshape(B * S, C, H, W)
    flat_poses = poses34.reshape(B * S, 3, 4)
    warped, _ = warp_frame_depth(flat_sources, depth_s, flat_poses, cam, padding_mode="border", min_depth=min_depth)
    pinhole = isinstance(cam, Tensor) or cam.model == 0
    with torch.no_grad():
        if pinhole:  # the choice kernel tests the moved points' z itself, from pose and K
            front = target.new_empty(0)
            K_s = (cam if isinstance(cam, Tensor) else cam.K).detach().expand(B * S, 3, 3).contiguous()
        else:  # through a lens: where each source sees the target's points is the warp of a constant 1
            ones = torch.ones((B * S, 1, H, W), dtype=target.dtype)
            front, _ = warp_frame_depth(ones, depth_s.detach(), flat_poses.detach(), _detached(cam),
                                        padding_mode="border", min_depth=min_depth)
            K_s = target.new_zeros(B * S, 3, 3)
    target_c = target.contiguous()
    sources_c = sources.contiguous()
    shape = (S, C, H, W, float(alpha))
    choice, best, _ = _ops.reprojection_choice(
        target_c.detach(), warped.detach(), sources_c.detach(), front, depth.detach().contiguous(),
        flat_poses.detach().contiguous(), K_s, *shape, int(automask), min_depth, int(not pinhole),
    )
    pe, weight = _ops.reprojection_error_copy(target_c, warped, sources_c, choice, best, *shape)
    loss, _ = _ops.per_item_mean(pe.reshape(B, H * W), weight.reshape(B, H * W), H * W)
    if not return_maps:
        return loss
    choice = choice.reshape(B, 1, H, W)
    maps = {
        "error": pe.detach().reshape(B, 1, H, W),
        "automask": (choice >= 0) & (choice < S),
        "source": torch.where(choice >= 0, choice.remainder(S), -1).long(),
    }
    return loss, maps


def _detached(cam):
    if isinstance(cam, Tensor):
        return cam.detach()
    return type(cam)(cam.K.detach(), *(() if cam.dist is None else (cam.dist.detach(),)))


def edge_aware_smoothness(disparity: Tensor, image: Tensor) -> Tensor:
    """Monodepth2's edge-aware smoothness of a disparity map, per batch item.

    With d = disparity / (its mean over the item + 1e-7), the mean over pixels of
    |d(x+1, y) - d(x, y)| exp(-mean_c |I(x+1, y) - I(x, y)|) plus the same in y (each term averaged
    over its own (W - 1) H or W (H - 1) differences).

    Args:
        disparity: (B, 1, H, W), H, W >= 2.
        image: (B, C, H, W), the frame the disparity belongs to.

    Returns:
        (B,) smoothness; gradients flow to disparity and image.
    """
    chk = ArgCheck("edge_aware_smoothness")
    chk.tensor("disparity", disparity, "B 1 H W")
    chk.tensor("image", image, "B C H W", image=True)
    B, C, H, W = image.shape
    if H < 2 or W < 2:
        chk.fail(ValueError, f"images must be at least 2x2, got {H}x{W}")
    disparity = disparity.contiguous()
    mean = _ops.disparity_mean(disparity, H * W)
    rows = _ops.smoothness_rows(disparity, image.contiguous(), mean, C, H, W)
    return _ops.rows_total(rows, H)
