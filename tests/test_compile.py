"""torch.library integration: opcheck for every registered op, torch.compile(fullgraph=True)."""

import pytest
import torch
from refs import assert_only_wanted_gradients, intrinsics

import gvnn_warp as G
from gvnn_warp import _ops


def _samples():
    g = torch.Generator().manual_seed(0)
    f64 = torch.float64

    def r(*s):
        return torch.rand(*s, generator=g, dtype=f64)

    B, C, H, W = 2, 2, 5, 6
    K = intrinsics(W, H).expand(B, 3, 3).contiguous()
    pose = G.se3_to_matrix(r(B, 6) * 0.1).contiguous()
    return {
        "so3_exp": (r(3, 3),),
        "so3_log": (G.so3_exp(r(3, 3)),),
        "quaternion_to_matrix": (r(3, 4),),
        "euler_to_matrix": (r(3, 3), 2, 1, 0),
        "se3_to_matrix": (r(3, 3), r(3, 3)),
        "sim3_to_matrix": (r(3, 3), r(3, 3), r(3)),
        "se3_exp": (r(3, 3), r(3, 3)),
        "se3_log": (G.se3_exp(r(3, 6)).contiguous(),),
        "depth_to_points": (r(B * H * W) + 1, K, H, W),
        "transform_points": (pose, r(B * 4, 3), 4),
        "project_points": (r(B * 4, 3) + 1, K, 4, 1e-3),
        "bilinear_sample": (r(B, C, H, W), r(B * 12, 2) * 2 - 1, C, H, W, 12, 0, 0),
        "bilinear_sample_lanes": (r(B, C, H, W), r(B * 16, 2) * 2 - 1, C, H, W, 16, 1, 1),
        "warp_frame_depth": (r(B, C, H, W), r(B, 1, H, W) + 1, pose, K, C, H, W, 1e-3, 0),
    }


@pytest.mark.parametrize("name", list(_samples()))
def test_opcheck(name):
    args = tuple(a.requires_grad_() if isinstance(a, torch.Tensor) else a for a in _samples()[name])
    torch.library.opcheck(getattr(_ops, name), args)


@pytest.mark.parametrize("name", list(_samples()))
def test_only_wanted_gradients_are_computed(name):
    """The backward computes the gradients torch asks for (needs_input_grad), bitwise the same."""
    assert_only_wanted_gradients(getattr(_ops, name), _samples()[name])


def test_compile_fullgraph_matches_eager():
    B, C, H, W = 2, 3, 8, 10
    K = intrinsics(W, H, dtype=torch.float32)
    image = torch.rand(B, C, H, W)
    depth = torch.rand(B, 1, H, W) + 1

    def loss_fn(xi, image, depth):
        warped, valid = G.warp_frame_depth(image, depth, G.se3_to_matrix(xi), K)
        return ((warped - image) * valid).square().mean()

    compiled = torch.compile(loss_fn, fullgraph=True)
    xi1 = torch.tensor([[0.01, -0.02, 0.0, 0.03, 0.0, 0.01]] * B, requires_grad=True)
    xi2 = xi1.detach().clone().requires_grad_()
    l1 = loss_fn(xi1, image, depth)
    l2 = compiled(xi2, image, depth)
    l1.backward()
    l2.backward()
    torch.testing.assert_close(l1, l2)
    torch.testing.assert_close(xi1.grad, xi2.grad)


def test_backward_from_needs_the_same_signature():
    from gvnn_warp._bridge import Output, Param, warp_op

    with pytest.raises(ValueError, match="backward_from must be a warp_op with the same inputs"):
        warp_op(
            "never_registered", None, ["image", "grid"], [Param("C", "int")],
            [Output("out", "vec8", lambda *a: (1,))], lambda *a: 0,
            backward_from=_ops.bilinear_sample,
            select=lambda *a: None,
            array_kinds={"image": "scalar", "grid": "vec16"},
        )
