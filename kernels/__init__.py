"""Pure-Warp building blocks of gvnn_warp, installed as ``gvnn_warp.kernels``; never imports torch.

- ``@wp.func`` libraries to call from your own kernels: :mod:`.lie` (so3/SE3/Sim3 exp and log,
  quaternions, Euler angles, poses), :mod:`.camera` (unproject, project), :mod:`.lens` (camera
  models: pinhole, radial-tangential, fisheye; project, unproject, distort, undistort),
  :mod:`.lens_rays` (pixel rays moved and projected through a lens, for fused kernels),
  :mod:`.sampler` (bilinear sampling with zeros/border padding).
- Thin kernels with float32/float64 overloads: :mod:`.lie_kernels`, :mod:`.camera_kernels`,
  :mod:`.lens_kernels`,
  :mod:`.sampling_kernels` (including the fused 3D spatial transformer; through a lens model:
  :mod:`.sampling_lens_kernels`).
- Host functions on ``wp.array``s, usable under ``wp.Tape``: :mod:`.pipeline`; the fused
  photometric objective (its Gauss-Newton normal equations): :mod:`.photometric_pipeline`
  (both take a distorted lens as ``dist=``, ``model=``; its kernels: :mod:`.photometric_lens_kernels`).
- The launch layer: :mod:`.kinds` (array kinds, float32/float64 overloads, each kernel's declaration
  of how it may be split), :mod:`.threads` (thread count, pools), :mod:`.launch` (the chunk
  planner and ``launch()``; re-exports the public names of the other two).

Conventions: ``docs/conventions.md``.
"""

import importlib

# Submodules and re-exported names are imported on first use (PEP 562): defining the camera
# models' custom adjoints makes Warp build their functions (~2 s on a slow guest), which a user
# of the layers without a lens, or of `gvnn-warp --help`, should not wait for.
_SUBMODULES = (
    "camera", "camera_kernels", "kinds", "launch", "lens", "lens_kernels", "lens_rays", "lie", "lie_kernels",
    "photometric", "photometric_kernels", "photometric_lens_kernels", "photometric_pipeline", "pipeline",
    "sampler", "sampling_kernels", "sampling_lens_kernels",
)
_NAMES = {
    **{n: "camera" for n in ("MIN_DEPTH", "pixel_ray", "project", "project_clamped", "unproject")},
    **{n: "lie" for n in ("euler_to_matrix", "hat", "pose_from_rt", "quat_wxyz_to_matrix", "se3_exp", "se3_to_pose",
                          "sim3_to_pose", "so3_exp", "so3_log", "transform_point", "vee")},
    **{n: "photometric_pipeline" for n in ("NormalEquations", "photometric_error", "photometric_normal_equations")},
    **{n: "pipeline" for n in ("masked_squared_error", "warp_frame_depth")},
    **{n: "sampler" for n in ("bilinear", "normalized_to_pixel", "sample_position")},
}


# the other modules (not in __all__), which ``gvnn_warp.kernels.<name>`` also reaches
_OTHER_MODULES = ("lm", "perpixel", "perpixel_kernels", "photometric_error_kernels", "pyramid", "robust", "threads")


def __getattr__(name: str):
    if name in _SUBMODULES or name in _OTHER_MODULES:
        return importlib.import_module(f".{name}", __name__)  # (the import sets the attribute)
    if name in _NAMES:
        value = getattr(importlib.import_module(f".{_NAMES[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


__all__ = sorted([*_SUBMODULES, *_NAMES])
