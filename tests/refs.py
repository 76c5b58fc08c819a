"""Independent float64 references and shared helpers for the tests, written with plain torch."""

import math

import torch


def tol(dtype):
    """(rtol, atol) for comparing against a float64 reference."""
    return (1e-5, 1e-5) if dtype == torch.float32 else (1e-10, 1e-11)


def skew(w):
    """(..., 3) -> (..., 3, 3) with skew(w) @ p = cross(w, p)."""
    z = torch.zeros_like(w[..., 0])
    return torch.stack(
        [
            torch.stack([z, -w[..., 2], w[..., 1]], -1),
            torch.stack([w[..., 2], z, -w[..., 0]], -1),
            torch.stack([-w[..., 1], w[..., 0], z], -1),
        ],
        -2,
    )


def rotvec_with_angle(angle, n=1, seed=0, dtype=torch.float64):
    """n random rotation vectors of exactly this angle."""
    g = torch.Generator().manual_seed(seed)
    axis = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=torch.float64), dim=-1)
    return (axis * angle).to(dtype)


def pose44(T34):
    """(B, 3, 4) -> (B, 4, 4) with last row [0, 0, 0, 1]."""
    bottom = torch.zeros(*T34.shape[:-2], 1, 4, dtype=T34.dtype)
    bottom[..., 0, 3] = 1
    return torch.cat([T34, bottom], dim=-2)


def intrinsics(W, H, dtype=torch.float64, f=None, skew_=0.0):
    f = f if f is not None else 0.9 * W
    return torch.tensor([[f, skew_, (W - 1) / 2], [0.0, f * 1.05, (H - 1) / 2], [0.0, 0.0, 1.0]], dtype=dtype)


ANGLES = {
    "zero": 0.0,
    "tiny": 1e-8,
    "small": 3e-3,
    "generic": 1.2,
    "near_pi": math.pi - 1e-3,
}



def gradients_of(op, args, wanted):
    """Gradients of a fixed random weighting of the float outputs of ``op(*args)`` with respect to
    its float tensor arguments, of which only those whose position (counting float tensors only)
    is in ``wanted`` require grad. One entry per float tensor argument, None where not wanted."""
    call, leaves = [], []
    for a in args:
        if isinstance(a, torch.Tensor) and a.is_floating_point():
            a = a.detach().clone().requires_grad_(len(leaves) in wanted)
            leaves.append(a)
        call.append(a)
    weighted_backward(op(*call), seed=7)
    return [t.grad for t in leaves]


def weighted_backward(outs, seed):
    """Backpropagate a fixed random weighting (from ``seed``) of the float tensors in ``outs`` (one
    tensor or a tuple/list). Returns ``outs`` as a tuple."""
    outs = outs if isinstance(outs, (tuple, list)) else (outs,)
    g = torch.Generator().manual_seed(seed)
    loss = sum((o * torch.randn(o.shape, generator=g, dtype=o.dtype)).sum() for o in outs if o.is_floating_point())
    loss.backward()
    return tuple(outs)


def assert_only_wanted_gradients(op, args):
    """Asking for the gradient of one tensor argument (or of all but one) gives exactly (bitwise)
    what asking for all gives, and None for the others."""
    n = sum(isinstance(a, torch.Tensor) and a.is_floating_point() for a in args)
    full = gradients_of(op, args, set(range(n)))
    assert all(g is not None for g in full)
    subsets = [{k} for k in range(n)] + ([set(range(n)) - {k} for k in range(n)] if n > 2 else [])
    for wanted in subsets:
        got = gradients_of(op, args, wanted)
        for k, (a, b) in enumerate(zip(got, full)):
            if k in wanted:
                assert torch.equal(a, b), f"gradient {k} differs when only {sorted(wanted)} are wanted"
            else:
                assert a is None
