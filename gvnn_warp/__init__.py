"""gvnn_warp: differentiable geometric computer-vision layers as NVIDIA Warp kernels.

The package, by layer (``docs/architecture.md``):

- :mod:`gvnn_warp.kernels`: pure Warp (never imports torch): ``@wp.func`` libraries, thin kernels,
  the launch layer;
- :mod:`gvnn_warp.ops`: each kernel registered as a torch custom op whose backward is the kernel's
  Warp adjoint (the bridge, the argument checks);
- the torch front: :mod:`gvnn_warp.functional` (functions), :mod:`gvnn_warp.nn` (``nn.Module``
  layers), :mod:`gvnn_warp.cameras` (camera models); their public names are also this package's;
- applications: :mod:`gvnn_warp.odometry` (direct RGB-D alignment, tracking, evaluation; no
  torch), :mod:`gvnn_warp.vo` (learned visual odometry), :mod:`gvnn_warp.datasets`,
  :mod:`gvnn_warp.synthetic` (rendered RGB-D data), :mod:`gvnn_warp.cli` (``gvnn-warp``).

``import gvnn_warp`` does not import torch: the torch front's names load on first use.
"""

from __future__ import annotations

import importlib
import platform as _platform

import warp as _wp

# Warp logs a start-up banner and a line per module load at INFO level; gvnn_warp shows only
# warnings. Set ``warp.config.log_level = warp.LOG_INFO`` after importing gvnn_warp to see them.
_wp.config.log_level = max(_wp.config.log_level, _wp.LOG_WARNING)

from ._warp_setup import init_warp_quietly  # noqa: E402

# Warp's native library prints a warning about the missing NVIDIA CUDA driver on every machine
# without one; gvnn_warp runs on the CPU, so Warp is initialised here with that one line dropped.
init_warp_quietly()

__version__ = "0.1.0"

from .kernels.core import threads as _threads  # noqa: E402
from .kernels.core.launch import get_num_threads as get_num_threads  # noqa: E402  (pure Warp, no torch)
from .kernels.core.launch import set_num_threads as set_num_threads  # noqa: E402
from .kernels.core.moved import moved  # noqa: E402

# the torch front, whose public names (their __all__) are gvnn_warp's, in the order they are searched
_FRONT = ("functional", "nn", "cameras")
_SUBPACKAGES = (*_FRONT, "cli", "datasets", "demos", "depth", "kernels", "odometry", "ops", "synthetic", "vo")

# the module paths of earlier releases, kept importable (a tuple: the old module's names now live in several)
_MOVED = {
    "layers": ("nn.lie", "nn.camera", "nn.sampling"),
    "perpixel_layers": "nn.perpixel",
    "perpixel": "functional.perpixel",
    "photometric": ("functional.photometric", "nn.photometric"),
    "tracking": "odometry.tracking",
    "evaluation": "odometry.evaluation",
    "_lens_ops": "ops.lens",
}
moved({f"{__name__}.{old}": tuple(f"{__name__}.{n}" for n in new) if isinstance(new, tuple) else f"{__name__}.{new}"
       for old, new in _MOVED.items()})
# what ``from gvnn_warp import *`` binds besides the front's names: the modules it bound before (not
# the sub-packages a star import would shadow user names with, such as ``nn``)
_STAR_MODULES = ("cameras", "functional", "kernels", "layers", "perpixel", "perpixel_layers", "photometric")


def info() -> dict:
    """Versions and threading of this installation, for bug reports and for checking where
    launches run: ``gvnn_warp``, ``warp``, ``torch`` (None if not installed), ``python``,
    ``num_threads``, ``thread_backend`` (``"openmp:<library>"``, ``"python"`` or ``"serial"``) and
    ``thread_backend_reason`` (e.g. why torch's OpenMP team is not used). Loads the torch bridge
    if torch is installed, since that is where the backend is chosen."""
    try:  # (torch on demand: importing gvnn_warp never imports it)
        importlib.import_module(".ops.bridge", __name__)
        import torch

        torch_version = torch.__version__
    except ImportError:
        torch_version = None
    return {
        "gvnn_warp": __version__,
        "warp": _wp.config.version,
        "torch": torch_version,
        "python": _platform.python_version(),
        "num_threads": _threads.get_num_threads(),
        "thread_backend": _threads.thread_backend(),
        "thread_backend_reason": _threads.backend_reason(),
    }


def _front_names() -> list[str]:
    """The public names of the torch front (imports it, and so torch)."""
    return [n for pkg in _FRONT for n in importlib.import_module(f".{pkg}", __name__).__all__]


def __getattr__(name: str):
    if name in _SUBPACKAGES or name in _MOVED:
        return importlib.import_module(f".{name}", __name__)  # (old module names: through the hook)
    if name == "__all__":  # derived from the front's lists (PEP 562 serves it like any other name)
        return sorted({*_front_names(), *_STAR_MODULES, "get_num_threads", "info", "set_num_threads"})
    if not name.startswith("_"):
        for pkg in _FRONT:
            module = importlib.import_module(f".{pkg}", __name__)
            if name in module.__all__:
                value = globals()[name] = getattr(module, name)
                return value
    raise AttributeError(f"module 'gvnn_warp' has no attribute {name!r}")


def __dir__():
    return sorted({n for n in globals() if not n.startswith("_")} | set(__getattr__("__all__")) | set(_SUBPACKAGES))
