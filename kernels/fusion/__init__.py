"""A sparse truncated signed distance function (TSDF) of voxel blocks, in Warp (no torch).

The volume is a set of blocks of ``BLOCK`` ^ 3 voxels, allocated where depth is seen and found
through an open-addressing hash table of their integer coordinates (as Open3D's VoxelBlockGrid and
Voxblox do), so a room at 1 cm needs no dense cube. Conventions (``docs/conventions.md``): voxel
``(i, j, k)`` is centred at the world point ``(i, j, k) * voxel_size``; block ``b`` holds voxels
``BLOCK * b + (0 .. BLOCK - 1)`` on each axis; a voxel stores the truncated signed distance
``tsdf`` in [-1, 1] (units of the truncation; positive in front of the surface, towards the
camera), its ``weight`` (0: never observed) and a ``colour`` (RGB in [0, 1]).

- :mod:`.hashing`: ``@wp.func`` s of the hash table and of voxel lookups (no launches);
- :mod:`.kernels`: the thin kernels of integration (blocks touched by a depth image, block
  insertion, integration); :mod:`.integrate_lanes`: the integration with a block's row of 8 voxels
  as 8 lanes; :mod:`.raycasting`: raycasting (:mod:`.raycast_lanes`: a tile's row of 8
  rays marched together); :mod:`.marching`: marching cubes;
- the host object that checks, grows its arrays and launches (numpy in and out) is
  ``gvnn_warp.fusion.TSDFVolume``.
"""
