"""The Warp bilinear sampler against torch.nn.functional.grid_sample: values and gradients."""

import pytest
import torch
import torch.nn.functional as F
from torch.autograd import gradcheck

import gvnn_warp as G

# Output sizes: 5 x 6 takes the one-location-per-thread kernel, 4 x 6 (a multiple of 8) the
# 8-lane forward kernel (see bilinear_sample)
SIZES = [(5, 6), (4, 6)]


@pytest.mark.parametrize("h,w", SIZES)
@pytest.mark.parametrize("align_corners", [False, True])
@pytest.mark.parametrize("padding_mode", ["zeros", "border"])
def test_bilinear_sample_matches_grid_sample(h, w, align_corners, padding_mode, dtype):
    g = torch.Generator().manual_seed(0)
    image = torch.rand(2, 3, 7, 9, generator=g, dtype=dtype)
    grid = (torch.rand(2, h, w, 2, generator=g, dtype=dtype) * 2.6 - 1.3)  # ~20% outside
    grid[0, 0, 0] = torch.tensor([-1.0, 1.0])  # exact corners
    kw = dict(align_corners=align_corners, padding_mode=padding_mode)
    i1, g1 = image.clone().requires_grad_(), grid.clone().requires_grad_()
    i2, g2 = image.clone().requires_grad_(), grid.clone().requires_grad_()
    out = G.bilinear_sample(i1, g1, **kw)
    ref = F.grid_sample(i2, g2, mode="bilinear", **kw)
    atol = 1e-6 if dtype == torch.float32 else 1e-13
    torch.testing.assert_close(out, ref, rtol=0, atol=atol)
    w = torch.randn_like(ref)
    (out * w).sum().backward()
    (ref * w).sum().backward()
    torch.testing.assert_close(i1.grad, i2.grad, rtol=0, atol=atol * 10)
    torch.testing.assert_close(g1.grad, g2.grad, rtol=1e-4 if dtype == torch.float32 else 1e-10, atol=atol * 100)


@pytest.mark.parametrize("h,w", [(3, 3), (2, 4)])
@pytest.mark.parametrize("align_corners", [False, True])
@pytest.mark.parametrize("padding_mode", ["zeros", "border"])
def test_bilinear_sample_gradcheck(h, w, align_corners, padding_mode):
    g = torch.Generator().manual_seed(1)
    image = torch.rand(1, 2, 4, 5, generator=g, dtype=torch.float64, requires_grad=True)
    grid = (torch.rand(1, h, w, 2, generator=g, dtype=torch.float64) * 2.4 - 1.2).requires_grad_()
    assert gradcheck(
        lambda i, q: G.bilinear_sample(i, q, align_corners=align_corners, padding_mode=padding_mode), (image, grid)
    )


def test_worked_example_align_corners():
    # W = 4: with align_corners=False gx = 0 is pixel x = 1.5, with True gx = 0 is x = 1.5 too,
    # but gx = -1 is x = -0.5 (half zero padding) vs x = 0.
    image = torch.tensor([[[[0.0, 10.0, 20.0, 30.0]]]])
    grid = torch.tensor([[[[0.0, 0.0], [-1.0, 0.0]]]])
    torch.testing.assert_close(G.bilinear_sample(image, grid), torch.tensor([[[[15.0, 0.0]]]]))
    torch.testing.assert_close(G.bilinear_sample(image, grid, align_corners=True), torch.tensor([[[[15.0, 0.0]]]]))
    grid = torch.tensor([[[[-0.5, 0.0]]]])  # x = 0.5 (align False) / 0.75 (align True)
    torch.testing.assert_close(G.bilinear_sample(image, grid), torch.tensor([[[[5.0]]]]))
    torch.testing.assert_close(G.bilinear_sample(image, grid, align_corners=True), torch.tensor([[[[7.5]]]]))


@pytest.mark.parametrize("extra", [0, 5])  # 3 locations: one per thread; 8: the 8-lane kernel
def test_non_finite_grid_gives_defined_values_and_finite_gradient(extra):
    image = torch.rand(1, 1, 4, 4, dtype=torch.float64, requires_grad=True)
    grid = torch.tensor([[[[float("nan"), 0.0], [float("inf"), 0.0], [0.1, -float("inf")]]]], dtype=torch.float64)
    grid = torch.cat([grid, torch.full((1, 1, extra, 2), float("nan"), dtype=torch.float64)], dim=2)
    grid.requires_grad_()
    out = G.bilinear_sample(image, grid, padding_mode="zeros")
    assert (out == 0).all()
    out.sum().backward()
    assert torch.isfinite(grid.grad).all() and torch.isfinite(image.grad).all()
    # border clamps +-inf onto the edge (as grid_sample does); NaN samples 0
    grid.grad = None
    out = G.bilinear_sample(image, grid, padding_mode="border")
    assert out[0, 0, 0, 0] == 0
    assert (out[..., 3:] == 0).all()
    ref = F.grid_sample(image, grid[:, :, 1:3], padding_mode="border", align_corners=False)
    torch.testing.assert_close(out[:, :, :, 1:3], ref)
    out.sum().backward()
    assert torch.isfinite(grid.grad).all()
    assert grid.grad[0, 0, 0, 0] == 0 and grid.grad[0, 0, 1, 0] == 0 and grid.grad[0, 0, 2, 1] == 0  # clamped


def _bits(t):
    """The raw bits of a float tensor: equal bits also means equal signs of zero and equal NaNs."""
    return t.view(torch.int32 if t.dtype == torch.float32 else torch.int64)


@pytest.mark.parametrize("C", [1, 2, 4, 6])  # 4 = the channels the kernels unroll; 6: more
@pytest.mark.parametrize("H,W", [(6, 7), (1, 5), (5, 1), (1, 1)])
@pytest.mark.parametrize("align_corners", [0, 1])
@pytest.mark.parametrize("padding", [0, 1])
def test_lanes_kernel_equals_scalar_kernel(C, H, W, align_corners, padding, dtype):
    """The 8-lane forward kernel gives bitwise the values of the one-location-per-thread kernel
    (whose adjoint it shares): inside, outside, on the edges, for non-finite positions and for
    NaN/inf pixels next to the samples."""
    from gvnn_warp.ops import sampling as _ops

    g = torch.Generator().manual_seed(3)
    B, hw = 2, 64
    image = torch.randn(B, C, H, W, generator=g, dtype=dtype)  # negative values: signs of zero
    image[0, 0, 0, 0] = float("nan")
    image[0, -1, -1, -1] = float("inf")
    image[1, 0, H - 1, 0] = -float("inf")
    grid = torch.rand(B * hw, 2, generator=g, dtype=dtype) * 2.8 - 1.4
    # pixel x = W - 1 and x = W exactly (and likewise y) for both conventions
    ex = (2 * (W - 1) / (W - 1 if align_corners else W)) - 1 if W > 1 else 0.0
    fx = (2 * W / (W - 1 if align_corners else W)) - 1 if W > 1 else 2.0
    ey = (2 * (H - 1) / (H - 1 if align_corners else H)) - 1 if H > 1 else 0.0
    special = [
        [-1.0, -1.0], [1.0, 1.0], [-1.0, 1.0], [1.0, -1.0], [0.0, 1.0 + 1e-7], [-1.0 - 1e-7, 0.0],
        [float("nan"), 0.0], [0.0, float("nan")], [float("inf"), 0.5], [-float("inf"), 0.5],
        [0.5, float("inf")], [0.5, -float("inf")], [ex, 0.0], [fx, 0.0], [0.0, ey], [-5.0, -5.0],
        [5.0, 5.0], [ex, ey], [-0.0, -0.0], [1e30, 0.0],
    ]
    grid[: len(special)] = torch.tensor(special, dtype=dtype)
    grid[hw : hw + len(special)] = torch.tensor(special, dtype=dtype)
    args = (C, H, W, hw, align_corners, padding)
    lanes = _ops.bilinear_sample_lanes(image, grid, *args)
    scalar = _ops.bilinear_sample(image, grid, *args)
    assert torch.equal(_bits(lanes), _bits(scalar))


@pytest.mark.parametrize("C", [1, 3, 6])  # 6: more than the kernels unroll
@pytest.mark.parametrize("align_corners", [0, 1])
@pytest.mark.parametrize("padding", [0, 1])
@pytest.mark.parametrize("image_grad", [True, False], ids=["image-grad", "image-data"])
def test_lanes_adjoint_equals_scalar_adjoint(C, align_corners, padding, image_grad, dtype):
    """The 8-lane kernel's hand-written adjoint gives the one-location-per-thread kernel's (Warp's
    adjoint of its code) gradients for the image and the grid, up to the order of the sums: samples
    inside, across the edges, outside, on the border padding's clamp and at non-finite positions;
    both of its paths (with and without the image gradient). A NaN incoming gradient where a sample
    passes none (outside, a non-finite position) changes nothing. With NaN and inf pixels, the
    gradients of what samples them are NaN in both, at the same places."""
    from gvnn_warp.ops import sampling as _ops

    H, W, B, hw = 7, 9, 2, 64
    tol = {"rtol": 1e-10, "atol": 1e-10} if dtype == torch.float64 else {"rtol": 1e-5, "atol": 1e-5}
    args = (C, H, W, hw, align_corners, padding)
    for bad_pixels in (False, True):
        g = torch.Generator().manual_seed(C + 10 * padding)
        image = torch.randn(B, C, H, W, generator=g, dtype=dtype)
        if bad_pixels:
            image[0, 0, 2, 3] = float("nan")
            image[1, -1, 4, 5] = float("inf")
        grid = torch.rand(B * hw, 2, generator=g, dtype=dtype) * 2.8 - 1.4
        grid[:6] = torch.tensor([[float("nan"), 0.0], [0.0, float("inf")], [-5.0, 0.2], [0.3, 5.0], [-1.0, -1.0],
                                 [1.0, 1.0]], dtype=dtype)
        g_out = torch.randn(B, C, hw, generator=g, dtype=dtype)
        # where a sample reads nothing: a NaN incoming gradient (a NaN position; with zeros padding also
        # one whose taps all miss the image, an infinite one included; the border padding clamps those)
        x = grid[:, 0].reshape(B, hw)
        y = grid[:, 1].reshape(B, hw)
        span = 1.0 + (1.0 / (W - 1) if align_corners else 1.0 / W) * 2
        silent = x.isnan() | y.isnan()
        if padding == 0:
            silent |= (x.abs() > span + 0.3) | (y.abs() > span + 0.3)
        g_out = torch.where(silent[:, None], float("nan"), g_out)
        grads = []
        for op in (_ops.bilinear_sample_lanes, _ops.bilinear_sample):
            im, gr = image.clone().requires_grad_(image_grad), grid.clone().requires_grad_()
            op(im, gr, *args).backward(g_out)
            grads.append((im.grad, gr.grad))
        (li, lg), (si, sg) = grads
        if not image_grad:  # (the backward took the variant compiled without the image gradient)
            from gvnn_warp.kernels.core import cache

            key = f"C={C if C <= 4 else None}, align_corners={align_corners}, padding={padding}, image_grad=False"
            assert f"sampling.bilinear_sample_lanes({key})" in cache.entries()
        if image_grad:
            if not bad_pixels:
                assert torch.isfinite(li).all() and (li != 0).any()
            torch.testing.assert_close(li, si, **tol, equal_nan=True)
        else:
            assert li is None and si is None
        if not bad_pixels:
            assert torch.isfinite(lg).all() and (lg != 0).any()
        torch.testing.assert_close(lg, sg, **tol, equal_nan=True)
        assert (lg.reshape(B, hw, 2)[silent] == 0).all()


def test_bilinear_sample_takes_the_lanes_kernel_where_it_applies(monkeypatch):
    from gvnn_warp.ops import sampling as _ops

    calls = []
    lanes = _ops.bilinear_sample_lanes
    monkeypatch.setattr(_ops, "bilinear_sample_lanes", lambda *a: calls.append(a) or lanes(*a))
    image = torch.rand(1, 1, 5, 5)
    G.bilinear_sample(image, torch.zeros(1, 3, 3, 2))
    assert not calls
    G.bilinear_sample(image, torch.zeros(1, 2, 4, 2))
    assert len(calls) == 1
