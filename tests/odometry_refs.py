"""Test-only references and data for the direct aligner (tests/odometry/test_aligner.py, benchmarks).

- :func:`normal_equations_torch`: a slow, independent float64 Gauss-Newton system of the
  photometric residuals, with the Jacobian from torch's forward-mode autograd through a plain torch
  warp (unproject, move, project, bilinear sample), not from gvnn_warp's kernels.
- :func:`rendered_pair`: a reference / live RGB-D pair rendered by ``gvnn_warp.synthetic``
  with a known relative pose.
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from gvnn_warp.synthetic import default_intrinsics, relative_pose


def _so3_exp(w):
    theta2 = (w * w).sum()
    theta = torch.sqrt(theta2 + 1e-300)
    wx = torch.zeros(3, 3, dtype=w.dtype)
    wx = wx + torch.tensor([[0, 0, 0], [0, 0, -1], [0, 1, 0]], dtype=w.dtype) * w[0]
    wx = wx + torch.tensor([[0, 0, 1], [0, 0, 0], [-1, 0, 0]], dtype=w.dtype) * w[1]
    wx = wx + torch.tensor([[0, -1, 0], [1, 0, 0], [0, 0, 0]], dtype=w.dtype) * w[2]
    small = theta2 < 1e-8
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, (1 - torch.cos(theta)) / (theta2 + 1e-300))
    return torch.eye(3, dtype=w.dtype) + a * wx + b * (wx @ wx)


def _residuals(delta, ref_image, ref_depth, live_image, pose, K, min_depth):
    """(C, N) residuals and the (N,) validity of every reference pixel for pose exp(delta) pose."""
    C, H, W = ref_image.shape
    y, x = torch.meshgrid(torch.arange(H, dtype=delta.dtype), torch.arange(W, dtype=delta.dtype), indexing="ij")
    d = ref_depth.reshape(-1)
    fx, fy, cx, cy, s = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    yn = (y.reshape(-1) - cy) / fy
    xn = (x.reshape(-1) - cx - s * yn) / fx
    X = torch.stack([xn * d, yn * d, d], 0)  # (3, N)
    R = _so3_exp(delta[:3]) @ pose[:3, :3]
    t = _so3_exp(delta[:3]) @ pose[:3, 3] + delta[3:]
    P = R @ X + t[:, None]
    z = P[2]
    valid_z = torch.isfinite(d) & (d > min_depth) & (z > min_depth)
    zs = torch.where(valid_z, z, torch.ones_like(z))
    u = fx * P[0] / zs + s * P[1] / zs + cx
    v = fy * P[1] / zs + cy
    eps = 1e-3
    inside = (u >= -eps) & (u <= W - 1 + eps) & (v >= -eps) & (v <= H - 1 + eps)
    valid = valid_z & inside
    uc = torch.where(valid, u, torch.zeros_like(u)).clamp(0, W - 1)
    vc = torch.where(valid, v, torch.zeros_like(v)).clamp(0, H - 1)
    x0 = torch.floor(uc).detach().clamp(max=W - 2) if W > 1 else torch.zeros_like(uc)
    y0 = torch.floor(vc).detach().clamp(max=H - 2) if H > 1 else torch.zeros_like(vc)
    ax, ay = uc - x0, vc - y0
    i0, j0 = x0.long(), y0.long()
    img = live_image.reshape(C, -1)

    def at(j, i):
        return img[:, j * W + i]

    sample = (at(j0, i0) * (1 - ax) * (1 - ay) + at(j0, i0 + 1) * ax * (1 - ay)
              + at(j0 + 1, i0) * (1 - ax) * ay + at(j0 + 1, i0 + 1) * ax * ay)
    r = sample - ref_image.reshape(C, -1)
    return torch.where(valid, r, torch.zeros_like(r)), valid


def _rho_weight(r, robust, scale):
    a = r.abs()
    if robust == "l2":
        return 0.5 * r * r, torch.ones_like(r)
    if robust == "huber":
        rho = torch.where(a <= scale, 0.5 * r * r, scale * (a - 0.5 * scale))
        w = torch.where(a <= scale, torch.ones_like(r), scale / a.clamp_min(1e-300))
        return rho, w
    if robust == "cauchy":
        z = (r / scale) ** 2
        return 0.5 * scale**2 * torch.log1p(z), 1 / (1 + z)
    raise ValueError(robust)


def normal_equations_torch(ref_image, ref_depth, live_image, pose, K, *, robust="huber", scale=1.0,
                           min_depth=1e-3):
    """float64 (JtWJ (6, 6), JtWr (6,), cost, count) of one pair; arrays are numpy (C, H, W),
    (1, H, W), (C, H, W), pose (4, 4) or (3, 4), K (3, 3). Jacobian by forward-mode autograd."""
    args = [torch.as_tensor(np.asarray(a, dtype=np.float64)) for a in (ref_image, ref_depth, live_image, pose, K)]
    delta = torch.zeros(6, dtype=torch.float64)
    r, valid = _residuals(delta, *args, min_depth)
    f = functools.partial(lambda dl: _residuals(dl, *args, min_depth)[0])
    J = torch.func.jacfwd(f)(delta)  # (C, N, 6)
    rho, w = _rho_weight(r, robust, scale)
    m = valid[None].to(r.dtype)
    Jw = J * (w * m)[..., None]
    JtWJ = torch.einsum("cni,cnj->ij", Jw, J)
    JtWr = torch.einsum("cni,cn->i", Jw, r)
    cost = (rho * m).sum()
    return JtWJ.numpy(), JtWr.numpy(), float(cost), int(valid.sum())


@functools.lru_cache(maxsize=8)
def _scene(seed):
    from gvnn_warp.synthetic import make_room_scene

    return make_room_scene(seed)


def look_pose(seed: int = 0) -> np.ndarray:
    """A camera T_world_cam inside the room looking at its far wall and boxes (deterministic)."""
    from gvnn_warp.synthetic import smooth_se3_trajectory

    return smooth_se3_trajectory(2, seed)[0]


def rendered_pair(T_ref_live: np.ndarray, *, width=80, height=60, seed=0, scene_seed=0):
    """(ref_image (3,H,W), ref_depth (1,H,W), live_image, live_depth, K, T_live_ref) float32 / float64.

    The reference camera is ``look_pose(seed)``; the live camera is ``T_world_ref @ T_ref_live``.
    ``T_live_ref`` is what the aligner estimates (points of the reference camera into the live one).
    """
    from gvnn_warp.synthetic import render_rgbd

    T_world_ref = look_pose(seed)
    T_world_live = T_world_ref @ T_ref_live
    K = default_intrinsics(width, height)
    image, depth = render_rgbd(_scene(scene_seed), np.stack([T_world_ref, T_world_live]), K, width, height)
    return image[0], depth[0], image[1], depth[1], K, relative_pose(T_world_live, T_world_ref)


def motion(omega_deg=(0.0, 0.0, 0.0), t=(0.0, 0.0, 0.0)) -> np.ndarray:
    """A (4, 4) rigid motion: rotation vector in degrees, translation in metres."""
    w = np.radians(np.asarray(omega_deg, dtype=np.float64))
    th = np.linalg.norm(w)
    Wx = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    R = np.eye(3) if th < 1e-12 else np.eye(3) + np.sin(th) / th * Wx + (1 - np.cos(th)) / th**2 * Wx @ Wx
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(rotation error in degrees, translation error in metres) of T_est against T_true."""
    E = np.linalg.inv(T_true) @ T_est
    cos = np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)
    return float(np.degrees(np.arccos(cos))), float(np.linalg.norm(E[:3, 3]))
