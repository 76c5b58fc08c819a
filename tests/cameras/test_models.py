"""Camera models (gvnn_warp.cameras, kernels.geometry.lens) against OpenCV, float64 gradcheck (including the
implicit-function gradient of the undistortion), the domain rule and bad inputs."""

import math

import cv2
import numpy as np
import pytest
import torch
from gvnn_warp.kernels.geometry import lens
from torch.autograd import gradcheck

import gvnn_warp as G

f64 = torch.float64
# TUM RGB-D freiburg1 (published calibration): 640 x 480
TUM_K = [[517.3, 0.0, 318.6], [0.0, 516.5, 255.3], [0.0, 0.0, 1.0]]
TUM_D = [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]
TUM_SIZE = (640, 480)
# TUM-VI cam0, equidistant fisheye (published calibration): 512 x 512, ~190 degrees field of view
VI_K = [[190.978, 0.0, 254.932], [0.0, 190.973, 256.897], [0.0, 0.0, 1.0]]
VI_D = [0.003482, 0.000715, -0.002053, 0.000203]
VI_SIZE = (512, 512)
CRIT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)


def image_pixels(W, H, step=16):
    """A grid over the whole image, its last row and column and the four corners included."""
    xs = np.unique(np.r_[np.arange(0, W, step), W - 1]).astype(np.float64)
    ys = np.unique(np.r_[np.arange(0, H, step), H - 1]).astype(np.float64)
    x, y = np.meshgrid(xs, ys)
    return np.stack([x.ravel(), y.ravel()], -1)


def cameras(dtype=f64):
    narrow = [[300.0, 0.0, 254.932], [0.0, 300.0, 256.897], [0.0, 0.0, 1.0]]  # the whole image within 90 deg
    return {
        "radtan": (G.RadTanCamera(torch.tensor(TUM_K, dtype=dtype), torch.tensor(TUM_D, dtype=dtype)), TUM_SIZE),
        "fisheye": (G.FisheyeCamera(torch.tensor(narrow, dtype=dtype), torch.tensor(VI_D, dtype=dtype)), VI_SIZE),
        "fisheye_vi": (G.FisheyeCamera(torch.tensor(VI_K, dtype=dtype), torch.tensor(VI_D, dtype=dtype)), VI_SIZE),
    }


def cv_undistort(name, px, K, D):
    if name == "radtan":
        return cv2.undistortPoints(px[:, None], K, D, None, None, K, CRIT)[:, 0]
    return cv2.fisheye.undistortPoints(px[:, None], K, D, R=np.eye(3), P=K, criteria=CRIT)[:, 0]


def cv_project(name, pts, K, D):
    if name == "radtan":
        return cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, D)[0][:, 0]
    return cv2.fisheye.projectPoints(pts[:, None], np.zeros(3), np.zeros(3), K, D)[0][:, 0]


def test_fisheye_beyond_90_degrees_is_invalid():
    """TUM-VI's 190-degree fisheye: the image corners see rays behind the camera (theta_d beyond
    theta_d(pi/2)); they are invalid and finite, the rest matches OpenCV."""
    cam, (W, H) = cameras()["fisheye_vi"]
    K, D = cam.K.numpy(), cam.dist.numpy()
    px = image_pixels(W, H)
    und, ok = G.undistort_points(torch.tensor(px)[None], cam)
    ok = ok[0].numpy()
    theta_d = np.linalg.norm((px - K[:2, 2]) / np.diag(K)[:2], axis=1)
    half_pi = math.pi / 2
    limit = half_pi * (1 + D[0] * half_pi**2 + D[1] * half_pi**4 + D[2] * half_pi**6 + D[3] * half_pi**8)
    assert not ok[[0, len(ok) - 1]].any() and ok.any()  # corners out, centre in
    np.testing.assert_array_equal(ok, theta_d < limit)
    assert torch.isfinite(und).all()
    np.testing.assert_allclose(und[0].numpy()[ok], cv_undistort("fisheye", px[ok], K, D), rtol=0, atol=1e-6)


@pytest.mark.parametrize("name", ["radtan", "fisheye"])
def test_values_match_opencv_over_the_whole_image(name):
    cam, (W, H) = cameras()[name]
    K, D = cam.K.numpy(), cam.dist.numpy()
    px = image_pixels(W, H)
    ideal = cv_undistort(name, px, K, D)
    assert np.isfinite(ideal).all() and (np.abs(ideal) < 1e5).all()  # OpenCV converged everywhere
    und, ok = G.undistort_points(torch.tensor(px)[None], cam)
    assert ok.all()
    np.testing.assert_allclose(und[0].numpy(), ideal, rtol=0, atol=1e-6)
    # project the rays of those ideal pixels at several depths: back to px, as OpenCV projects them
    rays = np.c_[ideal, np.ones(len(px))] @ np.linalg.inv(K).T
    depth = np.linspace(0.3, 5.0, len(px))
    pts = rays * depth[:, None]
    pix, valid = cam.project(torch.tensor(pts)[None])
    assert valid.all()
    np.testing.assert_allclose(pix[0].numpy(), cv_project(name, pts, K, D), rtol=0, atol=1e-6)
    np.testing.assert_allclose(pix[0].numpy(), px, rtol=0, atol=1e-6)
    dist_px, ok = G.distort_points(torch.tensor(ideal)[None], cam)
    assert ok.all()
    np.testing.assert_allclose(dist_px[0].numpy(), px, rtol=0, atol=1e-6)
    # unproject: the same points, from the distorted pixels and their depths
    back = cam.unproject(torch.tensor(px)[None], torch.tensor(depth)[None])
    np.testing.assert_allclose(back[0].numpy(), pts, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", ["radtan", "fisheye"])
def test_float32_is_float64_rounded(name):
    cam64, (W, H) = cameras()[name]
    cam32, _ = cameras(torch.float32)[name]
    px = torch.tensor(image_pixels(W, H, step=64))[None]
    u64, ok64 = G.undistort_points(px, cam64)
    u32, ok32 = G.undistort_points(px.float(), cam32)
    assert torch.equal(ok64, ok32)
    torch.testing.assert_close(u32.double(), u64, rtol=2e-6, atol=2e-4)  # float32 K and pixels: their rounding
    pts = torch.cat([u64 - torch.tensor([TUM_K[0][2], TUM_K[1][2]]), torch.full_like(u64[..., :1], 400.0)], -1)
    p64, _ = cam64.project(pts)
    p32, _ = cam32.project(pts.float())
    torch.testing.assert_close(p32.double(), p64, rtol=2e-6, atol=2e-4)


def _points(n, seed, spread=0.6):
    g = torch.Generator().manual_seed(seed)
    xy = (torch.rand(n, 2, generator=g, dtype=f64) * 2 - 1) * spread
    z = torch.rand(n, 1, generator=g, dtype=f64) + 0.5
    return torch.cat([xy * z, z], -1)


@pytest.mark.parametrize("model", ["radtan", "fisheye"])
def test_gradcheck_every_parameter(model):
    """float64 gradcheck of project, unproject (the implicit-function gradient), distort and
    undistort for points, pixels, depth, K (fx, fy, cx, cy, skew) and every coefficient."""
    cls, D = (G.RadTanCamera, TUM_D) if model == "radtan" else (G.FisheyeCamera, VI_D)
    K0 = torch.tensor([[300.0, 0.7, 40.0], [0.0, 310.0, 30.0], [0.0, 0.0, 1.0]], dtype=f64)
    D0 = torch.tensor(D, dtype=f64) * (3.0 if model == "fisheye" else 1.0)
    pts = _points(6, 1)
    pts[0, :2] = 0.0  # on the optical axis (the fisheye's r = 0 series)
    pts[1, :2] = 1e-7
    pts = pts[None]
    px = (pts[..., :2] / pts[..., 2:]) * 280 + torch.tensor([40.0, 30.0], dtype=f64)
    depth = pts[..., 2].clone()

    def project(p, K, d):
        return cls(K, d).project(p)[0]

    def unproject(x, dep, K, d):
        return cls(K, d).unproject(x, dep)

    def undistort(x, K, d):
        return G.undistort_points(x, cls(K, d))[0]

    def distort(x, K, d):
        return G.distort_points(x, cls(K, d))[0]

    req = [t.clone().requires_grad_() for t in (pts, px, depth, K0, D0)]
    pts_, px_, dep_, K_, D_ = req
    assert gradcheck(project, (pts_, K_, D_))
    assert gradcheck(unproject, (px_, dep_, K_, D_))
    assert gradcheck(undistort, (px_, K_, D_))
    assert gradcheck(distort, (px_, K_, D_))
    # every coefficient and intrinsic gets a non-zero gradient (none is silently ignored)
    for fn, args in ((project, (pts_, K_, D_)), (unproject, (px_, dep_, K_, D_))):
        grads = torch.autograd.grad(fn(*args).square().sum(), (K_, D_))
        assert (grads[1] != 0).all(), grads[1]
        assert (grads[0][:2] != 0).sum() == 5, grads[0]  # fx, s, cx, fy, cy


def test_ift_gradient_is_the_inverse_jacobian():
    """d undistort / d pixel is the inverse of d distort / d pixel at the solution."""
    cam, (W, H) = cameras()["radtan"]
    px = torch.tensor([[[3.0, 5.0], [600.0, 470.0], [320.0, 240.0]]], dtype=f64)
    und = G.undistort_points(px, cam)[0]
    J_und = torch.autograd.functional.jacobian(lambda x: G.undistort_points(x, cam)[0], px)
    J_dis = torch.autograd.functional.jacobian(lambda x: G.distort_points(x, cam)[0], und)
    for i in range(3):
        torch.testing.assert_close(J_und[0, i, :, 0, i] @ J_dis[0, i, :, 0, i], torch.eye(2, dtype=f64))


def test_depth_to_points_with_a_camera():
    B, H, W = 2, 6, 8
    K = torch.tensor([[9.0, 0.0, 3.5], [0.0, 9.5, 2.5], [0.0, 0.0, 1.0]], dtype=f64)
    d = torch.tensor(TUM_D, dtype=f64)
    depth = torch.rand(B, 1, H, W, dtype=f64) + 0.5
    cam = G.RadTanCamera(K, d)
    pts = G.depth_to_points(depth, cam)
    ys, xs = torch.meshgrid(torch.arange(H, dtype=f64), torch.arange(W, dtype=f64), indexing="ij")
    px = torch.stack([xs, ys], -1).expand(B, H, W, 2)
    torch.testing.assert_close(pts, cam.unproject(px, depth[:, 0]))
    back, ok = cam.project(pts)
    assert ok.all()
    torch.testing.assert_close(back, px, rtol=0, atol=1e-9)
    assert gradcheck(
        lambda dep, K_, d_: G.depth_to_points(dep, G.RadTanCamera(K_, d_)),
        (depth[:, :, :3, :3].clone().requires_grad_(), K.clone().requires_grad_(), d.clone().requires_grad_()),
    )


def test_pinhole_camera_is_bitwise_k(dtype):
    B, H, W = 2, 5, 7
    K = torch.tensor([[8.0, 0.3, 3.0], [0.0, 8.5, 2.0], [0.0, 0.0, 1.0]], dtype=dtype)
    pts = torch.randn(B, 4, 3, dtype=dtype)
    pts[0, 0, 2] = float("nan")
    pts[1, 1, 2] = -1.0
    cam = G.PinholeCamera(K)
    assert torch.equal(G.project_points(pts, cam).nan_to_num(7.0), G.project_points(pts, K).nan_to_num(7.0))
    depth = torch.rand(B, 1, H, W, dtype=dtype) + 0.5
    assert torch.equal(G.depth_to_points(depth, cam), G.depth_to_points(depth, K))
    ys, xs = torch.meshgrid(torch.arange(H, dtype=dtype), torch.arange(W, dtype=dtype), indexing="ij")
    px = torch.stack([xs, ys], -1).expand(B, H, W, 2)
    assert torch.equal(cam.unproject(px, depth[:, 0]), G.depth_to_points(depth, K))
    good = pts[..., 2] > 1e-3
    pix, valid = cam.project(pts)
    assert torch.equal(valid, good) and torch.equal(pix[good], G.project_points(pts, K)[good])
    und, ok = G.undistort_points(px, cam)
    assert ok.all() and torch.equal(und, px) and torch.equal(G.distort_points(px, cam)[0], px)
    # gradients: the same as K's
    Kc = K.double().clone().requires_grad_()
    Kd = K.double().clone().requires_grad_()
    p = pts.double().abs() + 0.5
    G.project_points(p, G.PinholeCamera(Kc)).sum().backward()
    G.project_points(p, Kd).sum().backward()
    assert torch.equal(Kc.grad, Kd.grad)


def test_out_of_domain_is_finite_invalid_and_has_zero_gradient():
    K = torch.tensor([[200.0, 0.0, 100.0], [0.0, 200.0, 80.0], [0.0, 0.0, 1.0]], dtype=f64)
    # radial-tangential with k1 = -0.5: r (1 - 0.5 r^2) stops increasing at r^2 = 2/3
    rt = torch.tensor([-0.5, 0.0, 0.001, 0.001, 0.0], dtype=f64, requires_grad=True)
    # fisheye with k1 = -0.3: theta (1 - 0.3 theta^2) stops increasing at theta^2 = 1/0.9
    fe = torch.tensor([-0.3, 0.0, 0.0, 0.0], dtype=f64, requires_grad=True)
    assert lens.domain_limit(lens.RADTAN, rt.tolist()) == pytest.approx(2 / 3)
    assert lens.domain_limit(lens.FISHEYE, fe.tolist()) == pytest.approx(math.tan(math.sqrt(1 / 0.9)) ** 2)
    theta_max = math.sqrt(1 / 0.9)
    cases = {
        "radtan": (G.RadTanCamera, rt, [[0.5, 0.0, 1.0], [0.7, 0.7, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]),
        "fisheye": (
            G.FisheyeCamera,
            fe,
            [
                [math.tan(theta_max - 0.05), 0.0, 1.0],  # inside
                [math.tan(theta_max + 0.05), 0.0, 1.0],  # beyond the monotonic angle
                [0.3, 0.2, -1.0],  # behind the camera (beyond 90 degrees off axis)
                [1.0, 0.0, 0.0],  # at z = 0
                [float("nan"), 0.0, 1.0],
                [0.0, 0.0, float("inf")],
            ],
        ),
    }
    for name, (cls, d, pts) in cases.items():
        Kg = K.clone().requires_grad_()
        p = torch.tensor([pts], dtype=f64, requires_grad=True)
        pix, valid = cls(Kg, d).project(p)
        assert valid[0, 0] and not valid[0, 1:].any(), name
        assert torch.isfinite(pix).all(), (name, pix)
        pix[:, 1:].sum().backward()
        assert torch.isfinite(p.grad).all() and (p.grad == 0).all(), name
        assert (Kg.grad == 0).all() and (d.grad == 0).all(), name
        d.grad = None
    # undistortion of pixels beyond the largest distorted radius: no solution in the domain
    cam = G.FisheyeCamera(K, fe)
    r_max = theta_max * (1 - 0.3 * theta_max**2)  # the largest distorted radius, normalized
    px = torch.tensor([[[100.0 + 200 * (r_max - 0.02), 80.0], [100.0 + 200 * (r_max + 0.05), 80.0]]], dtype=f64)
    px.requires_grad_()
    und, ok = G.undistort_points(px, cam)
    assert ok.tolist() == [[True, False]] and torch.isfinite(und).all()
    und[0, 1].sum().backward()
    assert (px.grad == 0).all() and (fe.grad == 0).all()
    # distort_points of an ideal pixel whose ray is beyond the domain: itself, no gradient to anything
    Kg = K.clone().requires_grad_()
    fe.grad = None
    ideal = torch.tensor([[[100.0 + 200 * math.tan(theta_max + 0.05), 80.0]]], dtype=f64, requires_grad=True)
    out, ok = G.distort_points(ideal, G.FisheyeCamera(Kg, fe))
    assert not ok.any() and torch.equal(out, ideal.detach())
    out.sum().backward()
    assert (ideal.grad == 0).all() and (Kg.grad == 0).all() and (fe.grad == 0).all()
    pts = cam.unproject(px.detach(), torch.ones(1, 2, dtype=f64))
    assert torch.isfinite(pts).all()
    # the largest radius inside is reached: the valid projection of the first pixel's point goes back
    torch.testing.assert_close(cam.project(pts[:, :1])[0], px.detach()[:, :1])


def test_undistort_image():
    K = torch.tensor([[40.0, 0.0, 15.5], [0.0, 40.0, 11.5], [0.0, 0.0, 1.0]], dtype=f64)
    d = torch.tensor([0.1, -0.05, 0.001, -0.002, 0.01], dtype=f64)
    cam = G.RadTanCamera(K, d)
    B, C, H, W = 2, 3, 24, 32
    image = torch.rand(B, C, H, W, dtype=f64)
    out, valid = G.undistort_image(image, cam)
    assert out.shape == image.shape and valid.shape == (B, 1, H, W) and valid.any() and not valid.all()
    ys, xs = torch.meshgrid(torch.arange(H, dtype=f64), torch.arange(W, dtype=f64), indexing="ij")
    src, ok = G.distort_points(torch.stack([xs, ys], -1).expand(B, H, W, 2), cam)
    grid = src / torch.tensor([(W - 1) / 2, (H - 1) / 2], dtype=f64) - 1
    ref = torch.nn.functional.grid_sample(image, grid, align_corners=True)
    torch.testing.assert_close(out, ref)
    # an identity camera (no distortion) gives the image back
    same, ok = G.undistort_image(image, G.RadTanCamera(K, torch.zeros(5, dtype=f64)))
    assert ok.all() and torch.allclose(same, image)
    small = image[:1, :1, :6, :8].clone().requires_grad_()
    Ks = torch.tensor([[10.0, 0.0, 3.5], [0.0, 10.0, 2.5], [0.0, 0.0, 1.0]], dtype=f64, requires_grad=True)
    ds = d.clone().requires_grad_()
    assert gradcheck(lambda im, K_, d_: G.undistort_image(im, G.RadTanCamera(K_, d_))[0], (small, Ks, ds))


def test_batched_cameras():
    Kb = torch.tensor(TUM_K, dtype=f64).expand(2, 3, 3).clone()
    Kb[1, 0, 0] = 400.0
    db = torch.tensor(TUM_D, dtype=f64).expand(2, 5).clone()
    db[1] = db[1] * 0.5
    pts = _points(5, 2).expand(2, 5, 3)
    pix, _ = G.RadTanCamera(Kb, db).project(pts)
    for b in range(2):
        torch.testing.assert_close(pix[b], G.RadTanCamera(Kb[b], db[b]).project(pts[b : b + 1])[0][0])


def test_bad_inputs_raise_clear_errors():
    K = torch.tensor(TUM_K, dtype=f64)
    d = torch.tensor(TUM_D, dtype=f64)
    with pytest.raises(ValueError, match=r"RadTanCamera: argument 'dist' must have shape \(5\), got \(4,\)"):
        G.RadTanCamera(K, d[:4])
    with pytest.raises(ValueError, match=r"FisheyeCamera: argument 'dist'"):
        G.FisheyeCamera(K, d)
    with pytest.raises(TypeError, match=r"RadTanCamera: argument 'dist' must be a torch.Tensor"):
        G.RadTanCamera(K, list(TUM_D))
    with pytest.raises(TypeError, match=r"RadTanCamera: argument 'dist' has dtype torch.float32"):
        G.RadTanCamera(K, d.float())
    with pytest.raises(ValueError, match=r"RadTanCamera: argument 'dist' has B=3"):
        G.RadTanCamera(K.expand(2, 3, 3), d.expand(3, 5))
    with pytest.raises(ValueError, match=r"PinholeCamera: argument 'K' must have shape"):
        G.PinholeCamera(K[:2])
    cam = G.RadTanCamera(K, d)
    with pytest.raises(TypeError, match=r"gvnn_warp.project_points: argument 'K' must be a \(3, 3\) or \(B, 3, 3\) "
                       r"torch.Tensor or a camera"):
        G.project_points(torch.ones(1, 2, 3, dtype=f64), "K")
    with pytest.raises(TypeError, match=r"project_points: argument 'K.K' has dtype torch.float64 but 'points'"):
        G.project_points(torch.ones(1, 2, 3), cam)
    with pytest.raises(ValueError, match=r"depth_to_points: argument 'K.K' has B=2 .* but 'depth' has B=1"):
        G.depth_to_points(torch.ones(1, 1, 2, 2, dtype=f64), G.RadTanCamera(K.expand(2, 3, 3), d))
    with pytest.raises(TypeError, match=r"undistort_points: argument 'camera' must be a camera"):
        G.undistort_points(torch.ones(1, 2, 2, dtype=f64), K)
    with pytest.raises(ValueError, match=r"unproject_points: argument 'depth' must have shape \(1, 2\)"):
        G.unproject_points(torch.ones(1, 2, 2, dtype=f64), torch.ones(1, 3, dtype=f64), cam)
    with pytest.raises(ValueError, match=r"RadTanCamera.project: argument 'points' must have shape"):
        cam.project(torch.ones(2, 2, dtype=f64))
    with pytest.raises(ValueError, match=r"undistort_image: argument 'image' must have shape"):
        G.undistort_image(torch.ones(2, 2, dtype=f64), cam)
    with pytest.raises(ValueError, match=r"kernels.lens.pack_dist: model 1 takes 5 coefficients"):
        lens.pack_dist(lens.RADTAN, [0.1])


def test_lens_funcs_in_a_users_own_kernel_under_tape():
    """The pure-Warp contract: a user's kernel calling kernels.geometry.lens.project, differentiated by
    wp.Tape, gives the torch op's values and gradients."""
    import warp as wp
    from gvnn_warp.kernels.core.kinds import vec8d

    @wp.kernel
    def user_project(points: wp.array(dtype=wp.vec3d), K: wp.array(dtype=wp.mat33d), dist: wp.array(dtype=vec8d),
                     model: int, out: wp.array(dtype=wp.vec2d)):
        i = wp.tid()
        uv, ok = lens.project(model, K[0], dist[0], points[i], wp.float64(1e-3))
        out[i] = wp.where(ok, uv, wp.vec2d())

    K = torch.tensor(TUM_K, dtype=f64)
    d = torch.tensor(TUM_D, dtype=f64)
    pts = _points(7, 3)
    P = wp.array(pts.numpy(), dtype=wp.vec3d, requires_grad=True)
    Ka = wp.array(K.numpy()[None], dtype=wp.mat33d, requires_grad=True)
    Da = wp.array(lens.pack_dist(lens.RADTAN, TUM_D)[None], dtype=vec8d, requires_grad=True)
    out = wp.zeros(7, dtype=wp.vec2d, requires_grad=True)
    tape = wp.Tape()
    with tape:
        wp.launch(user_project, 7, [P, Ka, Da, lens.RADTAN], [out])
    tape.backward(grads={out: wp.array(np.ones((7, 2)), dtype=wp.vec2d)})
    Kt, dt, pt = K.clone().requires_grad_(), d.clone().requires_grad_(), pts[None].clone().requires_grad_()
    ref, ok = G.RadTanCamera(Kt, dt).project(pt)
    assert ok.all()
    (ref * ok[..., None]).sum().backward()
    np.testing.assert_allclose(out.numpy(), ref[0].detach().numpy(), rtol=0, atol=1e-9)
    np.testing.assert_allclose(P.grad.numpy(), pt.grad[0].numpy(), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(Ka.grad.numpy()[0], Kt.grad.numpy(), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(Da.grad.numpy()[0, :5], dt.grad.numpy(), rtol=1e-12, atol=1e-9)


def test_fisheye_atan_ratio_is_float64_accurate():
    """kernels.lens._atan_ratio (the fisheye's atan(r) / r as a polynomial in r^2, no atan) against
    40-digit arithmetic: the value within 2 float64 ulps over [0, 1] (the polynomial) and beyond
    (the reciprocal identity, up to a 190-degree lens' r^2 and far past it), its derivative to 1e-13."""
    import warp as wp

    mpmath = pytest.importorskip("mpmath")
    mpmath.mp.dps = 40

    @wp.kernel
    def ratio(z: wp.array(dtype=wp.float64), c: wp.array(dtype=wp.float64), dc: wp.array(dtype=wp.float64),
              cv: wp.array(dtype=wp.float64)):
        i = wp.tid()
        a, b = lens._atan_ratio(z[i])
        c[i] = a
        dc[i] = b
        cv[i] = lens._atan_ratio_value(z[i])

    rng = np.random.default_rng(4)
    z = np.r_[0.0, 1e-300, 1e-12, 1e-6, np.linspace(0, 1, 801), np.nextafter(1.0, 2.0), rng.uniform(0, 1, 400),
              np.exp(rng.uniform(0, 12, 200)), 1e20]
    out = [wp.zeros(len(z), dtype=wp.float64) for _ in range(3)]
    wp.launch(ratio, len(z), [wp.array(z, dtype=wp.float64)], out)
    c, dc, cv = (o.numpy() for o in out)

    def ref(zi):
        zi = mpmath.mpf(zi)
        if zi < 1e-10:  # the series (the closed-form derivative cancels even in 40 digits)
            return 1 - zi / 3 + zi * zi / 5, mpmath.mpf(-1) / 3 + 2 * zi / 5
        r = mpmath.sqrt(zi)
        v = mpmath.atan(r) / r
        return v, (1 / (1 + zi) - v) / (2 * zi)

    rc, rdc = (np.array([float(v) for v in col]) for col in zip(*(ref(zi) for zi in z)))
    np.testing.assert_array_equal(c, cv)
    assert np.max(np.abs(c - rc) / (rc * np.finfo(np.float64).eps)) <= 2.0
    np.testing.assert_allclose(dc, rdc, rtol=1e-13, atol=0)
