"""The tree is ruff-clean with the configuration in pyproject.toml, and follows rules ruff cannot check."""

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_ruff_clean():
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    assert ruff, "ruff is part of the test extra"
    result = subprocess.run([ruff, "check", str(ROOT)], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_launches_go_through_wp_launch():
    # kernels.core.launch.wp_launch / ensure_loaded / load_module load modules under a lock (Warp's JIT
    # crashed when threads loaded kernels at once): no other package module calls Warp's launch or
    # module loading itself, under any name
    import ast

    loaders = {"launch", "load_module", "force_load"}
    offenders = []
    for folder in ("gvnn_warp", "kernels"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            if path == ROOT / "kernels" / "core" / "launch.py":
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                bad = (isinstance(node, ast.Attribute) and node.attr in loaders and isinstance(node.value, ast.Name)
                       and node.value.id in ("wp", "warp")) or (
                    isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "warp"
                    and any(alias.name in loaders for alias in node.names))
                if bad:
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not offenders, offenders
