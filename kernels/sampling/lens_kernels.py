"""(shim; the lead removes it) The fused 3D spatial transformer through a lens model, now made on
first use by :mod:`.kernels`' makers: ``pixel_rays`` is ``kernels.pixel_rays_lens()``,
``warp_frame_depth_lens`` is ``kernels.warp_frame_depth_lens()``. Kept for the importers of this
module (``gvnn_warp.ops.lens``); reading an attribute makes the kernel (seconds, once).
"""

from . import kernels as _kernels

_MAKERS = {"pixel_rays": _kernels.pixel_rays_lens, "warp_frame_depth_lens": _kernels.warp_frame_depth_lens}


def __getattr__(name: str):
    if name in _MAKERS:
        value = globals()[name] = _MAKERS[name]()  # (later reads skip this hook)
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_MAKERS))
