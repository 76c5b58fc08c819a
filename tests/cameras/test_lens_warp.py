"""warp_frame_depth, SpatialTransformer3D and the pure-Warp pipeline with a distorted camera
(radtan, fisheye): values against an independent torch reference (Newton / fixed-point
undistortion, the model's formulas, grid_sample), float64 gradcheck for every input including
every distortion coefficient, the pinhole path bitwise unchanged, bad regimes finite."""

import numpy as np
import pytest
import torch
import warp as wp
from gvnn_warp.kernels.core.kinds import mat34d, mat34f, vec8d
from gvnn_warp.kernels.geometry import lens
from gvnn_warp.kernels.sampling import pipeline as P

import gvnn_warp as G
from gvnn_warp.cameras import FisheyeCamera, PinholeCamera, RadTanCamera
from gvnn_warp.cameras import fused as Fn

f64 = torch.float64
FR1 = [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]  # TUM freiburg1's published radtan coefficients
FISH = [0.08, -0.02, 0.004, -0.001]


def tum_like_K(W, H, dtype=f64):
    """TUM freiburg1's intrinsics scaled to W x H (pixel-centre convention): the same field of view."""
    sx, sy = W / 640, H / 480
    return torch.tensor([[517.3 * sx, 0.0, (318.6 + 0.5) * sx - 0.5], [0.0, 516.5 * sy, (255.3 + 0.5) * sy - 0.5],
                         [0.0, 0.0, 1.0]], dtype=dtype)


def scene(B=2, C=2, H=12, W=16, seed=0, dtype=f64):
    g = torch.Generator().manual_seed(seed)
    image = torch.rand(B, C, H, W, generator=g, dtype=dtype)
    depth = 1.5 + torch.rand(B, 1, H, W, generator=g, dtype=dtype)
    pose = G.se3_to_matrix(torch.randn(B, 6, generator=g, dtype=dtype) * 0.04)
    return image, depth, pose, tum_like_K(W, H, dtype)


def camera(model, K, coeffs=None):
    if model == "radtan":
        return RadTanCamera(K, torch.tensor(FR1, dtype=K.dtype) if coeffs is None else coeffs)
    return FisheyeCamera(K, torch.tensor(FISH, dtype=K.dtype) if coeffs is None else coeffs)


# ----------------------------------------------------------------------------- torch reference


def distort_ref(model, c, x, y):
    if model == "radtan":
        k1, k2, p1, p2, k3 = c
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        return (x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)
    r = torch.sqrt(x * x + y * y).clamp_min(1e-300)
    th = torch.atan(r)
    t2 = th * th
    thd = th * (1 + t2 * (c[0] + t2 * (c[1] + t2 * (c[2] + t2 * c[3]))))
    return x * thd / r, y * thd / r


def undistort_ref(model, c, xd, yd):
    """OpenCV's fixed-point iteration for radtan; 1-D Newton on theta for the fisheye (float64)."""
    if model == "radtan":
        k1, k2, p1, p2, k3 = c
        x, y = xd.clone(), yd.clone()
        for _ in range(500):
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            x = (xd - (2 * p1 * x * y + p2 * (r2 + 2 * x * x))) / radial
            y = (yd - (p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)) / radial
        return x, y
    rd = torch.sqrt(xd * xd + yd * yd)
    th = rd.clone()
    for _ in range(100):
        t2 = th * th
        f = th * (1 + t2 * (c[0] + t2 * (c[1] + t2 * (c[2] + t2 * c[3])))) - rd
        fp = 1 + t2 * (3 * c[0] + t2 * (5 * c[1] + t2 * (7 * c[2] + t2 * 9 * c[3])))
        th = th - f / fp
    s = torch.where(rd > 0, torch.tan(th) / rd.clamp_min(1e-300), torch.ones_like(rd))
    return xd * s, yd * s


def warp_ref(image, depth, pose, K, model, c, min_depth=1e-3):
    B, C, H, W = image.shape
    ys, xs = torch.meshgrid(torch.arange(H, dtype=f64), torch.arange(W, dtype=f64), indexing="ij")
    fx, s, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    yd = (ys - cy) / fy
    xd = (xs - cx - s * yd) / fx
    xn, yn = undistort_ref(model, c, xd, yd)
    pts = torch.stack([xn, yn, torch.ones_like(xn)], -1) * depth[:, 0, :, :, None]  # (B, H, W, 3)
    q = torch.einsum("bij,bhwj->bhwi", pose[:, :3, :3], pts) + pose[:, None, None, :3, 3]
    x, y = q[..., 0] / q[..., 2], q[..., 1] / q[..., 2]
    dx, dy = distort_ref(model, c, x, y)
    u, v = fx * dx + s * dy + cx, fy * dy + cy
    grid = torch.stack([u / (W - 1) * 2 - 1, v / (H - 1) * 2 - 1], -1)
    out = torch.nn.functional.grid_sample(image, grid, mode="bilinear", padding_mode="zeros", align_corners=True)
    tol = 1e-3
    valid = (depth[:, 0] > min_depth) & (q[..., 2] > min_depth) & (u >= -tol) & (u <= W - 1 + tol) & (v >= -tol) & (
        v <= H - 1 + tol)
    return out, valid[:, None], u, v


@pytest.mark.parametrize("model", ["radtan", "fisheye"])
@pytest.mark.parametrize("W", [32, 30])  # (every block sampled as lanes; only the blocks starting a group of 8)
def test_distorted_warp_matches_torch_reference(model, W):
    H = 24
    image, depth, pose, K = scene(B=2, C=3, H=H, W=W)
    c = FR1 if model == "radtan" else FISH
    warped, valid = G.warp_frame_depth(image, depth, pose, camera(model, K))
    ref, ref_valid, u, v = warp_ref(image, depth, pose, K, model, c)
    # away from the 1e-3 px tolerance band the masks agree exactly
    edge = ((u + 1e-3).abs() < 1e-7) | ((u - W + 1 - 1e-3).abs() < 1e-7) | ((v + 1e-3).abs() < 1e-7) | (
        (v - H + 1 - 1e-3).abs() < 1e-7)
    assert torch.equal(valid[~edge[:, None]], ref_valid[~edge[:, None]])
    assert valid.float().mean() > 0.7 and (~valid).any()  # the motion moves some pixels out
    assert torch.allclose(warped * valid, ref * valid, atol=1e-9, rtol=0)


def test_distorted_camera_differs_from_ignoring_the_distortion():
    """The distortion matters at these coefficients (the test above could not pass by accident)."""
    image, depth, pose, K = scene(B=1, C=1, H=24, W=32)
    a, va = G.warp_frame_depth(image, depth, pose, camera("radtan", K))
    b, vb = G.warp_frame_depth(image, depth, pose, K)
    m = va & vb
    assert (a - b)[m].abs().max() > 0.05


@pytest.mark.parametrize("model", ["radtan", "fisheye"])
def test_gradcheck_every_input_and_coefficient(model):
    image, depth, pose, K = scene(B=2, C=2, H=6, W=8, seed=1)
    c = torch.tensor(FR1 if model == "radtan" else FISH, dtype=f64)
    xi = torch.randn(2, 6, dtype=f64, generator=torch.Generator().manual_seed(3)) * 0.04

    def f(image, depth, xi, K, c):
        return G.warp_frame_depth(image, depth, G.se3_to_matrix(xi), camera(model, K, c))[0]

    args = [t.clone().requires_grad_() for t in (image, depth, xi, K, c)]
    assert torch.autograd.gradcheck(f, args, eps=1e-6, atol=1e-7)


def wide_fisheye_scene(dtype=f64):
    """A 13 px wide image (one full block of 8 pixels and a partial one) behind a wide-angle fisheye:
    the corner pixels' rays are ~85 degrees off the axis (r^2 = (X/Z)^2 + (Y/Z)^2 up to ~80), most
    pixels beyond 45 degrees (the z > 1 case of the lanes' atan ratio)."""
    image, depth, pose, _ = scene(B=2, C=2, H=9, W=13, seed=5, dtype=dtype)
    K = torch.tensor([[4.5, 0.0, 6.0], [0.0, 4.5, 4.0], [0.0, 0.0, 1.0]], dtype=dtype)
    return image, depth, pose, K


def test_wide_angle_fisheye_matches_torch_reference_and_gradcheck():
    image, depth, pose, K = wide_fisheye_scene()
    warped, valid = G.warp_frame_depth(image, depth, pose, camera("fisheye", K))
    ref, ref_valid, u, v = warp_ref(image, depth, pose, K, "fisheye", FISH)
    r2 = ((torch.arange(13, dtype=f64) - 6.0) / 4.5) ** 2 + ((torch.arange(9, dtype=f64)[:, None] - 4.0) / 4.5) ** 2
    assert r2.max() > 1.5  # the undistorted corners are wider still
    assert torch.equal(valid, ref_valid) and valid.float().mean() > 0.5
    assert torch.allclose(warped * valid, ref * valid, atol=1e-9, rtol=0)
    c = torch.tensor(FISH, dtype=f64)

    def f(image, depth, pose, K, c):
        return G.warp_frame_depth(image, depth, pose, camera("fisheye", K, c))[0]

    args = [t.clone().requires_grad_() for t in (image, depth, pose, K, c)]
    assert torch.autograd.gradcheck(f, args, eps=1e-6, atol=1e-7)


@pytest.mark.parametrize("model", ["radtan", "fisheye", "wide fisheye"])
def test_float32_warp_is_the_float64_one_to_float32_precision(model):
    """float32 evaluates the lens in float32 (kernels.geometry.lens.lanes, 8 lanes): values and gradients (for
    image, depth, pose, K and the coefficients) within float32 rounding of the float64 op's, valid
    masks equal on at least 99% of the pixels (they may differ where a pixel lands within rounding
    of the image border)."""
    if model == "wide fisheye":
        image, depth, pose, K = wide_fisheye_scene()
        model = "fisheye"
    else:
        image, depth, pose, K = scene(B=2, C=3, H=24, W=29, seed=7)
    c = torch.tensor(FR1 if model == "radtan" else FISH, dtype=f64)
    out = {}
    for dtype in (f64, torch.float32):
        args = [t.detach().to(dtype).requires_grad_() for t in (image, depth, pose, K, c)]
        warped, valid = G.warp_frame_depth(*args[:3], camera(model, args[3], args[4]))
        (warped * torch.linspace(0.5, 1.5, warped.numel(), dtype=dtype).reshape(warped.shape)).sum().backward()
        out[dtype] = (warped.double(), valid, [a.grad.double() for a in args])
    (w64, v64, g64), (w32, v32, g32) = out[f64], out[torch.float32]
    assert (v64 == v32).float().mean() > 0.99
    both = v64 & v32
    torch.testing.assert_close(w32 * both, w64 * both, atol=2e-5, rtol=0)
    for name, a, b in zip(("image", "depth", "pose", "K", "dist"), g32, g64):
        torch.testing.assert_close(a, b, atol=2e-3 * b.abs().max().item(), rtol=1e-3, msg=name)


def test_gradcheck_batched_camera_and_border_padding():
    """A camera per batch item (rays per item) and border padding."""
    image, depth, pose, K = scene(B=2, C=1, H=6, W=8, seed=2)
    Kb = torch.stack([K, K * torch.tensor([[1.02], [0.98], [1.0]], dtype=f64)])
    cb = torch.tensor([FR1, [0.1, -0.2, 0.001, -0.002, 0.05]], dtype=f64)

    def f(image, depth, pose, Kb, cb):
        return G.warp_frame_depth(image, depth, pose, RadTanCamera(Kb, cb), padding_mode="border")[0]

    args = [t.clone().requires_grad_() for t in (image, depth, pose, Kb, cb)]
    assert torch.autograd.gradcheck(f, args, eps=1e-6, atol=1e-7)


def test_pinhole_camera_is_bitwise_the_K_path_and_zero_distortion_matches_it():
    image, depth, pose, K = scene(B=2, C=3, H=12, W=16, dtype=torch.float32)
    a, va = G.warp_frame_depth(image, depth, pose, K)
    b, vb = G.warp_frame_depth(image, depth, pose, PinholeCamera(K))
    assert torch.equal(a, b) and torch.equal(va, vb)
    image, depth, pose, K = scene(B=2, C=3, H=12, W=16)
    a, va = G.warp_frame_depth(image, depth, pose, K)
    for cam in (RadTanCamera(K, torch.zeros(5, dtype=f64)), FisheyeCamera(K, torch.zeros(4, dtype=f64))):
        b, vb = G.warp_frame_depth(image, depth, pose, cam)
        if isinstance(cam, RadTanCamera):
            assert torch.equal(va, vb)
            assert torch.allclose(a, b, atol=1e-12, rtol=0)
        else:  # the fisheye with k = 0 is the equidistant projection, not the pinhole
            assert not torch.allclose(a, b, atol=1e-3)


def test_bad_depths_and_out_of_domain_points_are_finite_masked_and_pass_no_gradient():
    """Every rule of the valid mask checked against an independent torch computation, each case
    present: depths not above min_depth or not finite, pixels without a ray (beyond the strong
    fisheye's domain), moved points behind the camera or beyond the domain, samples outside the
    image. Where a pixel is not active (all but the last rule) its output and depth gradient are 0."""
    H, W = 8, 10  # a full block of 8 pixels and a partial one per row
    image, depth, _, K = scene(B=3, C=2, H=H, W=W, seed=4)
    depth = depth.clone()
    depth[:, 0, 3, :5] = torch.tensor([0.0, -1.0, float("nan"), float("inf"), 5e-4], dtype=f64)
    depth[:, 0, 4, 9] = float("nan")  # the last pixel of a row: the lanes past it repeat it
    depth[1, 0, 4, 5] = 1.0  # near the axis: behind the camera after item 1's move, yet in the domain
    # item 0 turns by 0.3 rad about y (points leave the domain), item 1 moves 1.8 m back (points
    # behind), item 2 0.3 m forward (the 5e-4 m depth lands in front and in the domain)
    twists = [[0.0, 0.3, 0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0, 0.0, -1.8], [0.0, 0.0, 0.0, 0.0, 0.0, 0.3]]
    pose = G.se3_to_matrix(torch.tensor(twists, dtype=f64))
    # a strong fisheye whose domain ends inside the field of view (theta_max ~ 0.49 rad)
    c = torch.tensor([-0.6, 0.0, 0.0, 0.0], dtype=f64)
    limit = float(lens.pack_dist(lens.FISHEYE, c.numpy())[lens.LIMIT])
    th_max = float(np.arctan(np.sqrt(limit)))
    args = [t.clone().requires_grad_() for t in (image, depth, pose, K, c)]
    warped, valid = G.warp_frame_depth(*args[:3], FisheyeCamera(args[3], args[4]))
    (warped * torch.rand(warped.shape, dtype=f64, generator=torch.Generator().manual_seed(0))).sum().backward()

    # the reference: rays by 1-D Newton where the pixel's distorted radius is below theta_d(theta_max)
    ys, xs = torch.meshgrid(torch.arange(H, dtype=f64), torch.arange(W, dtype=f64), indexing="ij")
    yd = (ys - K[1, 2]) / K[1, 1]
    xd = (xs - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    rd = torch.sqrt(xd * xd + yd * yd)
    has_ray = rd < th_max * (1 + c[0] * th_max**2)
    xn, yn = undistort_ref("fisheye", c, xd, yd)
    d = depth[:, 0]
    depth_ok = torch.isfinite(d) & (d > 1e-3)
    dd = torch.where(depth_ok, d, torch.ones_like(d))
    pts = torch.stack([xn, yn, torch.ones_like(xn)], -1) * dd[..., None]
    q = torch.einsum("bij,bhwj->bhwi", pose[:, :3, :3], pts) + pose[:, None, None, :3, 3]
    front = q[..., 2] > 1e-3
    x, y = q[..., 0] / q[..., 2], q[..., 1] / q[..., 2]
    in_domain = front & (x * x + y * y < limit)
    active = depth_ok & has_ray & in_domain
    dx, dy = distort_ref("fisheye", c, torch.where(active, x, 0.0), torch.where(active, y, 0.0))
    u, v = K[0, 0] * dx + K[0, 1] * dy + K[0, 2], K[1, 1] * dy + K[1, 2]
    inside = (u >= -1e-3) & (u <= W - 1 + 1e-3) & (v >= -1e-3) & (v <= H - 1 + 1e-3)
    # every case is present
    for case in (~depth_ok, depth_ok & ~has_ray, depth_ok & has_ray & ~front, front & has_ray & depth_ok & ~in_domain,
                 active & ~inside, active & inside):
        assert case.any()
    assert torch.equal(valid[:, 0], active & inside)
    assert torch.isfinite(warped).all()
    assert (warped.permute(1, 0, 2, 3)[:, ~active] == 0).all()
    for a in args:
        assert torch.isfinite(a.grad).all()
    assert (args[1].grad[:, 0][~active] == 0).all() and (args[1].grad[:, 0][active & inside] != 0).any()


def test_rays_cache_follows_the_camera_values():
    image, depth, pose, K = scene(B=1, C=1, H=8, W=10)
    c = torch.tensor(FR1, dtype=f64)
    a = G.warp_frame_depth(image, depth, pose, RadTanCamera(K, c))[0]
    c2 = c.clone()
    c2[0] = 0.0  # another camera, same tensor shapes
    b = G.warp_frame_depth(image, depth, pose, RadTanCamera(K, c2))[0]
    c[0] = 0.0  # the first camera changed in place: its rays are recomputed
    a2 = G.warp_frame_depth(image, depth, pose, RadTanCamera(K, c))[0]
    assert not torch.equal(a, b) and torch.equal(a2, b)
    assert len(Fn.RAYS_CACHE) <= Fn.RAYS_CACHE_SIZE


def test_spatial_transformer_3d_with_a_camera_learns_its_coefficients():
    image, depth, _, K = scene(B=2, C=2, H=6, W=8)
    layer = G.SpatialTransformer3D(RadTanCamera(K, torch.tensor(FR1, dtype=f64)), learnable_intrinsics=True)
    xi = torch.randn(2, 6, dtype=f64) * 0.03
    warped, valid = layer(image, depth, xi)
    ref, ref_valid = G.warp_frame_depth(image, depth, G.se3_to_matrix(xi), camera("radtan", K))
    assert torch.equal(warped, ref) and torch.equal(valid, ref_valid)
    (warped * valid).sum().backward()
    grads = [p.grad for p in layer.parameters()]
    assert len(grads) == 2 and all(g is not None and g.abs().sum() > 0 for g in grads)


@pytest.mark.parametrize("model", ["radtan", "fisheye"])
def test_pure_warp_pipeline_matches_the_torch_op_values_and_gradients(model):
    image, depth, pose, K = scene(B=2, C=2, H=6, W=8, seed=5)
    c = torch.tensor(FR1 if model == "radtan" else FISH, dtype=f64)
    ts = [t.clone().requires_grad_() for t in (image, depth, pose, K, c)]
    warped, valid = G.warp_frame_depth(*ts[:3], camera(model, ts[3], ts[4]))
    weights = torch.rand(warped.shape, dtype=f64, generator=torch.Generator().manual_seed(1))
    (warped * weights).sum().backward()

    m = lens.MODEL_IDS[model]
    dist8 = np.broadcast_to(lens.pack_dist(m, c.numpy()), (2, 8)).copy()
    arrs = [
        wp.array(image.numpy(), dtype=wp.float64, requires_grad=True),
        wp.array(depth.numpy(), dtype=wp.float64, requires_grad=True),
        wp.array(pose.numpy(), dtype=mat34d, requires_grad=True),
        wp.array(K.expand(2, 3, 3).numpy().copy(), dtype=wp.mat33d, requires_grad=True),
        wp.array(dist8, dtype=vec8d, requires_grad=True),
    ]
    tape = wp.Tape()
    with tape:
        w_warped, w_valid = P.warp_frame_depth(*arrs[:4], dist=arrs[4], model=model)
    assert np.array_equal(w_valid.numpy(), valid.numpy())
    assert np.allclose(w_warped.numpy(), warped.detach().numpy(), atol=1e-13, rtol=0)
    tape.backward(grads={w_warped: wp.array(weights.numpy(), dtype=wp.float64)})
    for name, a, t in zip(("image", "depth", "pose"), arrs, ts):
        assert np.allclose(a.grad.numpy(), t.grad.numpy(), atol=1e-11, rtol=0), name
    # the torch camera is shared by the batch: its gradient is the sum of the items'
    assert np.allclose(arrs[3].grad.numpy().sum(0), ts[3].grad.numpy(), atol=1e-10, rtol=0)
    assert np.allclose(arrs[4].grad.numpy().sum(0)[: len(c)], ts[4].grad.numpy(), atol=1e-10, rtol=0)


def test_pure_warp_pipeline_refuses_bad_camera_arguments():
    image, depth, pose, K = scene(B=1, C=1, H=4, W=5, dtype=torch.float32)
    arrs = [wp.array(image.numpy(), dtype=wp.float32), wp.array(depth.numpy(), dtype=wp.float32),
            wp.array(pose.numpy(), dtype=mat34f), wp.array(K[None].numpy(), dtype=wp.mat33f)]
    with pytest.raises(ValueError, match="argument 'model'"):
        P.warp_frame_depth(*arrs, model="kb4")
    with pytest.raises(TypeError, match="argument 'dist'"):
        P.warp_frame_depth(*arrs, model="radtan")
    with pytest.raises(TypeError, match="argument 'dist'"):
        P.warp_frame_depth(*arrs, model="radtan", dist=wp.zeros(1, dtype=wp.types.vector(8, wp.float64)))


# ----------------------------------------------------------------------------- photometric objective


def photometric_scene(B=2, C=2, H=8, W=10, seed=6):
    image, depth, pose, K = scene(B=B, C=C, H=H, W=W, seed=seed)
    g = torch.Generator().manual_seed(seed + 1)
    # a smooth live image (bilinear derivatives that vary), the reference = live + noise
    ys, xs = torch.meshgrid(torch.arange(H, dtype=f64), torch.arange(W, dtype=f64), indexing="ij")
    live = torch.stack([torch.sin(0.7 * xs + 0.3 * c) * torch.cos(0.5 * ys) for c in range(C)])[None].expand(B, C, H, W)
    ref = live + 0.05 * torch.randn(B, C, H, W, generator=g, dtype=f64)
    return ref.contiguous(), depth, live.contiguous(), pose, K


@pytest.mark.parametrize("model", ["radtan", "fisheye"])
def test_photometric_error_gradcheck_with_a_distorted_camera(model):
    ref, depth, live, pose, K = photometric_scene(B=2, C=1, H=5, W=6)
    c = torch.tensor(FR1 if model == "radtan" else FISH, dtype=f64)

    def f(ref, depth, live, pose, K, c):
        return G.photometric_error(ref, depth, live, pose, camera(model, K, c), robust="huber", scale=0.3)[0]

    args = [t.clone().requires_grad_() for t in (ref, depth, live, pose, K, c)]
    assert torch.autograd.gradcheck(f, args, eps=1e-6, atol=1e-7)


@pytest.mark.parametrize("model", ["radtan", "fisheye"])
def test_photometric_error_is_the_masked_mean_of_the_distorted_warp(model):
    ref, depth, live, pose, K = photometric_scene()
    cam = camera(model, K)
    err, count = G.photometric_error(ref, depth, live, pose, cam, robust="l2")
    warped, valid = G.warp_frame_depth(live, depth, pose, cam)
    r = (warped - ref) * valid
    assert torch.equal(count, valid.sum((1, 2, 3)).to(f64))
    assert torch.allclose(err, 0.5 * (r * r).sum((1, 2, 3)) / (ref.shape[1] * count), atol=1e-14, rtol=0)


@pytest.mark.parametrize("model", ["radtan", "fisheye"])
@pytest.mark.parametrize("robust", ["l2", "huber"])
def test_normal_equations_with_a_distorted_camera_match_autograd(model, robust):
    """JtWJ, JtWr against torch.autograd's Jacobian of the same residuals (the distorted warp as a
    function of the left-multiplied twist delta), float64."""
    ref, depth, live, pose, K = photometric_scene(B=2, C=2, H=8, W=10)
    cam = camera(model, K)
    scale = 0.1
    JtWJ, JtWr, cost, count = G.photometric_normal_equations(ref, depth, live, pose, cam, robust=robust, scale=scale)
    _, valid = G.warp_frame_depth(live, depth, pose, cam)
    for b in range(2):
        def residuals(delta, b=b):
            T = G.se3_exp(delta[None])[0]
            Tb = torch.cat([T[:, :3] @ pose[b, :, :3], T[:, :3] @ pose[b, :, 3:] + T[:, 3:]], dim=1)
            w, _ = G.warp_frame_depth(live[b:b + 1], depth[b:b + 1], Tb[None], cam)
            return (w - ref[b:b + 1])[valid[b:b + 1].expand_as(w)]

        zero = torch.zeros(6, dtype=f64)
        r = residuals(zero)
        J = torch.autograd.functional.jacobian(residuals, zero)
        if robust == "l2":
            w = torch.ones_like(r)
            rho = 0.5 * r * r
        else:
            a = r.abs()
            w = torch.where(a <= scale, torch.ones_like(r), scale / a)
            rho = torch.where(a <= scale, 0.5 * r * r, scale * (a - 0.5 * scale))
        assert count[b] == valid[b].sum()
        assert torch.allclose(JtWJ[b], J.T @ (w[:, None] * J), atol=1e-9, rtol=0)
        assert torch.allclose(JtWr[b], J.T @ (w * r), atol=1e-9, rtol=0)
        assert torch.allclose(cost[b], rho.sum(), atol=1e-12, rtol=0)


def test_pure_warp_normal_equations_with_a_distorted_camera_match_the_torch_op():
    # three scenes of the same shapes: the torch op's second and third calls replay the launches
    # its first recorded, pointed at new tensors
    from gvnn_warp.kernels.photometric import pipeline as PP

    for seed in (6, 7, 8):
        ref, depth, live, pose, K = photometric_scene(B=2, C=1, H=8, W=10, seed=seed)
        JtWJ, JtWr, cost, count = G.photometric_normal_equations(ref, depth, live, pose, camera("radtan", K),
                                                                 live_depth=depth, depth_weight=0.5)
        dist8 = np.broadcast_to(lens.pack_dist(lens.RADTAN, FR1), (2, 8)).copy()
        arr = [wp.array(t.numpy(), dtype=wp.float64) for t in (ref, depth, live)]
        ne = PP.photometric_normal_equations(
            *arr, wp.array(pose.numpy(), dtype=mat34d), wp.array(K.expand(2, 3, 3).numpy().copy(), dtype=wp.mat33d),
            live_depth=arr[1], depth_weight=0.5, dist=wp.array(dist8, dtype=vec8d), model="radtan",
        )
        for a, t in zip(ne.numpy(), (JtWJ, JtWr, cost, count)):
            assert np.allclose(a, t.numpy(), atol=1e-12, rtol=1e-12)
    again = PP.photometric_normal_equations(*arr, ne._args[3], ne._args[4], live_depth=arr[1], depth_weight=0.5,
                                            dist=ne._args[6], model="radtan", out=ne)  # replays the recorded launches
    assert again is ne and np.allclose(ne.numpy()[0], JtWJ.numpy(), atol=1e-12, rtol=1e-12)


# ----------------------------------------------------------------------------- the aligner


def render_room(T_cam_world, K, model, c, H, W):
    """Exact image and depth of a textured floor (y = 0.8), back wall (z = 3) and side wall
    (x = 1.2) seen by a distorted camera at T_cam_world: every pixel's ray (undistort_ref) is
    intersected with the planes; a smooth texture (the bilinear sampling is then near exact)."""
    ys, xs = torch.meshgrid(torch.arange(H, dtype=f64), torch.arange(W, dtype=f64), indexing="ij")
    yd = (ys - K[1, 2]) / K[1, 1]
    xd = (xs - K[0, 2] - K[0, 1] * yd) / K[0, 0]
    xn, yn = undistort_ref(model, c, xd, yd) if model != "pinhole" else (xd, yd)
    d_cam = torch.stack([xn, yn, torch.ones_like(xn)], -1)
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    origin = -R.T @ t
    d = d_cam @ R  # R^T d_cam, as rows
    far = torch.full_like(xn, 1e9)
    hits = [torch.where(d[..., k] * sgn > 1e-9, (level - origin[k]) / d[..., k], far)
            for k, level, sgn in ((1, 0.8, 1), (2, 3.0, 1), (0, 1.2, 1))]
    s = torch.stack(hits).min(0).values
    X = origin + s[..., None] * d
    x, y, z = X.unbind(-1)  # a texture of the 3D position: continuous across the creases
    img = 0.45 + 0.2 * torch.sin(2.5 * x + 1.0) * torch.cos(2.0 * y + 1.5 * z)
    img = img + 0.1 * torch.sin(3.0 * z - 2.0 * x + 0.5)
    return img[None].float(), (s * d_cam[..., 2])[None].float()


def test_aligner_with_the_distorted_camera_recovers_the_motion_and_beats_ignoring_it():
    from gvnn_warp.odometry.aligner import DirectAligner

    H, W = 96, 128
    K = tum_like_K(W, H)  # TUM freiburg1's camera at 128 x 96 (the corners move ~1.5 px)
    c = torch.tensor(FR1, dtype=f64)
    T = torch.eye(4, dtype=f64)  # 3.9 deg, 11.6 cm
    T[:3, :4] = G.se3_to_matrix(torch.tensor([0.03, -0.06, 0.01, 0.10, -0.03, 0.05], dtype=f64))
    ref_img, ref_depth = render_room(torch.eye(4, dtype=f64), K, "radtan", c, H, W)
    live_img, live_depth = render_room(T, K, "radtan", c, H, W)

    def error(aligner):
        est, info = aligner.align(ref_img.numpy(), ref_depth.numpy(), live_img.numpy(), live_depth.numpy())
        dR = est[:3, :3] @ T[:3, :3].numpy().T
        angle = np.degrees(np.arccos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
        return np.linalg.norm(est[:3, 3] - T[:3, 3].numpy()), angle

    kw = {"tolerance": 1e-3, "take_step": 0.0, "iterations": 30}  # converged: the optimum, not the stopping rule
    t_cam, r_cam = error(DirectAligner(RadTanCamera(K, c), **kw))
    t_same, r_same = error(DirectAligner(K.numpy(), model="radtan", dist=FR1, **kw))
    t_pin, r_pin = error(DirectAligner(K.numpy(), **kw))
    assert (t_cam, r_cam) == (t_same, r_same)
    # measured: 1.2 mm, 0.022 deg with the camera (a pinhole pair of this scene: 1.2 mm, 0.025 deg,
    # the bilinear sampling's bias); 4.2 mm, 0.12 deg ignoring the distortion
    assert t_cam < 2.5e-3 and r_cam < 0.05
    assert t_cam < 0.5 * t_pin and r_cam < 0.3 * r_pin


def test_aligner_refuses_bad_camera_arguments():
    from gvnn_warp.odometry.aligner import DirectAligner

    K = tum_like_K(32, 24).numpy()
    with pytest.raises(ValueError, match="argument 'model' must be one of"):
        DirectAligner(K, model="kb8")
    with pytest.raises(ValueError, match="argument 'dist' must be 5 finite coefficients"):
        DirectAligner(K, model="radtan", dist=[0.1, 0.2])
    with pytest.raises(ValueError, match="argument 'dist' must be None for the pinhole"):
        DirectAligner(K, model="pinhole", dist=[0.1])
    with pytest.raises(ValueError, match="unbatched camera"):
        DirectAligner(RadTanCamera(torch.from_numpy(K).expand(2, 3, 3), torch.zeros(2, 5, dtype=f64)))


@pytest.mark.parametrize("model", ["radtan", "fisheye"])
@pytest.mark.parametrize("dtype", [torch.float32, f64])
def test_blocks_sampled_as_lanes_are_bitwise_the_pixel_by_pixel_path(model, dtype):
    # W = 32, H = 7: every block 8 whole pixels of a plane of whole groups of 8, taken as lanes; the
    # same image with a 33rd column of zeros (H W = 231: no block is) goes pixel by pixel. With zeros
    # padding a tap on that column reads 0 as a tap outside the 32 columns does: the same samples
    image, depth, pose, K = scene(B=2, C=3, H=7, W=32, seed=5, dtype=dtype)
    pose = G.se3_to_matrix(torch.tensor([[0.01, -0.02, 0.03, 0.05, -0.04, 0.02]] * 2, dtype=dtype))
    depth[0, 0, 2, 3] = float("nan")
    depth[1, 0, 4, 9] = -1.0
    wide_image = torch.cat([image, torch.zeros(2, 3, 7, 1, dtype=dtype)], -1)
    wide_depth = torch.cat([depth, depth[..., -1:]], -1)
    g = torch.randn(2, 3, 7, 33, generator=torch.Generator().manual_seed(1), dtype=dtype)
    g[..., 32] = 0.0  # (the extra column passes no gradient: the pose's sums are over the same pixels)
    results = []
    for img, dep, upstream in ((image, depth, g[..., :32]), (wide_image, wide_depth, g)):
        img, dep, pz = img.clone().requires_grad_(), dep.clone().requires_grad_(), pose.clone().requires_grad_()
        out, _ = G.warp_frame_depth(img, dep, pz, camera(model, K.to(dtype)))
        (out * upstream).sum().backward()
        results.append((out[..., :32], img.grad[..., :32], dep.grad[..., :32], pz.grad))
    (a, ga, da, pa), (b, gb, db, pb) = results
    assert torch.isfinite(a).all() and (a != 0).float().mean() > 0.5
    assert torch.equal(a, b) and torch.equal(ga, gb) and torch.equal(da, db)
    assert torch.allclose(pa, pb, rtol=1e-5 if dtype == torch.float32 else 1e-12, atol=0)


def test_a_plane_beyond_the_lanes_exact_addresses_is_sampled_pixel_by_pixel():
    # float32 lanes hold tap addresses exactly up to 2^24 pixels a plane: a plane of 2049 x 8192
    # (rows 2048 on beyond it) must take the pixel-by-pixel path. Identity pose: every pixel samples
    # itself, so the warp of a lens camera with no distortion is the image, and so is the gradient
    H, W = 2049, 8192
    image = torch.rand(1, 1, H, W, generator=torch.Generator().manual_seed(0)).requires_grad_()
    depth = torch.full((1, 1, H, W), 2.0)
    cam = RadTanCamera(tum_like_K(W, H, torch.float32), torch.zeros(5))
    out, valid = G.warp_frame_depth(image, depth, torch.eye(4)[None], cam)
    out[:, :, -3:].sum().backward()
    last = slice(H - 3, H)
    assert valid[:, :, last].all()
    assert torch.allclose(out[:, :, last], image.detach()[:, :, last], atol=2e-3, rtol=0)
    assert torch.allclose(image.grad[:, :, last], torch.ones(1, 1, 3, W), atol=2e-3, rtol=0)
    assert image.grad[:, :, : H - 4].abs().max() < 2e-3
