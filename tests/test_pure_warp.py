"""gvnn_warp.kernels works without torch: the README's pure-Warp pipeline runs in a fresh process
that never imports torch, and its wp.Tape pose gradient matches finite differences."""

import subprocess
import sys
from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parents[1] / "README.md"


def readme_pure_warp_example() -> str:
    text = README.read_text()
    start = text.index("```python", text.index("<!-- pure-warp-example -->")) + len("```python")
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
