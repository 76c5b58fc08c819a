"""Adapters for the few Warp internals gvnn_warp.kernels relies on, one small function each.

Each is pinned by a test in ``tests/ops/test_compat.py`` that fails loudly if a Warp upgrade changes
it (warp-lang is pinned to 1.19.x in pyproject.toml). Never imports torch.
"""

from __future__ import annotations

import ctypes
import functools
import sys
from collections.abc import Callable, Sequence

import warp as wp


def alias(a: wp.array, dtype, shape: tuple[int, ...], grad: wp.array | None = None) -> wp.array:
    """A view of contiguous ``a``'s memory as ``shape`` elements of ``dtype`` (with ``grad`` as its
    gradient, if given) that keeps ``a`` alive, as Warp's own views do through their ``_ref``: an
    array made from a bare ``ptr`` does not, and a ``wp.Tape`` that replays it after the caller
    dropped ``a`` would read freed memory."""
    view = wp.array(ptr=a.ptr, dtype=dtype, shape=shape, device=a.device, grad=grad, requires_grad=grad is not None)
    view._ref = a
    return view


def kernel_arguments(kernel: wp.Kernel) -> list[tuple[str, bool]]:
    """``(name, is_array)`` of every argument of ``kernel``, in order.

    Warp keeps a kernel's signature in ``kernel.adj.args`` (``warp._src.codegen.Var`` objects with
    ``label`` and ``type``); there is no public accessor.
    """
    return [(a.label, wp.types.is_array(a.type)) for a in kernel.adj.args]


def kernel_argument_dtype(kernel: wp.Kernel, index: int):
    """The element type of array argument ``index`` of a concrete (overloaded) kernel (see
    :func:`kernel_arguments`)."""
    return kernel.adj.args[index].type.dtype


@functools.cache
def _array_descriptor_type() -> type:
    # The ctypes struct Warp passes to kernels for an array (``warp._src.types.array_t``); it is
    # what ``wp.from_torch(t, return_ctype=True)`` returns. Taken from an array, not imported from
    # Warp's private module path.
    return type(wp.empty(0, dtype=wp.float32, device="cpu").__ctype__())


def array_descriptor(ptr: int, length: int, stride_bytes: int):
    """A bare 1-D array descriptor (no data ownership, no gradient) over ``length`` elements at
    ``ptr``, ``stride_bytes`` apart; ``wp.launch`` accepts it wherever an array goes (~1 us to
    make, against ~9 us for ``wp.from_torch``). Warp's constructor is positional:
    ``(data, grad, ndim, shape, strides)``."""
    return _array_descriptor_type()(ptr, 0, 1, (length,), (stride_bytes,))


def is_array_descriptor(a) -> bool:
    return isinstance(a, _array_descriptor_type())


def array_length(a) -> int:
    """The first dimension of a ``wp.array`` or of an array descriptor."""
    return int(a.shape[0])


def array_pointer(a) -> int:
    """The data address of a ``wp.array`` (``ptr``) or of an array descriptor (``data``)."""
    return int(a.ptr) if isinstance(a, wp.array) else int(a.data)


def scalar_type(dtype):
    """The scalar type of a Warp element type (``wp.float32`` for ``wp.vec3f``; a scalar type
    itself for a scalar). Warp keeps it as the private class attribute ``_wp_scalar_type_``."""
    return getattr(dtype, "_wp_scalar_type_", dtype)


def scalars_per_element(dtype) -> int:
    """How many scalars one element of a Warp element type holds (3 for ``vec3``, 12 for a 3x4
    matrix, 1 for a scalar); Warp's private class attribute ``_length_``."""
    return int(getattr(dtype, "_length_", 1))


def matrix_shape(dtype) -> tuple[int, ...] | None:
    """The shape of a Warp vector or matrix type ((3,), (3, 4)), None for a scalar; Warp's private
    class attribute ``_shape_``."""
    shape = getattr(dtype, "_shape_", None)
    return tuple(shape) if shape is not None else None


def add_function_overload(first, other) -> None:
    """Make the ``wp.Function`` ``other`` (same name and module, other argument types) an overload of
    ``first``, and ``first`` the one Warp's module resolves the shared name to (defining ``other``
    registered it under that name)."""
    first.add_overload(other)
    first.module.functions[first.key] = first


def func_grad(forward):
    """``@wp.func_grad(forward)`` for a concrete ``@wp.func`` (no generic argument types): registers
    the decorated function as ``forward``'s custom adjoint exactly as Warp does, without Warp's
    check of its signature against ``forward``'s return types. To learn those, Warp builds
    ``forward`` (a code-generation pass over it and everything it calls) in every process that
    defines it, kernels in the cache or not: 0.5-1 s before a first ``warp_frame_depth`` call, 3 s
    for the whole API. What can be checked without that is checked here (the adjoint takes the
    function's arguments, same types, first); a wrong or missing ``adj_ret`` argument fails the
    calling kernel's build (a C++ compile error, not a Warp message), and a cached kernel was built
    from this very source (its hash)."""
    if len(forward.user_overloads) != 1:  # (a generic function has none until overloaded)
        raise TypeError(f"func_grad({forward.key}): needs a function of concrete argument types (one overload)")
    (f,) = forward.user_overloads.values()
    inputs = list(forward.input_types.values())

    def register(grad):
        types = [t for name, t in grad.__annotations__.items() if name != "return"]
        if len(types) < len(inputs) or not all(wp.types.types_equal(a, b) for a, b in zip(types, inputs)):
            raise TypeError(f"func_grad({forward.key}): the adjoint {grad.__qualname__} must take the function's "
                            "arguments (same types) and then the adjoint of each returned value")
        # Warp's own registration (warp._src.context.func_grad's add_custom_grad), field for field
        f.custom_grad_func = type(f)(
            grad, key=f.key, native_func=f.native_func, namespace=f.namespace, input_types=dict(forward.input_types),
            value_func=None, module=f.module, skip_forward_codegen=True, custom_reverse_mode=True,
            custom_reverse_num_input_args=len(f.input_types), skip_adding_overload=False,
            code_transformers=f.adj.transformers, inline_hint=f.inline_hint,
        )
        f.adj.skip_reverse_codegen = True
        return grad

    return register


def gil_enabled() -> bool:
    """False on a free-threaded CPython running without the GIL (``sys._is_gil_enabled``, 3.13+);
    True everywhere else."""
    check = getattr(sys, "_is_gil_enabled", None)
    return True if check is None else bool(check())


# ctypes argument struct types of recorded launches, by their fields (names and ctypes types):
# making a ctypes Structure class costs ~50-100 us of Python, filling one a few
_ARGS_STRUCTS: dict[tuple, type] = {}


def replay_pieces(cmd, pieces: Sequence[tuple[int, int]] | None = None) -> list[Callable[[], None]] | None:
    """Callables that replay a recorded forward CPU launch (``wp.launch(..., record_cmd=True)``)
    with its ctypes argument struct built once, one per ``(start, size)`` piece: the launch over
    ``size`` elements with its first argument (the ``offset`` of a kernel written
    ``kernel(offset, ...)``) set to ``start``; ``pieces`` None: the launch as recorded, one callable.
    Warp 1.19's ``Launch.launch()`` rebuilds that struct on every call (a ``setattr`` per kernel
    argument: 10-15 us of Python per replay measured on a loaded host, against 5-8 us for the bare
    call), and recording one launch per piece packs every argument again (``wp.launch``).
    Uses the launch's private ``params`` (bounds, then one ctypes value per argument),
    ``hooks.forward``, the kernel's argument labels (as Warp's own ``invoke`` does) and the bounds'
    struct type (constructed from a size). Returns None where that does not apply (adjoint, GPU,
    block launches, pieces of a launch over more than one dimension, a missing attribute): replay
    the launch with ``cmd.launch`` then. Neither a ``wp.Tape`` nor Warp's CPU graph capture records
    these replays. After ``cmd.set_param_at_index``, update them with :func:`set_replay_arg` (or
    build them again)."""
    try:
        if not cmd.device.is_cpu or cmd.adjoint or cmd.block_dim > 1 or cmd.hooks.forward is None:
            return None
        params = list(cmd.params)
        labels = [a.label for a in cmd.kernel.adj.args]
        if len(params) != 1 + len(labels):
            return None
        fields = tuple((name, type(params[1 + i])) for i, name in enumerate(labels))
        struct = _ARGS_STRUCTS.get(fields)
        if struct is None:
            struct = _ARGS_STRUCTS[fields] = type("ArgsStruct", (ctypes.Structure,), {"_fields_": list(fields)})
        bounds_type = type(params[0])
        if pieces is not None and len(params[0].shape) != 1:
            return None  # pieces of a 1-D range only
        forward = cmd.hooks.forward
        runs = []
        for piece in pieces if pieces is not None else [None]:
            args = struct()
            for i, (name, _) in enumerate(fields):
                setattr(args, name, params[1 + i])
            if piece is None:
                bounds = params[0]
            else:
                setattr(args, fields[0][0], piece[0])
                bounds = bounds_type(piece[1])
            runs.append(_replay(forward, ctypes.byref(bounds), ctypes.byref(args), (params, bounds, args)))
    except AttributeError:
        return None
    return runs


def _replay(forward, bounds, args, keep) -> Callable[[], None]:
    def replay() -> None:
        forward(bounds, args)

    replay.keep = keep  # the ctypes values the pointers refer to
    replay.args = keep[2]  # the argument struct (see set_replay_arg)
    return replay


def set_replay_arg(cmd, runs: Sequence[Callable[[], None]], index: int) -> bool:
    """Copy argument ``index`` of the recorded launch ``cmd`` (0 = the kernel's first argument, as
    ``cmd.set_param_at_index``; set it there first) into the argument structs of its replays
    ``runs`` (:func:`replay_pieces`), in place: ~1 us per replay against ~30 us per piece for
    building them again. The argument of a piece's ``offset`` (index 0) is not touched. Returns
    False (nothing changed) where ``runs`` are not such replays: build them again then."""
    if index == 0 or not all(hasattr(run, "args") for run in runs):
        return False
    label = cmd.kernel.adj.args[index].label
    value = cmd.params[1 + index]
    try:
        for run in runs:
            setattr(run.args, label, value)
    except TypeError:  # a value of another ctypes type than when built: build them again
        return False
    return True


def replay_function(cmd) -> Callable[[], None]:
    """:func:`replay_pieces` of the launch as recorded, or ``cmd.launch`` where it does not apply."""
    runs = replay_pieces(cmd)
    return runs[0] if runs else cmd.launch


# LLVM's own default depth of the SLP vectoriser's tree search, which Warp 1.19 lowers to 4 in its
# default CPU flags (``wp.config.cpu_compiler_flags``)
_SLP_DEPTH_FLAG = "-slp-recursion-max-depth="


def lanes_compiler_flags(flags: str | None = None) -> str:
    """CPU compiler flags for the 8-lane kernels: ``flags`` (default: ``wp.config.cpu_compiler_flags``
    as it is when called; None there means ``"-march=native"``, as Warp resolves it) without any
    limit on the depth of LLVM's SLP vectoriser, so it runs at LLVM's default (12).
    :data:`.kinds.LANES_MODULE_OPTIONS` calls it once, when ``gvnn_warp.kernels`` is imported: a
    change to ``wp.config.cpu_compiler_flags`` made later does not reach the 8-lane kernels (a
    module option replaces the global setting), so set it before importing gvnn_warp.

    Warp 1.19's default flags cap that depth at 4. The 8-lane kernels are written as length-8
    vector operations, and LLVM turns them into SIMD instructions only where that vectoriser finds
    whole trees of them. With the cap it gave up on parts of them (one variant of
    ``photometric_error`` came out entirely scalar); without it the same kernels, bit for bit the
    same results, take up to half the time (figures: ``benchmarks/RESULTS.md``). Both spellings,
    ``-mllvm=<option>`` and ``-mllvm <option>``, are removed. Warp scopes ``-mllvm`` options to one
    compilation, so nothing leaks to or from other modules."""
    if flags is None:
        flags = wp.config.cpu_compiler_flags
    if flags is None:
        flags = "-march=native"
    def is_cap(option: str) -> bool:  # LLVM takes its options with one dash or two
        return option.lstrip("-").startswith(_SLP_DEPTH_FLAG.lstrip("-"))

    out: list[str] = []
    words = flags.split()
    i = 0
    while i < len(words):
        w = words[i]
        if w.startswith("-mllvm=") and is_cap(w.removeprefix("-mllvm=")):
            i += 1
            continue
        if w == "-mllvm" and i + 1 < len(words) and is_cap(words[i + 1]):
            i += 2
            continue
        out.append(w)
        i += 1
    return " ".join(out)
