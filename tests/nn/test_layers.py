"""nn.Module layers are thin wrappers: same values as the functions, learnable intrinsics train."""

import pytest
import torch
from refs import intrinsics

import gvnn_warp as G


def test_layers_equal_functions():
    xi = torch.randn(4, 7, dtype=torch.float64)
    torch.testing.assert_close(G.SO3()(xi[:, :3]), G.so3_exp(xi[:, :3]))
    torch.testing.assert_close(G.SE3()(xi[:, :6]), G.se3_to_matrix(xi[:, :6]))
    torch.testing.assert_close(G.Sim3()(xi), G.sim3_to_matrix(xi))
    K = intrinsics(8, 6)
    depth = torch.rand(4, 1, 6, 8, dtype=torch.float64) + 1
    pose = G.se3_to_matrix(xi[:, :6] * 0.05)
    pts = G.GridGenerator3D(K)(depth, pose)
    torch.testing.assert_close(pts, G.transform_points(pose, G.depth_to_points(depth, K)))
    torch.testing.assert_close(G.PinholeProjection(K)(pts), G.project_points(pts, K))
    grid = torch.rand(4, 3, 5, 2, dtype=torch.float64) * 2 - 1
    image = torch.rand(4, 2, 6, 8, dtype=torch.float64)
    sampler = G.BilinearSampler(align_corners=True, padding_mode="border")
    ref = G.bilinear_sample(image, grid, align_corners=True, padding_mode="border")
    torch.testing.assert_close(sampler(image, grid), ref)
    warped, valid = G.SpatialTransformer3D(K)(image, depth, xi[:, :6] * 0.05)
    ref_w, ref_v = G.warp_frame_depth(image, depth, pose, K)
    torch.testing.assert_close(warped, ref_w)
    assert torch.equal(valid, ref_v)
    # the layer's own argument named in its errors (an unbatched xi is not the function's 3x4 'pose')
    with pytest.raises(ValueError, match=r"SpatialTransformer3D: argument 'xi' must have shape \(B, 6\), got \(6,\)"):
        G.SpatialTransformer3D(K)(image, depth, xi[0, :6])
    with pytest.raises(ValueError, match=r"argument 'xi' has B=2 \(shape \(2, 6\)\) but 'image' has B=4"):
        G.SpatialTransformer3D(K)(image, depth, xi[:2, :6])
    with pytest.raises(TypeError, match=r"argument 'xi' has dtype torch.float32 but 'image' has torch.float64"):
        G.SpatialTransformer3D(K)(image, depth, xi[:, :6].float())


def test_identity_at_zero_pose_and_learnable_intrinsics():
    K = intrinsics(10, 8, dtype=torch.float32)
    stn = G.SpatialTransformer3D(K, learnable_intrinsics=True)
    assert isinstance(stn.K, torch.nn.Parameter)
    image = torch.rand(2, 3, 8, 10)
    depth = torch.rand(2, 1, 8, 10) + 1
    warped, valid = stn(image, depth, torch.zeros(2, 6))
    assert valid.all()
    torch.testing.assert_close(warped, image)
    warped, _ = stn(image, depth, torch.tensor([[0.0, 0.02, 0.0, 0.05, 0.0, 0.0]] * 2))
    warped.square().mean().backward()
    assert stn.K.grad is not None and stn.K.grad[0, 0] != 0
    assert "K" in dict(G.GridGenerator3D(K).named_buffers())
