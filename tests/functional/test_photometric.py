"""The fused photometric objective: normal equations and error against independent torch
references (grid_sample, torch autograd), gradients by float64 gradcheck, determinism, bad input."""

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F
import warp as wp
from gvnn_warp.kernels.core import compat as _compat
from gvnn_warp.kernels.core import launch
from gvnn_warp.kernels.core.launch import mat34d, mat34f
from gvnn_warp.kernels.photometric import pipeline as pp
from processes import run_python
from refs import intrinsics, skew

MIN_DEPTH = 1e-3
TOL = 1e-3  # the inside tolerance of the valid rule, pixels


# ----------------------------------------------------------------------------- scenes


def smooth_image(B, C, H, W, seed, dtype=torch.float64):
    """Smooth random intensities in about [0, 1] (a few low-frequency waves per channel)."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.arange(H, dtype=dtype), torch.arange(W, dtype=dtype), indexing="ij")
    out = torch.zeros(B, C, H, W, dtype=dtype)
    for _ in range(3):
        a, fx, fy, ph = torch.rand(4, B, C, 1, 1, generator=g, dtype=dtype)
        out = out + (0.3 * a) * torch.sin(xx * (0.2 + 0.6 * fx) + yy * (0.15 + 0.5 * fy) + 6 * ph)
    return 0.5 + out


def scene(B=2, C=2, H=9, W=11, seed=0, angle=0.04, shift=0.05, dtype=torch.float64, holes=True):
    """Reference and live images, reference depth (with invalid values), live depth, a pose that
    moves some pixels outside, K: all torch float64 (or dtype)."""
    g = torch.Generator().manual_seed(seed)
    ref = smooth_image(B, C, H, W, seed, dtype)
    live = smooth_image(B, C, H, W, seed + 1, dtype)
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, H, dtype=dtype), torch.linspace(-1, 1, W, dtype=dtype),
                            indexing="ij")
    depth = (2.0 + 0.3 * xx + 0.2 * torch.sin(2 * yy) + 0.05 * torch.rand(B, 1, H, W, generator=g, dtype=dtype))
    live_depth = (2.1 - 0.2 * xx + 0.1 * torch.cos(3 * yy) + 0.05 * torch.rand(B, 1, H, W, generator=g, dtype=dtype))
    if holes:
        depth[0, 0, 0, 0] = 0.0
        depth[0, 0, 1, 2] = -1.0
        depth[-1, 0, 2, 3] = float("nan")
        depth[-1, 0, 3, 1] = float("inf")
        depth[0, 0, 2, 2] = 5e-4  # below MIN_DEPTH
        live_depth[0, 0, 4, 5] = 0.0
        live_depth[-1, 0, 1, 1] = float("nan")
    omega = torch.randn(B, 3, generator=g, dtype=dtype) * angle
    t = torch.randn(B, 3, generator=g, dtype=dtype) * shift
    R = torch.linalg.matrix_exp(skew(omega))
    pose = torch.cat([R, t[:, :, None]], dim=2)
    K = intrinsics(W, H, dtype)
    return ref, depth, live, pose, K, live_depth


def to_wp(ref, depth, live, pose, K, live_depth=None):
    ft = wp.float64 if ref.dtype == torch.float64 else wp.float32
    m34 = mat34d if ft == wp.float64 else mat34f
    m33 = wp.mat33d if ft == wp.float64 else wp.mat33f
    B = ref.shape[0]
    Kb = K.expand(B, 3, 3) if K.dim() == 2 else K
    arrays = [
        wp.array(ref.numpy(), dtype=ft),
        wp.array(depth.numpy(), dtype=ft),
        wp.array(live.numpy(), dtype=ft),
        wp.array(pose.numpy(), dtype=m34),
        wp.array(Kb.contiguous().numpy(), dtype=m33),
    ]
    return arrays, (wp.array(live_depth.numpy(), dtype=ft) if live_depth is not None else None)


# ----------------------------------------------------------------------------- torch reference


def weight_ref(r, kind, c):
    """IRLS weights psi(r)/r, closed forms (1 at r = 0)."""
    u2 = (r / c) ** 2
    if kind == "l2":
        return torch.ones_like(r)
    if kind == "huber":
        return torch.where(r.abs() <= c, torch.ones_like(r), c / r.abs())
    if kind == "cauchy":
        return 1 / (1 + u2)
    if kind == "geman_mcclure":
        return 1 / (1 + u2) ** 2
    if kind == "tukey":
        return torch.where(r.abs() <= c, (1 - u2) ** 2, torch.zeros_like(r))
    raise AssertionError(kind)


def rho_ref(r, kind, c):
    """Penalties, closed forms (the gvnn paper's table)."""
    u2 = (r / c) ** 2
    if kind == "l1":
        return r.abs()
    if kind == "l2":
        return r * r / 2
    if kind == "huber":
        return torch.where(r.abs() <= c, r * r / 2, c * (r.abs() - c / 2))
    if kind == "cauchy":
        return c * c / 2 * torch.log1p(u2)
    if kind == "geman_mcclure":
        return r * r / 2 / (1 + u2)
    if kind == "tukey":
        return torch.where(r.abs() <= c, c * c / 6 * (1 - (1 - u2) ** 3), torch.full_like(r, c * c / 6))
    raise AssertionError(kind)


def moved_points(depth, pose, K, delta=None):
    """Reference pixels moved into the live camera: (B, H, W, 3); with ``delta`` (B, 6) the
    first-order perturbation exp(delta) ~ I + [omega]x, t (same derivative at delta = 0)."""
    B, _, H, W = depth.shape
    dtype = depth.dtype
    yy, xx = torch.meshgrid(torch.arange(H, dtype=dtype), torch.arange(W, dtype=dtype), indexing="ij")
    fx, s, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    ry = (yy - cy) / fy
    rx = (xx - cx - s * ry) / fx
    ray = torch.stack([rx, ry, torch.ones_like(rx)], -1)  # (H, W, 3)
    d = torch.where(torch.isfinite(depth) & (depth > MIN_DEPTH), depth, torch.ones_like(depth))[:, 0, :, :, None]
    X = d * ray
    P = torch.einsum("bij,bhwj->bhwi", pose[:, :, :3], X) + pose[:, None, None, :, 3]
    if delta is not None:
        omega, t = delta[:, None, None, :3], delta[:, None, None, 3:]
        P = P + torch.cross(omega.expand_as(P), P, dim=-1) + t
    return P


def project(P, K):
    fx, s, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    Z = P[..., 2]
    return fx * P[..., 0] / Z + s * P[..., 1] / Z + cx, fy * P[..., 1] / Z + cy


def sample(image, u, v):
    """Bilinear samples of image (B, C, H, W) at pixel positions u, v (B, H', W'), zeros padding."""
    H, W = image.shape[-2:]
    grid = torch.stack([2 * u / (W - 1) - 1, 2 * v / (H - 1) - 1], -1)
    return F.grid_sample(image, grid, mode="bilinear", padding_mode="zeros", align_corners=True)


def valid_ref(depth, pose, K, min_depth=MIN_DEPTH):
    """The valid rule of docs/conventions.md: (B, H, W) bool."""
    H, W = depth.shape[-2:]
    P = moved_points(depth, pose, K)
    u, v = project(P, K)
    d = depth[:, 0]
    ok = torch.isfinite(d) & (d > min_depth) & (P[..., 2] > min_depth)
    return ok & (u >= -TOL) & (u <= W - 1 + TOL) & (v >= -TOL) & (v <= H - 1 + TOL)


def depth_taps_valid(live_depth, u, v, min_depth=MIN_DEPTH):
    """All four bilinear taps of live_depth at (u, v) inside the image and valid depths."""
    B, _, H, W = live_depth.shape
    x0, y0 = torch.floor(u).long(), torch.floor(v).long()
    ok = torch.ones_like(u, dtype=torch.bool)
    for dx in (0, 1):
        for dy in (0, 1):
            x, y = x0 + dx, y0 + dy
            inside = (x >= 0) & (x < W) & (y >= 0) & (y < H)
            idx = (y.clamp(0, H - 1) * W + x.clamp(0, W - 1)).reshape(B, -1)
            val = torch.gather(live_depth.reshape(B, -1), 1, idx).reshape(u.shape)
            ok = ok & inside & torch.isfinite(val) & (val > min_depth)
    return ok


def normal_equations_ref(ref, depth, live, pose, K, kind, c, live_depth=None, depth_weight=0.0):
    """JtWJ, JtWr, cost, count from torch autograd's Jacobian of the residuals (float64)."""
    B, C, H, W = ref.shape
    valid = valid_ref(depth, pose, K)
    with torch.no_grad():
        P0 = moved_points(depth, pose, K)
        u0, v0 = project(P0, K)
        dvalid = valid & depth_taps_valid(live_depth, u0, v0) if live_depth is not None else None
    sw = math.sqrt(depth_weight)
    # 0 for NaN: masked out anyway, and reverse mode would spread 0 * NaN over every pixel
    live_depth_finite = live_depth.nan_to_num(0.0, 0.0, 0.0) if live_depth is not None else None

    def residuals(delta):
        P = moved_points(depth, pose, K, delta)
        u, v = project(P, K)
        r = sample(live, u, v) - ref  # (B, C, H, W)
        out = [r.reshape(B, -1)]
        if live_depth is not None:
            rd = sw * (P[..., 2] - sample(live_depth_finite, u, v)[:, 0])
            out.append(rd.reshape(B, -1))
        return torch.cat(out, 1)

    delta0 = torch.zeros(B, 6, dtype=torch.float64)
    r = residuals(delta0).detach()
    J = torch.autograd.functional.jacobian(residuals, delta0)  # (B, n, B, 6)
    J = torch.stack([J[b, :, b] for b in range(B)])  # (B, n, 6)
    mask = [valid[:, None].expand(B, C, H, W).reshape(B, -1)]
    if live_depth is not None:
        mask.append(dvalid.reshape(B, -1))
    mask = torch.cat(mask, 1)
    rm = torch.where(mask, r, torch.zeros_like(r))
    w = torch.where(mask, weight_ref(rm, kind, c), torch.zeros_like(r))
    Jm = torch.where(mask[..., None], J, torch.zeros_like(J))
    JtWJ = torch.einsum("bn,bni,bnj->bij", w, Jm, Jm)
    JtWr = torch.einsum("bn,bni,bn->bi", w, Jm, rm)
    cost = torch.where(mask, rho_ref(rm, kind, c), torch.zeros_like(r)).sum(1)
    return JtWJ, JtWr, cost, valid.reshape(B, -1).sum(1).to(torch.float64)


def assert_close_rel(got, want, rtol):
    got = np.asarray(got, dtype=np.float64)
    want = want.detach().numpy()
    scale = max(np.abs(want).max(), 1e-300)
    assert np.abs(got - want).max() <= rtol * scale, (np.abs(got - want).max() / scale, got, want)


# ----------------------------------------------------------------------------- normal equations (pure Warp)


@pytest.mark.parametrize("kind, c", [("huber", 0.1), ("l2", 1.0), ("cauchy", 0.2), ("geman_mcclure", 0.3),
                                     ("tukey", 0.4)])
def test_normal_equations_match_autograd_jacobian(kind, c):
    ref, depth, live, pose, K, _ = scene()
    want = normal_equations_ref(ref, depth, live, pose, K, kind, c)
    assert 0 < want[3].min() and want[3].max() < 99  # some pixels are skipped, some used
    arrays, _ = to_wp(ref, depth, live, pose, K)
    got = pp.photometric_normal_equations(*arrays, robust=kind, scale=c)
    for g, w in zip(got.numpy(), want):
        assert_close_rel(g, w, 1e-9)
    assert np.array_equal(got.count.numpy(), want[3].numpy())


@pytest.mark.parametrize("kind, c", [("huber", 0.1), ("l2", 1.0), ("tukey", 0.5)])
def test_normal_equations_depth_term(kind, c):
    ref, depth, live, pose, K, live_depth = scene(seed=3)
    lam = 2.5
    want = normal_equations_ref(ref, depth, live, pose, K, kind, c, live_depth, lam)
    arrays, ld = to_wp(ref, depth, live, pose, K, live_depth)
    got = pp.photometric_normal_equations(*arrays, robust=kind, scale=c, live_depth=ld, depth_weight=lam)
    for g, w in zip(got.numpy(), want):
        assert_close_rel(g, w, 1e-9)
    # the depth term changes the system; without it (weight 0) it is the photometric one alone
    photo = normal_equations_ref(ref, depth, live, pose, K, kind, c)
    assert not np.allclose(got.JtWJ.numpy(), photo[0].numpy())
    got0 = pp.photometric_normal_equations(*arrays, robust=kind, scale=c, live_depth=ld, depth_weight=0.0)
    for g, w in zip(got0.numpy(), photo):
        assert_close_rel(g, w, 1e-9)


def test_normal_equations_float32_close_to_float64():
    ref, depth, live, pose, K, live_depth = scene(seed=5, holes=False)
    want = normal_equations_ref(ref, depth, live, pose, K, "huber", 0.1, live_depth, 1.0)
    arrays, ld = to_wp(*(t.float() for t in (ref, depth, live, pose, K, live_depth)))
    got = pp.photometric_normal_equations(*arrays, robust="huber", scale=0.1, live_depth=ld, depth_weight=1.0)
    assert got.JtWJ.dtype == wp.float32
    for g, w in zip(got.numpy(), want):
        assert_close_rel(g, w, 1e-4)


def test_normal_equations_out_reuses_buffers_and_follows_inputs():
    ref, depth, live, pose, K, _ = scene(seed=7)
    arrays, _ = to_wp(ref, depth, live, pose, K)
    first = pp.photometric_normal_equations(*arrays, robust="huber", scale=0.1)
    H0 = first.JtWJ.numpy().copy()
    again = pp.photometric_normal_equations(*arrays, robust="huber", scale=0.1, out=first)
    assert again is first and np.array_equal(again.JtWJ.numpy(), H0)
    # the pose array updated in place: the recorded launches read the new values
    pose2 = pose.clone()
    pose2[:, :, 3] += 0.01
    arrays[3].assign(wp.array(pose2.numpy(), dtype=mat34d))
    got = pp.photometric_normal_equations(*arrays, robust="huber", scale=0.1, out=first)
    want = normal_equations_ref(ref, depth, live, pose2, K, "huber", 0.1)
    for g, w in zip(got.numpy(), want):
        assert_close_rel(g, w, 1e-9)
    # another scale, other arrays: recomputed
    got = pp.photometric_normal_equations(*to_wp(ref, depth, live, pose, K)[0], robust="l2", out=first)
    want = normal_equations_ref(ref, depth, live, pose, K, "l2", 1.0)
    for g, w in zip(got.numpy(), want):
        assert_close_rel(g, w, 1e-9)


@pytest.mark.parametrize("B, H, W", [(0, 4, 5), (1, 0, 5), (2, 4, 0)])
def test_normal_equations_pure_warp_of_no_pixels(B, H, W):
    # nothing to sum: zeros of the right shapes (the reduction still writes them: NaN-filled
    # buffers passed as out= come back zero), also where the row kernel has no rows (H = 0)
    pose, K = scene(B=max(B, 1), C=1, seed=8)[3:5]
    img = wp.zeros((B, 1, H, W), dtype=wp.float64)
    dep = wp.zeros((B, 1, H, W), dtype=wp.float64)
    pose_a = wp.array(pose.numpy()[:B], dtype=mat34d)
    K_a = wp.array(np.broadcast_to(K.numpy(), (B, 3, 3)).copy(), dtype=wp.mat33d)
    first = pp.photometric_normal_equations(img, dep, img, pose_a, K_a)
    for a in first:
        a.fill_(float("nan"))
    got = pp.photometric_normal_equations(img, dep, img, pose_a, K_a, out=first)
    shapes = [(B, 6, 6), (B, 6), (B,), (B,)]
    for a, shape in zip(got.numpy(), shapes):
        assert a.shape == shape and not np.any(a)


def test_normal_equations_deterministic_across_threads():
    # large enough for the rows to be split into several chunks
    ref, depth, live, pose, K, live_depth = scene(B=1, C=1, H=60, W=900, seed=11, holes=True)
    arrays, ld = to_wp(ref, depth, live, pose, K, live_depth)
    results = []
    try:
        for n in (1, 2, 3):
            launch.set_num_threads(n)
            got = pp.photometric_normal_equations(*arrays, live_depth=ld, depth_weight=1.0, scale=0.1)
            results.append([a.copy() for a in got.numpy()])
    finally:
        launch.set_num_threads(None)
    for other in results[1:]:
        for a, b in zip(results[0], other):
            assert np.array_equal(a, b)
    # batch items are independent: B=3 equals three B=1 calls, bitwise
    ref, depth, live, pose, K, live_depth = scene(B=3, C=3, H=8, W=10, seed=12)
    arrays, ld = to_wp(ref, depth, live, pose, K, live_depth)
    whole = pp.photometric_normal_equations(*arrays, live_depth=ld, depth_weight=0.5).numpy()
    for b in range(3):
        one, ldb = to_wp(ref[b:b + 1], depth[b:b + 1], live[b:b + 1], pose[b:b + 1], K, live_depth[b:b + 1])
        part = pp.photometric_normal_equations(*one, live_depth=ldb, depth_weight=0.5).numpy()
        for a, p in zip(whole, part):
            assert np.array_equal(a[b], p[0])


def test_normal_equations_skip_invalid_and_stay_finite():
    ref, depth, live, pose, K, live_depth = scene(seed=13)
    B, C, H, W = ref.shape
    depth[0] = float("nan")  # batch item 0: no valid depth at all
    depth[1, 0, :, : W // 2] = -2.0
    pose[1, 2, 3] = -3.0  # batch item 1: everything behind the camera but a few
    live = live.clone()
    live[1, 0, 0, 0] = float("nan")  # a non-finite intensity: its residuals are skipped
    arrays, ld = to_wp(ref, depth, live, pose, K, live_depth)
    got = pp.photometric_normal_equations(*arrays, live_depth=ld, depth_weight=1.0)
    for a in got.numpy():
        assert np.isfinite(a).all()
    assert got.count.numpy()[0] == 0 and np.all(got.JtWJ.numpy()[0] == 0) and got.cost.numpy()[0] == 0
    want = normal_equations_ref(ref, depth, live.nan_to_num(0.5), pose, K, "huber", 1.0, live_depth, 1.0)
    assert got.count.numpy()[1] == want[3][1]


def test_normal_equations_bad_arguments():
    ref, depth, live, pose, K, live_depth = scene(B=1, C=2, H=4, W=5, holes=False)
    arrays, ld = to_wp(ref, depth, live, pose, K, live_depth)
    f32, _ = to_wp(*(t.float() for t in (ref, depth, live, pose, K)))
    fn = r"gvnn_warp\.kernels\.photometric_normal_equations: argument "
    cases = [
        ((arrays[0], arrays[1], f32[2], *arrays[3:]), {}, TypeError, "'live_image' must be of dtype float64"),
        ((arrays[0], arrays[0], *arrays[2:]), {}, ValueError, r"'ref_depth' must be of shape \(1, 1, 4, 5\)"),
        ((*arrays[:3], f32[3], arrays[4]), {}, TypeError, "'pose' must be an array of 3x4 float64 matrices"),
        (arrays, {"robust": "l1"}, ValueError, r"'robust' must be one of \['l2', 'huber'"),
        (arrays, {"robust": "welsch"}, ValueError, "'robust' must be one of"),
        (arrays, {"scale": 0.0}, ValueError, "'scale' must be a positive finite number"),
        (arrays, {"scale": float("nan")}, ValueError, "'scale' must be a positive finite number"),
        (arrays, {"depth_weight": -1.0}, ValueError, "'depth_weight' must be a finite number >= 0"),
        (arrays, {"min_depth": 0.0}, ValueError, "'min_depth' must be a positive finite number"),
        (arrays, {"live_depth": arrays[0][:, :, :3]}, ValueError, "'live_depth' must be of shape"),
        ((ref, *arrays[1:]), {}, TypeError, "'ref_image' must be a 4-D"),
    ]
    for args, kw, exc, msg in cases:
        with pytest.raises(exc, match=fn + msg):
            pp.photometric_normal_equations(*args, **kw)
    first = pp.photometric_normal_equations(*arrays)
    big, _ = to_wp(*scene(B=2, C=2, H=4, W=5, holes=False)[:5])
    with pytest.raises(TypeError, match=fn + "'out' must be a NormalEquations of an earlier call with B=2"):
        pp.photometric_normal_equations(*big, out=first)


# ----------------------------------------------------------------------------- photometric error (torch)

KINDS = [("l1", 1.0), ("l2", 1.0), ("huber", 0.1), ("cauchy", 0.2), ("geman_mcclure", 0.3), ("tukey", 0.4)]


def unfused_error(ref, depth, live, pose, K, kind, c):
    """warp_frame_depth + penalty + masked mean (the unfused path a user would write)."""
    import gvnn_warp as G

    warped, valid = G.warp_frame_depth(live, depth, pose, K)
    r = warped - ref
    if kind in ("l1", "l2"):
        rho = r.abs() if kind == "l1" else r * r / 2
    else:
        rho = G.robust_rho(r, kind, c)
    n = valid.sum((1, 2, 3)).to(ref.dtype)
    total = (rho * valid).sum((1, 2, 3))
    return torch.where(n > 0, total / (ref.shape[1] * n.clamp(min=1)), torch.zeros_like(n)), n


@pytest.mark.parametrize("kind, c", KINDS)
def test_error_matches_unfused_path(kind, c, dtype):
    from gvnn_warp.functional.photometric import photometric_error

    ref, depth, live, pose, K, _ = (t.to(dtype) for t in scene(B=3, C=3, H=10, W=12, seed=2))
    err, n = photometric_error(ref, depth, live, pose, K, robust=kind, scale=c)
    want, want_n = unfused_error(ref, depth, live, pose, K, kind, c)
    assert err.dtype == dtype and err.shape == (3,) and n.shape == (3,)
    assert torch.equal(n, want_n) and n.min() > 0
    tol = 1e-12 if dtype == torch.float64 else 1e-5
    torch.testing.assert_close(err, want, rtol=tol, atol=tol)
    # and against the independent references (valid rule, grid_sample, closed-form penalties)
    ref64, depth64, live64, pose64, K64 = (t.double() for t in (ref, depth, live, pose, K))
    valid = valid_ref(depth64, pose64, K64)
    u, v = project(moved_points(depth64, pose64, K64), K64)
    rho = rho_ref(sample(live64, u, v) - ref64, kind, c) * valid[:, None]
    assert torch.equal(n.double(), valid.sum((1, 2)).double())
    torch.testing.assert_close(err.double(), rho.sum((1, 2, 3)) / (3 * valid.sum((1, 2))), rtol=tol * 10, atol=tol)


@pytest.mark.parametrize("kind, c", [("l1", 1.0), ("huber", 0.15), ("tukey", 0.6), ("cauchy", 0.2)])
def test_error_gradcheck_every_input(kind, c):
    from gvnn_warp.functional.photometric import photometric_error

    ref, depth, live, pose, K, _ = scene(B=2, C=1, H=6, W=7, seed=4, angle=0.03, shift=0.04)
    args = [t.clone().requires_grad_() for t in (ref, depth, live, pose, K.expand(2, 3, 3).contiguous())]

    def fn(*a):
        return photometric_error(*a, robust=kind, scale=c)[0]

    # away from the kinks: no residual at 0 or at +-c, no projection near a pixel edge or the border
    with torch.no_grad():
        P = moved_points(depth, pose, K)
        u, v = project(P, K)
        valid = valid_ref(depth, pose, K)
        r = (sample(live, u, v) - ref)[:, 0][valid]
        for x in (u[valid], v[valid]):
            assert (x - x.round()).abs().min() > 1e-4
        assert r.abs().min() > 1e-4 and (r.abs() - c).abs().min() > 1e-4
        assert 10 < valid.sum() < 2 * 6 * 7
        outside = valid_ref(depth, pose, K, min_depth=MIN_DEPTH) ^ valid
        assert not outside.any()
    assert torch.autograd.gradcheck(fn, args, eps=1e-6, atol=1e-8, rtol=1e-6)


def test_error_invalid_inputs_are_skipped_with_finite_gradients():
    from gvnn_warp.functional.photometric import photometric_error

    ref, depth, live, pose, K, _ = scene(B=3, C=2, H=8, W=9, seed=6)
    depth[0] = float("nan")  # nothing valid
    depth[1, 0, ::2] = -1.0
    depth[1, 0, 1::2] = float("inf")  # nothing valid either
    pose[2, 2, 3] = -2.1  # most points behind the camera or outside
    live[2, 1, 3, 3] = float("nan")
    args = [t.clone().requires_grad_() for t in (ref, depth, live, pose, K)]
    err, n = photometric_error(*args, robust="huber", scale=0.1)
    assert n[0] == 0 and n[1] == 0 and err[0] == 0 and err[1] == 0
    assert torch.isfinite(err).all()
    err.sum().backward()
    for a in args:
        assert torch.isfinite(a.grad).all()
    assert args[3].grad[:2].abs().max() == 0 and args[1].grad[:2].abs().max() == 0
    want, want_n = unfused_error(ref, depth, live.nan_to_num(0.0), pose, K, "huber", 0.1)
    assert torch.equal(n, want_n)


def test_error_deterministic_across_threads_and_batch():
    from gvnn_warp.kernels.core.launch import set_num_threads

    from gvnn_warp.functional.photometric import photometric_error

    def run(B, C, H, W):
        ref, depth, live, pose, K, _ = scene(B=B, C=C, H=H, W=W, seed=8)
        outs = []
        for n in (1, 2, 3):
            set_num_threads(n)
            try:
                args = [t.clone().requires_grad_() for t in (ref, depth, live, pose, K)]
                err, _ = photometric_error(*args, robust="huber", scale=0.1)
                (err * torch.arange(1, B + 1, dtype=err.dtype)).sum().backward()
                outs.append([err.detach()] + [a.grad for a in args])
            finally:
                set_num_threads(None)
        for other in outs[1:]:
            for a, b in zip(outs[0], other):
                assert torch.equal(a, b)
        return outs[0]

    run(1, 1, 60, 900)  # one batch item: rows and adjoint reductions cut into pieces
    run(2, 3, 40, 300)  # the compiled-in 3-channel kernel
    whole = run(3, 2, 24, 400)
    ref, depth, live, pose, K, _ = scene(B=3, C=2, H=24, W=400, seed=8)
    args = [t[1:2].clone().requires_grad_() for t in (ref, depth, live, pose)] + [K.clone().requires_grad_()]
    err, _ = photometric_error(*args, robust="huber", scale=0.1)
    (2 * err).sum().backward()
    assert torch.equal(err.detach(), whole[0][1:2])
    for a, w in zip(args[:4], whole[1:5]):
        assert torch.equal(a.grad, w[1:2])


def test_error_only_wanted_gradients_and_layer():
    from refs import assert_only_wanted_gradients

    import gvnn_warp as G
    from gvnn_warp.functional.photometric import photometric_error

    ref, depth, live, pose, K, _ = scene(B=2, C=2, H=7, W=8, seed=9)
    assert_only_wanted_gradients(lambda *a: photometric_error(*a, robust="cauchy", scale=0.3)[0],
                                 [ref, depth, live, pose, K.expand(2, 3, 3).contiguous()])
    loss = G.PhotometricLoss(robust="cauchy", scale=0.3)
    torch.testing.assert_close(loss(ref, depth, live, pose, K), photometric_error(ref, depth, live, pose, K,
                                                                                   robust="cauchy", scale=0.3)[0],
                               rtol=0, atol=0)
    assert "cauchy" in repr(loss)


@pytest.mark.parametrize("C, kind, c", [(3, "l1", 1.0), (2, "cauchy", 0.2), (1, "huber", 0.1)])  # compiled-in and
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])  # run-time channel counts and penalties
def test_error_value_only_and_backward_without_zero_filled_gradients(C, kind, c, dtype):
    # the value with and without gradients comes from one kernel (its gradient part skipped at run
    # time): bitwise the same; and the backward allocates no zero-filled gradient for the outputs it
    # does not use (autograd materialised one of each output's size, an image for dS/d depth)
    from gvnn_warp.functional.photometric import photometric_error

    ref, depth, live, pose, K, _ = scene(B=2, C=C, H=12, W=20, seed=31, dtype=dtype)
    with torch.no_grad():
        value, count = photometric_error(ref, depth, live, pose, K, robust=kind, scale=c)
    args = [t.clone().requires_grad_() for t in (depth, pose)]
    err, n = photometric_error(ref, args[0], live, args[1], K, robust=kind, scale=c)
    assert torch.equal(err.detach(), value) and torch.equal(n, count)
    loss = err.sum()
    with torch.profiler.profile(record_shapes=True) as prof:
        loss.backward()
    fills = [(e.name, e.input_shapes) for e in prof.events() if e.name in ("aten::fill_", "aten::zero_", "aten::zeros")
             and any(math.prod(s) >= depth.numel() for s in e.input_shapes if isinstance(s, list) and s)]
    assert not fills, fills
    assert args[0].grad is not None and args[0].grad.abs().sum() > 0


def reference_error(ref, depth, live, pose, K, kind, c):
    """photometric_error through the reference ops: the row kernel and the mean, differentiated
    by their Warp adjoints (the fast path computes its gradient analytically in the forward pass)."""
    from gvnn_warp.kernels.photometric.residual import KINDS as CODES

    from gvnn_warp.ops import photometric as ops

    _, C, H, W = ref.shape
    row_sum, row_count = ops.photometric_rows(ref, depth, live, pose, K, C, H, W, CODES[kind], c, MIN_DEPTH)
    return ops.photometric_mean(row_sum, row_count, H, C)


@pytest.mark.parametrize("kind, c", KINDS)
@pytest.mark.parametrize("C", [1, 2, 3])  # compiled-in channel counts (1, 3) and the run-time loop (2)
def test_error_fast_gradients_equal_warp_adjoint(kind, c, C):
    from gvnn_warp.functional.photometric import photometric_error

    ref, depth, live, pose, K, _ = scene(B=3, C=C, H=9, W=21, seed=20 + C)  # W: two full blocks of 8 and a tail
    live[1, 0, 4, 6] = float("nan")  # a non-finite live pixel: its residuals are skipped
    # the tail step reads pixels 13-20 and masks 13-15 (done by the block before): non-finite values
    # there must not reach its sums
    depth[0, 0, 2, 14] = float("nan")
    depth[1, 0, 6, 13] = float("inf")
    ref[0, 0, 3, 13] = float("inf")
    ref[1, -1, 5, 15] = float("nan")
    ref[2, 0, 7, 16] = float("nan")  # and in the tail's own first pixel
    pose[2, :, 3] += torch.tensor([0.3, 0.0, 0.0], dtype=pose.dtype)  # many pixels move outside
    weights = torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64)
    results = []
    for fn in (reference_error, lambda *a: photometric_error(*a[:5], robust=a[5], scale=a[6])):
        args = [t.clone().requires_grad_() for t in (ref, depth, live, pose, K.expand(3, 3, 3).contiguous())]
        err, n = fn(*args, kind, c)
        (err * weights).sum().backward()
        results.append([err.detach(), n.detach()] + [a.grad for a in args])
    want, got = results
    assert torch.equal(got[1], want[1]) and 0 < want[1].min() and want[1].max() < 9 * 21
    for g, w in zip(got, want):
        assert torch.isfinite(g).all()
        torch.testing.assert_close(g, w, rtol=1e-12, atol=1e-12 * float(w.abs().max()))


def test_error_fast_path_float32_and_second_order():
    from gvnn_warp.functional.photometric import photometric_error

    ref, depth, live, pose, K, _ = scene(B=2, C=3, H=12, W=16, seed=30, holes=False)
    args64 = [t.clone().requires_grad_() for t in (ref, depth, live, pose, K.expand(2, 3, 3).contiguous())]
    args32 = [t.detach().float().requires_grad_() for t in args64]
    for args in (args64, args32):
        err, _ = photometric_error(*args, robust="huber", scale=0.1)
        err.sum().backward(retain_graph=True)
    for a, b in zip(args32, args64):
        torch.testing.assert_close(a.grad.double(), b.grad, rtol=2e-3, atol=2e-4 * float(b.grad.abs().max()))
    # a second backward through the retained graph adds the same gradient again
    first = [a.grad.clone() for a in args64]
    err.sum().backward()
    for a, f in zip(args32, first):
        assert torch.allclose(a.grad.double(), 2 * f, rtol=2e-3, atol=1e-4 * float(f.abs().max()))
    err, _ = photometric_error(*args64, robust="l1")
    (g,) = torch.autograd.grad(err.sum(), args64[1], create_graph=True)
    with pytest.raises(NotImplementedError, match="photometric_error: second-order gradients"):
        g.sum().backward()


def test_error_large_planes_take_the_reference_path(monkeypatch):
    # planes beyond 2^24 pixels (float tap addresses of the 8-lane kernel no longer exact) run the
    # reference kernel and its Warp adjoint: same values and gradients to rounding
    from gvnn_warp.functional import photometric as P

    ref, depth, live, pose, K, _ = scene(B=2, C=2, H=6, W=9, seed=31)
    outs = []
    for limit in (P._MAX_LANES_PLANE, 6 * 9 - 1):
        monkeypatch.setattr(P, "_MAX_LANES_PLANE", limit)
        args = [t.clone().requires_grad_() for t in (ref, depth, live, pose, K)]
        err, n = P.photometric_error(*args, robust="cauchy", scale=0.2)
        err.sum().backward()
        outs.append([err.detach(), n] + [a.grad for a in args])
    assert outs[1][1].grad_fn is None and not outs[1][1].requires_grad
    for a, b in zip(*outs):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-14)


def test_normal_equations_beyond_the_lanes_exact_addresses_go_pixel_by_pixel(monkeypatch):
    # planes of more than MAX_LANES_PLANE pixels (float32 lane addresses inexact) take the one-pixel
    # kernel, in the torch op and the pure-Warp function alike: the same sums up to their order (a
    # lowered limit stands in for a 16.7-megapixel image)
    import gvnn_warp as G
    from gvnn_warp.ops import photometric as ops_photometric

    ref, depth, live, pose, K, live_depth = scene(B=2, C=1, H=6, W=9, seed=33)
    results = []
    for limit in (pp.MAX_LANES_PLANE, 6 * 9 - 1):
        monkeypatch.setattr(pp, "MAX_LANES_PLANE", limit)
        monkeypatch.setattr(ops_photometric, "MAX_LANES_PLANE", limit)
        arrays, ld = to_wp(ref, depth, live, pose, K, live_depth)
        warp_ne = [a.numpy() for a in pp.photometric_normal_equations(*arrays, robust="huber", scale=0.1,
                                                                       live_depth=ld, depth_weight=0.5)]
        torch_ne = [t.numpy() for t in G.photometric_normal_equations(ref, depth, live, pose, K, robust="huber",
                                                                      scale=0.1, live_depth=live_depth,
                                                                      depth_weight=0.5)]
        results.append(warp_ne + torch_ne)
    assert results[0][3].sum() > 0
    for a, b in zip(*results):
        np.testing.assert_allclose(b, a, rtol=1e-10, atol=1e-12 * max(np.abs(a).max(), 1.0))


def test_error_pure_warp_tape_matches_torch():
    from gvnn_warp.functional.photometric import photometric_error

    ref, depth, live, pose, K, _ = scene(B=2, C=2, H=7, W=9, seed=10)
    args = [t.clone().requires_grad_() for t in (ref, depth, live, pose, K.expand(2, 3, 3).contiguous())]
    err, n = photometric_error(*args, robust="tukey", scale=0.5)
    (err * torch.tensor([1.0, -2.0], dtype=torch.float64)).sum().backward()
    arrays, _ = to_wp(ref, depth, live, pose, K)
    for a in arrays:
        a.requires_grad = True
    tape = wp.Tape()
    with tape:
        e, c = pp.photometric_error(*arrays, robust="tukey", scale=0.5)
    tape.backward(grads={e: wp.array([1.0, -2.0], dtype=wp.float64)})
    assert np.array_equal(e.numpy(), err.detach().numpy()) and np.array_equal(c.numpy(), n.detach().numpy())
    for a, t in zip(arrays, args):
        np.testing.assert_allclose(a.grad.numpy().reshape(t.shape), t.grad.numpy(), rtol=1e-12, atol=1e-14)


def test_normal_equations_torch_equals_pure_warp():
    from gvnn_warp.functional.photometric import photometric_normal_equations

    ref, depth, live, pose, K, live_depth = scene(seed=14)
    got = photometric_normal_equations(ref, depth, live, pose, K, robust="tukey", scale=0.4,
                                       live_depth=live_depth, depth_weight=3.0)
    arrays, ld = to_wp(ref, depth, live, pose, K, live_depth)
    want = pp.photometric_normal_equations(*arrays, robust="tukey", scale=0.4, live_depth=ld, depth_weight=3.0)
    for g, w in zip(got, want.numpy()):
        assert np.array_equal(g.numpy(), w)
    # 4x4 poses and shared K accepted; outputs carry no gradient
    pose44 = torch.cat([pose, torch.tensor([[[0.0, 0, 0, 1]]], dtype=torch.float64).expand(2, 1, 4)], 1)
    again = photometric_normal_equations(ref, depth, live, pose44.requires_grad_(), K, robust="tukey", scale=0.4,
                                         live_depth=live_depth, depth_weight=3.0)
    for a, b in zip(again, got):
        assert torch.equal(a, b) and not a.requires_grad


def test_normal_equations_torch_calls_reuse_their_recorded_launches(monkeypatch):
    # each torch call brings new tensors; calls of the same shapes and settings replay the launches
    # recorded by an earlier one, pointed at the new memory. Every call must equal a fresh
    # pure-Warp call (pinhole) or the op with nothing cached (lens cameras), bitwise, through cache
    # hits, misses, evictions, thread counts and settings that differ only in a scalar, and calls
    # from several threads at once must not share scratch buffers
    import threading

    from gvnn_warp.cameras import FisheyeCamera, RadTanCamera
    from gvnn_warp.functional.photometric import photometric_normal_equations
    from gvnn_warp.ops import photometric as ops

    recorded = []
    real = launch.RecordedLaunch.__init__

    def counting(self, *args, **kwargs):
        recorded.append(args[0])
        real(self, *args, **kwargs)

    monkeypatch.setattr(launch.RecordedLaunch, "__init__", counting)
    monkeypatch.setattr(ops._Recorded, "SIZE", 2)
    ops._RECORDED.entries.clear()

    def check(seed, H, W, robust="huber", depth_weight=0.0, dtype=torch.float64, scale=0.2, min_depth=MIN_DEPTH,
              lens=None):
        ref, depth, live, pose, K, live_depth = scene(B=2, C=1, H=H, W=W, seed=seed, dtype=dtype)
        extra = dict(live_depth=live_depth, depth_weight=depth_weight) if depth_weight else {}
        settings = dict(robust=robust, scale=scale, min_depth=min_depth, **extra)
        if lens is not None:  # (model, batched): one camera for the batch, or one per item
            model, batched = lens
            dist = torch.tensor([0.02, -0.01, 0.003, 0.001, 0.0][:5 if model is RadTanCamera else 4], dtype=dtype)
            cam = model(K.expand(2, 3, 3) if batched else K, dist)
            got = photometric_normal_equations(ref, depth, live, pose, cam, **settings)
            kept = ops._RECORDED.entries
            ops._RECORDED.entries = {}
            try:
                want = photometric_normal_equations(ref, depth, live, pose, cam, **settings)
            finally:
                ops._RECORDED.entries = kept
            want = [w.numpy() for w in want]
        else:
            got = photometric_normal_equations(ref, depth, live, pose, K, **settings)
            arrays, ld = to_wp(ref, depth, live, pose, K, live_depth)
            if depth_weight:
                settings["live_depth"] = ld
            want = pp.photometric_normal_equations(*arrays, **settings).numpy()
        for g, w in zip(got, want):
            assert np.array_equal(g.numpy(), w)

    check(1, 9, 11)
    first = len(recorded)  # the torch call's two launches, and the pure-Warp call's
    for seed in (2, 3):
        check(seed, 9, 11)
    assert len(recorded) == first + 2 * 2  # only the pure-Warp calls recorded theirs
    for seed, H, W, robust, dw, dtype in [
        (4, 12, 16, "huber", 0.0, torch.float64),  # another shape
        (5, 9, 11, "cauchy", 0.0, torch.float64),  # another penalty: a third entry, (9, 11, huber) dropped
        (6, 9, 11, "huber", 0.0, torch.float64),  # recorded again
        (7, 9, 11, "huber", 0.5, torch.float64),  # the depth term
        (8, 9, 11, "huber", 0.0, torch.float32),
        (9, 9, 11, "huber", 0.0, torch.float32),
    ]:
        check(seed, H, W, robust, dw, dtype)
    # settings that differ only in a scalar, one after the other
    for seed, scale, min_depth, dw in [(20, 0.2, MIN_DEPTH, 0.5), (21, 0.05, MIN_DEPTH, 0.5), (22, 0.2, 2.0, 0.5),
                                       (23, 0.2, 2.0, 2.0), (24, 0.05, MIN_DEPTH, 0.5)]:
        check(seed, 9, 11, depth_weight=dw, scale=scale, min_depth=min_depth)
    # lens cameras of the same shapes: the model, a camera shared by the batch or one per item
    for seed, lens in enumerate([(RadTanCamera, False), (FisheyeCamera, False), (RadTanCamera, False),
                                 (RadTanCamera, True), (FisheyeCamera, True), (RadTanCamera, False)]):
        check(30 + seed, 9, 11, lens=lens)
    try:
        launch.set_num_threads(1)
        check(10, 9, 11, dtype=torch.float32)
    finally:
        launch.set_num_threads(None)
    check(11, 9, 11, dtype=torch.float32)

    monkeypatch.setattr(ops._Recorded, "SIZE", 8)
    check(99, 30, 40)  # (the kernels loaded before the threads start)
    errors = []

    def worker(seed):
        try:
            for k in range(20):
                check(seed + k, 30, 40)  # all of the same shapes
        except Exception as e:  # reported below
            errors.append(e)

    workers = [threading.Thread(target=worker, args=(s,)) for s in (100, 200, 300)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    assert not errors, errors


def test_torch_functions_bad_arguments():
    from gvnn_warp.functional.photometric import photometric_error, photometric_normal_equations
    from gvnn_warp.nn.photometric import PhotometricLoss

    ref, depth, live, pose, K, live_depth = scene(B=2, C=2, H=5, W=6, holes=False)
    for fn, name in ((photometric_error, "photometric_error"),
                     (photometric_normal_equations, "photometric_normal_equations")):
        pre = rf"gvnn_warp\.{name}: argument "
        with pytest.raises(ValueError, match=pre + "'ref_depth' must have shape"):
            fn(ref, depth[:, :, 0], live, pose, K)
        with pytest.raises(ValueError, match=pre + "'live_image' has H=4"):
            fn(ref, depth, live[:, :, :4], pose, K)
        with pytest.raises(TypeError, match=pre + "'live_image' has dtype torch.float32"):
            fn(ref, depth, live.float(), pose, K)
        with pytest.raises(ValueError, match=pre + "'pose' must have shape"):
            fn(ref, depth, live, pose[:, :2], K)
        with pytest.raises(ValueError, match=pre + "'robust' must be one of"):
            fn(ref, depth, live, pose, K, robust="welsch")
        with pytest.raises(ValueError, match=pre + "'scale' must be a positive finite number"):
            fn(ref, depth, live, pose, K, scale=-1.0)
        with pytest.raises(TypeError, match=pre + "'K' must be a .* torch.Tensor or a camera"):
            fn(ref, depth, live, pose, K.numpy())
    pre = r"gvnn_warp\.photometric_normal_equations: argument "
    with pytest.raises(ValueError, match=pre + "'robust' must be one of"):
        photometric_normal_equations(ref, depth, live, pose, K, robust="l1")
    with pytest.raises(ValueError, match=pre + "'depth_weight' must be a finite number >= 0"):
        photometric_normal_equations(ref, depth, live, pose, K, live_depth=live_depth, depth_weight=float("inf"))
    with pytest.raises(ValueError, match=pre + "'live_depth' has W=5"):
        photometric_normal_equations(ref, depth, live, pose, K, live_depth=live_depth[..., :5])
    with pytest.raises(ValueError, match=r"gvnn_warp\.PhotometricLoss: argument 'robust'"):
        PhotometricLoss(robust="huberr")


@pytest.mark.parametrize("width", [13, 6])
def test_normal_equations_lanes_kernel_equals_scalar_kernel(width):
    # the 8-lane row kernel (used) against the plain one-pixel-at-a-time kernel, row by row,
    # with a width that is not a multiple of 8 (the last step reads the row's last 8 pixels and
    # masks those of the step before) and one narrower than 8 (clamped lanes)
    from gvnn_warp.kernels.photometric import normal_equations_lanes as nel
    from gvnn_warp.kernels.photometric import normal_equations_reduce as ner
    from gvnn_warp.kernels.photometric.normal_equations import normal_equations_rows

    ref, depth, live, pose, K, live_depth = scene(B=2, C=3, H=7, W=width, seed=15)
    arrays, ld = to_wp(ref, depth, live, pose, K, live_depth)
    B, C, H, W = ref.shape
    counts = []
    for depth_term, occlusion in ((False, False), (True, False), (False, True), (True, True)):
        rows = []
        scalar = normal_equations_rows(depth_term, occlusion)
        # the generic lane kernel (penalty, channels and row width read at run time) and the one
        # compiled for the call (huber, code 0)
        for kernel in (scalar, nel.normal_equations_lanes_kernel(depth_term, occlusion, None, None, None),
                       nel.normal_equations_lanes(depth_term, occlusion, C, 0, W)):
            out = wp.zeros(B * H * ner.ROW_STRIDE, dtype=wp.float64)
            # the lane kernels' running sums (memory slots per row; filled with garbage first: the
            # kernel must clear its own)
            acc = [] if kernel is scalar else [wp.full(B * H * ner.ROW_STRIDE, 7.0, dtype=launch.vec8d)]
            wp.launch(kernel[wp.float64], dim=B * H,
                      inputs=[0, arrays[0].flatten(), arrays[1].flatten(), arrays[2].flatten(), ld.flatten(),
                              arrays[3], arrays[4], C, H, W, 0, 0.1, MIN_DEPTH, 2.0, 0.05, out, *acc])
            rows.append(out.numpy().reshape(B * H, -1)[:, : ner.N_SUMS])
        np.testing.assert_allclose(rows[1], rows[0], rtol=1e-12, atol=1e-12 * np.abs(rows[0]).max())
        np.testing.assert_array_equal(rows[2], rows[1])  # specialised: bitwise the generic kernel's sums
        assert rows[0][:, 28].sum() > 0
        counts.append(rows[0][:, 28].sum())
    assert counts[2] < counts[0] and counts[3] < counts[1]  # the occlusion test dropped pixels
    # one channel (the aligner's case): the kernels compiled for C = 1 (channel loop unrolled)
    ref, depth, live, pose, K, live_depth = scene(B=2, C=1, H=6, W=width + 6, seed=17)
    arrays, ld = to_wp(ref, depth, live, pose, K, live_depth)
    B, C, H, W = ref.shape
    for depth_term, occlusion in ((False, False), (True, False), (False, True), (True, True)):
        rows = []
        scalar = normal_equations_rows(depth_term, occlusion)
        for kernel in (scalar, nel.normal_equations_lanes(depth_term, occlusion, 1, 0, W)):  # huber
            out = wp.zeros(B * H * ner.ROW_STRIDE, dtype=wp.float64)
            acc = [] if kernel is scalar else [wp.full(B * H * ner.ROW_STRIDE, 7.0, dtype=launch.vec8d)]
            wp.launch(kernel[wp.float64], dim=B * H,
                      inputs=[0, arrays[0].flatten(), arrays[1].flatten(), arrays[2].flatten(), ld.flatten(),
                              arrays[3], arrays[4], C, H, W, 0, 0.1, MIN_DEPTH, 2.0, 0.05, out, *acc])
            rows.append(out.numpy().reshape(B * H, -1)[:, : ner.N_SUMS])
        np.testing.assert_allclose(rows[1], rows[0], rtol=1e-12, atol=1e-12 * np.abs(rows[0]).max())
        assert rows[0][:, 28].sum() > 0


def test_opcheck_photometric_ops():
    from gvnn_warp.kernels.photometric.residual import KINDS as CODES

    from gvnn_warp.ops import photometric as ops

    ref, depth, live, pose, K, live_depth = scene(B=2, C=2, H=5, W=6, seed=16, holes=False)
    Kb = K.expand(2, 3, 3).contiguous()
    args = tuple(t.clone().requires_grad_() for t in (ref, depth, live, pose, Kb))
    torch.library.opcheck(ops.photometric_rows, (*args, 2, 5, 6, CODES["huber"], 0.1, MIN_DEPTH))
    row_sum, row_count = ops.photometric_rows(*(a.detach() for a in args), 2, 5, 6, CODES["huber"], 0.1, MIN_DEPTH)
    torch.library.opcheck(ops.photometric_mean, (row_sum.requires_grad_(), row_count, 5, 2))
    torch.library.opcheck(ops.photometric_error, (*args, CODES["huber"], 0.1, MIN_DEPTH, 31))
    torch.library.opcheck(ops.photometric_error, (*(a.detach() for a in args), CODES["l1"], 1.0, MIN_DEPTH, 0))
    torch.library.opcheck(ops.photometric_normal_equations,
                          (ref, depth, live, live_depth, pose, Kb, CODES["tukey"], 0.4, MIN_DEPTH, 2.0))


def views8(a: wp.array) -> list:
    """A float32 array and a length-8 vector view of it (scale_segments' src/src8 and out/out8)."""
    return [a, _compat.array_descriptor(a.ptr, a.shape[0] // 8, 32)]


@pytest.mark.parametrize("seg, n", [(5, 35), (1, 3), (8, 8), (2049, 4098), (4097, 3 * 4097), (7, 7 * 700)])
@pytest.mark.parametrize("threads", [1, 2])
def test_scale_segments_runs_across_spans(seg, n, threads, monkeypatch):
    # the backward's scaling: segments shorter and longer than a launch element's span, runs that
    # cross spans, short tails, a launch cut into one-element chunks; out[i] = src[i] g[b] / (C count[b]),
    # b = i // seg
    from gvnn_warp.kernels.photometric import error_reduce as pek

    if threads > 1:
        monkeypatch.setattr(launch, "_planner", lambda n, *a: [(i, 1, 0) for i in range(n)])

    rng = np.random.default_rng(seg + n)
    src, g = rng.standard_normal(n).astype(np.float32), rng.standard_normal(n // seg).astype(np.float32)
    count = rng.integers(0, 50, n // seg).astype(np.float32)
    count[0] = 0  # no valid pixel: factor 0
    out = wp.array(np.full(n, np.nan, np.float32))
    launch.set_num_threads(threads)
    try:
        launch.launch(pek.scale_segments[wp.float32], pek.scale_segments_dim(n),
                      [*views8(wp.array(src)), wp.array(g), wp.array(count), seg, n, 3], views8(out))
    finally:
        launch.set_num_threads(None)
    factor = np.where(count > 0, g / (np.float32(3) * np.maximum(count, 1)), 0).astype(np.float32)
    np.testing.assert_array_equal(out.numpy(), src * np.repeat(factor, seg))


_SCALE_NEAR_2_31 = r"""
import sys, torch, warp as wp
from gvnn_warp.kernels import _compat
from gvnn_warp.kernels.photometric import error_reduce as pek
for arg in sys.argv[1:]:
    n, seg = map(int, arg.split(","))
    S = ((n - 1) // pek.SCALE_SPAN) * pek.SCALE_SPAN  # the last launch element's first value
    m = n - S
    src = torch.arange(1, m + 65, dtype=torch.float32)
    out = torch.full((m + 64,), float("nan"))  # 64 guard values past index n - 1
    g = torch.arange(1, n // seg + 2, dtype=torch.float32)
    count = torch.ones(n // seg + 1)
    # descriptors of length n whose data starts S values before the buffers: only the last
    # element's values are real memory (a write below S faults, one at or past n lands in the guard)
    shifted = lambda t: _compat.array_descriptor(t.data_ptr() - S * 4, n, 4)
    plain = lambda t: _compat.array_descriptor(t.data_ptr(), t.numel(), 4)
    shifted8 = lambda t: _compat.array_descriptor(t.data_ptr() - S * 4, n // 8, 32)
    wp.launch(pek.scale_segments[wp.float32], dim=1, inputs=[(n - 1) // pek.SCALE_SPAN, shifted(src), shifted8(src),
              plain(g), plain(count), seg, n, 1], outputs=[shifted(out), shifted8(out)], device="cpu")
    want = src[:m] * g[(torch.arange(S, n) // seg)]
    print(arg, int(torch.equal(out[:m], want)), int((~out[m:].isnan()).sum()), flush=True)
"""


@pytest.mark.long
def test_scale_segments_last_element_near_2_31():
    # int32 bounds: n up to 2^31 - 1 values (what the ops accept); the last launch element writes
    # exactly its values and none past n (in a child process: a wrapped index faults there)

    cases = [f"{n},{seg}" for n in (2**31 - 1, 2**31 - 8, 2**31 - 100, 2**31 - 2047, 2**31 - 2048)
             for seg in (n, 2**20, n - 3, n - 5)]  # n - 3, n - 5: a segment starts off a multiple of 8
    r = run_python(_SCALE_NEAR_2_31, *cases, timeout=300)
    assert r.returncode == 0, (r.stdout, r.stderr[-2000:])
    assert r.stdout.split("\n")[-len(cases) - 1:-1] == [f"{c} 1 0" for c in cases], r.stdout
