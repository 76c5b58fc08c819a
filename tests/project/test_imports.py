"""The import graph of both trees, read from the sources (imports inside functions included): no cycle,
no module reaching upward, and gvnn_warp.kernels never importing the rest of gvnn_warp.

A module imports a module T when it names T or a name T defines (``from .a import b`` imports ``a.b``
if that is a module, else ``a``); importing T also imports T's packages, except those the importing
module is itself inside (they are its own parents). Dynamic imports (``importlib.import_module``) are
not seen: the lazy name tables of the package ``__init__`` files use them on purpose.
"""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TREES = {"gvnn_warp": ROOT / "gvnn_warp", "gvnn_warp.kernels": ROOT / "kernels"}


def modules() -> dict[str, Path]:
    out = {}
    for package, folder in TREES.items():
        for path in sorted(folder.rglob("*.py")):
            parts = list(path.relative_to(folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            name = ".".join([package, *parts])
            if package == "gvnn_warp" and name.startswith("gvnn_warp.kernels"):
                continue
            out[name] = path
    return out


def _ancestors(name: str) -> list[str]:
    parts = name.split(".")
    return [".".join(parts[:k]) for k in range(1, len(parts))]


def imports(name: str, path: Path, known: dict[str, Path]) -> set[tuple[str, int]]:
    """(module imported, line) for every import in the file, lazy ones included."""
    is_package = path.name == "__init__.py"
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")
                base = base[: len(base) - node.level + (1 if is_package else 0)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            for alias in node.names:
                sub = f"{module}.{alias.name}"
                targets.append(sub if sub in known else module)
        for target in targets:
            if target in known:
                found.add((target, node.lineno))
                own = set(_ancestors(name)) | {name}
                found |= {(a, node.lineno) for a in _ancestors(target) if a in known and a not in own}
    return found


def graph() -> dict[str, set[tuple[str, int]]]:
    known = modules()
    return {name: imports(name, path, known) for name, path in known.items()}


def test_no_import_cycles():
    edges = {m: {t for t, _ in ts if t != m} for m, ts in graph().items()}
    cycles, state = [], {}

    def visit(m, stack):
        state[m] = "open"
        for t in sorted(edges[m]):
            if state.get(t) == "open":
                cycles.append(" -> ".join(stack[stack.index(t):] + [t]))
            elif t not in state:
                visit(t, stack + [t])
        state[m] = "done"

    for m in sorted(edges):
        if m not in state:
            visit(m, [m])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_no_module_reaches_upward():
    # a module never imports from a package it is inside (its parents' __init__ names; a package's
    # __main__ runs the package's own entry), and the pure-Warp tree never imports the torch side
    offenders = []
    for m, ts in graph().items():
        for t, line in ts:
            if t in _ancestors(m) and not m.endswith(".__main__"):
                offenders.append(f"{m}:{line} imports its parent package {t}")
            if m.startswith("gvnn_warp.kernels") and not t.startswith("gvnn_warp.kernels"):
                offenders.append(f"{m}:{line} imports {t} (kernels never import the rest of gvnn_warp)")
    assert not offenders, "\n".join(sorted(offenders))
