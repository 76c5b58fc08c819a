"""The wheel built with ``python -m build`` installs into a fresh venv with its dependencies and
works there: the pure-Warp kernels without torch, and the torch ops once torch is installed."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SMOKE_KERNELS = """
import sys, numpy as np, warp as wp
import gvnn_warp.kernels as gk
from gvnn_warp.kernels import lie_kernels
from gvnn_warp.kernels.launch import launch
assert 'site-packages' in gk.__file__, gk.__file__
w = wp.array(np.array([[0.0, 0.0, np.pi / 2]]), dtype=wp.vec3d)
R = wp.zeros(1, dtype=wp.mat33d)
launch(lie_kernels.so3_exp[wp.float64], 1, [w], [R])
assert np.allclose(R.numpy()[0], [[0, -1, 0], [1, 0, 0], [0, 0, 1]]), R.numpy()
from gvnn_warp.synthetic import default_intrinsics, make_room_scene, render_rgbd
image, depth = render_rgbd(make_room_scene(seed=0), np.eye(4), default_intrinsics(8, 6), 8, 6)
assert image.shape == (1, 3, 6, 8) and (depth > 0).all()
assert 'torch' not in sys.modules
try:
    import kernels  # noqa: F401  - must not be installed as a top-level package
    raise SystemExit('a top-level "kernels" package was installed')
except ImportError:
    pass
"""

SMOKE_TORCH = """
import torch, gvnn_warp as G
img = torch.rand(1, 3, 8, 10, requires_grad=True)
depth = torch.rand(1, 1, 8, 10) + 1
K = torch.tensor([[9.0, 0, 4.5], [0, 9, 3.5], [0, 0, 1]])
warped, valid = G.warp_frame_depth(img, depth, torch.eye(4)[None], K)
assert valid.all() and torch.allclose(warped, img, atol=1e-5)
warped.sum().backward()
assert torch.allclose(img.grad, torch.ones_like(img), atol=1e-5)
"""


def _run(*cmd, cwd=None):
    subprocess.run([str(c) for c in cmd], check=True, cwd=cwd, capture_output=True, text=True)


def test_wheel_installs_into_fresh_venv(tmp_path):
    dist = tmp_path / "dist"
    _run(sys.executable, "-m", "build", "--wheel", "--outdir", dist, ROOT)
    (wheel,) = dist.glob("gvnn_warp-*.whl")
    venv = tmp_path / "venv"
    _run(sys.executable, "-m", "venv", venv)
    py = venv / "bin" / "python"
    _run(py, "-m", "pip", "install", "-q", wheel)
    _run(py, "-c", SMOKE_KERNELS, cwd=tmp_path)
    _run(py, "-m", "pip", "install", "-q", "torch==2.13.0")
    _run(py, "-c", SMOKE_TORCH, cwd=tmp_path)
