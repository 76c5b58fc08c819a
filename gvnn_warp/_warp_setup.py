"""Warp's start-up for a CPU package: initialisation without the CUDA-driver line, and a hook that
tells when Warp compiles (never imports torch).

Warp's native library (warp-lang 1.19, built with CUDA support) prints "Warp CUDA warning: Could
not find or load the NVIDIA CUDA driver. GPU execution will not be available." to the process's
stderr from ``wp.init()`` on every machine without the NVIDIA driver; Warp has no setting for it.
gvnn_warp runs on the CPU only, so :func:`init_warp_quietly` initialises Warp with that one line
removed and passes everything else Warp writes to stderr through unchanged.
"""

from __future__ import annotations

import functools
import os
import sys
import tempfile
import threading
from collections.abc import Callable

import warp as wp

__all__ = ["CUDA_DRIVER_WARNING", "cancel_first_compile", "init_warp_quietly", "on_first_compile"]

CUDA_DRIVER_WARNING = "Could not find or load the NVIDIA CUDA driver"


def init_warp_quietly(init: Callable[[], None] | None = None) -> None:
    """Run ``init`` (default ``wp.init``; a no-op once Warp is initialised) with file descriptor 2
    captured, then write back to it every line but Warp's CUDA-driver warning."""
    init = init or wp.init
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no usable stderr (e.g. pythonw): nothing to filter
        init()
        return
    try:
        with tempfile.TemporaryFile() as captured:
            os.dup2(captured.fileno(), 2)
            try:
                init()
            finally:
                try:
                    sys.stderr.flush()
                except (OSError, ValueError):
                    pass
                os.dup2(saved, 2)
            captured.seek(0)
            text = captured.read()
    finally:
        os.close(saved)
    kept = b"".join(line for line in text.splitlines(keepends=True) if CUDA_DRIVER_WARNING.encode() not in line)
    if kept:
        os.write(2, kept)


_hook_lock = threading.Lock()
_listeners: list[Callable[[], None]] = []


def on_first_compile(notify: Callable[[], None]) -> bool:
    """Call ``notify()`` once, just before Warp compiles (generates code for and builds) its first
    kernel module in this process; modules loaded from the kernel cache do not count. Returns
    False, and never calls ``notify``, if this Warp has no ``Module._run_codegen`` (the step it runs
    only when a module is not in the cache: warp-lang 1.19's private API)."""
    try:  # (here, not at the top: a private module of Warp's, which another Warp may not have)
        from warp._src.context import Module
    except ImportError:
        return False
    original = getattr(Module, "_run_codegen", None)
    if original is None:
        return False
    with _hook_lock:
        _listeners[:] = [notify]  # the latest caller's; one line per process
        if getattr(original, "_gvnn_warp_hook", False):
            return True

        @functools.wraps(original)
        def run_codegen(self, *args, **kwargs):
            if _listeners:
                with _hook_lock:
                    pending = list(_listeners)
                    _listeners.clear()
                for fn in pending:
                    fn()
            return original(self, *args, **kwargs)

        run_codegen._gvnn_warp_hook = True
        Module._run_codegen = run_codegen
    return True


def cancel_first_compile() -> None:
    """Forget a pending :func:`on_first_compile` callback (the hook itself stays, doing nothing)."""
    with _hook_lock:
        _listeners.clear()
