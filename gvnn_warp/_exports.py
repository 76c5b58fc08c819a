"""A package whose public names are its modules' and load on first use.

``lazy_exports(package, modules)`` gives a package ``__init__`` its ``__getattr__`` and ``__dir__``:
the package's ``__all__`` is the union of its modules' ``__all__`` lists, read from their sources
(``ast``, no import), and a name imports only the module that defines it. ``gvnn_warp.warp_frame_depth``
then loads the sampling functions and their ops, not every function of the front and every op
registration (~45 modules more, ~0.4 s here). A module's ``__all__`` must be a literal list.
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import sys
from collections.abc import Callable

__all__ = ["lazy_exports", "literal_all"]


def literal_all(module: str) -> list[str]:
    """The ``__all__`` list written in ``module``'s source (a ValueError if it is not a literal)."""
    spec = importlib.util.find_spec(module)
    with open(spec.origin, encoding="utf-8") as f:
        tree = ast.parse(f.read(), spec.origin)
    for node in tree.body:
        if isinstance(node, ast.AnnAssign) and node.value is not None:
            targets = [node.target]
        else:
            targets = node.targets if isinstance(node, ast.Assign) else []
        if any(isinstance(t, ast.Name) and t.id == "__all__" for t in targets):
            return list(ast.literal_eval(node.value))
    raise ValueError(f"{module}: no literal __all__ list")


def lazy_exports(package: str, modules: tuple[str, ...]) -> tuple[Callable, Callable]:
    """``(__getattr__, __dir__)`` for the package ``package`` whose public names are those of its
    ``modules`` (relative names, searched in order)."""
    index: dict[str, str] = {}  # public name -> the module that defines it, made on first use

    def names() -> dict[str, str]:
        if not index:
            for module in modules:
                for name in literal_all(f"{package}.{module}"):
                    index.setdefault(name, module)
        return index

    def __getattr__(name: str):
        if name == "__all__":  # (PEP 562 serves it like any other name; a star import reads it)
            return list(names())
        if name in modules:
            return importlib.import_module(f"{package}.{name}")
        if name in names():
            value = getattr(importlib.import_module(f"{package}.{index[name]}"), name)
            setattr(sys.modules[package], name, value)  # later lookups skip this function
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted({*names(), *modules, *vars(sys.modules[package])})

    return __getattr__, __dir__
