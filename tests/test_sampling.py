"""The Warp bilinear sampler against torch.nn.functional.grid_sample: values and gradients."""

import pytest
import torch
import torch.nn.functional as F
from torch.autograd import gradcheck

import gvnn_warp as G


@pytest.mark.parametrize("align_corners", [False, True])
@pytest.mark.parametrize("padding_mode", ["zeros", "border"])
def test_bilinear_sample_matches_grid_sample(align_corners, padding_mode, dtype):
    g = torch.Generator().manual_seed(0)
    image = torch.rand(2, 3, 7, 9, generator=g, dtype=dtype)
    grid = (torch.rand(2, 5, 6, 2, generator=g, dtype=dtype) * 2.6 - 1.3)  # ~20% outside
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


@pytest.mark.parametrize("align_corners", [False, True])
@pytest.mark.parametrize("padding_mode", ["zeros", "border"])
def test_bilinear_sample_gradcheck(align_corners, padding_mode):
    g = torch.Generator().manual_seed(1)
    image = torch.rand(1, 2, 4, 5, generator=g, dtype=torch.float64, requires_grad=True)
    grid = (torch.rand(1, 3, 3, 2, generator=g, dtype=torch.float64) * 2.4 - 1.2).requires_grad_()
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


def test_non_finite_grid_gives_defined_values_and_finite_gradient():
    image = torch.rand(1, 1, 4, 4, dtype=torch.float64, requires_grad=True)
    grid = torch.tensor([[[[float("nan"), 0.0], [float("inf"), 0.0], [0.1, -float("inf")]]]], dtype=torch.float64)
    grid.requires_grad_()
    out = G.bilinear_sample(image, grid, padding_mode="zeros")
    assert (out == 0).all()
    out.sum().backward()
    assert torch.isfinite(grid.grad).all() and torch.isfinite(image.grad).all()
    # border clamps +-inf onto the edge (as grid_sample does); NaN samples 0
    grid.grad = None
    out = G.bilinear_sample(image, grid, padding_mode="border")
    assert out[0, 0, 0, 0] == 0
    ref = F.grid_sample(image, grid[:, :, 1:], padding_mode="border", align_corners=False)
    torch.testing.assert_close(out[:, :, :, 1:], ref)
    out.sum().backward()
    assert torch.isfinite(grid.grad).all()
    assert grid.grad[0, 0, 0, 0] == 0 and grid.grad[0, 0, 1, 0] == 0 and grid.grad[0, 0, 2, 1] == 0  # clamped
