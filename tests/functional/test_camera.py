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
    # at / below it: finite, projected as if z = min_depth; no larger a gradient (to the point or
    # to K) than the same point at z = 1 m gets (it was fx / min_depth = 1e5 times the upstream)
    xy = torch.tensor([[0.1, 0.2], [-0.3, 0.05], [0.2, -0.4]], dtype=torch.float64)
    for z in (1e-3, 5e-4, 0.0, -3.0):
        bad = torch.cat([xy, torch.full((3, 1), z, dtype=torch.float64)], -1)[None].requires_grad_()
        Kb = K[None].clone().requires_grad_()
        out = G.project_points(bad, Kb)
        assert torch.isfinite(out).all()
        ref = G.project_points(torch.cat([xy, torch.full((3, 1), 1e-3, dtype=torch.float64)], -1)[None], K)
        torch.testing.assert_close(out, ref)
        up = torch.tensor([[[1.0, -2.0], [0.5, 1.0], [-1.5, 0.3]]], dtype=torch.float64)
        (out * up).sum().backward()
        at1 = torch.cat([xy, torch.ones(3, 1, dtype=torch.float64)], -1)[None].requires_grad_()
        K1 = K[None].clone().requires_grad_()
        (G.project_points(at1, K1) * up).sum().backward()
        assert (bad.grad.norm(dim=-1) <= at1.grad.norm(dim=-1)).all(), (z, bad.grad)
        assert Kb.grad.norm() <= K1.grad.norm(), (z, Kb.grad)


def test_project_points_non_finite_depth_gives_nan_pixels():
    # a point whose z is NaN or infinite (e.g. from a NaN depth) is no pixel: NaN out, and it adds
    # nothing to any gradient (it used to come out as an ordinary, finite pixel)
    K = intrinsics(32, 24).requires_grad_()
    pts = torch.tensor(
        [[[0.1, 0.2, float("nan")], [0.1, 0.2, float("inf")], [0.1, 0.2, -float("inf")], [0.3, -0.1, 2.0]]],
        dtype=torch.float64, requires_grad=True,
    )
    out = G.project_points(pts, K)
    assert torch.isnan(out[0, :3]).all() and torch.isfinite(out[0, 3]).all()
    ok = torch.isfinite(out)
    torch.where(ok, out, 0.0).sum().backward()
    assert (pts.grad[0, :3] == 0).all() and torch.isfinite(pts.grad).all()
    K_ref = K.detach().clone().requires_grad_()
    G.project_points(pts[:, 3:].detach(), K_ref).sum().backward()
    torch.testing.assert_close(K.grad, K_ref.grad)


def test_shared_K_gradient_is_the_sum():
    B, P = 3, 4
    pts = torch.rand(B, P, 3, dtype=torch.float64) + 0.5
    K = intrinsics(16, 12).requires_grad_()
    G.project_points(pts, K).sum().backward()
    Kb = K.detach().expand(B, 3, 3).clone().requires_grad_()
    G.project_points(pts, Kb).sum().backward()
    torch.testing.assert_close(K.grad, Kb.grad.sum(0))
