"""Dense fusion of RGB-D frames: a truncated signed distance function in hashed voxel blocks
(KinectFusion, Newcombe et al. 2011; the sparse layout of Open3D's VoxelBlockGrid and Voxblox).

- :mod:`.volume`: :class:`TSDFVolume` - ``integrate`` a frame, ``raycast`` the model from a pose,
  ``extract_mesh`` (marching cubes) and ``extract_points``;
- :mod:`.ply`: binary PLY files of meshes and point clouds (MeshLab, Open3D and Blender read them);
- :mod:`.sequence`: a sequence fused after tracking (``fuse_sequence``), or tracked against the model
  (``ModelTracker``; ``FrameToModel`` one frame at a time). Its names load on first use (it brings
  the direct aligner's modules).

Everything is numpy and Warp: no torch. The kernels are :mod:`gvnn_warp.kernels.fusion`.
"""

from .._exports import lazy_exports, literal_all
from .ply import write_ply
from .volume import BYTES_PER_BLOCK, MAX_BLOCKS, IntegrateReport, MapFull, TSDFVolume

__all__ = ["BYTES_PER_BLOCK", "MAX_BLOCKS", "IntegrateReport", "MapFull", "TSDFVolume", "write_ply",
           *literal_all(f"{__name__}.sequence")]

__getattr__, _dir = lazy_exports(__name__, ("sequence",))


def __dir__() -> list[str]:
    return sorted({*_dir(), *__all__})
