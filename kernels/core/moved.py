"""Module paths of earlier releases, kept importable after the package was laid out by concept.

``moved(table)`` installs one import hook for a table ``{old dotted name: new dotted name(s)}``.
For one new name, ``import`` of the old path gives the new module itself (the same object, so
``isinstance`` checks, monkeypatching and pickling by the new name all agree). For a tuple of new
names (a module whose contents now live in several), it gives a module named after the old path
whose attributes are looked up in those modules, in order, on first use. The tables live in
``gvnn_warp/__init__.py`` and ``gvnn_warp/kernels/__init__.py``; new code imports the new paths.
``names_of`` serves a package that took the place of a module of the same name (the old module's
names, found in the package's modules). This module never imports torch.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import types

__all__ = ["moved", "names_of"]


class _Merged(types.ModuleType):
    """An old module whose names now live in the modules ``sources`` (imported on first use)."""

    def __init__(self, name: str, sources: tuple[str, ...]):
        super().__init__(name, f"Moved: its names are those of {', '.join(sources)}.")
        self._sources = sources

    def __getattr__(self, attr: str):
        if attr == "__all__":  # the union of the sources' public names, for ``from <old path> import *``
            return [n for s in self._sources for n in getattr(importlib.import_module(s), "__all__", ())]
        if not attr.startswith("__"):
            for source in self._sources:
                module = importlib.import_module(source)
                if hasattr(module, attr):
                    return getattr(module, attr)
        raise AttributeError(f"module {self.__name__!r} (now {', '.join(self._sources)}) has no attribute {attr!r}")

    def __dir__(self) -> list[str]:
        return sorted({n for s in self._sources for n in dir(importlib.import_module(s)) if not n.startswith("_")})


class _Moved(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds the old names of ``table`` and loads each as its new module(s)."""

    def __init__(self, table: dict[str, str | tuple[str, ...]]):
        self.table = dict(table)
        self._specs: dict = {}  # old name -> the new module's own spec, while importlib loads it

    def find_spec(self, fullname, path=None, target=None):
        if fullname not in self.table:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec):
        new = self.table[spec.name]
        if isinstance(new, tuple):
            return _Merged(spec.name, new)
        module = importlib.import_module(new)
        self._specs[spec.name] = module.__spec__
        return module

    def exec_module(self, module) -> None:
        # importlib has set the old name's spec on the module it was given: give it back its own
        if not isinstance(module, _Merged):
            module.__spec__ = self._specs.pop(module.__spec__.name)


def moved(table: dict[str, str | tuple[str, ...]]) -> None:
    """Make every old module name in ``table`` importable (see the module docstring)."""
    sys.meta_path.append(_Moved(table))


def names_of(package: str, *modules: str):
    """A module ``__getattr__`` for a package that took the place of a module of the same name: a
    name is the package's submodule if it has one so named, else the name as defined by the first
    of ``modules`` (relative to ``package``, e.g. ``".residual"``) that has it."""

    def __getattr__(name: str):
        if not name.startswith("__"):
            if importlib.util.find_spec(f"{package}.{name}") is not None:
                return importlib.import_module(f"{package}.{name}")
            for module in modules:
                source = importlib.import_module(module, package)
                if hasattr(source, name):
                    return getattr(source, name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__

