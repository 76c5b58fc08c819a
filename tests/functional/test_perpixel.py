"""Per-pixel transformations, M-estimators and smoothness (gvnn_warp.functional.perpixel, GitHub issue 3).

Reference values are written independently here in plain torch (closed forms from the paper,
``grid_sample`` / ``affine_grid``, ``matrix_exp`` for rotations); gradients are checked with float64
``gradcheck`` against finite differences and against torch autograd of the references.
"""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from gvnn_warp.functional import perpixel as P
from gvnn_warp.nn import perpixel as L

D = torch.float64
KINDS = ("huber", "cauchy", "geman_mcclure", "tukey")


def gen(seed=0):
    return torch.Generator().manual_seed(seed)


def rand(*shape, seed=0, scale=1.0, dtype=D):
    return (torch.rand(*shape, generator=gen(seed), dtype=D) * 2 - 1).mul(scale).to(dtype)


def grad_ok(fn, *inputs):
    inputs = tuple(t.detach().to(D).requires_grad_() for t in inputs)
    return torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-6, rtol=1e-5)


def pixel_grid(H, W, dtype=D):
    y, x = torch.meshgrid(torch.arange(H, dtype=dtype), torch.arange(W, dtype=dtype), indexing="ij")
    return x, y


def sample_ref(image, px, py, padding_mode):
    """grid_sample(align_corners=True) at pixel positions px, py (B, H, W)."""
    _, _, H, W = image.shape
    grid = torch.stack([px / (W - 1) * 2 - 1, py / (H - 1) * 2 - 1], dim=-1)
    return F.grid_sample(image, grid, mode="bilinear", padding_mode=padding_mode, align_corners=True)


def skew(w):
    z = torch.zeros_like(w[..., 0])
    return torch.stack([z, -w[..., 2], w[..., 1], w[..., 2], z, -w[..., 0], -w[..., 1], w[..., 0], z], dim=-1).reshape(
        *w.shape[:-1], 3, 3
    )


def rotation_ref(params):
    """(B, >=3, H, W) -> (B, H, W, 3, 3) matrix exponentials of the first three channels."""
    return torch.linalg.matrix_exp(skew(params[:, :3].permute(0, 2, 3, 1)))


# ----------------------------------------------------------------------------- M-estimator references
def rho_ref(x, kind, c):
    u2 = (x / c) ** 2
    if kind == "huber":
        return torch.where(x.abs() <= c, x**2 / 2, c * (x.abs() - c / 2))
    if kind == "cauchy":
        return c**2 / 2 * torch.log1p(u2)
    if kind == "geman_mcclure":
        return (x**2 / 2) / (1 + u2)
    # 1 - (1 - u2)^3 as -expm1(3 log1p(-u2)): accurate for tiny u2 (the plain form cancels)
    inside = c**2 / 6 * -torch.expm1(3 * torch.log1p(-u2.clamp(max=1)))
    return torch.where(x.abs() <= c, inside, torch.full_like(x, c**2 / 6))


def psi_paper(x, kind, c):
    """The psi column of the paper's table (Geman-McClure generalised to scale c)."""
    u2 = (x / c) ** 2
    if kind == "huber":
        return torch.where(x.abs() <= c, x, c * x / x.abs())
    if kind == "cauchy":
        return x / (1 + u2)
    if kind == "geman_mcclure":
        return x / (1 + u2) ** 2
    return torch.where(x.abs() <= c, x * (1 - u2) ** 2, torch.zeros_like(x))


def residuals(c, seed=1):
    # values around and far beyond the scale, avoiding the kinks |x| = c
    x = rand(200, seed=seed, scale=4 * c)
    return x[(x.abs() - c).abs() > 1e-3]


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("c", [0.3, 1.0, 2.5])
def test_robust_rho_psi_closed_forms(kind, c):
    x = residuals(c).reshape(-1, 2)  # any shape
    assert torch.allclose(P.robust_rho(x, kind, c), rho_ref(x, kind, c), rtol=1e-12, atol=1e-14)
    assert torch.allclose(P.robust_psi(x, kind, c), psi_paper(x, kind, c), rtol=1e-12, atol=1e-14)
    # psi is the derivative of rho: of our rho (Warp adjoint) and of the reference rho (torch autograd)
    xg = x.clone().requires_grad_()
    (g_ours,) = torch.autograd.grad(P.robust_rho(xg, kind, c).sum(), xg)
    xr = x.clone().requires_grad_()
    (g_ref,) = torch.autograd.grad(rho_ref(xr, kind, c).sum(), xr)
    psi = P.robust_psi(x, kind, c)
    assert torch.allclose(g_ours, psi, rtol=1e-12, atol=1e-14)
    assert torch.allclose(g_ref, psi, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("kind", KINDS)
def test_robust_gradcheck_and_second_derivative(kind):
    x = residuals(0.7, seed=2)[:40]
    assert grad_ok(lambda t: P.robust_rho(t, kind, 0.7), x)
    assert grad_ok(lambda t: P.robust_psi(t, kind, 0.7), x)
    # rho'' from the psi kernel's adjoint vs torch double autograd of the reference
    xr = x.clone().requires_grad_()
    (d1,) = torch.autograd.grad(rho_ref(xr, kind, 0.7).sum(), xr, create_graph=True)
    (d2,) = torch.autograd.grad(d1.sum(), xr)
    xg = x.clone().requires_grad_()
    (g,) = torch.autograd.grad(P.robust_psi(xg, kind, 0.7).sum(), xg)
    assert torch.allclose(g, d2, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("kind", KINDS)
def test_robust_special_points(kind):
    c = 1.3
    # x = 0: rho = 0, psi = 0, gradient finite (= 0) and curvature 1 for every estimator
    z = torch.zeros(3, dtype=D, requires_grad=True)
    r = P.robust_rho(z, kind, c)
    (g,) = torch.autograd.grad(r.sum(), z)
    assert torch.equal(r, torch.zeros(3, dtype=D)) and torch.equal(g, torch.zeros(3, dtype=D))
    z2 = torch.zeros(1, dtype=D, requires_grad=True)
    (h,) = torch.autograd.grad(P.robust_psi(z2, kind, c).sum(), z2)
    assert torch.allclose(h, torch.ones(1, dtype=D))
    # continuity at the scale (the kinks of Huber and Tukey), both signs
    for s in (-1.0, 1.0):
        edge = torch.tensor([s * c * (1 - 1e-9), s * c, s * c * (1 + 1e-9)], dtype=D)
        assert (P.robust_rho(edge, kind, c).diff().abs() < 1e-8).all()
        assert (P.robust_psi(edge, kind, c).diff().abs() < 1e-8).all()
    # symmetric rho, odd psi
    x = residuals(c, seed=3)
    assert torch.equal(P.robust_rho(-x, kind, c), P.robust_rho(x, kind, c))
    assert torch.equal(P.robust_psi(-x, kind, c), -P.robust_psi(x, kind, c))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_robust_tiny_residuals_accurate(dtype):
    # Cauchy's log(1 + u^2) and Tukey's 1 - (1 - u^2)^3 must not cancel for small residuals
    x = torch.tensor([1e-6, 3e-5, 1e-3, 0.02], dtype=dtype)
    for kind in ("cauchy", "tukey"):
        got = P.robust_rho(x, kind, 2.0).double()
        ref = rho_ref(x.double(), kind, 2.0)
        assert torch.allclose(got, ref, rtol=1e-6 if dtype == torch.float32 else 1e-14, atol=0)


def test_robust_float32_matches_float64():
    x = residuals(1.0, seed=4)
    for kind in KINDS:
        for fn in (P.robust_rho, P.robust_psi):
            r32 = fn(x.float(), kind, 1.0)
            assert r32.dtype == torch.float32
            assert torch.allclose(r32.double(), fn(x, kind, 1.0), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_robust_huge_and_infinite_residuals(dtype):
    # |x/c| far beyond where (x/c)^2 overflows (1.8e19 in float32, 1.3e154 in float64), and +-inf:
    # rho and psi stay finite (inf only for the unbounded rho at inf) and d rho / dx equals psi.
    big = 3e19 if dtype == torch.float32 else 1e160
    x = torch.tensor([big, -big, 4e37 if dtype == torch.float32 else 1e300, math.inf, -math.inf], dtype=dtype)
    c = 1.5
    u = [abs(v) / c for v in x.tolist()]
    expect_rho = {
        "huber": [c * (abs(v) - c / 2) for v in x.tolist()],
        "cauchy": [c * c / 2 * 2 * math.log(a) for a in u],  # log(1 + u^2) = 2 log u to rounding here
        "geman_mcclure": [c * c / 2] * 5,
        "tukey": [c * c / 6] * 5,
    }
    for kind in KINDS:
        xg = x.clone().requires_grad_()
        r = P.robust_rho(xg, kind, c)
        (g,) = torch.autograd.grad(r.sum(), xg)
        psi = P.robust_psi(x, kind, c)
        assert not r.isnan().any() and torch.isfinite(g).all() and torch.isfinite(psi).all(), kind
        assert torch.allclose(r.double(), torch.tensor(expect_rho[kind], dtype=D), rtol=1e-6), kind
        assert torch.allclose(g, psi, rtol=1e-6, atol=0), kind
        # psi of a huge residual: c sign(x) (Huber), ~c^2/x (Cauchy), ~c^4/x^3 (GM, 0 here), 0 (Tukey)
        if kind == "cauchy":
            assert torch.allclose(psi[:2].double(), c * c / x[:2].double(), rtol=1e-6)
        if kind == "huber":
            assert torch.equal(psi, c * x.sign())
    # a small scale reaches the same regime with ordinary residuals
    r = P.robust_rho(torch.tensor([1e7], dtype=dtype), "cauchy", 1e-12)
    assert math.isclose(r.item(), 1e-24 / 2 * 2 * math.log(1e19), rel_tol=1e-5)


def test_robust_scale_argument():
    x = torch.tensor([0.5, 3.0])
    np = pytest.importorskip("numpy")
    for s in (np.float32(1.0), np.int64(1), 1):  # NumPy and Python scalars alike
        assert torch.equal(P.robust_rho(x, "huber", s), P.robust_rho(x, "huber", 1.0))
    with pytest.raises(TypeError, match=r"robust_rho: argument 'scale' must be a real number, got str"):
        P.robust_rho(x, "huber", "1")
    # c and c^2 must be normal numbers of the input's dtype (c = 1e39 is inf in float32)
    for s in (1e39, 1e-50, 1e20):
        with pytest.raises(ValueError, match=r"robust_rho: argument 'scale' must lie in .* for torch.float32"):
            P.robust_rho(x, "cauchy", s)
    assert torch.isfinite(P.robust_rho(x.double(), "cauchy", 1e20)).all()


@pytest.mark.parametrize("kind", KINDS)
def test_smoothness_loss(kind):
    f = rand(2, 3, 5, 6, seed=5, scale=2.0)
    c = 0.8

    def ref(t):
        return rho_ref(t.diff(dim=3), kind, c).mean() + rho_ref(t.diff(dim=2), kind, c).mean()

    got = P.smoothness_loss(f, kind, c)
    assert got.shape == () and torch.allclose(got, ref(f), rtol=1e-12)
    fg = f.clone().requires_grad_()
    fr = f.clone().requires_grad_()
    (g,) = torch.autograd.grad(P.smoothness_loss(fg, kind, c), fg)
    (gr,) = torch.autograd.grad(ref(fr), fr)
    assert torch.allclose(g, gr, rtol=1e-10, atol=1e-14)
    assert grad_ok(lambda t: P.smoothness_loss(t, kind, c), f)


def test_smoothness_loss_degenerate_sizes():
    assert P.smoothness_loss(torch.full((1, 2, 4, 5), 3.0, dtype=D)).item() == 0.0  # constant field
    col = rand(1, 1, 4, 1, seed=6)  # W == 1: only y differences
    assert torch.allclose(P.smoothness_loss(col, "cauchy"), rho_ref(col.diff(dim=2), "cauchy", 1.0).mean())
    assert P.smoothness_loss(torch.ones(1, 1, 1, 1, dtype=D)).item() == 0.0


# ----------------------------------------------------------------------------- sampling
@pytest.mark.parametrize("padding_mode", ["zeros", "border"])
def test_flow_warp_matches_grid_sample(padding_mode):
    B, C, H, W = 2, 3, 5, 6
    image = rand(B, C, H, W, seed=7)
    flow = rand(B, 2, H, W, seed=8, scale=4.0)  # many samples land outside the image
    x, y = pixel_grid(H, W)
    ref = sample_ref(image, x + flow[:, 0], y + flow[:, 1], padding_mode)
    out = P.flow_warp(image, flow, padding_mode=padding_mode)
    assert torch.allclose(out, ref, atol=1e-12)
    assert grad_ok(lambda i, f: P.flow_warp(i, f, padding_mode=padding_mode), image, flow)
    # gradients equal grid_sample's (chain rule through the normalisation)
    ig, fg = image.clone().requires_grad_(), flow.clone().requires_grad_()
    ir, fr = image.clone().requires_grad_(), flow.clone().requires_grad_()
    w = rand(B, C, H, W, seed=9)
    g = torch.autograd.grad((P.flow_warp(ig, fg, padding_mode=padding_mode) * w).sum(), (ig, fg))
    gr = torch.autograd.grad((sample_ref(ir, x + fr[:, 0], y + fr[:, 1], padding_mode) * w).sum(), (ir, fr))
    assert all(torch.allclose(a, b, atol=1e-10) for a, b in zip(g, gr, strict=True))


def test_flow_warp_zero_flow_and_outside():
    image = rand(2, 3, 5, 6, seed=10)
    assert torch.equal(P.flow_warp(image, torch.zeros(2, 2, 5, 6, dtype=D)), image)
    # integer translation by (+2, -1): out[y, x] = image[y - 1, x + 2], 0 where that is outside
    flow = torch.zeros(2, 2, 5, 6, dtype=D)
    flow[:, 0], flow[:, 1] = 2.0, -1.0
    out = P.flow_warp(image, flow)
    assert torch.equal(out[:, :, 1:, :4], image[:, :, :4, 2:])
    assert (out[:, :, 0] == 0).all() and (out[:, :, :, 4:] == 0).all()
    # far outside: zeros with zero gradients; border: the nearest edge pixel, zero flow gradient
    far = torch.full((2, 2, 5, 6), 50.0, dtype=D, requires_grad=True)
    img = image.clone().requires_grad_()
    out = P.flow_warp(img, far)
    out.sum().backward()
    assert (out == 0).all() and (far.grad == 0).all() and (img.grad == 0).all()
    far.grad = None
    out = P.flow_warp(image, far, padding_mode="border")
    out.sum().backward()
    assert torch.equal(out, image[:, :, -1:, -1:].expand(2, 3, 5, 6)) and (far.grad == 0).all()
    nan_flow = torch.full((2, 2, 5, 6), float("nan"), dtype=D)
    for mode in ("zeros", "border"):
        assert (P.flow_warp(image, nan_flow, padding_mode=mode) == 0).all()


@pytest.mark.parametrize("padding_mode", ["zeros", "border"])
def test_disparity_warp(padding_mode):
    B, C, H, W = 2, 2, 5, 6
    image = rand(B, C, H, W, seed=11)
    disp = rand(B, 1, H, W, seed=12, scale=3.0) + 1.5
    x, y = pixel_grid(H, W)
    ref = sample_ref(image, x - disp[:, 0], y.expand(B, H, W), padding_mode)
    assert torch.allclose(P.disparity_warp(image, disp, padding_mode=padding_mode), ref, atol=1e-12)
    flow = torch.cat([-disp, torch.zeros_like(disp)], dim=1)
    assert torch.equal(P.disparity_warp(image, disp), P.flow_warp(image, flow))
    assert grad_ok(lambda i, d: P.disparity_warp(i, d, padding_mode=padding_mode), image, disp)


def test_disparity_warp_reconstructs_left_view():
    # a rectified pair with constant disparity 2: right(x) = left(x + 2), so left(x) = right(x - 2)
    left = rand(1, 3, 4, 9, seed=13)
    right = torch.zeros_like(left)
    right[..., :-2] = left[..., 2:]
    out = P.disparity_warp(right, torch.full((1, 1, 4, 9), 2.0, dtype=D))
    assert torch.equal(out[..., 2:], left[..., 2:]) and (out[..., :2] == 0).all()


@pytest.mark.parametrize("padding_mode", ["zeros", "border"])
def test_affine_flow_warp_fused_matches_unfused(padding_mode):
    image = rand(2, 3, 5, 6, seed=14)
    params = rand(2, 6, 5, 6, seed=15, scale=0.4) + torch.tensor([1.0, 0, 0, 0, 1, 0], dtype=D).view(1, 6, 1, 1)
    params[:, 2] += 1.3
    fused = P.affine_flow_warp(image, params, padding_mode=padding_mode)
    unfused = P.flow_warp(image, P.affine_flow(params), padding_mode=padding_mode)
    assert torch.allclose(fused, unfused, atol=1e-12)
    assert grad_ok(lambda i, p: P.affine_flow_warp(i, p, padding_mode=padding_mode), image, params)
    w = rand(2, 3, 5, 6, seed=16)
    a = [image.clone().requires_grad_(), params.clone().requires_grad_()]
    b = [image.clone().requires_grad_(), params.clone().requires_grad_()]
    ga = torch.autograd.grad((P.affine_flow_warp(*a, padding_mode=padding_mode) * w).sum(), a)
    gb = torch.autograd.grad((P.flow_warp(b[0], P.affine_flow(b[1]), padding_mode=padding_mode) * w).sum(), b)
    assert all(torch.allclose(u, v, atol=1e-10) for u, v in zip(ga, gb, strict=True))


# ----------------------------------------------------------------------------- 2D flows
def test_affine_flow():
    B, H, W = 2, 5, 6
    p = rand(B, 6, H, W, seed=17, scale=2.0)
    x, y = pixel_grid(H, W)
    ref = torch.stack([p[:, 0] * x + p[:, 1] * y + p[:, 2] - x, p[:, 3] * x + p[:, 4] * y + p[:, 5] - y], 1)
    assert torch.allclose(P.affine_flow(p), ref, atol=1e-12)
    assert grad_ok(P.affine_flow, p)
    ident = torch.tensor([1.0, 0, 0, 0, 1, 0], dtype=D).view(1, 6, 1, 1).expand(B, 6, H, W)
    assert torch.equal(P.affine_flow(ident), torch.zeros(B, 2, H, W, dtype=D))
    trans = ident.clone()
    trans[:, 2], trans[:, 5] = 1.5, -0.25
    f = P.affine_flow(trans)
    assert (f[:, 0] == 1.5).all() and (f[:, 1] == -0.25).all()


def test_se2_flow():
    B, H, W = 2, 5, 6
    p = rand(B, 3, H, W, seed=18, scale=3.0)
    x, y = pixel_grid(H, W)
    c, s = torch.cos(p[:, 0]), torch.sin(p[:, 0])
    ref = torch.stack([x * c - y * s + p[:, 1] - x, x * s + y * c + p[:, 2] - y], 1)
    assert torch.allclose(P.se2_flow(p), ref, atol=1e-12)
    assert grad_ok(P.se2_flow, p)
    assert torch.equal(P.se2_flow(torch.zeros(B, 3, H, W, dtype=D)), torch.zeros(B, 2, H, W, dtype=D))


def test_homography_flow():
    B, H, W = 2, 5, 6
    p = rand(B, 9, H, W, seed=19, scale=0.2) + torch.eye(3, dtype=D).reshape(1, 9, 1, 1)
    x, y = pixel_grid(H, W)
    w = p[:, 6] * x + p[:, 7] * y + p[:, 8]
    ref = torch.stack([(p[:, 0] * x + p[:, 1] * y + p[:, 2]) / w - x, (p[:, 3] * x + p[:, 4] * y + p[:, 5]) / w - y], 1)
    assert torch.allclose(P.homography_flow(p), ref, atol=1e-10)
    assert grad_ok(P.homography_flow, p)
    # identity (at any scale) gives zero flow
    ident = torch.eye(3, dtype=D).reshape(1, 9, 1, 1) * torch.tensor([1.0, -2.5], dtype=D).view(2, 1, 1, 1)
    assert torch.allclose(P.homography_flow(ident.expand(B, 9, H, W)), torch.zeros(B, 2, H, W, dtype=D), atol=1e-14)


def test_homography_flow_singular_denominator():
    # h8 chosen so that w = h6 x + h7 y + h8 is exactly 0, tiny positive or tiny negative
    H, W = 2, 3
    p = torch.eye(3, dtype=D).reshape(1, 9, 1, 1).repeat(3, 1, H, W)
    p[:, 6] = 0.0
    p[:, 8] = torch.tensor([0.0, 1e-9, -1e-9], dtype=D).view(3, 1, 1)
    p = p.requires_grad_()
    flow = P.homography_flow(p)
    flow.sum().backward()
    x, y = pixel_grid(H, W)
    m = P.HOMOGRAPHY_MIN_DEN
    sign = torch.tensor([1.0, 1.0, -1.0], dtype=D).view(3, 1, 1)
    assert torch.isfinite(flow).all() and torch.isfinite(p.grad).all()
    assert torch.allclose(flow[:, 0], x / (sign * m) - x) and torch.allclose(flow[:, 1], y / (sign * m) - y)
    assert (p.grad[:, 6:] == 0).all()  # no gradient through the clamped denominator
    assert (p.grad[:, 0] != 0).any()  # the numerator still gets its (finite) gradient


def test_slanted_plane_disparity():
    p = rand(2, 3, 5, 6, seed=20, scale=2.0)
    x, y = pixel_grid(5, 6)
    ref = (p[:, 0] * x + p[:, 1] * y + p[:, 2]).unsqueeze(1)
    assert torch.allclose(P.slanted_plane_disparity(p), ref, atol=1e-12)
    assert grad_ok(P.slanted_plane_disparity, p)


# ----------------------------------------------------------------------------- 3D per-pixel
def se3_ref(pts, prm):
    return (rotation_ref(prm) @ pts.unsqueeze(-1)).squeeze(-1) + prm[:, 3:6].permute(0, 2, 3, 1)


def sim3_ref(pts, prm):
    s = prm[:, 6].exp().unsqueeze(-1)
    return s * (rotation_ref(prm) @ pts.unsqueeze(-1)).squeeze(-1) + prm[:, 3:6].permute(0, 2, 3, 1)


def t10_ref(pts, prm):
    s = prm[:, 6].exp().unsqueeze(-1)
    anchor = prm[:, 7:10].permute(0, 2, 3, 1)
    moved = (rotation_ref(prm) @ (pts - anchor).unsqueeze(-1)).squeeze(-1) + anchor
    return s * moved + prm[:, 3:6].permute(0, 2, 3, 1)


POINTWISE = [
    (P.pointwise_se3, se3_ref, 6),
    (P.pointwise_sim3, sim3_ref, 7),
    (P.pointwise_transform10, t10_ref, 10),
]


@pytest.mark.parametrize("fn, ref, k", POINTWISE)
def test_pointwise_transforms(fn, ref, k):
    B, H, W = 2, 5, 6
    pts = rand(B, H, W, 3, seed=21, scale=3.0)
    prm = rand(B, k, H, W, seed=22, scale=1.5)
    prm[0, :3, 0, 0] = 0.0  # zero rotation
    prm[0, :3, 0, 1] = torch.tensor([3e-3, -2e-3, 1e-3])  # Taylor branch
    prm[0, :3, 0, 2] = torch.tensor([0.0, 3.0, 0.5])  # beyond pi/2
    assert torch.allclose(fn(pts, prm), ref(pts, prm), atol=1e-12)
    assert grad_ok(fn, pts, prm)
    pg, qg = pts.clone().requires_grad_(), prm.clone().requires_grad_()
    pr, qr = pts.clone().requires_grad_(), prm.clone().requires_grad_()
    w = rand(B, H, W, 3, seed=23)
    g = torch.autograd.grad((fn(pg, qg) * w).sum(), (pg, qg))
    gr = torch.autograd.grad((ref(pr, qr) * w).sum(), (pr, qr))
    assert all(torch.allclose(a, b, atol=1e-10) for a, b in zip(g, gr, strict=True))


@pytest.mark.parametrize("fn, ref, k", POINTWISE)
def test_pointwise_identity_and_zero_rotation_gradcheck(fn, ref, k):
    B, H, W = 2, 3, 4
    pts = rand(B, H, W, 3, seed=24, scale=2.0)
    ident = torch.zeros(B, k, H, W, dtype=D)
    if k == 10:
        ident[:, 7:] = rand(B, 3, H, W, seed=25)  # any anchor: identity when R = I, s = 1, t = 0
    assert torch.allclose(fn(pts, ident), pts, atol=1e-15)
    assert grad_ok(fn, pts, ident)  # omega = 0 exactly: finite, exact gradients


@pytest.mark.parametrize("fn, ref, k", POINTWISE)
def test_pointwise_invalid_points(fn, ref, k):
    # NaN / inf points (a missing depth through depth_to_points) pass through unchanged; their
    # parameters get zero gradient, so a masked loss gives finite gradients everywhere
    B, H, W = 1, 2, 3
    pts = rand(B, H, W, 3, seed=30, scale=2.0)
    pts[0, 0, 1] = math.nan
    pts[0, 1, 2, 2] = math.inf
    prm = rand(B, k, H, W, seed=31).requires_grad_()
    p = pts.clone().requires_grad_()
    out = fn(p, prm)
    bad = ~torch.isfinite(pts).all(-1)
    assert torch.equal(out[bad].isnan(), pts[bad].isnan()) and torch.isfinite(out[~bad]).all()
    assert torch.allclose(out[~bad], ref(pts, prm.detach())[~bad], atol=1e-12)
    ok = torch.isfinite(out)
    (gp, gq) = torch.autograd.grad(torch.where(ok, out, 0.0).sum(), (p, prm))
    assert torch.isfinite(gq).all() and torch.isfinite(gp).all()
    assert (gq.permute(0, 2, 3, 1)[bad] == 0).all() and (gq.permute(0, 2, 3, 1)[~bad] != 0).any()


def test_homography_flow_nan_params():
    p = torch.eye(3, dtype=D).reshape(1, 9, 1, 1).repeat(1, 1, 2, 3)
    p[0, 8, 1, 2] = math.nan  # a NaN denominator must not be mistaken for a tiny one
    flow = P.homography_flow(p)
    assert flow[0, :, 1, 2].isnan().all()
    flow[0, :, 1, 2] = 0.0
    assert torch.equal(flow, torch.zeros_like(flow))


def test_pointwise_special_cases_agree():
    pts = rand(1, 3, 4, 3, seed=26)
    prm = rand(1, 10, 3, 4, seed=27)
    prm[:, 7:] = 0.0
    # transform10 with anchor 0 is sim3; sim3 with sigma 0 is se3
    assert torch.allclose(P.pointwise_transform10(pts, prm), P.pointwise_sim3(pts, prm[:, :7]), atol=1e-14)
    prm[:, 6] = 0.0
    assert torch.allclose(P.pointwise_sim3(pts, prm[:, :7]), P.pointwise_se3(pts, prm[:, :6]), atol=1e-14)


# ----------------------------------------------------------------------------- affine grid
@pytest.mark.filterwarnings("ignore:Since version 1.3.0, affine_grid:UserWarning")
@pytest.mark.parametrize("align_corners", [False, True])
@pytest.mark.parametrize("size", [(2, 3, 5, 6), (2, 1, 1, 4), (2, 1, 3, 1)])
def test_affine_grid_matches_torch(align_corners, size):
    theta = rand(2, 2, 3, seed=28, scale=1.5)
    got = P.affine_grid(theta, size, align_corners=align_corners)
    ref = F.affine_grid(theta, list(size), align_corners=align_corners)
    assert got.shape == ref.shape and torch.allclose(got, ref, atol=1e-14)
    assert grad_ok(lambda t: P.affine_grid(t, size, align_corners=align_corners), theta)
    t1, t2 = theta.clone().requires_grad_(), theta.clone().requires_grad_()
    w = rand(*ref.shape, seed=29)
    (g,) = torch.autograd.grad((P.affine_grid(t1, size, align_corners) * w).sum(), t1)
    (gr,) = torch.autograd.grad((F.affine_grid(t2, list(size), align_corners=align_corners) * w).sum(), t2)
    assert torch.allclose(g, gr, atol=1e-12)
    f32 = P.affine_grid(theta.float(), torch.Size(size), align_corners)
    assert f32.dtype == torch.float32 and torch.allclose(f32.double(), ref, atol=1e-5)


# ----------------------------------------------------------------------------- dtypes and layers
def test_float32_matches_float64():
    image = rand(2, 3, 5, 6, seed=30)
    params = rand(2, 6, 5, 6, seed=31, scale=0.3) + torch.tensor([1.0, 0, 0.5, 0, 1, -0.5], dtype=D).view(1, 6, 1, 1)
    pts = rand(2, 5, 6, 3, seed=32)
    p10 = rand(2, 10, 5, 6, seed=33)
    cases = [
        (P.flow_warp, (image, params[:, :2] * 3)),
        (P.disparity_warp, (image, params[:, :1])),
        (P.affine_flow_warp, (image, params)),
        (P.affine_flow, (params,)),
        (P.se2_flow, (params[:, :3],)),
        (P.homography_flow, (torch.cat([params, params[:, :3] * 0.01], 1),)),
        (P.slanted_plane_disparity, (params[:, :3],)),
        (P.pointwise_se3, (pts, p10[:, :6])),
        (P.pointwise_sim3, (pts, p10[:, :7])),
        (P.pointwise_transform10, (pts, p10)),
        (P.smoothness_loss, (params,)),
    ]
    for fn, args in cases:
        args32 = [a.float().requires_grad_() for a in args]
        out32 = fn(*args32)
        out32.sum().backward()
        assert out32.dtype == torch.float32 and all(a.grad.dtype == torch.float32 for a in args32)
        assert torch.allclose(out32.double(), fn(*args), rtol=1e-4, atol=1e-4), fn.__name__


def test_layers_match_functions():
    image = rand(1, 2, 4, 5, seed=34)
    prm = rand(1, 10, 4, 5, seed=35)
    pts = rand(1, 4, 5, 3, seed=36)
    assert torch.equal(L.FlowWarp("border")(image, prm[:, :2]), P.flow_warp(image, prm[:, :2], padding_mode="border"))
    assert torch.equal(L.DisparityWarp()(image, prm[:, :1]), P.disparity_warp(image, prm[:, :1]))
    assert torch.equal(L.AffineFlowWarp()(image, prm[:, :6]), P.affine_flow_warp(image, prm[:, :6]))
    assert torch.equal(L.AffineFlow()(prm[:, :6]), P.affine_flow(prm[:, :6]))
    assert torch.equal(L.SE2Flow()(prm[:, :3]), P.se2_flow(prm[:, :3]))
    assert torch.equal(L.HomographyFlow()(prm[:, :9]), P.homography_flow(prm[:, :9]))
    assert torch.equal(L.SlantedPlaneDisparity()(prm[:, :3]), P.slanted_plane_disparity(prm[:, :3]))
    assert torch.equal(L.PointwiseSE3()(pts, prm[:, :6]), P.pointwise_se3(pts, prm[:, :6]))
    assert torch.equal(L.PointwiseSim3()(pts, prm[:, :7]), P.pointwise_sim3(pts, prm[:, :7]))
    assert torch.equal(L.PointwiseTransform10()(pts, prm), P.pointwise_transform10(pts, prm))
    theta = rand(1, 2, 3, seed=37)
    assert torch.equal(L.AffineGridGenerator(True)(theta, (1, 2, 4, 5)), P.affine_grid(theta, (1, 2, 4, 5), True))
    assert torch.equal(L.SmoothnessLoss("tukey", 0.5)(prm), P.smoothness_loss(prm, "tukey", 0.5))
    x = rand(3, 4, seed=38, scale=3)
    r = P.robust_rho(x, "cauchy", 0.5)
    assert torch.equal(L.RobustLoss("cauchy", 0.5, reduction="none")(x), r)
    assert torch.allclose(L.RobustLoss("cauchy", 0.5, reduction="sum")(x), r.sum())
    assert torch.allclose(L.RobustLoss("cauchy", 0.5)(x), r.mean())


# ----------------------------------------------------------------------------- argument errors
def test_bad_arguments():
    img = torch.zeros(1, 2, 4, 5, dtype=D)
    prm6 = torch.zeros(1, 6, 4, 5, dtype=D)
    pts = torch.zeros(1, 4, 5, 3, dtype=D)
    cases = [
        (
            lambda: P.flow_warp(img, torch.zeros(1, 3, 4, 5, dtype=D)),
            ValueError,
            r"flow_warp: argument 'flow'",
        ),
        (
            lambda: P.flow_warp(img, torch.zeros(1, 2, 4, 6, dtype=D)),
            ValueError,
            r"flow_warp: argument 'flow' has W",
        ),
        (
            lambda: P.flow_warp(img, torch.zeros(1, 2, 4, 5)),
            TypeError,
            r"flow_warp: argument 'flow' has dtype",
        ),
        (
            lambda: P.flow_warp(img.int(), prm6[:, :2]),
            TypeError,
            r"flow_warp: argument 'image' must be float",
        ),
        (
            lambda: P.flow_warp(img, prm6[:, :2], padding_mode="reflection"),
            ValueError,
            r"flow_warp: argument 'padding_mode'",
        ),
        (lambda: P.disparity_warp(img, prm6[:, :2]), ValueError, r"disparity_warp: argument 'disparity'"),
        (lambda: P.affine_flow_warp(img, prm6[:, :5]), ValueError, r"affine_flow_warp: argument 'params'"),
        (lambda: P.affine_flow(prm6[:, :5]), ValueError, r"affine_flow: argument 'params'"),
        (lambda: P.affine_flow(prm6[0]), ValueError, r"affine_flow: argument 'params'"),
        (lambda: P.se2_flow(prm6), ValueError, r"se2_flow: argument 'params'"),
        (lambda: P.homography_flow(prm6), ValueError, r"homography_flow: argument 'params'"),
        (lambda: P.slanted_plane_disparity(prm6), ValueError, r"slanted_plane_disparity: argument 'params'"),
        (lambda: P.pointwise_se3(pts, prm6[:, :, :3]), ValueError, r"pointwise_se3: argument 'params' has H"),
        (lambda: P.pointwise_sim3(pts, prm6), ValueError, r"pointwise_sim3: argument 'params'"),
        (
            lambda: P.pointwise_transform10(pts[..., :2], prm6),
            ValueError,
            r"pointwise_transform10: argument 'points'",
        ),
        (
            lambda: P.pointwise_se3(pts.numpy(), prm6),
            TypeError,
            r"pointwise_se3: argument 'points' must be a torch",
        ),
        (
            lambda: P.affine_grid(torch.zeros(2, 3, 3, dtype=D), (2, 1, 4, 4)),
            ValueError,
            r"affine_grid: argument 'theta'",
        ),
        (
            lambda: P.affine_grid(torch.zeros(2, 2, 3, dtype=D), (3, 1, 4, 4)),
            ValueError,
            r"affine_grid: argument 'size' has B",
        ),
        (
            lambda: P.affine_grid(torch.zeros(2, 2, 3, dtype=D), (2, 4, 4)),
            ValueError,
            r"affine_grid: argument 'size'",
        ),
        (
            lambda: P.affine_grid(torch.zeros(2, 2, 3, dtype=D), (2, 1, 4.0, 4)),
            TypeError,
            r"affine_grid: argument 'size'",
        ),
        (lambda: P.robust_rho(img, "l2"), ValueError, r"robust_rho: argument 'kind' must be one of"),
        (
            lambda: P.robust_psi(img, "huber", 0.0),
            ValueError,
            r"robust_psi: argument 'scale' must be a positive",
        ),
        (lambda: P.robust_rho(img, "tukey", -1.0), ValueError, r"robust_rho: argument 'scale'"),
        (lambda: P.robust_rho(img, "tukey", float("nan")), ValueError, r"robust_rho: argument 'scale'"),
        (lambda: P.robust_rho(img.long(), "huber"), TypeError, r"robust_rho: argument 'x'"),
        (lambda: P.smoothness_loss(img[0]), ValueError, r"smoothness_loss: argument 'field'"),
        (lambda: P.smoothness_loss(img, "welsch"), ValueError, r"smoothness_loss: argument 'kind'"),
        (lambda: L.RobustLoss("huber", reduction="max"), ValueError, r"RobustLoss: argument 'reduction'"),
        (lambda: L.RobustLoss("hubber"), ValueError, r"RobustLoss: argument 'kind'"),
        (lambda: L.SmoothnessLoss(scale=0), ValueError, r"SmoothnessLoss: argument 'scale'"),
        (lambda: L.FlowWarp("wrap"), ValueError, r"FlowWarp: argument 'padding_mode'"),
    ]
    for fn, exc, match in cases:
        with pytest.raises(exc, match=match):
            fn()


def test_inputs_not_modified_and_noncontiguous_ok():
    image = rand(2, 3, 6, 5, seed=39).transpose(2, 3)  # (2, 3, 5, 6), non-contiguous
    flow = rand(2, 6, 5, 2, seed=40).permute(0, 3, 2, 1)  # (2, 2, 5, 6)
    i0, f0 = image.clone(), flow.clone()
    out = P.flow_warp(image, flow)
    assert torch.equal(image, i0) and torch.equal(flow, f0)
    assert torch.equal(out, P.flow_warp(image.contiguous(), flow.contiguous()))
    assert math.isfinite(out.sum().item())


def test_flow_demo_smoke(tmp_path, capsys):
    import argparse

    from gvnn_warp.cli import flow

    parser = argparse.ArgumentParser(prog="gvnn-warp")
    flow.add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["flow", "--out", str(tmp_path), "--steps", "3", "--size", "48x32", "--seed", "1"])
    assert args.func(args) == 0
    assert (tmp_path / "flow.png").stat().st_size > 10_000
    assert "final mean EPE" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        parser.parse_args(["flow", "--out", str(tmp_path), "--size", "48"])


# opcheck and the wanted-gradients test of these ops: tests/ops/test_compile.py (all ops)


@pytest.mark.parametrize("B", [1, 3])
def test_threaded_launches_bitwise_equal_single_thread(B):
    """Big enough to be split over threads (and, for B = 1, to cut a batch item into pieces):
    outputs and gradients must not depend on the thread count."""
    from gvnn_warp.kernels.core import launch

    H, W = 96, 128  # 12288 pixels per batch item: split even for B = 1
    image = rand(B, 3, H, W, seed=60)
    prm = rand(B, 10, H, W, seed=61)
    prm[:, 2] += 2.5  # shift samples across pixel and image borders
    pts = rand(B, H, W, 3, seed=62)
    theta = rand(B, 2, 3, seed=63)
    calls = [
        lambda i, p, q, t: P.flow_warp(i, p[:, :2] * 3, padding_mode="border"),
        lambda i, p, q, t: P.disparity_warp(i, p[:, :1] * 3),
        lambda i, p, q, t: P.affine_flow_warp(i, p[:, :6] * 0.05 + torch.eye(2, 3, dtype=D).reshape(1, 6, 1, 1)),
        lambda i, p, q, t: P.homography_flow(p[:, :9] * 0.1 + torch.eye(3, dtype=D).reshape(1, 9, 1, 1)),
        lambda i, p, q, t: P.pointwise_transform10(q, p),
        lambda i, p, q, t: P.affine_grid(t, (B, 3, H, W)),
        lambda i, p, q, t: P.robust_rho(p, "tukey", 0.5),
        lambda i, p, q, t: P.smoothness_loss(p, "cauchy", 0.3),
    ]

    def run(n_threads):
        launch.set_num_threads(n_threads)
        try:
            results = []
            for fn in calls:
                args = [a.clone().requires_grad_() for a in (image, prm, pts, theta)]
                out = fn(*args)
                out.backward(torch.ones_like(out))
                results.append([out.detach(), *[a.grad for a in args]])
            return results
        finally:
            launch.set_num_threads(None)

    for one, two in zip(run(1), run(2), strict=True):
        for a, b in zip(one, two, strict=True):
            assert (a is None and b is None) or torch.equal(a, b)
