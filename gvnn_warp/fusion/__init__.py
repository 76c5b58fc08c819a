"""Dense fusion of RGB-D frames: a truncated signed distance function in hashed voxel blocks
(KinectFusion, Newcombe et al. 2011; the sparse layout of Open3D's VoxelBlockGrid and Voxblox).

- :mod:`.volume`: :class:`TSDFVolume` - ``integrate`` a frame, ``raycast`` the model from a pose,
  ``extract_mesh`` (marching cubes) and ``extract_points``;
- :mod:`.ply`: binary PLY files of meshes and point clouds (MeshLab, Open3D and Blender read them).

Everything is numpy and Warp: no torch. The kernels are :mod:`gvnn_warp.kernels.fusion`.
"""

from .ply import write_ply
from .volume import BYTES_PER_BLOCK, MAX_BLOCKS, IntegrateReport, MapFull, TSDFVolume

__all__ = ["BYTES_PER_BLOCK", "MAX_BLOCKS", "IntegrateReport", "MapFull", "TSDFVolume", "write_ply"]
