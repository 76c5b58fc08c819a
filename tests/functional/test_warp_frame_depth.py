"""The fused 3D spatial transformer: values and gradients against kornia and against the
composition of the separate layers; the identity pose; invalid depths and poses."""

import math

import kornia
import pytest
import torch
import torch.nn.functional as F
from refs import intrinsics, pose44
from torch.autograd import gradcheck

import gvnn_warp as G


def scene(B=2, C=3, H=12, W=16, motion=0.05, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    image = torch.rand(B, C, H, W, generator=g, dtype=torch.float64)
    depth = torch.rand(B, 1, H, W, generator=g, dtype=torch.float64) * 2 + 1
    xi = torch.randn(B, 6, generator=g, dtype=torch.float64) * motion
    pose = G.se3_to_matrix(xi)
    K = intrinsics(W, H)
    return [t.to(dtype) for t in (image, depth, pose, K)]


def test_matches_kornia_everywhere_for_small_motion(dtype):
    image, depth, pose, K = scene(dtype=dtype)
    B = image.shape[0]
    warped, valid = G.warp_frame_depth(image, depth, pose, K)
    ref = kornia.geometry.depth.warp_frame_depth(image, depth, pose44(pose), K.expand(B, 3, 3))
    assert 0.5 < valid.float().mean() < 1.0  # some pixels leave the image
    atol = 1e-5 if dtype == torch.float32 else 1e-12
    # all moved points are in front of the camera here, so even out-of-image samples agree
    torch.testing.assert_close(warped, ref, rtol=0, atol=atol)


def test_gradients_match_kornia():
    image, depth, pose, K = scene(motion=0.03, seed=1)
    B = image.shape[0]
    ours = [t.clone().requires_grad_() for t in (image, depth, pose, K)]
    theirs = [t.clone().requires_grad_() for t in (image, depth, pose44(pose), K.expand(B, 3, 3).contiguous())]
    w = torch.randn(image.shape, dtype=torch.float64)
    (G.warp_frame_depth(*ours)[0] * w).sum().backward()
    (kornia.geometry.depth.warp_frame_depth(*theirs) * w).sum().backward()
    torch.testing.assert_close(ours[0].grad, theirs[0].grad)
    torch.testing.assert_close(ours[1].grad, theirs[1].grad)
    torch.testing.assert_close(ours[2].grad, theirs[2].grad[:, :3, :])
    # fx, fy, cx, cy (kornia projects without the skew K[0, 1] but unprojects with it, so the
    # skew's derivative differs between the two models; ours uses it consistently)
    idx = ([0, 1, 0, 1], [0, 1, 2, 2])
    torch.testing.assert_close(ours[3].grad[idx], theirs[3].grad.sum(0)[idx])


def test_equals_composition_of_layers():
    image, depth, pose, K = scene(motion=0.1, seed=2)
    H, W = image.shape[-2:]
    for padding_mode in ("zeros", "border"):
        warped, valid = G.warp_frame_depth(image, depth, pose, K, padding_mode=padding_mode)
        pix = G.project_points(G.transform_points(pose, G.depth_to_points(depth, K)), K)
        grid = torch.stack([pix[..., 0] / (W - 1), pix[..., 1] / (H - 1)], -1) * 2 - 1
        ref = F.grid_sample(image, grid, align_corners=True, padding_mode=padding_mode)
        torch.testing.assert_close(warped, ref)
        inside = (pix[..., 0] >= 0) & (pix[..., 0] <= W - 1) & (pix[..., 1] >= 0) & (pix[..., 1] <= H - 1)
        assert torch.equal(valid[:, 0], inside)


@pytest.mark.parametrize("shape", [(1, 1, 5, 7), (2, 3, 12, 16), (3, 2, 9, 4)])
def test_identity_pose_reproduces_image(shape, dtype):
    B, C, H, W = shape
    image = torch.rand(shape, dtype=dtype)
    depth = torch.rand(B, 1, H, W, dtype=dtype) * 5 + 0.1
    for pose in (torch.eye(4, dtype=dtype).expand(B, 4, 4), torch.eye(3, 4, dtype=dtype).expand(B, 3, 4)):
        warped, valid = G.warp_frame_depth(image, depth, pose, intrinsics(W, H, dtype=dtype))
        assert valid.all() and valid.shape == (B, 1, H, W) and valid.dtype == torch.bool
        torch.testing.assert_close(warped, image, rtol=0, atol=1e-5 if dtype == torch.float32 else 1e-12)


@pytest.mark.parametrize("W", [7, 16])  # the row kernel; the 8-lane kernel (rows of whole 8-pixel blocks)
def test_gradcheck_all_inputs(W):
    image, depth, pose, K = scene(B=2, C=2, H=6 if W == 7 else 4, W=W, motion=0.08, seed=3)
    args = [t.requires_grad_() for t in (image, depth, pose, K)]
    assert gradcheck(lambda *a: G.warp_frame_depth(*a)[0], args)
    assert gradcheck(lambda *a: G.warp_frame_depth(*a, padding_mode="border")[0], args)
    # the image as data (the 8-lane adjoint's other path)
    assert gradcheck(lambda *a: G.warp_frame_depth(image.detach(), *a)[0], args[1:])


def test_gradcheck_near_min_depth_and_outside_image():
    image, depth, pose, K = scene(B=1, C=1, H=5, W=6, motion=0.0, seed=4)
    depth[0, 0, 1:3] = 2.5e-3  # just above min_depth (1e-3) - and near the camera centre
    pose = torch.eye(3, 4, dtype=torch.float64)[None].clone()
    pose[0, :, 3] = torch.tensor([0.7, -0.2, 1.5e-3])  # big shift: many samples leave the image
    args = [t.requires_grad_() for t in (image, depth, pose, K)]
    warped, valid = G.warp_frame_depth(*args)
    assert (~valid).any() and valid.any()
    assert gradcheck(lambda *a: G.warp_frame_depth(*a)[0], args)


def test_invalid_depths_are_masked_with_zero_gradient(dtype):
    image, depth, pose, K = scene(B=1, C=3, H=6, W=8, motion=0.02, seed=5, dtype=dtype)
    bad = [0.0, -1.0, float("nan"), float("inf"), -float("inf"), 1e-4]
    for k, v in enumerate(bad):
        depth[0, 0, 2, k] = v
    args = [t.clone().requires_grad_() for t in (image, depth, pose, K)]
    warped, valid = G.warp_frame_depth(*args)
    assert not valid[0, 0, 2, : len(bad)].any()
    assert (warped[0, :, 2, : len(bad)] == 0).all()
    assert torch.isfinite(warped).all()
    warped.sum().backward()
    for t in args:
        assert torch.isfinite(t.grad).all()
    assert (args[1].grad[0, 0, 2, : len(bad)] == 0).all()
    # the valid pixels are unaffected by the bad ones
    depth_ok = depth.clone()
    depth_ok[0, 0, 2, : len(bad)] = 1.0
    warped_ok, _ = G.warp_frame_depth(image, depth_ok, pose, K)
    mask = torch.ones_like(warped, dtype=torch.bool)
    mask[0, :, 2, : len(bad)] = False
    torch.testing.assert_close(warped[mask], warped_ok[mask])


def test_points_behind_camera_and_extreme_poses():
    image, depth, pose, K = scene(B=3, C=1, H=6, W=8, seed=6)
    pose = pose.clone()
    pose[0] = torch.tensor([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -10.0]])  # everything behind
    pose[1, :, 3] = torch.tensor([1e3, -1e3, 1e3])  # translations of a kilometre
    pose[2, :, :3] = G.so3_exp(torch.tensor([math.pi, 0.0, 0.0], dtype=torch.float64))  # half turn
    args = [t.clone().requires_grad_() for t in (image, depth, pose, K)]
    warped, valid = G.warp_frame_depth(*args)
    assert not valid[0].any() and (warped[0] == 0).all()
    assert not valid[2].any()
    assert torch.isfinite(warped).all()
    warped.sum().backward()
    assert all(torch.isfinite(t.grad).all() for t in args)


def test_inputs_not_modified_and_layout_independent():
    image, depth, pose, K = scene(seed=7)
    copies = [t.clone() for t in (image, depth, pose, K)]
    out = G.warp_frame_depth(image, depth, pose, K)[0]
    for a, b in zip((image, depth, pose, K), copies):
        assert torch.equal(a, b)
    # channels-last image, transposed-then-back depth, and a sliced pose give the same result
    image_cl = image.to(memory_format=torch.channels_last)
    depth_t = depth.transpose(2, 3).contiguous().transpose(2, 3)
    pose_sl = torch.cat([pose, torch.zeros_like(pose)], -1)[..., :4]
    torch.testing.assert_close(G.warp_frame_depth(image_cl, depth_t, pose_sl, K)[0], out, rtol=0, atol=0)


def _torch_project(depth, pose, K):
    """Each pixel of ``depth`` (B, 1, H, W) unprojected, moved by ``pose`` (B, 3|4, 4) and projected
    with ``K`` ((3, 3), or (B, 3, 3) one per item), in plain torch: (u, v, z), each (B, H, W);
    meaningless where the depth is invalid or z is not positive."""
    B, _, H, W = depth.shape
    K = K.expand(B, 3, 3)[:, :, :, None, None]  # (entries broadcast over the pixels)
    y, x = torch.meshgrid(torch.arange(H, dtype=depth.dtype), torch.arange(W, dtype=depth.dtype), indexing="ij")
    d = depth[:, 0]
    ry = (y - K[:, 1, 2]) / K[:, 1, 1]
    rx = (x - K[:, 0, 2] - K[:, 0, 1] * ry) / K[:, 0, 0]
    p = torch.stack([rx * d, ry * d, d], -1)  # (B, H, W, 3)
    q = torch.einsum("bij,bhwj->bhwi", pose[:, :3, :3], p) + pose[:, None, None, :3, 3]
    u = K[:, 0, 0] * q[..., 0] / q[..., 2] + K[:, 0, 1] * q[..., 1] / q[..., 2] + K[:, 0, 2]
    v = K[:, 1, 1] * q[..., 1] / q[..., 2] + K[:, 1, 2]
    return u, v, q[..., 2]


def _torch_warp(image, depth, pose, K, padding_mode):
    """Reference in plain torch (unproject, move, project, grid_sample) for pixels whose depth is
    valid and whose moved point is in front; elsewhere its values are meaningless."""
    H, W = image.shape[2:]
    u, v, z = _torch_project(depth, pose, K)
    grid = torch.stack([u / (W - 1), v / (H - 1)], -1) * 2 - 1
    return F.grid_sample(image, grid, align_corners=True, padding_mode=padding_mode), u, v, z


@pytest.mark.parametrize("padding_mode", ["zeros", "border"])
def test_each_class_of_pixel_value_gradient_and_valid(padding_mode):
    # Four classes of pixels (docs/conventions.md): (a) invalid depth and (b) moved point at or
    # behind min_depth: output 0, zero gradient to everything; (c) projection outside the image:
    # valid is False but the output is the padded sample, with its gradient (grid_sample's);
    # (d) inside: valid, ordinary.
    H, W = 6, 8
    K = intrinsics(W, H)
    g = torch.Generator().manual_seed(12)
    image = torch.rand(2, 2, H, W, generator=g, dtype=torch.float64)
    depth = torch.full((2, 1, H, W), 2.0, dtype=torch.float64)
    depth[0, 0, 1, 3] = float("nan")
    depth[0, 0, 2, 5] = 0.0
    depth[0, 0, 4, 2] = 0.01  # shifted by -80 px: far outside (no tap inside)
    pose = torch.eye(3, 4, dtype=torch.float64).repeat(2, 1, 1)
    pose[0, 0, 3] = -0.4 * 2.0 / K[0, 0]  # every pixel moves 0.4 px left: column 0 lands at x = -0.4
    pose[1, 2, 3] = -10.0  # batch item 1: every moved point is behind the camera
    depth_ok = torch.isfinite(depth) & (depth > 1e-3)
    ref, u, v, z = _torch_warp(image, torch.where(depth_ok, depth, 1.0), pose, K, padding_mode)
    front = depth_ok[:, 0] & (z > 1e-3)
    inside = front & (u >= -1e-3) & (u <= W - 1 + 1e-3) & (v >= -1e-3) & (v <= H - 1 + 1e-3)
    classes = {
        "invalid_depth": ~depth_ok[:, 0],
        "behind": depth_ok[:, 0] & ~front,
        "outside": front & ~inside,
        "inside": inside,
    }
    assert all(m.any() for m in classes.values())
    assert classes["outside"][0, :, 0].all()  # the just-outside column

    args = [t.clone().requires_grad_() for t in (image, depth, pose, K)]
    warped, valid = G.warp_frame_depth(*args, padding_mode=padding_mode)
    assert torch.equal(valid[:, 0], inside)
    assert (warped.permute(1, 0, 2, 3)[:, ~front] == 0).all()
    torch.testing.assert_close(warped.permute(1, 0, 2, 3)[:, front], ref.permute(1, 0, 2, 3)[:, front])
    w = torch.randn(warped.shape, generator=g, dtype=torch.float64)
    for name, mask in classes.items():
        m = mask[:, None].expand_as(warped)
        ours = [t.clone().requires_grad_() for t in (image, depth, pose, K)]
        (G.warp_frame_depth(*ours, padding_mode=padding_mode)[0] * w * m).sum().backward()
        if name in ("invalid_depth", "behind"):
            assert all((t.grad == 0).all() for t in ours), name
            continue
        theirs = [t.clone().requires_grad_() for t in (image, torch.where(depth_ok, depth, 1.0), pose, K)]
        (_torch_warp(*theirs, padding_mode)[0] * w * m).sum().backward()
        for a, b in zip(ours, theirs):
            torch.testing.assert_close(a.grad, b.grad, msg=name)
        if name == "outside" and padding_mode == "zeros":
            assert ours[0].grad.abs().sum() > 0 and ours[2].grad.abs().sum() > 0  # a loss here moves the pose


def _bits(t):
    return t.view(torch.int32 if t.dtype == torch.float32 else torch.int64)


def _lanes_scene(C, motion, dtype, bad_pixels=True):
    """A scene for the 8-lane kernel against the row kernel: inside, outside and on the edges of the
    image (the identity pose puts the last column and row exactly there), behind the camera, invalid
    depths (0, negative, NaN, inf, just above min_depth, beyond 1e30), a skewed K and another K for
    the second batch item, NaN/inf pixels (``bad_pixels``); rows of two 8-pixel blocks. Returns the
    op's arguments."""
    B, H, W = 2, 6, 16
    image, depth, pose, _ = scene(B=B, C=C, H=H, W=W, motion={"identity": 0.0, "small": 0.05, "large": 0.6}[motion],
                                  seed=C, dtype=dtype)
    if motion == "large":
        pose[1, 2, 3] = -2.5  # (most of item 1's points behind the camera)
    if bad_pixels:
        image[0, 0, 0, 0], image[1, -1, 2, 3] = float("nan"), float("inf")
    depth[0, 0, 1, :7] = torch.tensor([0.0, -1.0, float("nan"), float("inf"), 1e-3, 1.0001e-3, 2e30], dtype=dtype)
    K = torch.tensor([[[14.0, 0.4, 7.5], [0, 12.0, 2.5], [0, 0, 1]],  # (each item its own K)
                      [[16.0, 0.0, 8.0], [0, 13.0, 3.0], [0, 0, 1]]], dtype=dtype)
    return image, depth, pose[:, :3].contiguous(), K


def _passes_no_gradient(depth, pose34, K, padding, min_depth=1e-3):
    """(B, H, W): the pixels that clearly pass no gradient (written from the conventions, in torch):
    invalid depth, the moved point behind ``min_depth``, and with zeros padding a sample position
    with no tap in the image; pixels within 1e-3 of those limits are left out (either way)."""
    H, W = depth.shape[2:]
    d = depth[:, 0]
    usable = (d > min_depth) & (d < 1e30)
    u, v, z = _torch_project(torch.where(usable, d, 1.0)[:, None], pose34, K)
    out = ~usable | (z < min_depth - 1e-3)
    if padding == 0:  # (NaN u, v from a zero z compare false: left out)
        out |= (u < -1 - 1e-3) | (u > W + 1e-3) | (v < -1 - 1e-3) | (v > H + 1e-3)
    return out


# (C, padding): each pair is a kernel compiled for it; C = 3 unrolled as a constant (up to 4 are),
# C = 6 read at run time
LANES_VARIANTS = [(3, 0), (3, 1), (6, 0)]


@pytest.mark.parametrize(("C", "padding"), LANES_VARIANTS)
@pytest.mark.parametrize("motion", ["identity", "small", "large"])
def test_lanes_kernel_equals_scalar_kernel(C, padding, motion, dtype):
    """The 8-lane forward kernel (a row per thread, 8 pixels at a time) gives bitwise the values and
    ``valid`` of the row kernel in every case of :func:`_lanes_scene`."""
    from gvnn_warp.ops import sampling as _ops

    image, depth, pose34, K = _lanes_scene(C, motion, dtype)
    args = (C, *image.shape[2:], 1e-3, padding)
    lanes = _ops.warp_frame_depth_lanes(image, depth, pose34, K, *args)
    scalar = _ops.warp_frame_depth(image, depth, pose34, K, *args)
    assert torch.equal(_bits(lanes[0]), _bits(scalar[0])) and torch.equal(lanes[1], scalar[1])
    if motion == "identity":
        assert scalar[1][1].all()  # (every pixel, the last row and column included, valid)


@pytest.mark.parametrize(("C", "padding"), LANES_VARIANTS)
@pytest.mark.parametrize("motion", ["identity", "small", "large"])
@pytest.mark.parametrize("image_grad", [True, False], ids=["image-grad", "image-data"])
def test_lanes_adjoint_equals_scalar_adjoint(C, padding, motion, image_grad, dtype):
    """The 8-lane kernel's hand-written adjoint gives the row kernel's (Warp's adjoint of its
    per-pixel code) gradients for image, depth, pose and K, up to the order of the sums, in every case
    of :func:`_lanes_scene` with finite pixels; both of its paths (with and without the image
    gradient). A NaN incoming gradient on every pixel that passes no gradient (invalid depth, behind
    the camera, no tap in the image) changes nothing. With NaN and inf pixels, the gradients of what
    samples them are NaN in both, at the same places."""
    from gvnn_warp.ops import sampling as _ops

    args = (C, 6, 16, 1e-3, padding)
    tol = {"rtol": 1e-10, "atol": 1e-10} if dtype == torch.float64 else {"rtol": 1e-5, "atol": 1e-4}
    for bad_pixels in (False, True):
        image, depth, pose34, K = _lanes_scene(C, motion, dtype, bad_pixels)
        g = torch.randn(image.shape, generator=torch.Generator().manual_seed(C), dtype=dtype)
        silent = _passes_no_gradient(depth, pose34, K, padding)
        assert silent.any() and (~silent).any()
        g = torch.where(silent[:, None], float("nan"), g)
        grads = []
        for op in (_ops.warp_frame_depth_lanes, _ops.warp_frame_depth):
            xs = [image.clone().requires_grad_(image_grad), *(t.clone().requires_grad_() for t in (depth, pose34, K))]
            op(*xs, *args)[0].backward(g)
            grads.append([x.grad for x in xs])
        if not image_grad:  # (the backward took the variant compiled without the image gradient)
            from gvnn_warp.kernels.core import cache

            key = f"C={C if C <= 4 else None}, padding={padding}, image_grad=False"
            assert f"sampling.warp_frame_depth_lanes({key})" in cache.entries()
        for name, a, b in zip(("image", "depth", "pose", "K"), *grads):
            if name == "image" and not image_grad:
                assert a is None and b is None
                continue
            if not bad_pixels:
                assert torch.isfinite(a).all(), name
            torch.testing.assert_close(a, b, **tol, equal_nan=True, msg=name)
        assert (grads[0][1][:, 0][silent] == 0).all()  # (the NaN incoming gradient there)
        if not bad_pixels:  # (gradients that could differ)
            assert all((t != 0).any() for t in grads[0][1:]) or motion == "large"


def test_warp_frame_depth_takes_the_lanes_kernel_where_rows_allow(monkeypatch):
    from gvnn_warp.ops import sampling as _ops

    calls = []
    lanes = _ops.warp_frame_depth_lanes
    monkeypatch.setattr(_ops, "warp_frame_depth_lanes", lambda *a: calls.append(a) or lanes(*a))
    for W, expected in ((12, 0), (16, 1)):
        image, depth, pose, K = scene(W=W)
        G.warp_frame_depth(image, depth, pose, K)
        assert len(calls) == expected
