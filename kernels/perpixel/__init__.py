"""Per-pixel transformations (gvnn's optical flow, disparity, slanted planes, per-pixel SE3/Sim3):
the ``@wp.func`` library (:mod:`.transforms`) and its thin kernels (:mod:`.kernels`).
"""

from ..core.moved import names_of

# the former module gvnn_warp.kernels.perpixel is now this package: its names still resolve here
__getattr__ = names_of(__name__, ".transforms")
