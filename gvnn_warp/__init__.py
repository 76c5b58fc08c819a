"""gvnn_warp: differentiable geometric computer-vision layers as NVIDIA Warp kernels.

The torch-facing names (functions and ``nn.Module`` layers) are loaded lazily on first use, so
``import gvnn_warp.kernels`` (the pure-Warp building blocks) never imports torch.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

_FUNCTIONAL = (
    "MIN_DEPTH",
    "bilinear_sample",
    "depth_to_points",
    "euler_to_matrix",
    "project_points",
    "quaternion_to_matrix",
    "se3_exp",
    "se3_log",
    "se3_to_matrix",
    "sim3_to_matrix",
    "so3_exp",
    "so3_log",
    "transform_points",
    "warp_frame_depth",
)
_LAYERS = (
    "SO3",
    "SE3",
    "Sim3",
    "GridGenerator3D",
    "PinholeProjection",
    "BilinearSampler",
    "SpatialTransformer3D",
)
_LAZY = {**{n: "functional" for n in _FUNCTIONAL}, **{n: "layers" for n in _LAYERS}}

__all__ = [*_FUNCTIONAL, *_LAYERS, "functional", "layers", "kernels"]


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    if name in ("functional", "layers"):
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'gvnn_warp' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
