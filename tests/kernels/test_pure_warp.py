"""gvnn_warp.kernels works without torch: the README's pure-Warp pipeline runs in a fresh process
that never imports torch, and its wp.Tape pose gradient matches finite differences."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from processes import run_python

README = Path(__file__).resolve().parents[2] / "README.md"


def readme_pure_warp_example(marker: str = "<!-- pure-warp-example -->") -> str:
    # the README's example, or the Gauss-Newton loop of docs/odometry.md
    text = next(t for t in (p.read_text() for p in (README, README.parent / "docs" / "odometry.md")) if marker in t)
    start = text.index("```python", text.index(marker)) + len("```python")
    return text[start : text.index("```", start)]


def test_kernels_package_never_imports_torch():
    code = (
        "import sys, gvnn_warp.kernels, gvnn_warp.synthetic, gvnn_warp\n"
        "assert 'torch' not in sys.modules, 'torch was imported'\n"
    )
    run_python(code, check=True, capture_output=False)


def test_layers_do_not_depend_on_data_generation():
    """gvnn_warp.synthetic (data generation) has one home that neither gvnn_warp.kernels nor the
    torch front imports (read from the sources, lazy imports included; vo/ and cli/ may)."""
    import ast

    root = README.parent
    front = ("cameras", "functional", "nn", "ops")
    sources = sorted((root / "kernels").rglob("*.py")) + [
        p for p in sorted((root / "gvnn_warp").rglob("*.py")) if p.parent.name in (*front, "gvnn_warp")]
    offenders = []
    for path in sources:
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""] + [a.name for a in node.names]
            if any("synthetic" in n for n in names):
                offenders.append(f"{path.relative_to(root)}:{node.lineno}")
    assert len(sources) > 20 and not offenders, offenders


def test_readme_pure_warp_pipeline(tmp_path):
    script = tmp_path / "example.py"
    script.write_text(
        readme_pure_warp_example()
        + "\nimport sys\nassert 'torch' not in sys.modules\n"
        + "np.save(sys.argv[1], np.concatenate([[loss.numpy()[0]], pose.grad.numpy().ravel()]))\n"
    )
    out = tmp_path / "result.npy"
    subprocess.run([sys.executable, str(script), str(out)], check=True, capture_output=True)
    result = np.load(out)
    assert np.isfinite(result).all() and result[0] > 0
    assert np.abs(result[1:]).max() > 0  # the photometric loss does depend on the pose


def test_readme_pure_warp_gauss_newton(tmp_path):
    script = tmp_path / "gauss_newton.py"
    script.write_text(
        readme_pure_warp_example("<!-- pure-warp-gauss-newton -->")
        + "\nimport sys\nassert 'torch' not in sys.modules\n"
        + "np.save(sys.argv[1], np.array([angle, np.linalg.norm(err[:3, 3]), it, np.degrees(np.arccos("
        + "np.clip((np.trace(T_true[:3, :3]) - 1) / 2, -1, 1))), np.linalg.norm(T_true[:3, 3])]))\n"
    )
    out = tmp_path / "result.npy"
    subprocess.run([sys.executable, str(script), str(out)], check=True, capture_output=True)
    angle, dist, iterations, angle0, dist0 = np.load(out)
    # from the identity (1.3 deg, 3.6 cm away) to within 0.15 deg and 0.5 cm (the rendered pair's
    # own photometric optimum is ~0.08 deg / 0.3 cm from the true pose), in fewer than 20 steps
    assert angle0 > 1.0 and dist0 > 0.03
    assert angle < 0.15 and dist < 0.005 and iterations < 19


def test_pipeline_checks_its_arguments():
    import pytest
    import warp as wp
    from gvnn_warp.kernels.sampling import pipeline

    mat34f, mat34d = (wp.types.matrix((3, 4), t) for t in (wp.float32, wp.float64))

    B, C, H, W = 1, 2, 3, 4

    def arrays(ft=wp.float32, pose_t=mat34f, K_t=wp.mat33f, image_t=None):
        image = wp.zeros((B, C, H, W), dtype=image_t or ft)
        depth = wp.ones((B, 1, H, W), dtype=image_t or ft)
        pose = wp.array([np.eye(3, 4)], dtype=pose_t)
        K = wp.array([np.eye(3)], dtype=K_t)
        return image, depth, pose, K

    warped, valid = pipeline.warp_frame_depth(*arrays())
    assert warped.shape == (B, C, H, W) and valid.numpy().all()
    bad = [
        (arrays(pose_t=mat34d), {}, TypeError, r"argument 'pose' must be an array of 3x4 float32 matrices, got 3x4 f"),
        (arrays(K_t=wp.mat33d), {}, TypeError, r"argument 'K' must be an array of 3x3 float32 matrices"),
        (arrays(image_t=wp.int32), {}, TypeError, r"argument 'image' must be of dtype float32 or float64, got int32"),
        (arrays(), {"min_depth": -1.0}, ValueError, r"argument 'min_depth' must be a positive finite number"),
        (arrays(), {"padding_mode": "reflect"}, ValueError, r"argument 'padding_mode' must be one of"),
    ]
    for args, kw, exc, pattern in bad:
        with pytest.raises(exc, match=r"gvnn_warp\.kernels\.warp_frame_depth: " + pattern):
            pipeline.warp_frame_depth(*args, **kw)
    with pytest.raises(TypeError, match=r"masked_squared_error: argument 'valid' must be of dtype bool"):
        pipeline.masked_squared_error(warped, warped, warped)
    # not Warp arrays (numpy, as a user of the pure-Warp API may pass): named, not an AttributeError
    image, depth, pose, K = arrays()
    for args, name, got in (((image.numpy(), depth, pose, K), "image", "numpy.ndarray"),
                            ((image, depth.numpy(), pose, K), "depth", "numpy.ndarray"),
                            ((image, depth, np.eye(3, 4)[None], K), "pose", "numpy.ndarray")):
        with pytest.raises(TypeError, match=rf"warp_frame_depth: argument '{name}' must be a wp.array \(wp.from_numpy "
                                            rf"/ wp.from_torch make one\), got {got}"):
            pipeline.warp_frame_depth(*args)
    with pytest.raises(TypeError, match=r"masked_squared_error: argument 'b' must be a wp.array"):
        pipeline.masked_squared_error(warped, warped.numpy(), valid)
    # a channel-last image: said so
    last = wp.zeros((B, 6, 8, 3), dtype=wp.float32)
    with pytest.raises(ValueError, match=r"argument 'depth' must be of shape \(1, 1, 8, 3\), got \(1, 1, 6, 8\), "
                                         r"which looks channel-last"):
        pipeline.warp_frame_depth(last, wp.ones((B, 1, 6, 8), dtype=wp.float32), pose, K)


def test_tape_keeps_the_arrays_its_views_read():
    # the 8-lane kernel's inputs are views over the caller's arrays; the tape replays them in the
    # backward pass after the call's temporaries are gone: the views must keep their memory alive (a
    # temporary depth's memory was freed and reused, and the pose gradient changed from run to run)
    import gc

    import warp as wp
    from gvnn_warp.kernels.core.kinds import mat34f

    from gvnn_warp import kernels as gk
    from gvnn_warp.synthetic import default_intrinsics, make_room_scene, render_rgbd, smooth_se3_trajectory

    K = default_intrinsics(64, 48)
    img, dep = render_rgbd(make_room_scene(seed=0), smooth_se3_trajectory(10, seed=0)[[0, 9]], K, 64, 48)
    c, s = np.cos(0.01), np.sin(0.01)
    P = np.array([[c, -s, 0, 0.0123], [s, c, 0, -0.0071], [0, 0, 1, 0.0093]])

    def pose_grad(keep):
        pose = wp.array([P], dtype=mat34f, requires_grad=True)
        kept = wp.array(dep[:1], dtype=wp.float32)
        tape = wp.Tape()
        with tape:
            warped, valid = gk.warp_frame_depth(wp.array(img[1:], dtype=wp.float32, requires_grad=True),
                                                kept if keep else wp.array(dep[:1], dtype=wp.float32), pose,
                                                wp.array([K], dtype=wp.mat33f))
            loss = gk.masked_squared_error(warped, wp.array(img[:1], dtype=wp.float32), valid)
        del kept
        gc.collect()
        reuse = [wp.full(64 * 48, 1.0e6, dtype=wp.float32) for _ in range(50)]  # (freed memory reused)
        tape.backward(loss=loss)
        del reuse
        return pose.grad.numpy()[0]

    want = pose_grad(True)
    assert np.abs(want).max() > 0
    for _ in range(3):
        np.testing.assert_array_equal(pose_grad(False), want)


@pytest.mark.parametrize("W", [13, 16])  # the row kernel; the 8-lane kernel (rows of whole 8-pixel blocks)
def test_both_fronts_run_the_same_kernel(W):
    """The torch op and the pure-Warp pipeline launch the same warp_frame_depth kernel: outputs and
    gradients (torch autograd vs wp.Tape) are bitwise equal (one thread: one launch each)."""
    import torch
    import warp as wp
    from gvnn_warp.kernels.core import launch
    from gvnn_warp.kernels.sampling import pipeline

    import gvnn_warp as G

    B, C, H = 2, 3, 11
    g = torch.Generator().manual_seed(0)
    image = torch.rand(B, C, H, W, generator=g, dtype=torch.float64)
    depth = torch.rand(B, 1, H, W, generator=g, dtype=torch.float64) + 1
    depth[0, 0, 0, :2] = torch.tensor([0.0, float("nan")])
    pose = G.se3_to_matrix(torch.randn(B, 6, generator=g, dtype=torch.float64) * 0.05).contiguous()
    K = torch.tensor([[12.0, 0, 6], [0, 12, 5], [0, 0, 1]], dtype=torch.float64).expand(B, 3, 3).contiguous()
    weight = torch.randn(B, C, H, W, generator=g, dtype=torch.float64)

    launch.set_num_threads(1)
    try:
        leaves = [t.clone().requires_grad_() for t in (image, depth, pose, K)]
        out, valid = G.warp_frame_depth(*leaves)
        out.backward(weight)
    finally:
        launch.set_num_threads(None)

    mat34d = launch.mat34d
    arrays = [
        wp.array(image.numpy(), dtype=wp.float64, requires_grad=True),
        wp.array(depth.numpy(), dtype=wp.float64, requires_grad=True),
        wp.array(pose.numpy(), dtype=mat34d, requires_grad=True),
        wp.array(K.numpy(), dtype=wp.mat33d, requires_grad=True),
    ]
    tape = wp.Tape()
    with tape:
        warped, wvalid = pipeline.warp_frame_depth(*arrays)
    tape.backward(grads={warped: wp.array(weight.numpy(), dtype=wp.float64)})
    assert np.array_equal(warped.numpy(), out.detach().numpy())
    assert np.array_equal(wvalid.numpy(), valid.numpy())
    for a, t in zip(arrays, leaves):
        assert np.array_equal(a.grad.numpy().reshape(t.shape), t.grad.numpy())


def test_lens_warp_on_a_tape_without_gradients_is_not_recorded():
    """A distorted-camera warp whose inputs need no gradient, recorded beside one that does: the
    tape's backward runs (it crashed when the first launch's adjoint was replayed) and is right."""
    code = r"""
import numpy as np, warp as wp
from gvnn_warp.kernels.sampling.pipeline import warp_frame_depth
from gvnn_warp.kernels.geometry import lens
from gvnn_warp.kernels.core.kinds import mat34d
B, C, H, W = 2, 1, 6, 7
rng = np.random.default_rng(0)
img = wp.array(rng.random((B, C, H, W)), dtype=wp.float64)
dep = wp.array(rng.random((B, 1, H, W)) + 1, dtype=wp.float64)
pose = wp.array(np.stack([np.eye(4)[:3]] * B), dtype=mat34d)
K = wp.array(np.stack([[[10, 0, 3], [0, 10, 3], [0, 0, 1.0]]] * B), dtype=wp.mat33d)
dist = wp.array(np.stack([lens.pack_dist(lens.RADTAN, [0.05, -0.02, 0.001, 0.002, 0])] * B),
                dtype=wp.types.vector(8, wp.float64))
img2 = wp.array(rng.random((B, C, H, W)), dtype=wp.float64, requires_grad=True)
tape = wp.Tape()
with tape:
    plain, _ = warp_frame_depth(img, dep, pose, K, dist=dist, model="radtan")
    warped, _ = warp_frame_depth(img2, dep, pose, K, dist=dist, model="radtan")
assert not plain.requires_grad and len(tape.launches) >= 1
tape.backward(grads={warped: wp.ones(warped.shape, dtype=wp.float64)})
assert np.isfinite(img2.grad.numpy()).all() and img2.grad.numpy().sum() > 0
print("ok")
"""
    out = run_python(code)
    assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stderr[-2000:]
