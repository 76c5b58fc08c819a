"""The wheel built with ``python -m build``: its files and metadata, and that it works when installed
into a fresh venv - the pure-Warp kernels and the ``gvnn-warp`` script without torch (which then
says what to install), the torch ops once torch is there.

The dependencies are not downloaded and installed again (that took most of a minute, and reinstalling
torch most of another): the wheel is installed with ``--no-deps`` and the test environment's packages
are made visible to the fresh venv through a ``.pth`` file - first all but torch, then torch too.
That pip installs what the metadata lists is pip's job; the metadata is checked here."""

import email
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest
from processes import FAST_EXIT

ROOT = Path(__file__).resolve().parents[2]
TORCH_PACKAGES = ("torch", "functorch", "torchgen")

SMOKE_KERNELS = """
import sys, numpy as np, warp as wp
import gvnn_warp.kernels as gk
from gvnn_warp.kernels.geometry import kernels as geometry_kernels
from gvnn_warp.kernels.launch import launch
assert gk.__file__.startswith(sys.prefix), (gk.__file__, sys.prefix)  # the wheel's copy, in the venv
w = wp.array(np.array([[0.0, 0.0, np.pi / 2]]), dtype=wp.vec3d)
R = wp.zeros(1, dtype=wp.mat33d)
launch(geometry_kernels.so3_exp[wp.float64], 1, [w], [R])
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
try:
    import torch  # noqa: F401
    raise SystemExit('torch is visible: the environment is not torch-free')
except ImportError:
    pass
print("kernels ok")
"""

SMOKE_TORCH = """
import sys, torch, gvnn_warp as G
assert G.__file__.startswith(sys.prefix), G.__file__
img = torch.rand(1, 3, 8, 10, requires_grad=True)
depth = torch.rand(1, 1, 8, 10) + 1
K = torch.tensor([[9.0, 0, 4.5], [0, 9, 3.5], [0, 0, 1]])
warped, valid = G.warp_frame_depth(img, depth, torch.eye(4)[None], K)
assert valid.all() and torch.allclose(warped, img, atol=1e-5)
warped.sum().backward()
assert torch.allclose(img.grad, torch.ones_like(img), atol=1e-5)
import contextlib, io
from gvnn_warp.cli import main
text = io.StringIO()
with contextlib.redirect_stdout(text):
    try:
        main(["vo", "--help"])  # (the script itself was run without torch above)
    except SystemExit as e:
        assert e.code == 0, e.code
assert "--motion" in text.getvalue(), text.getvalue()
print("torch ok")
"""


def _run(*cmd, cwd=None, check=True):
    res = subprocess.run([str(c) for c in cmd], cwd=cwd, capture_output=True, text=True, timeout=300)
    if check:
        assert res.returncode == 0, res.stderr[-3000:]
    return res


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    dist = tmp_path_factory.mktemp("dist")
    # (in this environment, which has the build requirements - build checks it - rather than in an isolated
    # one that pip would first fill from the package index)
    _run(sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir", dist, ROOT)
    (whl,) = dist.glob("gvnn_warp-*.whl")
    return whl


@pytest.mark.long  # (both: they share the wheel)
def test_wheel_files_and_metadata(wheel):
    import tomllib
    from packaging.requirements import Requirement

    names = zipfile.ZipFile(wheel).namelist()
    # every module of both trees is in the wheel (pyproject.toml lists the sub-packages)
    kernels = sorted(f"gvnn_warp/kernels/{p.relative_to(ROOT / 'kernels').as_posix()}"
                     for p in (ROOT / "kernels").rglob("*.py"))
    assert sorted(n for n in names if n.startswith("gvnn_warp/kernels/") and n.endswith(".py")) == kernels
    package = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "gvnn_warp").rglob("*.py"))
    assert sorted(n for n in names if n.startswith("gvnn_warp/") and n.endswith(".py")
                  and not n.startswith("gvnn_warp/kernels/")) == package
    assert not [n for n in names if n.startswith("kernels/")]  # never a top-level "kernels"
    assert "gvnn_warp/py.typed" in names
    (license_file,) = [n for n in names if n.endswith("dist-info/licenses/LICENSE")]
    assert "BSD 3-Clause" in zipfile.ZipFile(wheel).read(license_file).decode()
    (meta_name,) = [n for n in names if n.endswith("dist-info/METADATA")]
    meta = email.message_from_bytes(zipfile.ZipFile(wheel).read(meta_name))
    assert meta["License-Expression"] == "BSD-3-Clause"
    requires = [Requirement(r) for r in meta.get_all("Requires-Dist")]
    plain = {r.name.lower() for r in requires if r.marker is None}
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert plain == {Requirement(r).name.lower() for r in project["dependencies"]}
    assert {"warp-lang", "numpy", "matplotlib", "tqdm", "pillow"} <= plain  # what every command needs
    (torch_req,) = [r for r in requires if r.name == "torch"]
    assert torch_req.marker is not None and torch_req.marker.evaluate({"extra": "torch"})
    entry_points = zipfile.ZipFile(wheel).read(meta_name.replace("METADATA", "entry_points.txt")).decode()
    assert "gvnn-warp = gvnn_warp.cli:main" in entry_points


def _dependency_view(dest: Path) -> Path:
    """A folder of links to every package of this test environment but torch and gvnn_warp."""
    dest.mkdir()
    for entry in Path(sysconfig.get_paths()["purelib"]).iterdir():
        name = entry.name.lower()
        if name.startswith(TORCH_PACKAGES) or name.startswith(("gvnn_warp", "__editable__")) or name.endswith(".pth"):
            continue
        (dest / entry.name).symlink_to(entry)
    return dest


@pytest.mark.long
def test_wheel_works_in_a_fresh_venv_without_and_with_torch(wheel, tmp_path):
    venv = tmp_path / "venv"
    _run(sys.executable, "-m", "venv", "--without-pip", venv)
    py, script = venv / "bin" / "python", venv / "bin" / "gvnn-warp"
    _run(sys.executable, "-m", "pip", "--python", py, "install", "-q", "--no-deps", "--no-index", wheel)
    site = Path(_run(py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])").stdout.strip())
    pth = site / "test_dependencies.pth"
    pth.write_text(f"{_dependency_view(tmp_path / 'deps')}\n")

    # without torch: the kernels work, the script starts and says what a command needs
    assert _run(py, "-c", FAST_EXIT + SMOKE_KERNELS, cwd=tmp_path).stdout.strip() == "kernels ok"
    assert "align" in _run(script, "--help", cwd=tmp_path).stdout
    res = _run(script, "align", "--out", tmp_path / "out", cwd=tmp_path, check=False)
    assert res.returncode == 1, res.stderr
    assert res.stderr.startswith("gvnn-warp align: error: this command needs PyTorch") and res.stderr.count("\n") == 1
    assert not (tmp_path / "out").exists()

    # with torch
    pth.write_text(pth.read_text() + f"{sysconfig.get_paths()['purelib']}\n")
    assert _run(py, "-c", FAST_EXIT + SMOKE_TORCH, cwd=tmp_path).stdout.strip() == "torch ok"
