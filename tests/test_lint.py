"""The tree is ruff-clean with the configuration in pyproject.toml, and follows rules ruff cannot check."""

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_clean():
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    assert ruff, "ruff is part of the test extra"
    result = subprocess.run([ruff, "check", str(ROOT)], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_launches_go_through_wp_launch():
    # kernels.launch.wp_launch makes each kernel's first launch under a lock (Warp's JIT crashed
    # when threads loaded kernels at once): no package module calls wp.launch itself
    import re

    calls = re.compile(r"\bwp\.launch\(")
    offenders = [
        f"{path.relative_to(ROOT)}:{n}"
        for folder in ("gvnn_warp", "kernels")
        for path in sorted((ROOT / folder).rglob("*.py"))
        if path != ROOT / "kernels" / "launch.py"
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if calls.search(line.split("#")[0]) and "``" not in line
    ]
    assert not offenders, offenders
