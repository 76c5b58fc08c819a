"""The one cache of every kernel and function gvnn_warp generates.

Two things are generated rather than written once at module level:

- *specialisations*: a kernel compiled for the value of a few arguments (a channel count, a
  penalty kind, a flag, a lens), so that Warp folds the constants away and LLVM vectorises what is
  left, or so that an expensive definition (the lens models' custom adjoints) is made only when
  first used. :func:`specialise` turns a maker ``make(a, b, ...)`` into a function of the same
  arguments that makes each variant once and keeps it.
- *float overloads*: a ``@wp.func`` with a custom adjoint (``@wp.func_grad``) needs concrete types,
  so it is written as ``make(T)`` and :func:`float_overloads` makes its float32 and float64
  overloads as one Warp function.

Both go through one dictionary, one (reentrant) lock and one policy table, :data:`POLICIES`:
for each family of specialisations, the values of an argument that are compiled in as constants.
Any other value is replaced by ``None`` before the key is formed: the maker then builds the variant
that reads that argument at run time (one variant serves all such values). Keys are readable:
:func:`entries` lists what was made, e.g. ``photometric.error_lanes(kind=5, channels=3, narrow=False)``.

Generated kernels live in Warp modules of their own (``@wp.kernel(module="unique")``): adding one
after a module has loaded would make Warp rebuild that module. This module never imports torch.
"""

from __future__ import annotations

import functools
import inspect
import threading
from collections.abc import Callable
from typing import Any

from . import compat
from .kinds import FLOAT_TYPES

__all__ = ["POLICIES", "entries", "float_overloads", "specialise"]

ANY = None  # a policy entry: every value of the argument is compiled in as a constant

# family -> {argument: the values compiled in as constants, or ANY}; arguments not named are ANY
POLICIES: dict[str, dict[str, tuple | None]] = {}

_MADE: dict[tuple, Any] = {}  # (family, argument values) -> what the maker made
_PARAMETERS: dict[str, tuple[str, ...]] = {}  # family -> its maker's argument names (for entries())
_LOCK = threading.RLock()  # reentrant: a maker may ask the cache for what it builds on


def _made(key: tuple, make: Callable[[], Any]) -> Any:
    """The value under ``key``, made by ``make()`` once (under the lock, also when threads ask at once)."""
    value = _MADE.get(key)  # (no lock on the hit path: a dict read is atomic)
    if value is None:
        with _LOCK:
            value = _MADE.get(key)
            if value is None:
                value = _MADE[key] = make()
    return value


def specialise(family: str, **constants: tuple | None) -> Callable[[Callable], Callable]:
    """Decorator: ``make(a, b, ...)`` becomes ``get(a, b, ...)``, which returns the variant made by
    ``make`` for those values, made once per key and kept.

    ``family`` names the variants (``"<sub-package>.<what>"``, unique); ``constants`` is its entry
    in :data:`POLICIES`: for an argument, the tuple of values compiled in as constants (any other
    value reaches ``make`` as ``None``: read at run time), or ``ANY``. Arguments are passed
    positionally or by name; ``get.make`` is the maker itself.
    """

    def wrap(make: Callable) -> Callable:
        signature = inspect.signature(make)
        params = tuple(signature.parameters)
        unknown = set(constants) - set(params)
        if unknown or family in POLICIES:
            raise ValueError(f"specialise({family!r}): family already used, or no argument named {sorted(unknown)}")
        POLICIES[family] = dict(constants)
        _PARAMETERS[family] = params
        policy = tuple(constants.get(p) for p in params)
        seen: dict[tuple, Any] = {}  # the arguments as passed -> their variant (aliases of _MADE's entries)

        @functools.wraps(make)
        def get(*args, **kwargs):
            if kwargs:  # (by name: a TypeError names a missing or unknown argument)
                args = signature.bind(*args, **kwargs).args
            value = seen.get(args)  # the hit path (once per call of a torch op): one dict read, no lock
            if value is None:
                # (a TypeError for a wrong number of arguments; defaults filled in, so that a default
                # left out and passed are one variant)
                bound = signature.bind(*args)
                bound.apply_defaults()
                values = tuple(v if allowed is None or v in allowed else None
                               for v, allowed in zip(bound.args, policy))
                value = seen[args] = _made((family, values), lambda: make(*values))
            return value

        get.make = make
        get.family = family
        return get

    return wrap


def float_overloads(make: Callable) -> Any:
    """The Warp function(s) ``make(T)`` defines, with one overload per float type (float32 and
    float64), made once per maker. ``make`` returns a ``wp.Function`` or a tuple of them (same
    order for every ``T``); the float32 one is returned, holding the other as its overload."""

    def build():
        first = make(FLOAT_TYPES[0])
        for T in FLOAT_TYPES[1:]:
            other = make(T)
            for f, o in zip(_as_tuple(first), _as_tuple(other), strict=True):
                compat.add_function_overload(f, o)
        return first

    return _made(("float_overloads", make), build)  # (keyed on the maker itself, kept alive here)


def _as_tuple(f) -> tuple:
    return f if isinstance(f, tuple) else (f,)


def entries() -> list[str]:
    """What the cache holds, one readable key each, in the order made."""
    out = []
    for family, values in list(_MADE):
        if family == "float_overloads":
            out.append(f"float_overloads({values.__module__}.{values.__qualname__})")
        else:
            args = ", ".join(f"{p}={v!r}" for p, v in zip(_PARAMETERS[family], values))
            out.append(f"{family}({args})")
    return out
