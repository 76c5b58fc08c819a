"""The fused photometric objective of direct RGB-D alignment, as torch functions (Warp kernels).

One pass warps the reference frame into the live image, compares, weights and reduces: nothing
per pixel is allocated. :func:`photometric_error` is differentiable (to both images, the
reference depth, the pose and K; the gradient is computed in the same pass);
:func:`photometric_normal_equations` gives the Gauss-Newton system of the same residuals for a
pose update. Conventions (pixel centres, K,
minimum depth, the ``valid`` rule of ``warp_frame_depth``): ``docs/conventions.md``. The same
functions on ``wp.array`` s, without torch: ``gvnn_warp.kernels.photometric.pipeline``.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..cameras.base import Camera
from ..cameras.fused import FusedCamera
from ..kernels.geometry.camera import MIN_DEPTH
from ..kernels.photometric.pipeline import ERROR_KINDS, NORMAL_EQUATIONS_KINDS
from ..kernels.photometric.residual import KINDS as _CODES
from ..kernels.sampling.sampler import MAX_LANES_PLANE as _MAX_LANES_PLANE
from ..ops import photometric as _ops
from ..ops.checks import ArgCheck

__all__ = [
    "ERROR_KINDS",
    "NORMAL_EQUATIONS_KINDS",
    "photometric_error",
    "photometric_normal_equations",
]


def _check_frames(chk: ArgCheck, ref_image, ref_depth, live_image, pose, K):
    chk.tensor("ref_image", ref_image, "B C H W")
    chk.tensor("ref_depth", ref_depth, "B 1 H W")
    chk.tensor("live_image", live_image, "B C H W")
    pose34 = chk.pose("pose", pose, "B 3|4 4")
    return pose34.contiguous(), FusedCamera(chk, K)


def photometric_error(
    ref_image: Tensor,
    ref_depth: Tensor,
    live_image: Tensor,
    pose: Tensor,
    K: Tensor | Camera,
    *,
    robust: str = "l1",
    scale: float = 1.0,
    min_depth: float = MIN_DEPTH,
) -> tuple[Tensor, Tensor]:
    """Mean robust photometric error of the reference frame warped into the live image.

    For every reference pixel u whose depth is valid (finite, > min_depth) and whose moved point
    P = pose * (depth(u) K^-1 [u, 1]) has z > min_depth and projects inside the live image (the
    ``valid`` rule of :func:`gvnn_warp.warp_frame_depth`), the residual of channel c is
    r_c = live_c(project(P)) - ref_c(u) (bilinear sample). Then

        error = mean over those pixels and all channels of rho(r_c),   count = number of pixels,

    i.e. ``(robust_rho(warped - ref) * valid).sum() / (C * valid.sum())`` with ``warped, valid =
    warp_frame_depth(live_image, ref_depth, pose, K)``, computed in one fused pass without any
    per-pixel tensor. Residuals that are not finite (NaN or inf intensities) count 0.

    Since the error is one scalar per batch item, the same pass also computes its exact gradient
    for the inputs that require grad (rho'(r) times the bilinear interpolant's derivative at the
    sample point, times the projection's and the moved point's Jacobians), and the backward pass
    only scales it by the incoming gradient (no replay, no adjoint pass); the live image's
    gradient (a scatter) is the Warp adjoint of the row kernel.

    Args:
        ref_image: (B, C, H, W) reference intensities (e.g. in [0, 1]).
        ref_depth: (B, 1, H, W) depth (z, metres) of the reference frame; 0, negative, NaN or inf
            depths are skipped (no value, no gradient).
        live_image: (B, C, H, W) live intensities.
        pose: (B, 3, 4) or (B, 4, 4) maps reference-camera points into the live camera.
        K: (B, 3, 3) or (3, 3) intrinsics, shared by both views, or a camera from
            ``gvnn_warp.cameras`` (the projection and the rays of the reference pixels through
            its lens model, as :func:`gvnn_warp.warp_frame_depth` with a camera; gradients reach
            K and every distortion coefficient).
        robust: "l1" (|r|), "l2" (r^2 / 2), "huber", "cauchy", "geman_mcclure" or "tukey"
            (as :func:`gvnn_warp.robust_rho`, with ``scale``).
        scale: the M-estimator's scale (ignored by "l1" and "l2").
        min_depth: metres.

    Returns:
        error: (B,), 0 where count is 0. Gradients to ref_image, ref_depth, live_image, pose
            and K; only those of the inputs that require grad are computed (not
            differentiable twice). At r = 0, "l1" has gradient 0.
        count: (B,) number of pixels used, as a float tensor (not differentiable).
    """
    chk = ArgCheck("photometric_error")
    pose34, cam = _check_frames(chk, ref_image, ref_depth, live_image, pose, K)
    chk.option("robust", robust, ERROR_KINDS)
    scale = chk.positive("scale", scale, ref_image.dtype)
    min_depth = chk.positive("min_depth", min_depth)
    _, C, H, W = ref_image.shape
    if cam.model != 0:  # a distorted lens (see warp_frame_depth): its row kernel and Warp adjoint
        rays, stride = cam.rays(H, W)
        row_sum, row_count = _ops.photometric_rows_lens(
            ref_image.contiguous(), ref_depth.contiguous(), live_image.contiguous(), pose34, cam.K, cam.dist, rays,
            C, H, W, _CODES[robust], scale, min_depth, cam.model, stride,
        )
        error, count = _ops.photometric_mean(row_sum, row_count, H, C)
        return error, count.detach()
    inputs = (ref_image.contiguous(), ref_depth.contiguous(), live_image.contiguous(), pose34, cam.K)
    if H * W > _MAX_LANES_PLANE:  # the 8-lane kernel's float tap addresses would not be exact
        row_sum, row_count = _ops.photometric_rows(*inputs, C, H, W, _CODES[robust], scale, min_depth)
        error, count = _ops.photometric_mean(row_sum, row_count, H, C)
        return error, count.detach()
    # the gradients autograd may ask for are computed in the forward pass (bit k: input k)
    needs = sum(1 << k for k, t in enumerate(inputs) if t.requires_grad) if torch.is_grad_enabled() else 0
    error, count, *_ = _ops.photometric_error(*inputs, _CODES[robust], scale, min_depth, needs)
    return error, count


def photometric_normal_equations(
    ref_image: Tensor,
    ref_depth: Tensor,
    live_image: Tensor,
    pose: Tensor,
    K: Tensor | Camera,
    *,
    robust: str = "huber",
    scale: float = 1.0,
    live_depth: Tensor | None = None,
    depth_weight: float = 0.0,
    min_depth: float = MIN_DEPTH,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The Gauss-Newton system of :func:`photometric_error`'s residuals for a pose update.

    For the left-multiplied perturbation pose <- exp(delta) pose, delta = [omega, t] (radians,
    metres), J = dr/d delta at delta = 0 for every residual r (exact for the bilinear interpolant
    as sampled: (d live / d(u, v)) (d(u, v) / dP) (dP / d delta), dP/d omega = -[P]x, dP/dt = I),
    with IRLS weights w = psi(r) / r (its limit 1 at r = 0; 1 for "l2"):

        JtWJ = sum w J^T J,   JtWr = sum w J^T r,   cost = sum rho(r),   count = pixels used,

    summed in float64 in a fixed order (bitwise the same for any thread count). The step is
    delta = -JtWJ^-1 JtWr, then pose <- exp(delta) pose (``gvnn_warp.se3_exp``).

    Depth term: with ``live_depth`` and ``depth_weight > 0``, every pixel used adds the residual
    r_d = sqrt(depth_weight) (z(P) - live_depth(project(P))) (bilinear sample of the live depth;
    skipped where any of the four taps lies outside the image or is not a valid depth) with the
    same penalty and scale: cost += rho(r_d), JtWJ += w(r_d) J_d^T J_d, and so on. With "l2"
    that is cost += depth_weight (z - D)^2 / 2.

    Args:
        ref_image, live_image: (B, C, H, W) intensities.
        ref_depth: (B, 1, H, W) reference depth (metres); invalid depths are skipped.
        pose: (B, 3, 4) or (B, 4, 4) maps reference-camera points into the live camera.
        K: (B, 3, 3) or (3, 3) intrinsics, or a camera from ``gvnn_warp.cameras``: J then
            includes the lens distortion's Jacobian of the projection.
        robust: "huber" (default), "cauchy", "geman_mcclure", "tukey" or "l2" ("l1" has no IRLS
            weight at r = 0 and is refused).
        scale: the M-estimator's scale (ignored by "l2").
        live_depth: (B, 1, H, W) depth of the live frame, or None.
        depth_weight: >= 0, the weight of the depth term (0: none).
        min_depth: metres.

    Returns:
        JtWJ (B, 6, 6), JtWr (B, 6), cost (B,), count (B,), in the input dtype. Not
        differentiable (inputs that require grad are used as data).
    """
    chk = ArgCheck("photometric_normal_equations")
    pose34, cam = _check_frames(chk, ref_image, ref_depth, live_image, pose, K)
    if live_depth is not None:
        chk.tensor("live_depth", live_depth, "B 1 H W")
        ld = live_depth.detach().contiguous()
    else:
        ld = ref_depth.new_empty(0)
    chk.option("robust", robust, NORMAL_EQUATIONS_KINDS)
    scale = chk.positive("scale", scale, ref_image.dtype)
    min_depth = chk.positive("min_depth", min_depth)
    if isinstance(depth_weight, bool) or not isinstance(depth_weight, (int, float)) or not (
        0 <= depth_weight < float("inf")
    ):
        chk.fail(ValueError, f"argument 'depth_weight' must be a finite number >= 0, got {depth_weight!r}")
    frames = (ref_image.detach().contiguous(), ref_depth.detach().contiguous(), live_image.detach().contiguous(), ld,
              pose34.detach(), cam.K.detach())
    if cam.model == 0:
        return _ops.photometric_normal_equations(*frames, _CODES[robust], scale, min_depth, float(depth_weight))
    H, W = ref_image.shape[2:]
    rays, stride = cam.detached().rays(H, W)
    return _ops.photometric_normal_equations_lens(
        *frames, cam.dist.detach(), rays, _CODES[robust], scale, min_depth, float(depth_weight), cam.model, stride
    )
