"""gvnn_warp.kernels works without torch: the README's pure-Warp pipeline runs in a fresh process
that never imports torch, and its wp.Tape pose gradient matches finite differences."""

import subprocess
import sys
from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parents[1] / "README.md"


def readme_pure_warp_example(marker: str = "<!-- pure-warp-example -->") -> str:
    text = README.read_text()
    start = text.index("```python", text.index(marker)) + len("```python")
    return text[start : text.index("```", start)]


def test_kernels_package_never_imports_torch():
    code = (
        "import sys, gvnn_warp.kernels, gvnn_warp.kernels.render, gvnn_warp.synthetic, gvnn_warp\n"
        "assert 'torch' not in sys.modules, 'torch was imported'\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


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
    from gvnn_warp.kernels import pipeline

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
