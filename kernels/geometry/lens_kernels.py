"""(shim; the lead removes it) The thin kernels through the lens models, now made on first use by
:mod:`.kernels`' makers: ``lens_kernels.project_points`` is ``kernels.project_points_lens()``, and
so on for ``depth_to_points``, ``unproject_points``, ``distort_pixels`` and ``undistort_pixels``.
Kept for the importers of this module (``gvnn_warp.ops.lens``); reading an attribute makes the
kernel (seconds, once).
"""

from . import kernels as _kernels

_NAMES = ("project_points", "depth_to_points", "unproject_points", "distort_pixels", "undistort_pixels")


def __getattr__(name: str):
    if name in _NAMES:
        value = globals()[name] = getattr(_kernels, f"{name}_lens")()  # (later reads skip this hook)
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_NAMES))
