"""The self-supervised reprojection objective and the edge-aware smoothness against the plain-torch
reference written from Monodepth2's formulas (benchmarks/reprojection.py: grid_sample,
avg_pool2d SSIM, identity reprojection, min), float64 gradcheck, hard regimes (invalid depth,
points behind the source camera, ties, samples outside the image), determinism, bad input."""

import re

import pytest
import torch
from gvnn_warp.kernels.core import launch
from refs import intrinsics

import gvnn_warp as G
from benchmarks.reprojection import torch_edge_aware_smoothness, torch_reprojection_loss
from gvnn_warp.cameras import PinholeCamera, RadTanCamera


def frames(B=2, S=2, C=3, H=10, W=13, seed=0, dtype=torch.float64, motion=0.05):
    g = torch.Generator().manual_seed(seed)
    target = torch.rand(B, C, H, W, generator=g, dtype=dtype)
    sources = torch.rand(B, S, C, H, W, generator=g, dtype=dtype)
    depth = 1.5 + torch.rand(B, 1, H, W, generator=g, dtype=dtype)
    xi = (torch.rand(B * S, 6, generator=g, dtype=dtype) * 2 - 1) * motion
    poses = G.se3_to_matrix(xi).reshape(B, S, 3, 4)
    return target, sources, depth, poses, intrinsics(W, H).to(dtype)


def both(args, K, **kw):
    ours = G.reprojection_loss(*args, K, return_maps=True, **kw)
    ref = torch_reprojection_loss(*args, K, return_maps=True, **kw)
    return ours, ref


def assert_maps_equal(m, mr, atol):
    assert torch.equal(m["source"], mr["source"])
    assert torch.equal(m["automask"], mr["automask"])
    torch.testing.assert_close(m["error"], mr["error"], rtol=0, atol=atol)


@pytest.mark.parametrize("dtype,atol", [(torch.float32, 1e-5), (torch.float64, 1e-12)])
@pytest.mark.parametrize("alpha", [0.0, 0.85, 1.0])
@pytest.mark.parametrize("automask", [True, False])
def test_values_and_maps_match_torch_reference(dtype, atol, alpha, automask):
    *args, K = frames(dtype=dtype)
    (loss, m), (lr, mr) = both(args, K, alpha=alpha, automask=automask)
    torch.testing.assert_close(loss, lr, rtol=0, atol=atol)
    assert_maps_equal(m, mr, atol)
    if automask:  # random frames: the static sources win some pixels
        assert 0 < m["automask"].sum() < m["automask"].numel()


@pytest.mark.parametrize("S", [1, 3])
def test_any_number_of_sources(S):
    *args, K = frames(S=S, B=1, C=1, seed=S)
    (loss, m), (lr, mr) = both(args, K)
    torch.testing.assert_close(loss, lr, rtol=0, atol=1e-12)
    assert_maps_equal(m, mr, 1e-12)
    assert set(m["source"].unique().tolist()) <= set(range(S))


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-5), (torch.float64, 1e-10)])
def test_gradients_of_every_input_match_torch_reference(dtype, tol):
    target, sources, depth, poses, K = frames(dtype=dtype, seed=3)
    leaves = [t.clone().requires_grad_() for t in (target, sources, depth, poses, K)]
    ref_leaves = [t.clone().requires_grad_() for t in (target, sources, depth, poses, K)]
    w = torch.tensor([1.0, 0.5], dtype=dtype)
    (G.reprojection_loss(*leaves) * w).sum().backward()
    (torch_reprojection_loss(*ref_leaves) * w).sum().backward()
    # K: the entries the pinhole reads (fx, skew, cx, fy, cy; docs/conventions.md), the others get 0
    used = torch.tensor([[1, 1, 1], [0, 1, 1], [0, 0, 0]], dtype=torch.bool)
    ref_leaves[4].grad = torch.where(used, ref_leaves[4].grad, 0)
    for name, a, b in zip(("target", "sources", "depth", "poses", "K"), leaves, ref_leaves):
        scale = max(1.0, b.grad.abs().max().item())
        torch.testing.assert_close(a.grad, b.grad, rtol=0, atol=tol * scale, msg=name)


def test_gradcheck_float64():
    target, sources, depth, poses, K = frames(B=1, S=2, C=2, H=5, W=6, seed=4)
    poses44 = torch.cat([poses, torch.tensor([0, 0, 0, 1.0], dtype=poses.dtype).expand(1, 2, 1, 4)], 2)

    def f(t, s, d, p, k):
        return G.reprojection_loss(t, s, d, p, k)

    args = [x.clone().requires_grad_() for x in (target, sources, depth, poses44, K)]
    assert torch.autograd.gradcheck(f, args, eps=1e-6, atol=1e-7)


def test_invalid_depth_is_excluded_with_finite_gradients():
    target, sources, depth, poses, K = frames(seed=5)
    depth = depth.clone()
    depth[0, 0, 1, 1], depth[0, 0, 2, 3], depth[1, 0, 4, 4] = 0.0, -1.0, float("nan")
    depth[1, 0, 5, 5] = float("inf")
    (loss, m), (lr, mr) = both((target, sources, depth, poses), K)
    torch.testing.assert_close(loss, lr, rtol=0, atol=1e-12)
    assert_maps_equal(m, mr, 1e-12)
    for b, y, x in ((0, 1, 1), (0, 2, 3), (1, 4, 4), (1, 5, 5)):
        assert m["source"][b, 0, y, x] == -1 and m["error"][b, 0, y, x] == 0
    d = depth.clone().requires_grad_()
    p = poses.clone().requires_grad_()
    G.reprojection_loss(target, sources, d, p, K).sum().backward()
    assert torch.isfinite(d.grad).all() and torch.isfinite(p.grad).all()
    assert d.grad[0, 0, 1, 1] == 0 and d.grad[1, 0, 4, 4] == 0


def test_all_depth_invalid_gives_zero_loss():
    target, sources, depth, poses, K = frames(seed=6)
    loss = G.reprojection_loss(target, sources, torch.zeros_like(depth), poses, K)
    assert torch.equal(loss, torch.zeros(2, dtype=loss.dtype))


def test_points_behind_a_source_and_outside_the_image():
    """Source 0 moves 3 m forward (most points behind it: not candidates there), source 1 shifts
    sideways (many samples outside the image, read with border padding)."""
    target, sources, depth, poses, K = frames(seed=7, motion=0.02)  # (not 0: no sample on a pixel's edge)
    poses = poses.clone()
    poses[:, 0, 2, 3] = -3.0
    poses[:, 1, 0, 3] = 0.6
    (loss, m), (lr, mr) = both((target, sources, depth, poses), K)
    torch.testing.assert_close(loss, lr, rtol=0, atol=1e-12)
    assert_maps_equal(m, mr, 1e-12)
    assert not ((m["source"] == 0) & m["automask"]).any()  # source 0 never chosen as a reprojection
    leaves = [t.clone().requires_grad_() for t in (depth, poses)]
    ref_leaves = [t.clone().requires_grad_() for t in (depth, poses)]
    G.reprojection_loss(target, sources, *leaves, K).sum().backward()
    torch_reprojection_loss(target, sources, *ref_leaves, K).sum().backward()
    for a, b in zip(leaves, ref_leaves):
        torch.testing.assert_close(a.grad, b.grad, rtol=0, atol=1e-10)


def test_ties_go_to_the_reprojection_then_the_lower_source():
    """Black frames: every candidate's error is exactly 0, so the first reprojection wins
    everywhere (no pixel masked); two equal sources with equal poses: source 0 wins every tie."""
    target, sources, depth, poses, K = frames(seed=8)
    loss, m = G.reprojection_loss(target * 0, sources * 0, depth, poses, K, return_maps=True)
    assert torch.equal(loss, torch.zeros_like(loss))
    assert m["automask"].all() and (m["source"] == 0).all()
    twins = sources[:, :1].repeat(1, 2, 1, 1, 1)
    twin_poses = poses[:, :1].repeat(1, 2, 1, 1)
    _, m = G.reprojection_loss(target, twins, depth, twin_poses, K, return_maps=True)
    assert (m["source"] == 0).all() and 0 < m["automask"].sum() < m["automask"].numel()


def test_camera_objects_and_lens_models():
    target, sources, depth, poses, K = frames(seed=9, dtype=torch.float64)
    plain = G.reprojection_loss(target, sources, depth, poses, K)
    torch.testing.assert_close(G.reprojection_loss(target, sources, depth, poses, PinholeCamera(K)), plain)
    no_dist = RadTanCamera(K, torch.zeros(5, dtype=K.dtype))
    torch.testing.assert_close(G.reprojection_loss(target, sources, depth, poses, no_dist), plain, rtol=0, atol=1e-9)
    # batched K (one per item) equals the shared one
    torch.testing.assert_close(G.reprojection_loss(target, sources, depth, poses, K.expand(2, 3, 3)), plain)
    dist = torch.tensor([0.05, -0.02, 0.001, 0.002, 0.0], dtype=K.dtype, requires_grad=True)
    shared = G.reprojection_loss(target, sources, depth, poses, RadTanCamera(K, dist))
    batched = RadTanCamera(K.expand(2, 3, 3), dist.expand(2, 5))  # one camera per item, repeated per source
    torch.testing.assert_close(G.reprojection_loss(target, sources, depth, poses, batched), shared)
    k = K.clone().requires_grad_()
    loss = G.reprojection_loss(target, sources, depth, poses, RadTanCamera(k, dist))
    assert not torch.allclose(loss, plain)
    loss.sum().backward()
    assert torch.isfinite(dist.grad).all() and dist.grad.abs().sum() > 0 and k.grad.abs().sum() > 0


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_chosen_error_recomputed_equals_the_choice_pass(dtype):
    """reprojection_loss takes each pixel's error from the row pass that chose it; the kernel whose
    adjoint gives the gradients recomputes it per pixel: bitwise the same value."""
    from gvnn_warp.ops import reprojection as R

    target, sources, depth, poses, K = frames(dtype=dtype, seed=14)
    B, S, C, H, W = sources.shape
    warped = sources.flip(-1).contiguous()  # any images
    args = (target, warped, sources, target.new_empty(0), depth[:, 0].contiguous(), poses.reshape(B * S, 3, 4),
            K.expand(B * S, 3, 3).contiguous(), S, C, H, W, 0.85, 1, 1e-3, 0)
    choice, best, _ = R.reprojection_choice(*args)
    pe, _ = R.reprojection_error(target, warped, sources, choice, best, S, C, H, W, 0.85)
    assert torch.equal(pe, best) and (choice >= S).any() and (choice < S).any()


def test_deterministic_for_any_thread_count():
    target, sources, depth, poses, K = frames(B=2, H=64, W=96, seed=10, dtype=torch.float32)
    results = []
    for n in (1, 2, 3):
        launch.set_num_threads(n)
        try:
            leaves = [t.clone().requires_grad_() for t in (target, sources, depth, poses)]
            loss = G.reprojection_loss(*leaves, K)
            loss.sum().backward()
            results.append([loss.detach(), *(t.grad for t in leaves)])
        finally:
            launch.set_num_threads(None)
    for other in results[1:]:
        for a, b in zip(results[0], other):
            assert torch.equal(a, b)


def test_inputs_are_not_modified():
    args = frames(seed=11)
    copies = [t.clone() for t in args]
    G.reprojection_loss(*args[:4], args[4], return_maps=True)
    for a, b in zip(args, copies):
        assert torch.equal(a, b)


@pytest.mark.parametrize(
    "change,match",
    [
        (lambda a: {**a, "sources": a["sources"][:, :0]}, "S >= 1"),
        (lambda a: {**a, "alpha": 1.5}, "alpha"),
        (lambda a: {**a, "alpha": float("nan")}, "alpha"),
        (lambda a: {**a, "depth": a["depth"][:, :, :5]}, "depth"),
        (lambda a: {**a, "poses": a["poses"][:, :1]}, "poses"),
        (lambda a: {**a, "sources": a["sources"][:1]}, "sources"),
        (lambda a: {**a, "camera": torch.eye(4, dtype=torch.float64)}, "camera"),
        (lambda a: {**a, "camera": "K"}, "camera"),
        (lambda a: {**a, "target": a["target"][..., :1, :]}, "2x2"),
        (lambda a: {**a, "min_depth": -1.0}, "min_depth"),
    ],
)
def test_bad_input_names_the_argument(change, match):
    target, sources, depth, poses, K = frames()
    a = change({"target": target, "sources": sources, "depth": depth, "poses": poses, "camera": K, "alpha": 0.85,
                "min_depth": 1e-3})
    if match == "2x2":
        a["sources"], a["depth"] = a["sources"][..., :1, :], a["depth"][..., :1, :]
    with pytest.raises((ValueError, TypeError), match=match) as e:
        G.reprojection_loss(a["target"], a["sources"], a["depth"], a["poses"], a["camera"], alpha=a["alpha"],
                            min_depth=a["min_depth"])
    assert "gvnn_warp.reprojection_loss" in str(e.value)


def test_dtype_mismatch_is_a_type_error():
    target, sources, depth, poses, K = frames()
    with pytest.raises(TypeError, match="sources"):
        G.reprojection_loss(target, sources.float(), depth, poses, K)


def test_layer_is_the_function():
    target, sources, depth, poses, K = frames(seed=12)
    layer = G.ReprojectionLoss(alpha=0.5, automask=False)
    torch.testing.assert_close(layer(target, sources, depth, poses, K),
                               G.reprojection_loss(target, sources, depth, poses, K, alpha=0.5, automask=False))


# ----------------------------------------------------------------------------- edge-aware smoothness


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-5), (torch.float64, 1e-12)])
def test_smoothness_values_and_gradients_match_reference(dtype, tol):
    g = torch.Generator().manual_seed(0)
    disp = (torch.rand(2, 1, 7, 9, generator=g, dtype=dtype) + 0.1).requires_grad_()
    image = torch.rand(2, 3, 7, 9, generator=g, dtype=dtype).requires_grad_()
    ours, ref = G.edge_aware_smoothness(disp, image), torch_edge_aware_smoothness(disp, image)
    torch.testing.assert_close(ours, ref, rtol=0, atol=tol)
    for a, b in zip(torch.autograd.grad(ours.sum(), [disp, image]), torch.autograd.grad(ref.sum(), [disp, image])):
        torch.testing.assert_close(a, b, rtol=0, atol=tol * 10)
    layer = G.EdgeAwareSmoothness()
    torch.testing.assert_close(layer(disp, image), ours)


def test_smoothness_gradcheck_float64():
    g = torch.Generator().manual_seed(1)
    disp = (torch.rand(2, 1, 4, 5, generator=g, dtype=torch.float64) + 0.2).requires_grad_()
    image = torch.rand(2, 2, 4, 5, generator=g, dtype=torch.float64).requires_grad_()
    assert torch.autograd.gradcheck(G.edge_aware_smoothness, (disp, image))


def test_smoothness_bad_input():
    with pytest.raises(ValueError, match="gvnn_warp.edge_aware_smoothness.*image"):
        G.edge_aware_smoothness(torch.rand(2, 1, 4, 5), torch.rand(3, 3, 4, 5))
    with pytest.raises(ValueError, match="2x2"):
        G.edge_aware_smoothness(torch.rand(2, 1, 1, 5), torch.rand(2, 3, 1, 5))


# ----------------------------------------------------------------------------- pure Warp


@pytest.mark.parametrize("lens", [False, True])
def test_pure_warp_pipeline_matches_the_torch_op_with_a_tape(lens):
    import numpy as np
    import warp as wp
    from gvnn_warp.kernels.core.kinds import mat34d
    from gvnn_warp.kernels.geometry import lens as lens_models
    from gvnn_warp.kernels.reprojection.pipeline import reprojection_loss as warp_loss

    target, sources, depth, poses, K = frames(seed=13)
    B, S, C, H, W = sources.shape
    Kb = K.expand(B, 3, 3).contiguous()
    coeffs = [0.05, -0.02, 0.001, 0.002, 0.0]
    camera = RadTanCamera(Kb, torch.tensor(coeffs, dtype=K.dtype)) if lens else Kb
    leaves = [t.clone().requires_grad_() for t in (target, sources, depth, poses)]
    loss = G.reprojection_loss(*leaves, camera)
    (loss * torch.tensor([1.0, 2.0], dtype=loss.dtype)).sum().backward()

    def arr(t, dtype=wp.float64):
        return wp.array(t.detach().numpy(), dtype=dtype, requires_grad=True)

    w = [arr(target), arr(sources.reshape(B * S, C, H, W)), arr(depth), arr(poses, mat34d), arr(Kb, wp.mat33d)]
    extra = {}
    if lens:
        dist = np.stack([lens_models.pack_dist(lens_models.RADTAN, coeffs)] * B)
        extra = {"dist": wp.array(dist, dtype=wp.types.vector(8, wp.float64)), "model": "radtan"}
    tape = wp.Tape()
    with tape:
        wloss = warp_loss(*w, **extra)
    tape.backward(grads={wloss: wp.array([1.0, 2.0], dtype=wp.float64)})
    np.testing.assert_allclose(wloss.numpy(), loss.detach().numpy(), rtol=0, atol=1e-12)
    for t, a in zip(leaves, w):
        np.testing.assert_allclose(a.grad.numpy().reshape(t.shape), t.grad.numpy(), rtol=0, atol=1e-10)


def test_pure_warp_pipeline_names_bad_arguments():
    import warp as wp
    from gvnn_warp.kernels.reprojection.pipeline import reprojection_loss as warp_loss

    t = wp.zeros((1, 3, 4, 5), dtype=wp.float32)
    with pytest.raises(ValueError, match="argument 'poses'"):
        K = wp.zeros(1, dtype=wp.mat33f)
        warp_loss(t, t, wp.zeros((1, 1, 4, 5), dtype=wp.float32), K, K)
    # one float type (the target's), Warp arrays only: named, not a launch error
    d = wp.zeros((1, 1, 4, 5), dtype=wp.float32)
    P = wp.zeros((1, 1), dtype=wp.types.matrix((3, 4), wp.float32))
    t64 = wp.zeros((1, 3, 4, 5), dtype=wp.float64)
    for args, message in (((t64, t, d, P, K), "argument 'sources' must be of dtype float64 like 'target', got float32"),
                          ((t, t, d, P, wp.zeros(1, dtype=wp.mat33d)), "argument 'K' must be an array of 3x3 float32"),
                          ((t, t.numpy(), d, P, K), "argument 'sources' must be a wp.array"),
                          ((t, t, d, P.numpy(), K), "argument 'poses' must be a wp.array")):
        with pytest.raises(TypeError, match=r"gvnn_warp\.kernels\.reprojection_loss: " + re.escape(message)):
            warp_loss(*args)
    # the lens arguments under the loss's own name, for its (B,) items (not the repeated (B S,) warps')
    for kw, exc, message in (({"model": "radtan"}, TypeError, "argument 'dist' must be a wp.array of length-8"),
                             ({"model": "radtan", "dist": t.numpy()[:, 0, 0]}, TypeError,
                              "argument 'dist' must be a wp.array of length-8"),
                             ({"model": "magic"}, ValueError, "argument 'model' must be one of"),
                             ({"min_depth": 0.0}, ValueError, "argument 'min_depth' must be a positive finite")):
        with pytest.raises(exc, match=r"gvnn_warp\.kernels\.reprojection_loss: " + re.escape(message)):
            warp_loss(t, t, d, P, K, **kw)
