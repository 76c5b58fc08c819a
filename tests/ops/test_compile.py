"""torch.library integration: opcheck for every registered op, torch.compile(fullgraph=True)."""

import pytest
import torch
from op_samples import OPS, op_samples
from refs import assert_only_wanted_gradients, intrinsics

import gvnn_warp as G
from gvnn_warp.ops import sampling as _ops

OP_NAMES = sorted(OPS)  # every registered op; samples in tests/op_samples.py


@pytest.mark.parametrize("name", OP_NAMES)
def test_opcheck(name):
    """Schema, fake (meta) implementation, autograd registration and AOTAutograd tracing (the part
    of torch.compile that needs the fake and autograd registrations) of every op (the floating
    arguments of a differentiable one require grad)."""
    spec = OPS[name]
    args = tuple(a.requires_grad_() if torch.is_tensor(a) and a.is_floating_point() and spec.differentiable else a
                 for a in op_samples()[name])
    torch.library.opcheck(spec.op, args)


@pytest.mark.parametrize("name", OP_NAMES)
def test_only_wanted_gradients_are_computed(name):
    """The backward computes the gradients torch asks for (needs_input_grad), bitwise the same."""
    spec = OPS[name]
    if not spec.differentiable:
        pytest.skip(f"{name} is not differentiable")
    if "gradients" in spec.untested:
        pytest.skip(f"{name}: {spec.untested['gradients']}")
    assert_only_wanted_gradients(spec.op, op_samples()[name])


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


@pytest.mark.parametrize("model", ["radtan", "fisheye"])
def test_compile_fullgraph_through_a_lens_camera_matches_eager(model):
    # the camera made inside the compiled function, its coefficients learnt: the domain bound of its
    # lens is an op in the graph (it used to be computed in numpy from the tensor's values)
    torch._dynamo.reset()  # (each model compiled on its own: no shapes turned dynamic by the other case)
    B, C, H, W = 2, 3, 8, 10
    K = intrinsics(W, H, dtype=torch.float64)
    image = torch.rand(B, C, H, W, dtype=torch.float64)
    depth = torch.rand(B, 1, H, W, dtype=torch.float64) + 1
    camera = G.RadTanCamera if model == "radtan" else G.FisheyeCamera
    coeffs = [0.2624, -0.9531, -0.0054, 0.0026, 1.1633] if model == "radtan" else [0.08, -0.02, 0.004, -0.001]

    def loss_fn(xi, dist):
        cam = camera(K, dist)
        warped, valid = G.warp_frame_depth(image, depth, G.se3_to_matrix(xi), cam)
        target = image.flip(-1)
        loss = ((warped - image) * valid).square().mean()
        return loss + G.reprojection_loss(image, target[:, None], depth, G.se3_to_matrix(xi)[:, None], cam).mean()

    compiled = torch.compile(loss_fn, fullgraph=True)
    args = [torch.tensor([[0.01, -0.02, 0.0, 0.03, 0.0, 0.01]] * B, dtype=torch.float64),
            torch.tensor(coeffs, dtype=torch.float64)]
    eager = [a.clone().requires_grad_() for a in args]
    traced = [a.clone().requires_grad_() for a in args]
    l1, l2 = loss_fn(*eager), compiled(*traced)
    l1.backward()
    l2.backward()
    torch.testing.assert_close(l1, l2, rtol=1e-12, atol=1e-12)
    for a, b in zip(eager, traced):
        torch.testing.assert_close(a.grad, b.grad, rtol=1e-10, atol=1e-12)


def test_backward_from_needs_the_same_signature():
    from gvnn_warp.ops.bridge import warp_op
    from gvnn_warp.ops.registry import Output, Param

    with pytest.raises(ValueError, match="backward_from must be a warp_op with the same inputs"):
        warp_op(
            "never_registered", None, ["image", "grid"], [Param("C", "int")],
            [Output("out", "vec8", lambda *a: (1,))], lambda *a: 0, function="bilinear_sample",
            layer="BilinearSampler", backward_from=_ops.bilinear_sample,
            select=lambda *a: None,
            array_kinds={"image": "scalar", "grid": "vec16"},
        )


def test_backward_from_and_backward_select_exclude_each_other():
    from gvnn_warp.ops.bridge import warp_op
    from gvnn_warp.ops.registry import Output
    from gvnn_warp.ops.sampling import _SAMPLE_PARAMS

    with pytest.raises(ValueError, match="backward_from and backward_select exclude each other"):
        warp_op(
            "never_registered", None, ["image", "grid"], _SAMPLE_PARAMS,
            [Output("out", "vec8", lambda *a: (1,))], lambda *a: 0, function="bilinear_sample",
            layer="BilinearSampler", backward_from=_ops.bilinear_sample, select=lambda *a: None,
            backward_select=lambda *a: None, array_kinds={"image": "scalar", "grid": "vec16"},
        )
