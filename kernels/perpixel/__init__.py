"""Per-pixel transformations (gvnn's optical flow, disparity, slanted planes, per-pixel SE3/Sim3):
the ``@wp.func`` library (:mod:`.transforms`) and its thin kernels (:mod:`.kernels`).
"""

import importlib


def __getattr__(name: str):
    # the former module gvnn_warp.kernels.perpixel is now .transforms: its names still resolve here
    value = getattr(importlib.import_module(".transforms", __name__), name)
    globals()[name] = value
    return value
