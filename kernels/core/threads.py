"""How many threads gvnn_warp's launches use, and the two pools that run their chunks.

A Warp CPU launch runs its whole range on one thread, and releases the GIL. :func:`.launch.launch`
cuts the range into chunks and hands them to the current pool:

- the Python pool (default): a few Python threads; the calling thread takes part;
- the OpenMP pool, after :func:`use_openmp` (which the torch bridge calls with torch's own OpenMP
  runtime, on Linux): the chunks run on that runtime's thread team through ``GOMP_parallel``.

The number of threads is, in order of precedence: :func:`set_num_threads`, the environment
variable ``GVNN_WARP_NUM_THREADS``, the default provider (the torch bridge installs
``torch.get_num_threads``), else ``os.cpu_count()``. ``1`` disables threading. On a free-threaded
CPython running without the GIL, launches run on one thread (the chunk hand-out relies on the GIL).

:func:`thread_backend` says where chunks run, :func:`backend_reason` why (e.g. why the OpenMP pool
was not used); a choice is also logged at DEBUG level on the ``gvnn_warp`` logger.

This module never imports torch.
"""

from __future__ import annotations

import ctypes
import itertools
import logging
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

from . import compat as _compat

ENV_NUM_THREADS = "GVNN_WARP_NUM_THREADS"
log = logging.getLogger("gvnn_warp")

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
    """The number of threads :func:`.launch.launch` uses (see :func:`set_num_threads`)."""
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
    return _CPU_COUNT


_CPU_COUNT = os.cpu_count() or 1  # read once: the call costs ~20 us here, and launches ask often


def _drain(fn: Callable[[int], None], tasks, errors: list) -> None:
    """Run ``fn(k)`` for the chunk indices ``k`` left in ``tasks`` (an iterator shared by the
    threads of a pool: next() on it is atomic under the GIL, which is why a free-threaded
    interpreter runs pools on one thread), collecting exceptions in ``errors`` for the pool to
    re-raise."""
    for k in tasks:
        try:
            fn(k)
        except BaseException as e:  # noqa: BLE001 - re-raised by the pool's run()
            errors.append(e)


def _serial(fn: Callable[[int], None], n_tasks: int, n_threads: int) -> bool:
    """Run the tasks here, in order, if there is nothing to share (one thread) or sharing is not
    safe (no GIL); True if it did."""
    if n_threads > 1 and _compat.gil_enabled():
        return False
    for k in range(n_tasks):
        fn(k)
    return True


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
        if _serial(fn, n_tasks, n_threads):
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
        if _serial(fn, n_tasks, n_threads):
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
_reason = "default (no OpenMP runtime was offered: the torch bridge is not loaded)"


def pool() -> _Pool | _OpenMPPool:
    """The pool threaded launches run on (see :func:`use_openmp`)."""
    return _pool


def python_pool() -> _Pool:
    """gvnn_warp's own pool of Python threads, whatever :func:`pool` is. For callers that replay
    recorded launches in a tight loop (the fused normal equations): on a loaded host, torch's
    OpenMP team spin-waits and cost them several times more than these threads."""
    return _python_pool


def use_openmp(library: str | None, reason: str | None = None) -> None:
    """Run threaded launches on the thread team of the GNU OpenMP runtime (``GOMP_parallel``) found
    through ``library`` (an already loaded ``libgomp``, or a library linked against it: the torch
    bridge passes torch's ``libtorch_cpu``), or, with ``None``, on gvnn_warp's pool of Python
    threads. ``reason``: why (reported by :func:`backend_reason`). Results do not depend on it.
    Raises OSError / AttributeError if the library or its ``GOMP_parallel`` cannot be loaded."""
    global _pool, _reason
    _pool = _OpenMPPool(library) if library is not None else _python_pool
    _reason = reason or ("asked for" if library is not None else "asked for (use_openmp(None))")
    log.debug("gvnn_warp: threaded launches run on %s (%s)", thread_backend(), _reason)


def thread_backend() -> str:
    """Where threaded launches run: ``"openmp:<library>"``, ``"python"`` (gvnn_warp's Python
    threads) or ``"serial"`` (a free-threaded interpreter without the GIL: one thread)."""
    if not _compat.gil_enabled():
        return "serial"
    return f"openmp:{_pool.library}" if isinstance(_pool, _OpenMPPool) else "python"


def backend_reason() -> str:
    """Why :func:`thread_backend` is what it is (e.g. why torch's OpenMP team is not used)."""
    if not _compat.gil_enabled():
        return "free-threaded interpreter without the GIL: launches run on one thread"
    return _reason


__all__ = [
    "ENV_NUM_THREADS",
    "backend_reason",
    "get_num_threads",
    "pool",
    "python_pool",
    "set_default_num_threads",
    "set_num_threads",
    "thread_backend",
    "use_openmp",
]
