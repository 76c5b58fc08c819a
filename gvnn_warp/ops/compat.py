"""Adapters for the few torch internals gvnn_warp relies on, one small function each.

Each is pinned by a test in ``tests/ops/test_compat.py`` that fails loudly if a torch upgrade changes
it. (Warp's internals have their own adapters in :mod:`gvnn_warp.kernels.core.compat`.)
"""

from __future__ import annotations

import os
import sys

import torch


def custom_op_implementations(op) -> list:
    """The Python implementations a ``torch.library.custom_op`` wraps, one per backend.

    torch keeps them in ``op._backend_fns`` (backend -> wrapper); each wrapper's ``__wrapped__``
    is the function given to ``custom_op`` / ``register_kernel``. Empty if that changes.
    """
    impls = []
    for wrapper in getattr(op, "_backend_fns", {}).values():
        impl = getattr(wrapper, "__wrapped__", None)
        if impl is not None:
            impls.append(impl)
    return impls


def defer_dynamo_disable(impl) -> bool:
    """Spare the first call of a custom op's implementation ``impl`` the import of
    ``torch._dynamo`` (~2 s); returns whether it did.

    torch wraps custom-op implementations in ``torch._disable_dynamo``, which imports
    ``torch._dynamo`` on the first call to build its wrapper and caches it as the attribute
    ``__dynamo_disable`` of the function. Until something else imports ``torch._dynamo``
    nothing can be tracing, so the wrapper can wait: this installs a ``__dynamo_disable`` that
    calls the implementation directly and builds the real wrapper once ``torch._dynamo`` is
    loaded. Same behaviour otherwise.
    """
    if getattr(impl, "__dynamo_disable", None) is not None:
        return False

    def lazy(*args, **kwargs):
        dynamo = sys.modules.get("torch._dynamo")
        if dynamo is None:
            return impl(*args, **kwargs)
        real = dynamo.disable(impl, recursive=True, wrapping=False)
        impl.__dynamo_disable = real
        return real(*args, **kwargs)

    impl.__dynamo_disable = lazy
    return True


def torch_openmp_library() -> tuple[str | None, str]:
    """``(library, reason)``: a library through which the GNU OpenMP runtime torch's parallel ops
    run on is found (torch's ``libtorch_cpu``, whose ``GOMP_parallel`` resolves to that runtime:
    dlsym searches the library's own dependencies), or None and why not.

    torch says which parallel backend it was built with only in the text of
    ``torch.__config__.parallel_info()``. Only Linux builds use GNU OpenMP (libgomp); macOS
    builds use LLVM's libomp and Windows builds MSVC's OpenMP, which gvnn_warp does not drive:
    there launches use gvnn_warp's Python threads.
    """
    if not sys.platform.startswith("linux"):
        return None, f"{sys.platform}: torch's OpenMP runtime is not GNU libgomp; using Python threads"
    if "parallel backend: OpenMP" not in torch.__config__.parallel_info():
        return None, "torch's parallel backend is not OpenMP; using Python threads"
    lib_dir = os.path.join(os.path.dirname(os.path.realpath(torch.__file__)), "lib")
    path = os.path.join(lib_dir, "libtorch_cpu.so")
    if not os.path.exists(path):
        return None, f"{path} not found; using Python threads"
    return path, "torch's OpenMP thread team (through libtorch_cpu's GOMP_parallel)"
