"""Nothing in gvnn_warp depends on torch's default dtype: with ``torch.set_default_dtype`` set to
float64 before the first call (in a fresh process), or left at float32, every public function and
layer works in both dtypes, returns the dtype it was given, and layers' parameters take the dtype
of what they are given (the VO network is float32 throughout)."""

import sys
import textwrap

import pytest
import torch
from processes import run_python

SCRIPT = textwrap.dedent(
    r"""
    import sys
    import torch

    torch.set_default_dtype(getattr(torch, sys.argv[1]))  # before anything of gvnn_warp runs
    import gvnn_warp as G
    from gvnn_warp.vo.model import CascadeVO, SiameseVO

    B, C, H, W = 2, 2, 6, 8
    seen = set()

    def check(name, fn, *args, dtype):
        seen.add(name)
        leaves = [a.detach().clone().requires_grad_() if torch.is_tensor(a) and a.is_floating_point() else a
                  for a in args]
        outs = fn(*leaves)
        outs = outs if isinstance(outs, tuple) else (outs,)
        floats = [o for o in outs if o.is_floating_point()]
        assert floats and all(o.dtype == dtype for o in floats), (name, dtype, [o.dtype for o in outs])
        sum(torch.nan_to_num(o).sum() for o in floats).backward()
        for a in leaves:
            if torch.is_tensor(a) and a.is_floating_point():
                assert a.grad is not None and a.grad.dtype == dtype, (name, dtype)
                assert torch.isfinite(a.grad).all(), name

    for dt in (torch.float32, torch.float64):
        g = torch.Generator().manual_seed(0)

        def r(*shape, lo=-0.5, hi=0.5):
            return torch.rand(*shape, generator=g, dtype=dt) * (hi - lo) + lo

        K = torch.tensor([[7.0, 0.0, 3.5], [0.0, 7.0, 2.5], [0.0, 0.0, 1.0]], dtype=dt)
        image, depth, pose = r(B, C, H, W), r(B, 1, H, W, lo=1, hi=2), G.se3_to_matrix(r(B, 6, lo=-0.05, hi=0.05))
        xi6, xi7, points = r(B, 6), r(B, 7), r(B, 5, 3) + torch.tensor([0, 0, 2], dtype=dt)
        pmap = r(B, H, W, 3) + torch.tensor([0, 0, 2], dtype=dt)
        ident9 = torch.eye(3, dtype=dt).reshape(1, 9, 1, 1)
        cases = {
            "so3_exp": (G.so3_exp, r(4, 3)),
            "so3_log": (G.so3_log, G.so3_exp(r(4, 3))),
            "quaternion_to_matrix": (G.quaternion_to_matrix, r(4, 4)),
            "euler_to_matrix": (G.euler_to_matrix, r(4, 3)),
            "se3_to_matrix": (G.se3_to_matrix, xi6),
            "sim3_to_matrix": (G.sim3_to_matrix, xi7),
            "se3_exp": (G.se3_exp, xi6),
            "se3_log": (G.se3_log, G.se3_exp(xi6)),
            "depth_to_points": (G.depth_to_points, depth, K),
            "transform_points": (G.transform_points, pose, points),
            "project_points": (G.project_points, points, K),
            "bilinear_sample": (G.bilinear_sample, image, r(B, 3, 4, 2)),
            "warp_frame_depth": (G.warp_frame_depth, image, depth, pose, K),
            "flow_warp": (G.flow_warp, image, r(B, 2, H, W)),
            "disparity_warp": (G.disparity_warp, image, r(B, 1, H, W, lo=0, hi=1)),
            "affine_flow_warp": (G.affine_flow_warp, image, r(B, 6, H, W, lo=-0.05, hi=0.05)),
            "affine_flow": (G.affine_flow, r(B, 6, H, W)),
            "se2_flow": (G.se2_flow, r(B, 3, H, W)),
            "homography_flow": (G.homography_flow, ident9 + r(B, 9, H, W, lo=-0.01, hi=0.01)),
            "slanted_plane_disparity": (G.slanted_plane_disparity, r(B, 3, H, W)),
            "pointwise_se3": (G.pointwise_se3, pmap, r(B, 6, H, W)),
            "pointwise_sim3": (G.pointwise_sim3, pmap, r(B, 7, H, W)),
            "pointwise_transform10": (G.pointwise_transform10, pmap, r(B, 10, H, W)),
            "affine_grid": (lambda th: G.affine_grid(th, (B, C, H, W)), r(B, 2, 3)),
            "robust_rho": (lambda x: G.robust_rho(x, "cauchy"), r(B, 1, H, W)),
            "robust_psi": (lambda x: G.robust_psi(x, "cauchy"), r(B, 1, H, W)),
            "smoothness_loss": (G.smoothness_loss, r(B, 2, H, W)),
            "photometric_error": (lambda *a: G.photometric_error(*a, robust="huber", scale=0.1),
                                  image, depth, image.flip(-1), pose, K),
            "PhotometricLoss": (G.PhotometricLoss("cauchy", 0.2), image, depth, image.flip(-1), pose, K),
            # camera models (gvnn_warp.cameras)
            "PinholeCamera": (lambda p, k: G.PinholeCamera(k).project(p)[0], points, K),
            "RadTanCamera": (lambda p, k, d: G.RadTanCamera(k, d).project(p)[0], points, K, r(5, lo=-0.1, hi=0.1)),
            "FisheyeCamera": (lambda x, z, k, d: G.FisheyeCamera(k, d).unproject(x, z), r(B, 5, 2, lo=0, hi=6),
                              r(B, 5, lo=1, hi=2), K, r(4, lo=-0.01, hi=0.01)),
            "unproject_points": (lambda x, z, k, d: G.unproject_points(x, z, G.RadTanCamera(k, d)),
                                 r(B, 5, 2, lo=0, hi=6), r(B, 5, lo=1, hi=2), K, r(5, lo=-0.1, hi=0.1)),
            "distort_points": (lambda x, k, d: G.distort_points(x, G.RadTanCamera(k, d)), r(B, 5, 2, lo=0, hi=6), K,
                               r(5, lo=-0.1, hi=0.1)),
            "undistort_points": (lambda x, k, d: G.undistort_points(x, G.FisheyeCamera(k, d)), r(B, 5, 2, lo=0, hi=6),
                                 K, r(4, lo=-0.01, hi=0.01)),
            "undistort_image": (lambda im, k, d: G.undistort_image(im, G.RadTanCamera(k, d)), image, K,
                                r(5, lo=-0.1, hi=0.1)),
            # layers (the intrinsics layers get K of this dtype: their buffer/parameter keeps it)
            "SO3": (G.SO3(), r(4, 3)),
            "SE3": (G.SE3(), xi6),
            "Sim3": (G.Sim3(), xi7),
            "GridGenerator3D": (G.GridGenerator3D(K), depth, pose),
            "PinholeProjection": (G.PinholeProjection(K, learnable=True), points),
            "BilinearSampler": (G.BilinearSampler(), image, r(B, 3, 4, 2)),
            "SpatialTransformer3D": (G.SpatialTransformer3D(K, learnable_intrinsics=True), image, depth, xi6 * 0.1),
            "FlowWarp": (G.FlowWarp(), image, r(B, 2, H, W)),
            "DisparityWarp": (G.DisparityWarp(), image, r(B, 1, H, W, lo=0, hi=1)),
            "AffineFlowWarp": (G.AffineFlowWarp(), image, r(B, 6, H, W, lo=-0.05, hi=0.05)),
            "AffineFlow": (G.AffineFlow(), r(B, 6, H, W)),
            "SE2Flow": (G.SE2Flow(), r(B, 3, H, W)),
            "HomographyFlow": (G.HomographyFlow(), ident9 + r(B, 9, H, W, lo=-0.01, hi=0.01)),
            "SlantedPlaneDisparity": (G.SlantedPlaneDisparity(), r(B, 3, H, W)),
            "PointwiseSE3": (G.PointwiseSE3(), pmap, r(B, 6, H, W)),
            "PointwiseSim3": (G.PointwiseSim3(), pmap, r(B, 7, H, W)),
            "PointwiseTransform10": (G.PointwiseTransform10(), pmap, r(B, 10, H, W)),
            "AffineGridGenerator": (lambda th: G.AffineGridGenerator()(th, (B, C, H, W)), r(B, 2, 3)),
            "RobustLoss": (G.RobustLoss("huber"), r(B, 1, H, W)),
            "SmoothnessLoss": (G.SmoothnessLoss(), r(B, 2, H, W)),
            # the self-supervised objective (2 sources)
            "reprojection_loss": (G.reprojection_loss, image, torch.stack([image, image.flip(-1)], 1), depth,
                                  torch.stack([pose, pose], 1), K),
            "edge_aware_smoothness": (G.edge_aware_smoothness, r(B, 1, H, W, lo=0.1, hi=1), image),
            "ReprojectionLoss": (G.ReprojectionLoss(), image, torch.stack([image, image.flip(-1)], 1), depth,
                                 torch.stack([pose, pose], 1), K),
            "EdgeAwareSmoothness": (G.EdgeAwareSmoothness(), r(B, 1, H, W, lo=0.1, hi=1), image),
        }
        for name, (fn, *args) in cases.items():
            check(name, fn, *args, dtype=dt)
        # not differentiable (a Gauss-Newton system): its outputs' dtype
        seen.add("photometric_normal_equations")
        system = G.photometric_normal_equations(image, depth, image.flip(-1), pose, K)
        assert all(o.dtype == dt for o in system if o.is_floating_point()), [o.dtype for o in system]
        for layer in (G.PinholeProjection(K, learnable=True), G.SpatialTransformer3D(K, learnable_intrinsics=True),
                      G.GridGenerator3D(K)):
            assert layer.K.dtype == dt

    # intrinsics given as a list (no dtype of their own) are float32, whatever the default
    assert G.PinholeProjection([[7.0, 0, 3.5], [0, 7, 2.5], [0, 0, 1]], learnable=True).K.dtype == torch.float32
    # the VO networks are float32 throughout (their data are)
    for net in (SiameseVO("se3", size=(16, 12), widths=(4, 8, 8)),
                CascadeVO("se3", scales=(2, 1), size=(16, 12), widths=(4, 8, 8))):
        assert all(t.dtype == torch.float32 for t in [*net.parameters(), *net.buffers()])
        f32 = torch.float32
        ref, live = torch.rand(2, 3, 12, 16, dtype=f32), torch.rand(2, 3, 12, 16, dtype=f32)
        d = torch.rand(2, 1, 12, 16, dtype=f32) + 1
        K32 = torch.tensor([[12.0, 0, 7.5], [0, 12, 5.5], [0, 0, 1]], dtype=f32)
        out = net(ref, live, d, d, K32) if isinstance(net, CascadeVO) else net(ref, live, d, d)
        assert out.dtype == torch.float32 and out.shape == (2, 6)
        out.sum().backward()

    not_ops = {"get_num_threads", "set_num_threads", "info", "Camera"}  # (Camera: the models' base class)
    public = {n for n in set(G.__all__) - set(G._STAR_MODULES) - not_ops if callable(getattr(G, n))}  # (no constants)
    assert seen == public, sorted(public ^ seen)
    print("ok", len(seen))
    """
)


@pytest.mark.long
def test_whole_api_under_default_dtype_float64():
    res = run_python(SCRIPT, "float64", timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.strip().startswith("ok")


def test_whole_api_under_default_dtype_float32(monkeypatch, capsys):
    # torch's own default, the tests' process's: the script runs here (no process to start)
    assert torch.get_default_dtype() == torch.float32
    monkeypatch.setattr(sys, "argv", ["default_dtype", "float32"])
    exec(compile(SCRIPT, "default_dtype_script", "exec"), {"__name__": "__main__"})
    assert capsys.readouterr().out.strip().startswith("ok")
