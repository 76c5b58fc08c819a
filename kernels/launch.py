"""Typed kernel overloads and the one launch helper every op goes through, multi-core on the CPU.

Kernels in this package are generic (``typing.Any`` arrays) and declare, through
:class:`FloatKernel`, the *kind* of each array argument (``"scalar"``, ``"vec3"``, ``"mat34"``...).
That one declaration gives both the concrete float32/float64 overloads (compiled together, so a
module loads once) and the element types the torch bridge needs to wrap tensors zero-copy.

Every per-element kernel takes ``offset: int`` as its first argument and handles element
``wp.tid() + offset``, so a launch range can be split into chunks.

Threads
-------
A Warp CPU launch runs its whole range on one thread, and releases the GIL. :func:`launch` splits
the range into chunks and runs them on a small pool of Python threads (the calling thread takes
part), so one op uses several cores; or, after :func:`use_openmp` (which the torch bridge calls
with torch's own OpenMP runtime), on that runtime's thread team. The number of threads is, in
order of precedence: :func:`set_num_threads` (``gvnn_warp.kernels.launch.set_num_threads(n)``),
the environment variable ``GVNN_WARP_NUM_THREADS``, the default provider (the torch bridge
installs ``torch.get_num_threads``), else ``os.cpu_count()``. ``1`` disables threading.

Determinism
-----------
Results are bitwise identical for every thread count, forward and backward:

- forward launches write each element's outputs from that element only, so any split is exact;
- adjoint launches accumulate (``+=``). Each array argument has an *adjoint scope*: ``"element"``
  (element ``i`` writes only its own gradient entries: any split is exact), ``"segment"`` (the
  launch range is made of consecutive segments, e.g. batch items, and each segment writes its own
  disjoint part of the array, e.g. an image-gradient plane or one pose gradient), or ``"any"``.
  Splits never cut a segment unless the plan says so, and where a segment or the whole range must
  be cut into pieces (few batch items, or ``"any"`` arrays), the pieces are a fixed function of the
  launch size, never of the thread count; pieces after the first accumulate into zeroed partial
  buffers that are added to the result in a fixed order afterwards.

Kernels declare their scopes with :meth:`FloatKernel.set_parallel`; for other kernels they are
inferred from the kernel's source: an array only ever indexed as ``a[i]`` with
``i = wp.tid() + offset`` is ``"element"``, anything else ``"any"``; a kernel whose forward uses
atomics (``wp.atomic_*`` or ``a[j] += ...``, also inside the ``wp.func`` it calls) runs forward
on one thread.

A kernel may also register a *blocked* variant with the same arguments that handles ``L``
consecutive elements per thread (e.g. one image row, which amortises per-row work and keeps
reductions in registers); :func:`launch` uses it transparently.

This module never imports torch.
"""

from __future__ import annotations

import ast
import ctypes
import inspect
import itertools
import math
import os
import textwrap
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import warp as wp

wp.set_module_options({"enable_backward": False})  # only the helper kernel (_accumulate) lives here

mat34f = wp.types.matrix(shape=(3, 4), dtype=wp.float32)
mat34d = wp.types.matrix(shape=(3, 4), dtype=wp.float64)
vec8f = wp.types.vector(length=8, dtype=wp.float32)  # 8 lanes of a SIMD-friendly kernel
vec8d = wp.types.vector(length=8, dtype=wp.float64)
vec16f = wp.types.vector(length=16, dtype=wp.float32)  # 8 (x, y) pairs
vec16d = wp.types.vector(length=16, dtype=wp.float64)

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
}
FLOAT_TYPES = (wp.float32, wp.float64)

ENV_NUM_THREADS = "GVNN_WARP_NUM_THREADS"
# Adjoint reductions that must cut a range (fewer segments than this, or "any" scopes) cut it into
# this many pieces at most. A fixed number, so results do not depend on the thread count. It bounds
# the parallelism of such launches (e.g. a backward pass with batch size 1) and sets the number of
# partial gradient buffers, which cost memory traffic: measured on a batch-1 warp_frame_depth
# backward, 2 pieces cost +20% CPU time over 1 piece, 4 pieces +55%, so 2 pays from 2 threads on.
REDUCTION_PIECES = 2
# Chunks per thread for splits that are free (forward, element-scope adjoints): a little slack
# for load balancing when other processes share the cores.
CHUNKS_PER_THREAD = 4
DEFAULT_GRAIN = 32768  # elements: below about twice this, a launch stays on one thread

SCOPES = ("element", "segment", "any")


def element_type(kind: str, float_type) -> type:
    """The Warp element type of an array of ``kind`` for ``float_type``."""
    return KINDS[kind][1][float_type]


def element_shape(kind: str) -> tuple[int, ...]:
    """The trailing shape one element of ``kind`` occupies in a tensor, e.g. (3, 4) for mat34."""
    return KINDS[kind][0]


# ----------------------------------------------------------------------------- thread count

_user_num_threads: int | None = None
_default_num_threads: Callable[[], int] | None = None


def set_num_threads(n: int | None) -> None:
    """Use ``n`` threads for gvnn_warp launches (``None``: back to the default).

    Without it, ``GVNN_WARP_NUM_THREADS`` or else the default provider (``torch.get_num_threads``
    once the torch bridge is loaded, ``os.cpu_count()`` otherwise) decides. Results do not depend
    on the thread count.
    """
    global _user_num_threads
    if n is not None:
        n = int(n)
        if n < 1:
            raise ValueError(f"set_num_threads: n must be >= 1, got {n}")
    _user_num_threads = n


def set_default_num_threads(provider: Callable[[], int] | None) -> None:
    """Install the function giving the thread count when neither the user nor the environment set
    it (the torch bridge installs ``torch.get_num_threads``)."""
    global _default_num_threads
    _default_num_threads = provider


def get_num_threads() -> int:
    """The number of threads :func:`launch` uses (see :func:`set_num_threads`)."""
    if _user_num_threads is not None:
        return _user_num_threads
    env = os.environ.get(ENV_NUM_THREADS)
    if env:
        try:
            return max(1, int(env))
        except ValueError:
            pass
    if _default_num_threads is not None:
        return max(1, int(_default_num_threads()))
    return os.cpu_count() or 1


def _drain(fn: Callable[[int], None], tasks, errors: list) -> None:
    """Run ``fn(k)`` for the chunk indices ``k`` left in ``tasks`` (an iterator shared by the
    threads of a pool: next() on it is atomic under the GIL), collecting exceptions in ``errors``
    for the pool to re-raise."""
    for k in tasks:
        try:
            fn(k)
        except BaseException as e:  # noqa: BLE001 - re-raised by the pool's run()
            errors.append(e)


class _Pool:
    """Worker threads that run chunk launches; the calling thread always takes part.

    Workers pull chunk indices from a shared iterator, so a busy core delays no one. Chunks that
    no worker started by the time the caller ran out of work are cancelled, so a pool whose
    threads are busy (or gone after a fork) never blocks a launch.
    """

    def __init__(self):
        self._executor: ThreadPoolExecutor | None = None
        self._workers = 0
        self._pid = -1
        self._lock = threading.Lock()

    def _get(self, workers: int) -> ThreadPoolExecutor:
        with self._lock:
            if self._executor is None or self._pid != os.getpid() or self._workers < workers:
                if self._executor is not None and self._pid == os.getpid():
                    self._executor.shutdown(wait=False)
                self._workers = max(workers, (os.cpu_count() or 1) - 1, 1)
                self._executor = ThreadPoolExecutor(self._workers, thread_name_prefix="gvnn_warp")
                self._pid = os.getpid()
            return self._executor

    def run(self, fn: Callable[[int], None], n_tasks: int, n_threads: int) -> None:
        """Run ``fn(k)`` for k in [0, n_tasks) on up to ``n_threads`` threads; returns when all ran."""
        n_threads = min(n_threads, n_tasks)
        if n_threads <= 1:
            for k in range(n_tasks):
                fn(k)
            return
        tasks = iter(range(n_tasks))
        errors: list[BaseException] = []

        def work():
            _drain(fn, tasks, errors)

        executor = self._get(n_threads - 1)
        futures = [executor.submit(work) for _ in range(n_threads - 1)]
        try:
            work()
        finally:
            for f in futures:
                if not f.cancel():
                    f.result()  # wait: a running chunk still uses the caller's buffers
        if errors:
            raise errors[0]


_python_pool = _Pool()

# An OpenMP team's worker function: void fn(void *data)
_GOMP_FN = ctypes.CFUNCTYPE(None, ctypes.c_void_p)


class _OpenMPPool:
    """Runs the chunks on the thread team of an already loaded GNU OpenMP runtime (libgomp's
    ``GOMP_parallel``, the entry point GCC compiles ``#pragma omp parallel`` to); same contract as
    :class:`_Pool`: the calling thread takes part, threads pull chunk indices from a shared
    iterator, errors are re-raised.

    Why: torch's OpenMP workers keep spinning for milliseconds after every parallel torch op,
    waiting for more work. Python threads then share cores with them; a launch given to that team
    instead starts at once on the threads that are already spinning. ctypes releases the GIL for
    the call, and each team thread's callback takes it back while it picks a chunk (``wp.launch``
    releases it again while the kernel runs). After a fork the child uses :class:`_Pool`
    (libgomp's team does not survive a fork; like torch's own parallel ops, anything else that
    uses OpenMP in such a child hangs unless it runs on one thread, e.g. after
    ``torch.set_num_threads(1)``).

    ``library``: a loaded library in which ``GOMP_parallel`` resolves (the runtime itself, or a
    library linked against it: dlsym searches its dependencies).
    """

    def __init__(self, library: str):
        lib = ctypes.CDLL(library)
        self._parallel = lib.GOMP_parallel
        self._parallel.argtypes = [_GOMP_FN, ctypes.c_void_p, ctypes.c_uint, ctypes.c_uint]
        self._parallel.restype = None
        self.library = library
        self._pid = os.getpid()
        self._jobs: dict[int, tuple] = {}  # concurrent calls (several Python threads) by key
        self._keys = itertools.count(1)
        self._callback = _GOMP_FN(self._work)  # referenced here for as long as the pool lives

    def _work(self, key) -> None:
        _drain(*self._jobs[key])

    def run(self, fn: Callable[[int], None], n_tasks: int, n_threads: int) -> None:
        """Run ``fn(k)`` for k in [0, n_tasks) on up to ``n_threads`` threads; returns when all ran."""
        n_threads = min(n_threads, n_tasks)
        if n_threads <= 1 or os.getpid() != self._pid:  # serial, or a forked child
            _python_pool.run(fn, n_tasks, n_threads)
            return
        key = next(self._keys)
        errors: list[BaseException] = []
        self._jobs[key] = (fn, iter(range(n_tasks)), errors)
        try:
            self._parallel(self._callback, key, n_threads, 0)
        finally:
            del self._jobs[key]
        if errors:
            raise errors[0]


_pool: _Pool | _OpenMPPool = _python_pool


def use_openmp(library: str | None) -> None:
    """Run threaded launches on the thread team of the GNU OpenMP runtime (``GOMP_parallel``) found
    through ``library`` (an already loaded ``libgomp``, or a library linked against it: the torch
    bridge passes torch's ``libtorch_cpu``), or, with ``None``, on gvnn_warp's pool of Python
    threads (the default). Results do not depend on it."""
    global _pool
    _pool = _OpenMPPool(library) if library is not None else _python_pool


def thread_backend() -> str:
    """Where threaded launches run: ``"openmp:<library>"`` or ``"python"`` (see :func:`use_openmp`)."""
    return f"openmp:{_pool.library}" if isinstance(_pool, _OpenMPPool) else "python"


# ----------------------------------------------------------------------------- kernel metadata


@dataclass
class _Parallel:
    """How a kernel's launch range may be split (see the module docstring)."""

    segment: Callable[[dict], int] | None = None  # elements per segment, from the named arguments
    scopes: dict[str, str] = field(default_factory=dict)  # adjoint scope per array argument name
    forward: bool = True  # forward writes are per element (no atomics): any split is exact
    grain: Callable[[dict], int] | int = DEFAULT_GRAIN  # fewest elements worth a chunk
    blocked: tuple[wp.Kernel, Callable[[dict], int]] | None = None  # (kernel, elements per block)


_PARALLEL: dict[int, _Parallel] = {}  # id(kernel) -> how to split it
_KERNELS: dict[int, wp.Kernel] = {}  # keeps the kernels of _PARALLEL alive (ids stay unique)
_LOADED: set[int] = set()  # kernels launched once already (their module is loaded)


def _info(kernel: wp.Kernel) -> _Parallel:
    info = _PARALLEL.get(id(kernel))
    if info is None:
        info = _infer(kernel)
        _PARALLEL[id(kernel)] = info
        _KERNELS[id(kernel)] = kernel
    return info


class FloatKernel:
    """A generic kernel with explicit float32 and float64 overloads.

    ``FloatKernel(kernel, image="scalar", pose="mat34", ...)`` names the kind of every generic
    array argument; ``fk[wp.float64]`` is the concrete float64 kernel. :meth:`set_parallel`
    declares how its launches may be split over threads (otherwise inferred, see the module).
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

    def set_parallel(
        self,
        *,
        segment: Callable[[dict], int] | None = None,
        scopes: dict[str, str] | None = None,
        forward: bool = True,
        grain: Callable[[dict], int] | int = DEFAULT_GRAIN,
        blocked: tuple[FloatKernel, Callable[[dict], int]] | None = None,
    ) -> FloatKernel:
        """Declare how launches of this kernel may be split over threads.

        Args:
            segment: ``segment(args) -> int``, the number of consecutive elements of one segment
                (e.g. ``lambda a: a["H"] * a["W"]`` for a per-pixel kernel whose segments are batch
                items); ``args`` maps every kernel argument name to its launch value.
            scopes: adjoint scope (``"element"``, ``"segment"`` or ``"any"``) per input array;
                inputs not named count as ``"any"`` (outputs need none: adjoints only read them).
            forward: False if the forward pass accumulates into shared outputs (atomics).
            grain: fewest elements worth a chunk (int, or a function of ``args``).
            blocked: ``(fk, L)``: a kernel with the same arguments whose element ``k`` handles
                elements ``[k L, (k + 1) L)`` of this one; ``L(args)`` returns 0 where it does
                not apply (the launch size must be a multiple of L). Its own ``set_parallel``
                describes its blocks.
        """
        for name, scope in (scopes or {}).items():
            if scope not in SCOPES:
                raise ValueError(f"set_parallel: scope of {name!r} must be one of {SCOPES}, got {scope!r}")
        for ft, k in self._overloads.items():
            _PARALLEL[id(k)] = _Parallel(
                segment=segment,
                scopes=dict(scopes or {}),
                forward=forward,
                grain=grain,
                blocked=(blocked[0][ft], blocked[1]) if blocked is not None else None,
            )
            _KERNELS[id(k)] = k
        return self


# ----------------------------------------------------------------------------- inference


def _is_tid_plus_offset(node: ast.AST, offset: str) -> bool:
    """``wp.tid() + offset`` or ``offset + wp.tid()``."""

    def is_tid(n):
        return (
            isinstance(n, ast.Call)
            and not n.args
            and (
                (isinstance(n.func, ast.Attribute) and n.func.attr == "tid")
                or (isinstance(n.func, ast.Name) and n.func.id == "tid")
            )
        )

    def is_offset(n):
        return isinstance(n, ast.Name) and n.id == offset

    return (
        isinstance(node, ast.BinOp)
        and isinstance(node.op, ast.Add)
        and ((is_tid(node.left) and is_offset(node.right)) or (is_offset(node.left) and is_tid(node.right)))
    )


_TREES: dict[int, ast.FunctionDef | None] = {}


def _function_tree(func, source: str | None = None) -> ast.FunctionDef | None:
    """The parsed definition of a Python function (``source``: its text if already known)."""
    key = id(func)
    if key in _TREES:
        return _TREES[key]
    try:
        tree = ast.parse(textwrap.dedent(source if source is not None else inspect.getsource(func)))
    except (OSError, TypeError, SyntaxError):
        _TREES[key] = None
        return None
    node = tree.body[0] if tree.body else None
    _TREES[key] = node if isinstance(node, ast.FunctionDef) else None
    return _TREES[key]


def _resolve(node: ast.AST, namespace: dict) -> Any:
    """The object an ``a.b.c`` / ``name`` expression refers to in ``namespace`` (or None)."""
    if isinstance(node, ast.Name):
        return namespace.get(node.id)
    if isinstance(node, ast.Attribute):
        base = _resolve(node.value, namespace)
        return getattr(base, node.attr, None) if base is not None else None
    return None


def _uses_atomics(func, seen: set[int], depth: int = 0) -> bool:
    """Whether ``func`` (a Python function of a kernel or wp.func) or a wp.func it calls
    accumulates into arrays (``wp.atomic_*`` or ``a[j] += ...``). Conservative: True if unsure."""
    if id(func) in seen:
        return False
    seen.add(id(func))
    fn = _function_tree(func)
    if fn is None or depth > 8:
        return True
    namespace = dict(getattr(func, "__globals__", {}))
    closure = getattr(func, "__closure__", None) or ()
    for name, cell in zip(func.__code__.co_freevars, closure):
        try:
            namespace[name] = cell.cell_contents
        except ValueError:
            pass
    for node in ast.walk(fn):
        if isinstance(node, ast.AugAssign) and isinstance(node.target, ast.Subscript):
            return True
        if isinstance(node, ast.Call):
            name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
            if name.startswith("atomic_"):
                return True
            target = _resolve(node.func, namespace)
            if isinstance(target, wp.Function) and not target.is_builtin():
                funcs = [target.func]
                funcs += [f.func for f in getattr(target, "user_overloads", {}).values()]
                funcs += [f.func for f in getattr(target, "user_templates", {}).values()]
                if any(_uses_atomics(f, seen, depth + 1) for f in funcs if f is not None):
                    return True
    return False


def _infer(kernel: wp.Kernel) -> _Parallel:
    """Scopes and forward safety of a kernel that declared nothing (see the module docstring)."""
    fn = _function_tree(kernel.func, getattr(kernel.adj, "source", None))
    arrays = [a.label for a in kernel.adj.args if wp.types.is_array(a.type)]
    if fn is None or not fn.args.args:
        return _Parallel(scopes=dict.fromkeys(arrays, "any"), forward=False)
    offset = fn.args.args[0].arg
    assigned: dict[str, list[ast.AST]] = {}
    for node in ast.walk(fn):
        targets = node.targets if isinstance(node, ast.Assign) else []
        if isinstance(node, (ast.AugAssign, ast.AnnAssign)):
            targets = [node.target]
        stack = list(targets)
        while stack:  # names bound by the assignment (not those inside subscripts of its targets)
            t = stack.pop()
            if isinstance(t, ast.Name):
                assigned.setdefault(t.id, []).append(node)
            elif isinstance(t, (ast.Tuple, ast.List)):
                stack.extend(t.elts)
            elif isinstance(t, ast.Starred):
                stack.append(t.value)
    for node in ast.walk(fn):  # loop variables are bound too
        if isinstance(node, (ast.For, ast.comprehension)):
            for t in ast.walk(node.target):
                if isinstance(t, ast.Name):
                    assigned.setdefault(t.id, []).extend([node, node])
    elem = {
        name
        for name, nodes in assigned.items()
        if len(nodes) == 1 and isinstance(nodes[0], ast.Assign) and _is_tid_plus_offset(nodes[0].value, offset)
    }
    parents = {child: node for node in ast.walk(fn) for child in ast.iter_child_nodes(node)}
    scopes = {}
    for name in arrays:
        scope = "element"
        for node in ast.walk(fn):
            if isinstance(node, ast.Name) and node.id == name and not isinstance(parents.get(node), ast.arg):
                parent = parents.get(node)
                if not (
                    isinstance(parent, ast.Subscript)
                    and parent.value is node
                    and isinstance(parent.slice, ast.Name)
                    and parent.slice.id in elem
                ):
                    scope = "any"
                    break
        scopes[name] = scope
    return _Parallel(scopes=scopes, forward=not _uses_atomics(kernel.func, set()))


# ----------------------------------------------------------------------------- launching


def _even_chunks(n: int, count: int) -> list[tuple[int, int]]:
    """[0, n) cut into ``count`` nearly equal (start, size) chunks."""
    count = max(1, min(count, n))
    bounds = [n * k // count for k in range(count + 1)]
    return [(bounds[k], bounds[k + 1] - bounds[k]) for k in range(count)]


def _launch_one(kernel, start, size, inputs, outputs, adjoint, adj_inputs, adj_outputs) -> None:
    if adjoint:
        wp.launch(
            kernel,
            dim=size,
            inputs=[start, *inputs],
            outputs=outputs,
            adj_inputs=[0, *adj_inputs],
            adj_outputs=adj_outputs,
            adjoint=True,
            device="cpu",
        )
    else:
        wp.launch(kernel, dim=size, inputs=[start, *inputs], outputs=outputs, device="cpu")


def _array_length(a) -> int:
    return int(a.shape[0])


def _array_ptr(a) -> int:
    return int(a.ptr) if isinstance(a, wp.array) else int(a.data)


@wp.kernel
def _accumulate(offset: int, dst: wp.array(dtype=Any), src: wp.array(dtype=Any)):
    i = wp.tid() + offset
    dst[i] = dst[i] + src[i]


_accumulate_f = {
    ft: wp.overload(_accumulate, {"dst": wp.array(dtype=ft), "src": wp.array(dtype=ft)}) for ft in FLOAT_TYPES
}


def _run_jobs(jobs: list, threads: int) -> None:
    """Run the launches (kernel, arrays, start, size) = ``kernel(start, *arrays)`` over ``size``
    elements on the pool."""

    def run(c: int) -> None:
        kernel, arrays, start, size = jobs[c]
        wp.launch(kernel, dim=size, inputs=[start, *arrays], device="cpu")

    first = 0
    if jobs and id(jobs[0][0]) not in _LOADED:  # load the module before threads start
        run(0)
        _LOADED.add(id(jobs[0][0]))
        first = 1
    _pool.run(lambda c: run(c + first), len(jobs) - first, threads)


def _flat_view(a, dtype, length: int, scalar) -> wp.array:
    """A 1-D ``scalar`` view of the ``length`` elements of ``dtype`` stored in array ``a``."""
    return wp.array(ptr=_array_ptr(a), dtype=scalar, shape=(length * getattr(dtype, "_length_", 1),), device="cpu")


def launch(
    kernel: wp.Kernel,
    n: int,
    inputs: Sequence,
    outputs: Sequence,
    *,
    adjoint: bool = False,
    adj_inputs: Sequence | None = None,
    adj_outputs: Sequence | None = None,
) -> None:
    """Launch ``kernel`` over elements [0, n) on the CPU (forward, or its adjoint), on
    :func:`get_num_threads` threads.

    ``inputs``/``outputs`` exclude the leading ``offset`` argument, which this helper supplies.
    Arrays may be ``wp.array`` s or array descriptors (``wp.from_torch(..., return_ctype=True)``).
    For an adjoint launch, ``adj_inputs`` holds one gradient array (or a placeholder for scalar
    arguments) per input, accumulated into (callers zero them; a null array, with no data and no
    elements, for a gradient that is not wanted: writes to it are skipped), and ``adj_outputs``
    the incoming gradient of each output (``None`` or a null array for non-differentiable ones).
    Results are bitwise identical for every thread count.
    """
    if n <= 0:
        return
    inputs = list(inputs)
    outputs = list(outputs)
    adj_inputs = list(adj_inputs) if adj_inputs is not None else []
    adj_outputs = list(adj_outputs) if adj_outputs is not None else []
    info = _info(kernel)
    names = None
    if info.blocked is not None or info.segment is not None or callable(info.grain):
        names = dict(zip((a.label for a in kernel.adj.args[1:]), (*inputs, *outputs)))
    if info.blocked is not None:
        block = int(info.blocked[1](names))
        if block > 1 and n % block == 0:
            kernel, n = info.blocked[0], n // block
            info = _info(kernel)
    grain = max(1, int(info.grain(names) if callable(info.grain) else info.grain))
    threads = get_num_threads()

    if adjoint:
        arg_names = [a.label for a in kernel.adj.args[1 : 1 + len(inputs)]]
        shared = [
            (k, info.scopes.get(name, "any"))
            for k, name in enumerate(arg_names)
            if wp.types.is_array(kernel.adj.args[1 + k].type)
            and adj_inputs[k] is not None
            and _array_length(adj_inputs[k]) > 0  # a null array: that gradient is not wanted
            and info.scopes.get(name, "any") != "element"
        ]
    else:
        shared = []

    # ---- the plan: chunks (start, size, slot); slot > 0 accumulates into partial buffer `slot`
    if not adjoint and not info.forward:
        plan = [(0, n, 0)]
    elif not shared or (
        all(s == "segment" for _, s in shared)
        and info.segment is not None
        and math.ceil(n / max(1, min(n, int(info.segment(names))))) >= REDUCTION_PIECES
    ):
        # free split: per-element writes, or whole segments (enough of them to keep all pieces busy)
        seg = max(1, min(n, int(info.segment(names)))) if shared else 1
        units = math.ceil(n / seg)
        plan = [(0, n, 0)]
        if threads > 1:
            # equal chunks of whole units (a few per thread, none below the grain): with few units
            # (e.g. 8 batch items on 2 threads) unequal chunks would leave a thread idle
            per = max(math.ceil(units / (threads * CHUNKS_PER_THREAD)), math.ceil(grain / seg))
            plan = [(u * seg, min(n, (u + per) * seg) - u * seg, 0) for u in range(0, units, per)]
    elif all(s == "segment" for _, s in shared) and info.segment is not None:
        # few segments: cut each into a fixed number of pieces, piece p -> partial slot p
        seg = max(1, min(n, int(info.segment(names))))
        n_seg = math.ceil(n / seg)
        pieces = max(1, min(math.ceil(REDUCTION_PIECES / n_seg), seg // grain))
        plan = []
        for s in range(n_seg):
            s0 = s * seg
            for p, (start, size) in enumerate(_even_chunks(min(n, s0 + seg) - s0, pieces)):
                plan.append((s0 + start, size, p))
    else:
        # "any" scopes: a fixed number of pieces over the whole range, piece q -> slot q
        pieces = max(1, min(REDUCTION_PIECES, n // grain))
        plan = [(start, size, q) for q, (start, size) in enumerate(_even_chunks(n, pieces))]

    if len(plan) == 1:
        _launch_one(kernel, 0, n, inputs, outputs, adjoint, adj_inputs, adj_outputs)
        return

    slots = max(s for _, _, s in plan)
    partials: dict[int, list] = {}
    for k, _ in shared if slots > 0 else ():
        dtype = kernel.adj.args[1 + k].type.dtype
        length = _array_length(adj_inputs[k])
        partials[k] = [wp.zeros(length, dtype=dtype, device="cpu") for _ in range(slots)]

    def run(c: int) -> None:
        start, size, slot = plan[c]
        adj = adj_inputs
        if slot > 0:
            adj = list(adj_inputs)
            for k, bufs in partials.items():
                adj[k] = bufs[slot - 1]
        _launch_one(kernel, start, size, inputs, outputs, adjoint, adj, adj_outputs)

    first = 0
    if id(kernel) not in _LOADED:  # load (compile) the module on this thread before threads start
        run(0)
        _LOADED.add(id(kernel))
        first = 1
    _pool.run(lambda c: run(c + first), len(plan) - first, threads)

    # ---- partial buffers, added in slot order (the same order for every thread count)
    for k, bufs in partials.items():
        dtype = kernel.adj.args[1 + k].type.dtype
        scalar = getattr(dtype, "_wp_scalar_type_", dtype)
        length = _array_length(adj_inputs[k])
        dst = _flat_view(adj_inputs[k], dtype, length, scalar)
        m = dst.shape[0]
        chunks = _even_chunks(m, min(threads, max(1, m // (8 * DEFAULT_GRAIN))))
        for buf in bufs:  # one buffer after the other: the order of the sums is fixed
            src = _flat_view(buf, dtype, length, scalar)
            _run_jobs([(_accumulate_f[scalar], [dst, src], start, size) for start, size in chunks], threads)


__all__ = [
    "FLOAT_TYPES",
    "KINDS",
    "FloatKernel",
    "element_shape",
    "element_type",
    "get_num_threads",
    "launch",
    "set_default_num_threads",
    "set_num_threads",
    "thread_backend",
    "use_openmp",
]
