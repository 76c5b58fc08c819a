"""so3 / quaternion / Euler / SE3 / Sim3 layers against independent references (matrix_exp,
closed forms, kornia) and float64 finite differences, including 0, 1e-8 and pi - 1e-3."""

import math

import kornia
import numpy as np
import pytest
import torch
from refs import ANGLES, rotvec_with_angle, skew, tol
from torch.autograd import gradcheck

import gvnn_warp as G


def ref_so3_exp(w):
    return torch.linalg.matrix_exp(skew(w.double()))


@pytest.mark.parametrize("name", list(ANGLES))
def test_so3_exp_matches_matrix_exp(name, dtype):
    w = rotvec_with_angle(ANGLES[name], n=5, dtype=dtype)
    R = G.so3_exp(w)
    assert R.dtype == dtype and R.shape == (5, 3, 3)
    torch.testing.assert_close(R.double(), ref_so3_exp(w), rtol=tol(dtype)[0], atol=tol(dtype)[1])


def test_so3_exp_large_angles_and_orthonormality():
    w = torch.randn(200, 3, dtype=torch.float64) * 4.0  # angles well beyond pi
    R = G.so3_exp(w)
    torch.testing.assert_close(R, ref_so3_exp(w), rtol=1e-10, atol=1e-11)
    eye = torch.eye(3, dtype=torch.float64).expand(200, 3, 3)
    torch.testing.assert_close(R @ R.transpose(-1, -2), eye, rtol=0, atol=1e-12)
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(200, dtype=torch.float64))


@pytest.mark.parametrize("name", list(ANGLES))
def test_so3_exp_gradcheck(name):
    w = rotvec_with_angle(ANGLES[name], n=3).requires_grad_()
    assert gradcheck(G.so3_exp, (w,))


def test_so3_exp_gradient_at_zero_is_exact():
    # d R / d w_i at 0 is hat(e_i): the gradient of <G, R> is vee(G - G^T)/2 * 2 = (G32 - G23, ...)
    w = torch.zeros(1, 3, dtype=torch.float64, requires_grad=True)
    Gm = torch.randn(1, 3, 3, dtype=torch.float64)
    (G.so3_exp(w) * Gm).sum().backward()
    expected = torch.stack([Gm[0, 2, 1] - Gm[0, 1, 2], Gm[0, 0, 2] - Gm[0, 2, 0], Gm[0, 1, 0] - Gm[0, 0, 1]])
    torch.testing.assert_close(w.grad[0], expected, rtol=0, atol=1e-15)


@pytest.mark.parametrize("name", list(ANGLES))
def test_so3_log_round_trip(name, dtype):
    w = rotvec_with_angle(ANGLES[name], n=5, dtype=dtype)
    w_back = G.so3_log(G.so3_exp(w))
    atol = 2e-6 if dtype == torch.float32 else 1e-10
    if name == "near_pi" and dtype == torch.float32:
        atol = 5e-4  # the axis at pi - 1e-3 is conditioned by 1 / sin(theta)
    torch.testing.assert_close(w_back, w, rtol=0, atol=atol)


def test_so3_log_at_pi_and_beyond():
    # at exactly pi either sign is a logarithm: check exp(log(R)) == R and |log| == pi
    w = rotvec_with_angle(math.pi, n=8, seed=3)
    R = G.so3_exp(w)
    w_back = G.so3_log(R)
    torch.testing.assert_close(w_back.norm(dim=-1), torch.full((8,), math.pi, dtype=torch.float64))
    torch.testing.assert_close(G.so3_exp(w_back), R, rtol=0, atol=1e-12)
    # angles in (pi, 2 pi) come back as the equivalent rotation of angle 2 pi - theta
    w = rotvec_with_angle(4.0, n=4, seed=4)
    torch.testing.assert_close(G.so3_exp(G.so3_log(G.so3_exp(w))), G.so3_exp(w), rtol=0, atol=1e-12)


def test_so3_log_matches_kornia():
    w = rotvec_with_angle(0.7, n=6, seed=1)
    R = G.so3_exp(w)
    torch.testing.assert_close(G.so3_log(R), kornia.geometry.conversions.rotation_matrix_to_axis_angle(R))


@pytest.mark.parametrize("name", ["zero", "tiny", "small", "generic", "near_pi"])
def test_so3_log_gradcheck(name):
    R = G.so3_exp(rotvec_with_angle(ANGLES[name], n=2, seed=2)).requires_grad_()
    assert gradcheck(G.so3_log, (R,))


def test_quaternion_to_matrix(dtype):
    q = torch.randn(7, 4, dtype=torch.float64) * 3  # not unit: normalised inside
    ref = kornia.geometry.conversions.quaternion_to_rotation_matrix(torch.nn.functional.normalize(q, dim=-1))
    R = G.quaternion_to_matrix(q.to(dtype))
    torch.testing.assert_close(R.double(), ref, rtol=tol(dtype)[0], atol=tol(dtype)[1])
    # (w, x, y, z) order: q = (cos a/2, sin a/2 * axis) equals so3_exp(a * axis)
    w = rotvec_with_angle(0.9, n=3, seed=5)
    half = w.norm(dim=-1, keepdim=True) / 2
    qa = torch.cat([half.cos(), half.sin() * torch.nn.functional.normalize(w, dim=-1)], -1)
    torch.testing.assert_close(G.quaternion_to_matrix(qa), G.so3_exp(w))


def test_quaternion_gradcheck_and_zero():
    q = torch.randn(4, 4, dtype=torch.float64, requires_grad=True)
    assert gradcheck(G.quaternion_to_matrix, (q,))
    q0 = torch.zeros(1, 4, dtype=torch.float64, requires_grad=True)
    R = G.quaternion_to_matrix(q0)
    torch.testing.assert_close(R[0], torch.eye(3, dtype=torch.float64))
    R.sum().backward()
    assert torch.isfinite(q0.grad).all()


def _axis_rot(axis, a):
    c, s = math.cos(a), math.sin(a)
    m = {
        "X": [[1, 0, 0], [0, c, -s], [0, s, c]],
        "Y": [[c, 0, s], [0, 1, 0], [-s, 0, c]],
        "Z": [[c, -s, 0], [s, c, 0], [0, 0, 1]],
    }[axis]
    return torch.tensor(m, dtype=torch.float64)


@pytest.mark.parametrize("convention", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "ZYZ", "XYX"])
def test_euler_to_matrix(convention, dtype):
    angles = torch.tensor([[0.3, -1.1, 2.5], [0.0, 0.0, 0.0], [3.0, 1.5, -0.2]], dtype=torch.float64)
    R = G.euler_to_matrix(angles.to(dtype), convention)
    for i, a in enumerate(angles.tolist()):
        ref = _axis_rot(convention[0], a[0]) @ _axis_rot(convention[1], a[1]) @ _axis_rot(convention[2], a[2])
        torch.testing.assert_close(R[i].double(), ref, rtol=tol(dtype)[0], atol=tol(dtype)[1])
    if dtype == torch.float64:
        assert gradcheck(lambda x: G.euler_to_matrix(x, convention), (angles.clone().requires_grad_(),))


def test_se3_and_sim3_to_matrix():
    xi = torch.randn(2, 3, 7, dtype=torch.float64)
    xi[0, 0, :3] = 0.0  # zero rotation
    T = G.sim3_to_matrix(xi)
    assert T.shape == (2, 3, 3, 4)
    R = ref_so3_exp(xi[..., :3])
    torch.testing.assert_close(T[..., :3], R * xi[..., 6, None, None].exp())
    torch.testing.assert_close(T[..., 3], xi[..., 3:6])
    T6 = G.se3_to_matrix(xi[..., :6])
    torch.testing.assert_close(T6[..., :3], R)
    torch.testing.assert_close(T6[..., 3], xi[..., 3:6])
    x = xi.reshape(-1, 7).clone().requires_grad_()
    assert gradcheck(G.sim3_to_matrix, (x,))
    assert gradcheck(G.se3_to_matrix, (x[:, :6].detach().clone().requires_grad_(),))


def _twist_matrix(xi):
    M = torch.zeros(*xi.shape[:-1], 4, 4, dtype=xi.dtype)
    M[..., :3, :3] = skew(xi[..., :3])
    M[..., :3, 3] = xi[..., 3:]
    return M


@pytest.mark.parametrize("name", list(ANGLES))
def test_se3_exp_log(name, dtype):
    w = rotvec_with_angle(ANGLES[name], n=4, seed=6)
    xi = torch.cat([w, torch.randn(4, 3, dtype=torch.float64)], -1)
    T = G.se3_exp(xi.to(dtype))
    ref = torch.linalg.matrix_exp(_twist_matrix(xi))[:, :3, :]
    torch.testing.assert_close(T.double(), ref, rtol=tol(dtype)[0] * 10, atol=tol(dtype)[1] * 10)
    if dtype == torch.float64:
        torch.testing.assert_close(G.se3_log(T), xi, rtol=0, atol=1e-9)
        torch.testing.assert_close(G.se3_log(ref), xi, rtol=0, atol=1e-9)
        assert gradcheck(G.se3_exp, (xi.clone().requires_grad_(),))
        assert gradcheck(G.se3_log, (T.clone().requires_grad_(),))


def test_se3_log_accepts_4x4():
    xi = torch.randn(3, 6, dtype=torch.float64) * 0.5
    T = G.se3_exp(xi)
    T44 = torch.cat([T, torch.tensor([0, 0, 0, 1.0], dtype=torch.float64).expand(3, 1, 4)], -2)
    torch.testing.assert_close(G.se3_log(T44), xi)


def test_batch_dims_and_empty():
    w = torch.randn(2, 5, 3)
    assert G.so3_exp(w).shape == (2, 5, 3, 3)
    assert G.so3_exp(torch.zeros(0, 3)).shape == (0, 3, 3)
    assert G.so3_exp(torch.zeros(3)).shape == (3, 3)
    e = torch.zeros(0, 3, requires_grad=True)
    G.so3_exp(e).sum().backward()
    assert e.grad.shape == (0, 3)


def _sweep_inputs(n=400, seed=11):
    """Angles log-spaced over [1e-3, pi] (pi included), plus pi - 1e-7 ... pi - 1e-1, random axes.
    Near pi the logs stay within float32 rounding of float64 all the way (pi - 1e-7 is the
    closest a float32 matrix can tell apart from pi)."""
    g = torch.Generator().manual_seed(seed)
    theta = torch.cat([
        torch.logspace(-3, math.log10(math.pi), n, dtype=torch.float64),
        math.pi - torch.logspace(-7, -1, 7, dtype=torch.float64),
    ])
    axis = torch.nn.functional.normalize(torch.randn(len(theta), 3, generator=g, dtype=torch.float64), dim=-1)
    w = axis * theta[:, None]
    t = torch.randn(len(theta), 3, generator=g, dtype=torch.float64)
    sigma = 0.3 * torch.randn(len(theta), 1, generator=g, dtype=torch.float64)
    half = theta[:, None] / 2
    return theta, {
        "so3_exp": (G.so3_exp, w),
        "so3_log": (G.so3_log, G.so3_exp(w)),
        "quaternion_to_matrix": (G.quaternion_to_matrix, torch.cat([half.cos(), axis * half.sin()], -1)),
        "euler_to_matrix": (lambda a: G.euler_to_matrix(a, "ZYX"), w),
        "se3_to_matrix": (G.se3_to_matrix, torch.cat([w, t], -1)),
        "sim3_to_matrix": (G.sim3_to_matrix, torch.cat([w, t, sigma], -1)),
        "se3_exp": (G.se3_exp, torch.cat([w, t], -1)),
        "se3_log": (G.se3_log, G.se3_exp(torch.cat([w, t], -1))),
    }


@pytest.mark.parametrize("name", list(_sweep_inputs(n=1)[1]))
def test_float32_gradients_match_float64_for_every_angle(name):
    # The float32 op's gradient against the float64 op's at the same input (the float32 one) and the
    # same upstream gradient (representable in float32): norm-wise relative error per element. Near
    # the small-angle threshold (1e-2) float32 closed forms used to lose ~1e-5 (se3_exp, se3_log).
    theta, ops = _sweep_inputs()
    fn, x = ops[name]
    x32 = x.float()
    up = torch.randn(fn(x32).shape, generator=torch.Generator().manual_seed(5), dtype=torch.float64).float()
    grads = []
    for xi, u in ((x32, up), (x32.double(), up.double())):
        xi = xi.clone().requires_grad_()
        (fn(xi) * u).sum().backward()
        grads.append(xi.grad.double().flatten(1))
    err = (grads[0] - grads[1]).norm(dim=1) / grads[1].norm(dim=1)
    assert err.max() < 1e-6, f"{name}: worst relative error {err.max():.2e} at |omega| = {theta[err.argmax()]:.9g}"


def _nearest_rotation_np(M):
    """Special orthogonal Procrustes with numpy: the rotation nearest to M (Frobenius)."""
    u, _, vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def _log_np(R):
    """Reference log of a rotation whose angle is well inside (0, pi)."""
    theta = math.acos(np.clip((np.trace(R) - 1) / 2, -1, 1))
    return theta / (2 * math.sin(theta)) * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])


def _non_rotations():
    """(name, matrix, unique): matrices that are not rotations; ``unique`` where a single rotation
    is nearest (and its angle is well inside (0, pi), for the reference log)."""
    rng = np.random.default_rng(8)
    R = ref_so3_exp(torch.tensor([0.3, -0.8, 0.5], dtype=torch.float64)).numpy()
    shear = np.eye(3) + np.array([[0.0, 0.4, 0.0], [0.0, 0.0, -0.2], [0.1, 0.0, 0.0]])
    cases = [
        ("zero", np.zeros((3, 3)), False),
        ("reflection_z", np.diag([1.0, 1.0, -1.0]), False),
        ("minus_identity", -np.eye(3), False),
        ("rotated_reflection", R @ np.diag([1.0, -1.0, 1.0]), False),
        ("rank_one", np.outer([1.0, 2.0, 0.5], [0.3, -1.0, 2.0]), False),
        ("scaled_0.5", 0.5 * R, True),
        ("scaled_3", 3.0 * R, True),
        ("stretched", R @ np.diag([1.3, 1.0, 0.8]), True),
        ("sheared", R @ shear, True),
        ("sheared_reflection", R @ shear @ np.diag([1.0, 1.0, -1.0]), True),
        ("rotation_plus_noise", R + 0.05 * rng.standard_normal((3, 3)), True),
    ]
    for k in range(4):
        M = rng.standard_normal((3, 3))
        cases.append((f"random_{k}", M, 0.2 < np.linalg.norm(_log_np(_nearest_rotation_np(M))) < 2.9))
    return cases


@pytest.mark.parametrize("name, M, unique", _non_rotations(), ids=[c[0] for c in _non_rotations()])
def test_so3_log_of_non_rotations_is_the_log_of_the_nearest_rotation(name, M, unique, dtype):
    Rn = _nearest_rotation_np(M)
    Mt = torch.tensor(M, dtype=dtype, requires_grad=True)
    w = G.so3_log(Mt)
    assert torch.isfinite(w).all(), f"{name}: {w}"
    # exp(log(M)) is a rotation as near to M as the nearest one (any of them, where several are)
    R_back = ref_so3_exp(w.detach().double()).numpy()
    atol = 1e-5 if dtype == torch.float32 else 1e-9
    assert abs(np.linalg.norm(R_back - M) - np.linalg.norm(Rn - M)) < atol * max(1.0, np.linalg.norm(M))
    if unique:
        np.testing.assert_allclose(w.detach().double().numpy(), _log_np(Rn), rtol=0, atol=atol)
    (w * torch.tensor([0.3, -1.2, 0.7], dtype=dtype)).sum().backward()
    assert torch.isfinite(Mt.grad).all(), f"{name}: {Mt.grad}"
    if unique and dtype == torch.float64:
        assert gradcheck(G.so3_log, (Mt.detach().clone().requires_grad_(),))
    # se3_log reads its rotation block the same way
    T = torch.cat([Mt.detach(), torch.tensor([[1.0], [-2.0], [0.5]], dtype=dtype)], -1)
    torch.testing.assert_close(G.se3_log(T)[:3], w.detach())

