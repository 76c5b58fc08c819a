"""Array kinds, typed kernel overloads and each kernel's declaration of how it may be split.

Kernels in this package are generic (``typing.Any`` arrays) and declare, through
:class:`FloatKernel`, the *kind* of each array argument (``"scalar"``, ``"vec3"``, ``"mat34"``...).
That one declaration gives both the concrete float32/float64 overloads (compiled together, so a
module loads once) and the element types the torch bridge needs to wrap tensors zero-copy.

Every per-element kernel takes ``offset: int`` as its first argument and handles element
``wp.tid() + offset``, so a launch range can be cut into chunks. :meth:`FloatKernel.set_parallel`
declares where it may be cut (the *adjoint scope* of every differentiable input array, see
:mod:`.launch`); every kernel given to :func:`.launch.launch` must declare it (nothing is inferred).

This module never imports torch.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import warp as wp

from . import compat as _compat

mat34f = wp.types.matrix(shape=(3, 4), dtype=wp.float32)
mat34d = wp.types.matrix(shape=(3, 4), dtype=wp.float64)
vec8f = wp.types.vector(length=8, dtype=wp.float32)  # 8 lanes of a SIMD-friendly kernel
vec8d = wp.types.vector(length=8, dtype=wp.float64)
vec8i = wp.types.vector(length=8, dtype=wp.int32)  # 8 lanes' indices
vec16f = wp.types.vector(length=16, dtype=wp.float32)  # 8 (x, y) pairs
vec16d = wp.types.vector(length=16, dtype=wp.float64)

# module options of the 8-lane kernels (``module_options=`` of their ``@wp.kernel``): LLVM's SLP
# vectoriser at its own default depth, see :func:`._compat.lanes_compiler_flags` (Warp's CPU flags
# as they are when this module is imported)
LANES_MODULE_OPTIONS = {"cpu_compiler_flags": _compat.lanes_compiler_flags()}

# kind -> (element shape, {float type: Warp element type})
KINDS: dict[str, tuple[tuple[int, ...], dict]] = {
    "scalar": ((), {wp.float32: wp.float32, wp.float64: wp.float64}),
    "vec2": ((2,), {wp.float32: wp.vec2f, wp.float64: wp.vec2d}),
    "vec3": ((3,), {wp.float32: wp.vec3f, wp.float64: wp.vec3d}),
    "vec4": ((4,), {wp.float32: wp.vec4f, wp.float64: wp.vec4d}),
    "vec8": ((8,), {wp.float32: vec8f, wp.float64: vec8d}),
    "vec16": ((16,), {wp.float32: vec16f, wp.float64: vec16d}),
    "mat33": ((3, 3), {wp.float32: wp.mat33f, wp.float64: wp.mat33d}),
    "mat34": ((3, 4), {wp.float32: mat34f, wp.float64: mat34d}),
    "bool": ((), {wp.float32: wp.bool, wp.float64: wp.bool}),
    "int32": ((), {wp.float32: wp.int32, wp.float64: wp.int32}),  # indices (never differentiable)
}
FLOAT_TYPES = (wp.float32, wp.float64)

SCOPES = ("element", "segment", "any")
DEFAULT_GRAIN = 32768  # elements: below about twice this, a launch stays on one thread


def element_type(kind: str, float_type) -> type:
    """The Warp element type of an array of ``kind`` for ``float_type``."""
    return KINDS[kind][1][float_type]


def element_shape(kind: str) -> tuple[int, ...]:
    """The trailing shape one element of ``kind`` occupies in a tensor, e.g. (3, 4) for mat34."""
    return KINDS[kind][0]


@dataclass
class Parallel:
    """How a kernel's launch range may be split (see :meth:`FloatKernel.set_parallel`)."""

    segment: Callable[[dict], int] | None = None  # elements per segment, from the named arguments
    scopes: dict[str, str] = field(default_factory=dict)  # adjoint scope per array argument name
    forward: bool = True  # forward writes are per element (no atomics): any split is exact
    grain: Callable[[dict], int] | int = DEFAULT_GRAIN  # fewest elements worth a chunk
    blocked: tuple[wp.Kernel, Callable[[dict], int]] | None = None  # (kernel, elements per block)
    owner: FloatKernel | None = None  # the FloatKernel that declared it

    def scope(self, name: str) -> str:
        """The adjoint scope of array argument ``name`` (``"any"`` where none was declared)."""
        return self.scopes.get(name, "any")


_DECLARED: dict[int, Parallel] = {}  # id(kernel overload) -> its declaration
_KERNELS: dict[int, wp.Kernel] = {}  # keeps the kernels of _DECLARED alive (ids stay unique)
_REGISTRY: list[FloatKernel] = []  # every FloatKernel that declared itself, in declaration order


def declaration(kernel: wp.Kernel) -> Parallel:
    """The declaration of a concrete kernel overload; a ValueError naming the kernel if it has none."""
    info = _DECLARED.get(id(kernel))
    if info is None:
        raise ValueError(
            f"gvnn_warp.kernels.core.launch: kernel {kernel.key!r} has no declaration of how its launches may be "
            "split: wrap it as FloatKernel(kernel, ...).set_parallel(scopes={...}, ...) (see CONTRIBUTING.md)"
        )
    return info


def registered() -> list[FloatKernel]:
    """Every :class:`FloatKernel` that declared itself with :meth:`~FloatKernel.set_parallel`."""
    return list(_REGISTRY)


class FloatKernel:
    """A generic kernel with explicit float32 and float64 overloads.

    ``FloatKernel(kernel, image="scalar", pose="mat34", ...)`` names the kind of every generic
    array argument; ``fk[wp.float64]`` is the concrete float64 kernel. :meth:`set_parallel`
    declares how its launches may be split over threads (required before it is launched).
    """

    def __init__(self, kernel: wp.Kernel, **array_kinds: str):
        self.kernel = kernel
        self.array_kinds = dict(array_kinds)
        self._overloads = {
            ft: wp.overload(
                kernel, {name: wp.array(dtype=element_type(kind, ft)) for name, kind in array_kinds.items()}
            )
            for ft in FLOAT_TYPES
        }

    def __getitem__(self, float_type) -> wp.Kernel:
        return self._overloads[float_type]

    def __repr__(self) -> str:
        return f"FloatKernel({self.kernel.key})"

    def set_parallel(
        self,
        *,
        segment: Callable[[dict], int] | None = None,
        scopes: dict[str, str] | None = None,
        forward: bool = True,
        grain: Callable[[dict], int] | int = DEFAULT_GRAIN,
        blocked: tuple[FloatKernel, Callable[[dict], int]] | None = None,
    ) -> FloatKernel:
        """Declare how launches of this kernel may be split over threads; returns ``self``.

        Args:
            segment: ``segment(args) -> int``, the number of consecutive elements of one segment
                (e.g. ``lambda a: a["H"] * a["W"]`` for a per-pixel kernel whose segments are batch
                items); ``args`` maps every kernel argument name to its launch value.
            scopes: adjoint scope per input array: ``"element"`` (element ``i``'s adjoint writes
                gradient entries no other element writes), ``"segment"`` (the entries it writes
                are written only by elements of its own segment) or ``"any"``. Inputs not named
                count as ``"any"`` (always correct, but cut into pieces with partial buffers);
                outputs need none (adjoints only read them). ``tests/ops/test_scopes.py`` runs every
                registered kernel cut into many pieces and fails on a wrong declaration.
            forward: False if the forward pass accumulates into shared outputs (atomics): it
                then runs on one thread.
            grain: fewest elements worth a chunk (int, or a function of ``args``).
            blocked: ``(fk, L)``: a kernel with the same arguments whose element ``k`` handles
                elements ``[k L, (k + 1) L)`` of this one; ``L(args)`` returns 0 where it does
                not apply (the launch size must be a multiple of L). Its own ``set_parallel``
                describes its blocks.
        """
        arrays = {name for name, is_array in _compat.kernel_arguments(self.kernel) if is_array}
        for name, scope in (scopes or {}).items():
            if scope not in SCOPES:
                raise ValueError(f"set_parallel: scope of {name!r} must be one of {SCOPES}, got {scope!r}")
            if name not in arrays:
                raise ValueError(
                    f"set_parallel: {self.kernel.key!r} has no array argument {name!r} (arrays: {sorted(arrays)})"
                )
        for ft, k in self._overloads.items():
            _DECLARED[id(k)] = Parallel(
                segment=segment,
                scopes=dict(scopes or {}),
                forward=forward,
                grain=grain,
                blocked=(blocked[0][ft], blocked[1]) if blocked is not None else None,
                owner=self,
            )
            _KERNELS[id(k)] = k
        if self not in _REGISTRY:
            _REGISTRY.append(self)
        return self


__all__ = [
    "DEFAULT_GRAIN",
    "FLOAT_TYPES",
    "KINDS",
    "SCOPES",
    "FloatKernel",
    "Parallel",
    "declaration",
    "element_shape",
    "element_type",
    "mat34d",
    "mat34f",
    "registered",
    "vec16d",
    "vec16f",
    "vec8d",
    "vec8f",
    "vec8i",
]
