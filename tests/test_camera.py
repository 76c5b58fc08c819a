"""3D grid generator, rigid transform and projection layers vs closed forms and kornia."""

import kornia
import torch
from refs import intrinsics, pose44, tol
from torch.autograd import gradcheck

import gvnn_warp as G


def test_depth_to_points_closed_form(dtype):
    B, H, W = 2, 5, 7
    K = intrinsics(W, H, skew_=0.3)
    depth = torch.rand(B, 1, H, W, dtype=torch.float64) + 0.5
    pts = G.depth_to_points(depth.to(dtype), K.to(dtype))
    assert pts.shape == (B, H, W, 3) and pts.dtype == dtype
    y, x = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    pix = torch.stack([x, y, torch.ones_like(x)], -1)  # (H, W, 3), x = column
    ref = (pix @ torch.linalg.inv(K).T)[None] * depth[:, 0, ..., None]
    torch.testing.assert_close(pts.double(), ref, rtol=tol(dtype)[0], atol=tol(dtype)[1])


def test_depth_to_points_matches_kornia_and_grad():
    B, H, W = 2, 4, 6
    K = intrinsics(W, H).expand(B, 3, 3).contiguous()
    depth = torch.rand(B, 1, H, W, dtype=torch.float64) + 0.5
    ref = kornia.geometry.depth.depth_to_3d_v2(depth[:, 0], K)
    torch.testing.assert_close(G.depth_to_points(depth, K), ref)
    assert gradcheck(G.depth_to_points, (depth.requires_grad_(), K.clone().requires_grad_()))


def test_transform_points():
    B = 3
    T = G.se3_to_matrix(torch.randn(B, 6, dtype=torch.float64))
    pts = torch.randn(B, 4, 5, 3, dtype=torch.float64)
    out = G.transform_points(T, pts)
    ref = torch.einsum("bij,bhwj->bhwi", T[:, :, :3], pts) + T[:, None, None, :, 3]
    torch.testing.assert_close(out, ref)
    torch.testing.assert_close(G.transform_points(pose44(T), pts), out)
    assert gradcheck(G.transform_points, (T.requires_grad_(), pts.requires_grad_()))


def test_project_points_matches_kornia_and_learnable_K(dtype):
    B, P = 2, 9
    pts = torch.randn(B, P, 3, dtype=torch.float64)
    pts[..., 2] = pts[..., 2].abs() + 0.5
    K = intrinsics(64, 48)
    out = G.project_points(pts.to(dtype), K.to(dtype))
    ref = kornia.geometry.camera.project_points(pts, K.expand(B, P, 3, 3))
    torch.testing.assert_close(out.double(), ref, rtol=tol(dtype)[0], atol=tol(dtype)[1] * 100)
    if dtype == torch.float64:
        Kb = K.expand(B, 3, 3).clone().requires_grad_()
        assert gradcheck(G.project_points, (pts.clone().requires_grad_(), Kb))
        # only fx, s, cx, fy, cy are read, so only they receive gradient
        G.project_points(pts, Kb).sum().backward()
        assert (Kb.grad[:, 1, 0] == 0).all() and (Kb.grad[:, 2] == 0).all()
        assert (Kb.grad[:, 0, 0] != 0).all() and (Kb.grad[:, 1, 1] != 0).all()


def test_project_points_near_and_below_min_depth():
    K = intrinsics(32, 24)
    # just above the minimum depth: ordinary projection, finite gradients that pass gradcheck
    pts = torch.tensor([[[0.01, -0.02, 2e-3], [0.5, 0.1, 1.5e-3]]], dtype=torch.float64, requires_grad=True)
    assert gradcheck(G.project_points, (pts, K.unsqueeze(0)))
    # at / below it (and NaN z): finite, projected at z = min_depth, no gradient to z
    bad = torch.tensor([[[0.1, 0.2, 0.0], [0.1, 0.2, -3.0], [0.1, 0.2, float("nan")]]], dtype=torch.float64)
    bad.requires_grad_()
    out = G.project_points(bad, K)
    assert torch.isfinite(out).all()
    ref = G.project_points(torch.tensor([[[0.1, 0.2, 1e-3]]], dtype=torch.float64), K)
    torch.testing.assert_close(out, ref.expand(1, 3, 2))
    out.sum().backward()
    assert torch.isfinite(bad.grad).all() and (bad.grad[..., 2] == 0).all()


def test_shared_K_gradient_is_the_sum():
    B, P = 3, 4
    pts = torch.rand(B, P, 3, dtype=torch.float64) + 0.5
    K = intrinsics(16, 12).requires_grad_()
    G.project_points(pts, K).sum().backward()
    Kb = K.detach().expand(B, 3, 3).clone().requires_grad_()
    G.project_points(pts, Kb).sum().backward()
    torch.testing.assert_close(K.grad, Kb.grad.sum(0))
