"""Property-based tests (hypothesis) over random shapes, poses and depths."""

import math

import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from refs import intrinsics

import gvnn_warp as G

SETTINGS = settings(max_examples=25, deadline=None)
finite = st.floats(-10, 10, allow_nan=False)
vec3 = st.lists(finite, min_size=3, max_size=3)


def _t(x):
    return torch.tensor(x, dtype=torch.float64)


@SETTINGS
@given(w=vec3)
def test_so3_exp_inverse_and_log(w):
    w = _t(w)
    R = G.so3_exp(w)
    torch.testing.assert_close(R @ G.so3_exp(-w), torch.eye(3, dtype=torch.float64), rtol=0, atol=1e-12)
    torch.testing.assert_close(G.so3_exp(G.so3_log(R)), R, rtol=0, atol=1e-10)
    theta = w.norm()
    if theta < math.pi - 1e-3:
        torch.testing.assert_close(G.so3_log(R), w, rtol=0, atol=1e-9)


@SETTINGS
@given(w=vec3, u=vec3)
def test_se3_log_exp_round_trip(w, u):
    xi = torch.cat([_t(w), _t(u)])
    T = G.se3_exp(xi)
    torch.testing.assert_close(G.se3_exp(G.se3_log(T)), T, rtol=1e-9, atol=1e-9)


@SETTINGS
@given(xi1=st.lists(finite, min_size=6, max_size=6), xi2=st.lists(finite, min_size=6, max_size=6),
       n=st.integers(1, 5), B=st.integers(1, 3))
def test_transform_composition(xi1, xi2, n, B):
    T1 = G.se3_to_matrix(_t(xi1)).expand(B, 3, 4)
    T2 = G.se3_to_matrix(_t(xi2)).expand(B, 3, 4)
    p = torch.randn(B, n, 3, dtype=torch.float64)
    T21 = torch.cat([T2[:, :, :3] @ T1[:, :, :3], T2[:, :, :3] @ T1[:, :, 3:] + T2[:, :, 3:]], -1)
    torch.testing.assert_close(G.transform_points(T2, G.transform_points(T1, p)), G.transform_points(T21, p))


@SETTINGS
@given(B=st.integers(1, 3), C=st.integers(1, 4), H=st.integers(1, 9), W=st.integers(1, 9),
       dmin=st.floats(0.01, 5), f=st.floats(0.3, 50))
def test_identity_pose_warps_image_onto_itself(B, C, H, W, dmin, f):
    image = torch.rand(B, C, H, W)
    depth = torch.rand(B, 1, H, W) * 3 + dmin
    warped, valid = G.warp_frame_depth(image, depth, torch.eye(4).expand(B, 4, 4), intrinsics(W, H, torch.float32, f=f))
    assert valid.all()
    torch.testing.assert_close(warped, image, rtol=0, atol=1e-5)


special = st.sampled_from([0.0, -1.0, float("nan"), float("inf"), -float("inf"), 1e-9, 1e-3, 1e6])


@SETTINGS
@given(depths=st.lists(st.one_of(special, st.floats(0.01, 20)), min_size=12, max_size=12),
       xi=st.lists(st.floats(-5, 5), min_size=6, max_size=6), pad=st.sampled_from(["zeros", "border"]))
def test_gradients_finite_everywhere(depths, xi, pad):
    image = torch.rand(1, 2, 3, 4, dtype=torch.float64, requires_grad=True)
    depth = _t(depths).reshape(1, 1, 3, 4).requires_grad_()
    xi = _t(xi)[None].requires_grad_()
    K = intrinsics(4, 3).requires_grad_()
    warped, valid = G.warp_frame_depth(image, depth, G.se3_to_matrix(xi), K, padding_mode=pad)
    assert torch.isfinite(warped).all()
    (warped * torch.rand_like(warped)).sum().backward()
    for t in (image, depth, xi, K):
        assert torch.isfinite(t.grad).all()
    bad = ~(torch.isfinite(depth) & (depth > 1e-3))
    assert (depth.grad[bad] == 0).all() and not valid[bad].any()
