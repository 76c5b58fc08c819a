"""Pure-Warp building blocks of gvnn_warp, installed as ``gvnn_warp.kernels``; never imports torch.

Laid out by concept (the map: ``docs/architecture.md``; conventions: ``docs/conventions.md``):

- :mod:`.core`: array kinds and :class:`~.core.kinds.FloatKernel` (float32/float64 overloads,
  each kernel's declaration of how it may be split), the launch layer (``launch``,
  ``RecordedLaunch``, ``wp_launch``), threads, and the one cache of generated kernels.
- :mod:`.geometry`: ``@wp.func`` libraries for so3/SE3/Sim3 (:mod:`.geometry.lie`), the pinhole
  camera (:mod:`.geometry.camera`) and the lens models (:mod:`.geometry.lens`), and their thin kernels.
- :mod:`.sampling`: the bilinear sampler, the fused 3D spatial transformer, and host functions on
  ``wp.array`` s that ``wp.Tape`` can record (:mod:`.sampling.pipeline`).
- :mod:`.robust`: the M-estimators; :mod:`.perpixel`: per-pixel transformations.
- :mod:`.photometric`: the fused photometric objective, its Gauss-Newton normal equations and the
  Levenberg-Marquardt step (host functions: :mod:`.photometric.pipeline`).
- :mod:`.pyramid`: image and depth pyramids for coarse-to-fine alignment.

The names below are loaded on first use (PEP 562): a user of the pinhole layers, or of
``gvnn-warp --help``, does not wait for the lens models' functions and the other kernels.
"""

import importlib

from .core.moved import moved

_SUBPACKAGES = ("core", "geometry", "perpixel", "photometric", "pyramid", "reprojection", "robust", "sampling")
# convenience names for pure-Warp users: name -> the module that defines it
_NAMES = {
    **{n: "geometry.camera" for n in ("MIN_DEPTH", "pixel_ray", "project", "project_clamped", "unproject")},
    **{n: "geometry.lie" for n in ("euler_to_matrix", "hat", "pose_from_rt", "quat_wxyz_to_matrix", "se3_exp",
                                   "se3_to_pose", "sim3_to_pose", "so3_exp", "so3_log", "transform_point", "vee")},
    **{n: "photometric.pipeline" for n in ("NormalEquations", "photometric_error", "photometric_normal_equations")},
    **{n: "sampling.pipeline" for n in ("masked_squared_error", "warp_frame_depth")},
    **{n: "sampling.sampler" for n in ("bilinear", "normalized_to_pixel", "sample_position")},
}

# the module paths of earlier releases (gvnn_warp.kernels.lie, ...), kept importable; a tuple: the old
# module's names now live in several. The thin kernels through a lens (lens_kernels,
# sampling_lens_kernels, photometric_lens_kernels) have no old path: they are made on first use by the
# <name>_lens() makers beside their pinhole twins.
_MOVED = {
    "_compat": "core.compat", "kinds": "core.kinds", "launch": "core.launch", "threads": "core.threads",
    "lie": "geometry.lie", "camera": "geometry.camera", "lens": "geometry.lens",
    "lens_rays": ("geometry.lens.rays", "geometry.lens.lanes", "sampling.lens_block"),
    "lie_kernels": "geometry.kernels", "camera_kernels": "geometry.kernels",
    "sampler": "sampling.sampler", "sampling_kernels": "sampling.kernels", "pipeline": "sampling.pipeline",
    "perpixel_kernels": "perpixel.kernels",
    "photometric_error_kernels": ("photometric.error", "photometric.error_reduce"),
    "photometric_kernels": ("photometric.error_rows", "photometric.normal_equations",
                            "photometric.normal_equations_lanes", "photometric.normal_equations_reduce"),
    "photometric_pipeline": "photometric.pipeline", "lm": "photometric.lm",
}
moved({f"{__name__}.{old}": tuple(f"{__name__}.{n}" for n in new) if isinstance(new, tuple) else f"{__name__}.{new}"
       for old, new in _MOVED.items()})


def __getattr__(name: str):
    if name in _SUBPACKAGES:
        return importlib.import_module(f".{name}", __name__)  # (the import sets the attribute)
    if name in _MOVED:
        return importlib.import_module(f".{name}", __name__)  # through the hook: the new module
    if name in _NAMES:
        value = getattr(importlib.import_module(f".{_NAMES[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


__all__ = sorted([*_SUBPACKAGES, *_NAMES])
