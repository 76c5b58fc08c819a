"""The self-supervised reprojection objective (Monodepth2's, with auto-masking) and edge-aware
smoothness written the way users write them today in plain torch (``grid_sample``, SSIM through
``avg_pool2d`` on reflection-padded images, a full-resolution tensor per source and per SSIM
term), against ``gvnn_warp.reprojection_loss``. The torch functions here are also the tests'
reference (``tests/functional/test_reprojection.py``): they follow the definitions of
``gvnn_warp.kernels.reprojection`` and use nothing of gvnn_warp.

    .venv/bin/python -m benchmarks.reprojection [--size 640x192] [--batch 4] [--sources 2] [--repeats 7]
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

SSIM_C1, SSIM_C2 = 0.01**2, 0.03**2


def ssim_error(x, y):
    """clamp((1 - SSIM) / 2, 0, 1) per channel, 3x3 windows, reflection padding (Monodepth2)."""
    x, y = F.pad(x, (1, 1, 1, 1), mode="reflect"), F.pad(y, (1, 1, 1, 1), mode="reflect")
    mu_x, mu_y = F.avg_pool2d(x, 3, 1), F.avg_pool2d(y, 3, 1)
    sigma_x = F.avg_pool2d(x * x, 3, 1) - mu_x**2
    sigma_y = F.avg_pool2d(y * y, 3, 1) - mu_y**2
    sigma_xy = F.avg_pool2d(x * y, 3, 1) - mu_x * mu_y
    n = (2 * mu_x * mu_y + SSIM_C1) * (2 * sigma_xy + SSIM_C2)
    d = (mu_x**2 + mu_y**2 + SSIM_C1) * (sigma_x + sigma_y + SSIM_C2)
    return torch.clamp((1 - n / d) / 2, 0, 1)


def photometric_error(target, pred, alpha=0.85):
    """(B, 1, H, W): alpha * mean_c SSIM term + (1 - alpha) * mean_c |target - pred|."""
    l1 = (target - pred).abs().mean(1, keepdim=True)
    return alpha * ssim_error(target, pred).mean(1, keepdim=True) + (1 - alpha) * l1


def torch_reprojection_loss(target, sources, depth, poses, K, *, alpha=0.85, automask=True, min_depth=1e-3,
                            return_maps=False):
    """Plain-torch reprojection loss, pinhole K (B, 3, 3) or (3, 3); see gvnn_warp.reprojection_loss."""
    B, S, C, H, W = sources.shape
    K = K.expand(B, 3, 3)
    ys, xs = torch.meshgrid(torch.arange(H, dtype=depth.dtype), torch.arange(W, dtype=depth.dtype), indexing="ij")
    pix = torch.stack([xs, ys, torch.ones_like(xs)]).reshape(1, 3, H * W)
    d = depth.reshape(B, 1, H * W)
    depth_ok = (d > min_depth) & torch.isfinite(d)
    points = torch.linalg.inv(K) @ pix * torch.where(depth_ok, d, torch.ones_like(d))  # (B, 3, HW)
    candidates, fronts = [], []
    for s in range(S):
        moved = poses[:, s, :3, :3] @ points + poses[:, s, :3, 3:]
        z = moved[:, 2:3]
        front = depth_ok & (z > min_depth)
        uv = (K @ moved)[:, :2] / torch.where(front, z, torch.ones_like(z))
        grid = torch.stack([2 * uv[:, 0] / (W - 1) - 1, 2 * uv[:, 1] / (H - 1) - 1], -1).reshape(B, H, W, 2)
        grid = torch.where(front.reshape(B, H, W, 1), grid, torch.zeros_like(grid))  # no NaN reaches grid_sample
        warped = F.grid_sample(sources[:, s], grid, padding_mode="border", align_corners=True)
        front = front.reshape(B, 1, H, W)
        warped = warped * front  # gvnn_warp's warp gives 0 where a point cannot be projected
        pe = photometric_error(target, warped, alpha)
        candidates.append(torch.where(front, pe, torch.full_like(pe, float("inf"))))
        fronts.append(front)
    if automask:
        candidates += [photometric_error(target, sources[:, s], alpha) for s in range(S)]
    error, index = torch.cat(candidates, 1).min(1, keepdim=True)  # ties: the first (reprojections first)
    counted = depth_ok.reshape(B, 1, H, W) & torch.isfinite(error)
    error = torch.where(counted, error, torch.zeros_like(error))
    n = counted.sum((1, 2, 3))
    loss = error.sum((1, 2, 3)) / n.clamp(min=1)
    if not return_maps:
        return loss
    return loss, {"error": error.detach(), "automask": counted & (index < S),
                  "source": torch.where(counted, index % S, -1)}


def torch_edge_aware_smoothness(disp, img):
    """Monodepth2's get_smooth_loss on the mean-normalised disparity, per batch item (B,)."""
    disp = disp / (disp.mean((2, 3), keepdim=True) + 1e-7)
    gdx = (disp[:, :, :, :-1] - disp[:, :, :, 1:]).abs()
    gdy = (disp[:, :, :-1, :] - disp[:, :, 1:, :]).abs()
    gix = (img[:, :, :, :-1] - img[:, :, :, 1:]).abs().mean(1, keepdim=True)
    giy = (img[:, :, :-1, :] - img[:, :, 1:, :]).abs().mean(1, keepdim=True)
    return (gdx * torch.exp(-gix)).mean((1, 2, 3)) + (gdy * torch.exp(-giy)).mean((1, 2, 3))
