"""Behaviour under real training code: threads, determinism, memory, layouts, empty and huge inputs."""

import math
import os
import threading

import torch
from refs import intrinsics

import gvnn_warp as G


def _problem(B=2, C=3, H=24, W=32, seed=0, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    image = torch.rand(B, C, H, W, generator=g, dtype=dtype)
    depth = torch.rand(B, 1, H, W, generator=g, dtype=dtype) + 1
    xi = (torch.randn(B, 6, generator=g, dtype=dtype) * 0.05)
    return image, depth, xi, intrinsics(W, H, dtype=dtype)


def _forward_backward(image, depth, xi, K):
    args = [t.clone().requires_grad_() for t in (image, depth, xi, K)]
    warped, valid = G.warp_frame_depth(args[0], args[1], G.se3_to_matrix(args[2]), args[3])
    ((warped - image).square() * valid).sum().backward()
    return [warped.detach(), valid] + [a.grad for a in args]


def test_backward_is_bitwise_deterministic():
    problem = _problem(B=3, H=31, W=45)
    first = _forward_backward(*problem)
    for _ in range(3):
        for a, b in zip(first, _forward_backward(*problem)):
            assert torch.equal(a, b)


def test_concurrent_calls_from_threads_match_serial():
    problems = [_problem(seed=s, B=1 + s % 3, H=20 + s, W=30 - s) for s in range(6)]
    serial = [_forward_backward(*p) for p in problems]
    results = [None] * len(problems)

    def work(k):
        for _ in range(3):
            results[k] = _forward_backward(*problems[k])

    threads = [threading.Thread(target=work, args=(k,)) for k in range(len(problems))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for ser, par in zip(serial, results):
        for a, b in zip(ser, par):
            assert torch.equal(a, b)


def _rss_mb():
    with open(f"/proc/{os.getpid()}/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def test_repeated_forward_backward_does_not_grow_memory():
    problem = _problem(B=2, H=48, W=64)
    for _ in range(30):
        _forward_backward(*problem)
    before = _rss_mb()
    for _ in range(300):  # ~0.2 MB of tensors per iteration: a leak would show as > 50 MB
        _forward_backward(*problem)
    assert _rss_mb() - before < 25


def test_strided_and_expanded_inputs_equal_contiguous():
    image, depth, xi, K = _problem(B=2, H=10, W=14, dtype=torch.float64)
    pose = G.se3_to_matrix(xi)
    ref = G.warp_frame_depth(image, depth, pose, K)
    big = torch.zeros(2, 5, 20, 28, dtype=torch.float64)
    big[:, 1:4, ::2, ::2] = image
    image_strided = big[:, 1:4, ::2, ::2]
    depth_t = depth.transpose(-1, -2).contiguous().transpose(-1, -2)
    pose_t = pose.transpose(-1, -2).contiguous().transpose(-1, -2)
    K_expanded = K.expand(2, 3, 3)  # stride 0
    out = G.warp_frame_depth(image_strided, depth_t, pose_t, K_expanded)
    assert torch.equal(out[0], ref[0]) and torch.equal(out[1], ref[1])
    # gradients reach strided / expanded leaves too
    leaves = [t.clone().requires_grad_() for t in (big, depth, pose)]
    warped, _ = G.warp_frame_depth(leaves[0][:, 1:4, ::2, ::2], leaves[1], leaves[2], K)
    warped.sum().backward()
    assert leaves[0].grad[:, 0].abs().sum() == 0 and leaves[0].grad[:, 1:4, ::2, ::2].abs().sum() > 0


def test_empty_batch():
    image, depth, xi, K = _problem(B=0, H=6, W=8)
    image.requires_grad_()
    warped, valid = G.warp_frame_depth(image, depth, G.se3_to_matrix(xi), K)
    assert warped.shape == (0, 3, 6, 8) and valid.shape == (0, 1, 6, 8)
    warped.sum().backward()
    assert image.grad.shape == image.shape
    assert G.bilinear_sample(image.detach(), torch.zeros(0, 4, 4, 2)).shape == (0, 3, 4, 4)


def test_huge_image_and_extreme_values_stay_finite():
    H, W = 1080, 1920
    image = torch.rand(1, 1, H, W)
    depth = torch.rand(1, 1, H, W) * 10
    depth[0, 0, ::7, ::5] = float("nan")
    depth[0, 0, 3::11, ::3] = -1.0
    xi = torch.tensor([[100.0, -50.0, 7.0, 1e3, -1e3, 1e3]], requires_grad=True)  # any rotation, 1 km
    image.requires_grad_()
    warped, valid = G.warp_frame_depth(image, depth, G.se3_to_matrix(xi), intrinsics(W, H, dtype=torch.float32))
    assert torch.isfinite(warped).all()
    warped.sum().backward()
    assert torch.isfinite(xi.grad).all() and torch.isfinite(image.grad).all()
    R = G.so3_exp(torch.tensor([[1e4, 0.0, 0.0], [math.pi * 1e3, 1.0, 2.0]], dtype=torch.float64))
    torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(2, 3, 3))
