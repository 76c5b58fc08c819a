"""gvnn_warp: differentiable geometric computer-vision layers as NVIDIA Warp kernels.

The torch-facing names (functions and ``nn.Module`` layers) are loaded lazily on first use, so
``import gvnn_warp.kernels`` (the pure-Warp building blocks) never imports torch.
"""

from __future__ import annotations

import importlib

import warp as _wp

# Warp logs a start-up banner and a line per module load at INFO level; gvnn_warp shows only
# warnings. Set ``warp.config.log_level = warp.LOG_INFO`` after importing gvnn_warp to see them.
_wp.config.log_level = max(_wp.config.log_level, _wp.LOG_WARNING)

from ._warp_setup import init_warp_quietly  # noqa: E402

# Warp's native library prints a warning about the missing NVIDIA CUDA driver on every machine
# without one; gvnn_warp runs on the CPU, so Warp is initialised here with that one line dropped.
init_warp_quietly()

__version__ = "0.1.0"

from .kernels.launch import get_num_threads, set_num_threads  # noqa: E402  (pure Warp, no torch)

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
_PERPIXEL = (
    "affine_flow",
    "affine_flow_warp",
    "affine_grid",
    "disparity_warp",
    "flow_warp",
    "homography_flow",
    "pointwise_se3",
    "pointwise_sim3",
    "pointwise_transform10",
    "robust_psi",
    "robust_rho",
    "se2_flow",
    "slanted_plane_disparity",
    "smoothness_loss",
)
_PERPIXEL_LAYERS = (
    "AffineFlow",
    "AffineFlowWarp",
    "AffineGridGenerator",
    "DisparityWarp",
    "FlowWarp",
    "HomographyFlow",
    "PointwiseSE3",
    "PointwiseSim3",
    "PointwiseTransform10",
    "RobustLoss",
    "SE2Flow",
    "SlantedPlaneDisparity",
    "SmoothnessLoss",
)
_PHOTOMETRIC = ("PhotometricLoss", "photometric_error", "photometric_normal_equations")
_CAMERAS = (
    "FisheyeCamera",
    "PinholeCamera",
    "RadTanCamera",
    "distort_points",
    "undistort_image",
    "undistort_points",
    "unproject_points",
)
_LAZY = {
    **{n: "functional" for n in _FUNCTIONAL},
    **{n: "layers" for n in _LAYERS},
    **{n: "perpixel" for n in _PERPIXEL},
    **{n: "perpixel_layers" for n in _PERPIXEL_LAYERS},
    **{n: "photometric" for n in _PHOTOMETRIC},
    **{n: "cameras" for n in _CAMERAS},
}
_SUBMODULES = ("cameras", "functional", "layers", "perpixel", "perpixel_layers", "photometric")

__all__ = [
    *_FUNCTIONAL, *_LAYERS, *_PERPIXEL, *_PERPIXEL_LAYERS, *_PHOTOMETRIC, *_CAMERAS, *_SUBMODULES,
    "kernels", "get_num_threads", "info", "set_num_threads",
]


def info() -> dict:
    """Versions and threading of this installation, for bug reports and for checking where
    launches run: ``gvnn_warp``, ``warp``, ``torch`` (None if not installed), ``python``,
    ``num_threads``, ``thread_backend`` (``"openmp:<library>"``, ``"python"`` or ``"serial"``) and
    ``thread_backend_reason`` (e.g. why torch's OpenMP team is not used). Loads the torch bridge
    if torch is installed, since that is where the backend is chosen."""
    import platform

    from .kernels import threads

    try:
        importlib.import_module("._bridge", __name__)
        import torch

        torch_version = torch.__version__
    except ImportError:
        torch_version = None
    return {
        "gvnn_warp": __version__,
        "warp": _wp.config.version,
        "torch": torch_version,
        "python": platform.python_version(),
        "num_threads": threads.get_num_threads(),
        "thread_backend": threads.thread_backend(),
        "thread_backend_reason": threads.backend_reason(),
    }


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    if name in _SUBMODULES:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'gvnn_warp' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
