"""The launch layer: :func:`launch`, through which every torch op and the non-recording pure-Warp
functions run their kernels (a kernel's range cut into chunks over threads), and
:class:`RecordedLaunch`, arguments packed once and replayed in pieces (the normal equations, the
pyramids). The pure-Warp functions a ``wp.Tape`` can record launch on one thread through
:func:`wp_launch` (``wp.launch`` with safe first loads).

The other jobs of the launch layer live in their own modules: :mod:`.kinds` (array kinds, the
float32/float64 overloads of :class:`FloatKernel` and each kernel's declaration of how it may be
split) and :mod:`.threads` (thread count, the Python and OpenMP pools). Their public names are
re-exported here, so ``from gvnn_warp.kernels.core.launch import FloatKernel, mat34f, set_num_threads``
keeps working.

Determinism
-----------
Results are bitwise identical for every thread count, forward and backward:

- forward launches write each element's outputs from that element only, so any split is exact;
- adjoint launches accumulate (``+=``). Each differentiable array input has an *adjoint scope*,
  declared with :meth:`FloatKernel.set_parallel` (a kernel that declared nothing is refused, not
  guessed at): ``"element"`` (the gradient entries element ``i`` writes are written by no other
  element: any split is exact), ``"segment"`` (the launch range is made of consecutive segments,
  e.g. batch items, and each segment writes its own disjoint part of the array, e.g. an
  image-gradient plane or one pose gradient), or ``"any"``. Splits never cut a segment unless the
  plan says so, and where a segment or the whole range must be cut into pieces (few batch items,
  or ``"any"`` arrays), the pieces are a fixed function of the launch size, never of the thread
  count; pieces after the first accumulate into zeroed partial buffers that are added to the
  result in a fixed order afterwards. ``tests/ops/test_scopes.py`` runs every registered kernel cut
  into many pieces, in reverse order, against one piece: a wrong declaration fails it.

A kernel may also register a *blocked* variant with the same arguments that handles ``L``
consecutive elements per thread (e.g. one image row, which amortises per-row work and keeps
reductions in registers); :func:`launch` uses it transparently.

First launches
--------------
A kernel's first launch builds or loads its module and looks its entry points up in Warp's CPU
JIT, which is not safe from several threads at once (Warp 1.19 crashed). Every launch in
gvnn_warp goes through :func:`wp_launch`, which does that loading first, under one lock
(:func:`ensure_loaded`), and runs the kernel outside it; later launches take no lock.

This module never imports torch.
"""

from __future__ import annotations

import math
import os
import threading
import weakref
from collections.abc import Callable, Sequence
from typing import Any

import warp as wp

from . import compat as _compat
from . import threads
from .kinds import (
    DEFAULT_GRAIN,
    FLOAT_TYPES,
    KINDS,
    SCOPES,
    FloatKernel,
    Parallel,
    declaration,
    element_shape,
    element_type,
    mat34d,
    mat34f,
    registered,
    vec8d,
    vec8f,
    vec16d,
    vec16f,
)
from .threads import (
    ENV_NUM_THREADS,
    backend_reason,
    get_num_threads,
    set_default_num_threads,
    set_num_threads,
    thread_backend,
    use_openmp,
)

wp.set_module_options({"enable_backward": False})  # only the helper kernel (_accumulate) lives here

# Adjoint reductions that must cut a range (fewer segments than this, or "any" scopes) cut it into
# this many pieces at most. A fixed number, so results do not depend on the thread count. It bounds
# the parallelism of such launches (e.g. a backward pass with batch size 1) and sets the number of
# partial gradient buffers, which cost memory traffic: measured on a batch-1 warp_frame_depth
# backward, 2 pieces cost +20% CPU time over 1 piece, 4 pieces +55%, so 2 pays from 2 threads on.
REDUCTION_PIECES = 2
# Chunks per thread for splits that are free (forward, element-scope adjoints): a little slack
# for load balancing when other processes share the cores.
CHUNKS_PER_THREAD = 4

_LOADED: weakref.WeakSet = weakref.WeakSet()  # kernels whose module is loaded and entry points looked up
_FIRST_LAUNCH_LOCK = threading.RLock()


def _new_lock_in_child() -> None:
    # a fork while another thread held the lock would leave the child's copy held forever
    global _FIRST_LAUNCH_LOCK
    _FIRST_LAUNCH_LOCK = threading.RLock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_new_lock_in_child)


def ensure_loaded(kernel, *args, **kwargs) -> None:
    """Load ``kernel``'s module and look its entry points up in Warp's CPU JIT, under a lock, unless
    done before; the arguments are those of a ``wp.launch`` of it (packed, not run). Two threads
    doing this at once crashed the process with Warp 1.19 (a segmentation fault in ``wp_lookup``
    while another module loaded). Not covered: a module changed after it was loaded (new kernels
    or functions added to it: its next launch reloads it), and a user's own kernels loading at
    the same moment."""
    if kernel in _LOADED:
        return
    with _FIRST_LAUNCH_LOCK:
        if kernel not in _LOADED:
            # record_cmd: Warp loads the module and looks the kernel up, then returns the launch
            # without running it (and without recording it on a tape)
            wp.launch(kernel, *args, **{**kwargs, "record_cmd": True})
            _LOADED.add(kernel)


def wp_launch(kernel, *args, **kwargs):
    """``wp.launch(kernel, ...)`` (same arguments, same result: a tape records it, ``record_cmd``
    returns the launch), after :func:`ensure_loaded`. Every launch in gvnn_warp goes through here,
    so first uses from several threads are safe; only the loading holds the lock, not the run."""
    ensure_loaded(kernel, *args, **kwargs)
    return wp.launch(kernel, *args, **kwargs)


def load_module(module, device: str = "cpu") -> None:
    """``wp.load_module(module, device)`` (compile or load it now) under the lock of
    :func:`ensure_loaded`."""
    with _FIRST_LAUNCH_LOCK:
        wp.load_module(module, device=device)


def _even_chunks(n: int, count: int) -> list[tuple[int, int]]:
    """[0, n) cut into ``count`` nearly equal (start, size) chunks."""
    count = max(1, min(count, n))
    bounds = [n * k // count for k in range(count + 1)]
    return [(bounds[k], bounds[k + 1] - bounds[k]) for k in range(count)]


def plan_chunks(
    n: int, adjoint: bool, info: Parallel, names: dict | None, shared: list[str], n_threads: int, grain: int
) -> list[tuple[int, int, int]]:
    """The chunks ``(start, size, slot)`` of a launch over [0, n); slot 0 writes the gradients
    themselves, slot ``s > 0`` accumulates into partial buffer ``s`` (added in slot order).

    ``shared``: the scopes (``"segment"`` or ``"any"``) of the wanted gradient arrays that are not
    ``"element"``; ``names``: the kernel's arguments by name (for ``info.segment``).
    """
    if not adjoint and not info.forward:
        return [(0, n, 0)]
    segment = max(1, min(n, int(info.segment(names)))) if info.segment is not None else None
    if not shared or (
        all(s == "segment" for s in shared) and segment is not None and math.ceil(n / segment) >= REDUCTION_PIECES
    ):
        # free split: per-element writes, or whole segments (enough of them to keep all pieces busy)
        seg = segment if shared else 1
        units = math.ceil(n / seg)
        if n_threads <= 1:
            return [(0, n, 0)]
        # equal chunks of whole units (a few per thread, none below the grain): with few units
        # (e.g. 8 batch items on 2 threads) unequal chunks would leave a thread idle
        per = max(math.ceil(units / (n_threads * CHUNKS_PER_THREAD)), math.ceil(grain / seg))
        return [(u * seg, min(n, (u + per) * seg) - u * seg, 0) for u in range(0, units, per)]
    if all(s == "segment" for s in shared) and segment is not None:
        # few segments: cut each into a fixed number of pieces, piece p -> partial slot p
        n_seg = math.ceil(n / segment)
        pieces = max(1, min(math.ceil(REDUCTION_PIECES / n_seg), segment // grain))
        plan = []
        for s in range(n_seg):
            s0 = s * segment
            for p, (start, size) in enumerate(_even_chunks(min(n, s0 + segment) - s0, pieces)):
                plan.append((s0 + start, size, p))
        return plan
    # "any" scopes: a fixed number of pieces over the whole range, piece q -> slot q
    pieces = max(1, min(REDUCTION_PIECES, n // grain))
    return [(start, size, q) for q, (start, size) in enumerate(_even_chunks(n, pieces))]


# The planner launch() uses; tests replace it (tests/ops/test_scopes.py cuts every kernel into many pieces).
_planner = plan_chunks


def _launch_one(kernel, start, size, inputs, outputs, adjoint, adj_inputs, adj_outputs) -> None:
    if adjoint:
        wp_launch(
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
        wp_launch(kernel, dim=size, inputs=[start, *inputs], outputs=outputs, device="cpu")


@wp.kernel
def _accumulate(offset: int, dst: wp.array(dtype=Any), src: wp.array(dtype=Any)):
    i = wp.tid() + offset
    dst[i] = dst[i] + src[i]


_accumulate_f = FloatKernel(_accumulate, dst="scalar", src="scalar")  # (run by _run_jobs, not launch(): no declaration)


def _run_jobs(jobs: list, n_threads: int) -> None:
    """Run the launches (kernel, arrays, start, size) = ``kernel(start, *arrays)`` over ``size``
    elements on the pool."""

    def run(c: int) -> None:
        kernel, arrays, start, size = jobs[c]
        wp_launch(kernel, dim=size, inputs=[start, *arrays], device="cpu")

    first = 0
    if jobs and jobs[0][0] not in _LOADED:  # load the module before threads start
        run(0)
        first = 1
    threads.pool().run(lambda c: run(c + first), len(jobs) - first, n_threads)


def _flat_view(a, dtype, length: int, scalar) -> wp.array:
    """A 1-D ``scalar`` view of the ``length`` elements of ``dtype`` stored in array ``a``."""
    return wp.array(
        ptr=_compat.array_pointer(a), dtype=scalar, shape=(length * _compat.scalars_per_element(dtype),), device="cpu"
    )


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

    ``kernel`` is a concrete overload of a :class:`FloatKernel` that declared how it may be split
    (:meth:`FloatKernel.set_parallel`; a ValueError names any other). ``inputs``/``outputs``
    exclude the leading ``offset`` argument, which this helper supplies. Arrays may be
    ``wp.array`` s or array descriptors (``wp.from_torch(..., return_ctype=True)``). For an
    adjoint launch, ``adj_inputs`` holds one gradient array (or a placeholder for scalar
    arguments) per input, accumulated into (callers zero them; a null array, with no data and no
    elements, for a gradient that is not wanted: writes to it are skipped), and ``adj_outputs``
    the incoming gradient of each output (``None`` or a null array for non-differentiable ones).
    Results are bitwise identical for every thread count.
    """
    info = declaration(kernel)
    if n <= 0:
        return
    inputs = list(inputs)
    outputs = list(outputs)
    adj_inputs = list(adj_inputs) if adj_inputs is not None else []
    adj_outputs = list(adj_outputs) if adj_outputs is not None else []
    args = _compat.kernel_arguments(kernel)[1:]  # after offset
    names = None
    if info.blocked is not None or info.segment is not None or callable(info.grain):
        names = dict(zip((name for name, _ in args), (*inputs, *outputs)))
    if info.blocked is not None:
        block = int(info.blocked[1](names))
        if block > 1 and n % block == 0:
            kernel, n = info.blocked[0], n // block
            info = declaration(kernel)
    grain = max(1, int(info.grain(names) if callable(info.grain) else info.grain))
    n_threads = threads.get_num_threads()

    shared_args = []  # (input index, scope) of the wanted gradients that are not per element
    if adjoint:
        for k, (name, is_array) in enumerate(args[: len(inputs)]):
            if (
                is_array
                and adj_inputs[k] is not None
                and _compat.array_length(adj_inputs[k]) > 0  # a null array: that gradient is not wanted
                and info.scope(name) != "element"
            ):
                shared_args.append((k, info.scope(name)))

    plan = _planner(n, adjoint, info, names, [s for _, s in shared_args], n_threads, grain)
    if len(plan) == 1:
        _launch_one(kernel, 0, n, inputs, outputs, adjoint, adj_inputs, adj_outputs)
        return

    slots = max(s for _, _, s in plan)
    partials: dict[int, list] = {}
    for k, _ in shared_args if slots > 0 else ():
        dtype = _compat.kernel_argument_dtype(kernel, 1 + k)
        length = _compat.array_length(adj_inputs[k])
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
    if kernel not in _LOADED:  # load (compile) the module on this thread before threads start
        run(0)
        first = 1
    threads.pool().run(lambda c: run(c + first), len(plan) - first, n_threads)

    # ---- partial buffers, added in slot order (the same order for every thread count)
    for k, bufs in partials.items():
        dtype = _compat.kernel_argument_dtype(kernel, 1 + k)
        scalar = _compat.scalar_type(dtype)
        length = _compat.array_length(adj_inputs[k])
        dst = _flat_view(adj_inputs[k], dtype, length, scalar)
        m = dst.shape[0]
        chunks = _even_chunks(m, min(n_threads, max(1, m // (8 * DEFAULT_GRAIN))))
        for buf in bufs:  # one buffer after the other: the order of the sums is fixed
            src = _flat_view(buf, dtype, length, scalar)
            _run_jobs([(_accumulate_f[scalar], [dst, src], start, size) for start, size in chunks], n_threads)



def launch_chunks(kernel: wp.Kernel, n: int, args: Sequence, chunks_per_thread: int = 4, grain: int = 4096) -> None:
    """A forward-only kernel whose first argument is an element offset, over elements [0, n), cut
    into contiguous chunks run on :func:`get_num_threads` threads (for kernels outside the
    float32/float64 :class:`FloatKernel` family, e.g. the TSDF's): ``chunks_per_thread`` chunks a
    thread, each of at least about ``grain`` elements (fewer chunks for a short range; a kernel
    whose elements are heavy, e.g. a row of 8 rays, passes a smaller grain so that its chunks still
    share out over the threads). Each element must write only its own outputs, so any cut gives the
    same result."""
    if n <= 0:
        return
    n_threads = threads.get_num_threads()
    count = max(1, min(n_threads * chunks_per_thread, n // max(1, grain) + 1))
    step = -(-n // count)
    chunks = [(start, min(step, n - start)) for start in range(0, n, step)]
    ensure_loaded(kernel, dim=chunks[0][1], inputs=[chunks[0][0], *args], device="cpu")  # (before the threads)
    threads.pool().run(lambda c: wp.launch(kernel, dim=chunks[c][1], inputs=[chunks[c][0], *args], device="cpu"),
                       len(chunks), n_threads)


class RecordedLaunch:
    """A forward kernel ``kernel(offset, *inputs, *outputs)`` over elements [0, n) (1-D), its
    arguments packed once (one ``wp.launch(..., record_cmd=True)``) and replayed by calling the
    object (a few microseconds per piece, against ~14 us for ``wp.launch``): min(threads, n,
    n * work // grain) pieces over equal ranges (at least one; ``work``: pixels per element, so a
    piece has at least ``grain`` pixels), several run on :func:`.threads.python_pool` whatever
    :func:`.threads.pool` is (on a loaded host torch's spin-waiting
    OpenMP team cost such tight replay loops several times more). Only for kernels whose elements
    write only their own outputs, so any split gives the same bits. The thread count is read when
    recording.

    The pieces' replay functions (:func:`._compat.replay_pieces`, one argument struct each) are
    built on the first call; :meth:`set_arg` updates their structs in place. Where they do not
    apply, one launch per piece is recorded then and replayed by Warp, and recorded again after
    :meth:`set_arg`. ``n`` <= 0: calls do nothing. The replays
    bypass ``wp.Tape`` and Warp's CPU graph capture (neither records them).
    """

    def __init__(self, kernel: wp.Kernel, n: int, inputs: Sequence, outputs: Sequence = (), *,
                 work: int = 1, grain: int = DEFAULT_GRAIN):
        pieces = max(1, min(threads.get_num_threads(), n, n * work // grain)) if n > 0 else 0
        self._pieces = [(n * k // pieces, n * (k + 1) // pieces - n * k // pieces) for k in range(pieces)]
        self._kernel, self._args = kernel, [*inputs, *outputs]
        self._cmd = None  # nothing to run (n <= 0)
        if pieces:
            self._cmd = wp_launch(kernel, dim=self._pieces[0][1], inputs=[0, *self._args], device="cpu",
                                  record_cmd=True)
        self._runs = None  # the replay functions, built on the first call

    def set_arg(self, index: int, value) -> None:
        """Replace argument ``index`` (0 = the first after ``offset``): a few microseconds once the
        launch has run (an array descriptor, :func:`._compat.array_descriptor`, is the cheapest
        value for an array argument)."""
        if not 0 <= index < len(self._args):
            raise IndexError(f"RecordedLaunch.set_arg: index must be in [0, {len(self._args)}), got {index}")
        if self._cmd is not None:
            self._cmd.set_param_at_index(index + 1, value)  # first: a value Warp refuses changes nothing
        self._args[index] = value
        if self._runs is not None and not _compat.set_replay_arg(self._cmd, self._runs, index + 1):
            self._runs = None  # Warp's replays (the fallback): recorded again on the next call

    def __call__(self) -> None:
        runs = self._runs
        if runs is None:
            if self._cmd is None:
                return
            runs = self._runs = _compat.replay_pieces(self._cmd, self._pieces) or [
                self._fallback(start, size) for start, size in self._pieces]
        if len(runs) == 1:
            runs[0]()
        else:
            threads.python_pool().run(lambda k: runs[k](), len(runs), len(runs))

    def _fallback(self, start: int, size: int) -> Callable[[], None]:
        # where the fast replay does not apply: Warp's own replay of one recorded launch per piece
        return wp_launch(self._kernel, dim=size, inputs=[start, *self._args], device="cpu", record_cmd=True).launch


__all__ = [
    "ENV_NUM_THREADS",
    "FLOAT_TYPES",
    "KINDS",
    "SCOPES",
    "FloatKernel",
    "RecordedLaunch",
    "backend_reason",
    "declaration",
    "element_shape",
    "element_type",
    "get_num_threads",
    "launch",
    "launch_chunks",
    "mat34d",
    "mat34f",
    "plan_chunks",
    "registered",
    "set_default_num_threads",
    "set_num_threads",
    "thread_backend",
    "use_openmp",
    "vec16d",
    "vec16f",
    "vec8d",
    "vec8f",
    "ensure_loaded",
    "load_module",
    "wp_launch",
]
