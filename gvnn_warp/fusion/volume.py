"""The TSDF volume: depth frames fused into a sparse voxel-block grid, raycast and meshed (no torch).

:class:`TSDFVolume` checks its inputs (numpy arrays or CPU torch tensors), grows its arrays and
launches the kernels of :mod:`gvnn_warp.kernels.fusion` (conventions: that module's docstring and
``docs/conventions.md``), cutting every per-voxel and per-pixel launch into chunks over the
library's threads (``launch_chunks``) (:func:`gvnn_warp.set_num_threads`); results do not depend on the thread count.

Example::

    import numpy as np
    from gvnn_warp.fusion import TSDFVolume

    vol = TSDFVolume(voxel_size=0.01)
    for depth, colour, T_world_cam in frames:      # (H, W) metres, (3, H, W) in [0, 1], (4, 4)
        vol.integrate(depth, colour, K, T_world_cam)
    depth, colour, normals = vol.raycast(K, T_world_cam, 480, 640)
    vertices, faces, colours = vol.extract_mesh()
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..kernels.core.launch import launch_chunks, wp_launch
from ..kernels.core.threads import get_num_threads
from ..kernels.fusion import integrate_lanes as I_
from ..kernels.fusion import kernels as K_
from ..kernels.fusion import marching
from ..kernels.fusion import raycast_lanes as RL_
from ..kernels.fusion import raycasting as R_
from ..kernels.fusion.hashing import BLOCK, BLOCK_VOXELS
from ..kernels.geometry import lens as _lens
from ..kernels.sampling.pipeline import pixel_rays
from ..odometry.inputs import as_numpy, colour_values, dist_array, fail, lens_camera, real_number, rigid_pose

__all__ = ["BYTES_PER_BLOCK", "EMPTY_VOLUME", "IntegrateReport", "MAX_BLOCKS", "MapFull", "TSDFVolume"]

BYTES_PER_BLOCK = BLOCK_VOXELS * (8 + 16)  # per voxel: TSDF and weight, colour and its weight (float32)
MAX_BLOCKS = (2**31 - 1) // BLOCK_VOXELS  # the kernels index voxels (block * BLOCK_VOXELS + voxel) in int32
_FIRST_BLOCKS = 1024  # blocks allocated at first (10 MiB); doubled as needed
EMPTY_VOLUME = "the volume is empty"  # (extract_mesh's warning, after its name: callers that report it filter it)
_TILE = 8  # pixels per side of the tiles of the raycast's depth range
_BLOCKS_PER_PART = 1024  # the raycast's depth range: the blocks are shared out between threads from 2 x this
_NORMAL_JUMP = 0.05  # a raycast normal needs its neighbours' depths within 5% (else it is a depth edge)


class MapFull(ValueError):
    """The map needs more blocks than ``max_memory_mb`` holds (the message says how many and what to change)."""


@dataclass
class IntegrateReport:
    """What one :meth:`TSDFVolume.integrate` did: ``valid_pixels`` (depths in range), ``blocks``
    (touched by the frame), ``new_blocks`` (allocated for it), ``total_blocks``."""

    valid_pixels: int
    blocks: int
    new_blocks: int
    total_blocks: int


def _name(method: str) -> str:
    return f"gvnn_warp.fusion.TSDFVolume.{method}"


class TSDFVolume:
    """A truncated signed distance function in voxel blocks allocated where depth is seen.

    Args:
        voxel_size: metres (> 0).
        truncation: metres, the band around the surface that a depth updates (default 4 voxels;
            at least one voxel).
        max_memory_mb: the most memory the voxels may take; :meth:`integrate` refuses a frame that
            would need more (:class:`MapFull`, a ValueError saying how much the map holds and what
            to change). At most :data:`MAX_BLOCKS` blocks (48 GiB) whatever it allows: the kernels
            index voxels with 32-bit integers.
        min_depth, max_depth: metres; depths outside (and 0, NaN, negative) are not used.
        pixel_stride: every ``pixel_stride``-th pixel on each axis decides which blocks a frame
            allocates (every pixel updates the voxels: a block is 8 voxels, tens of pixels wide at
            room distances, so 2 misses none that matter and halves the cost of finding them); it
            is lowered where a block at ``max_depth`` would be narrower than the stride (fine voxels).
    """

    def __init__(self, voxel_size: float = 0.01, truncation: float | None = None, *, max_memory_mb: float = 2048.0,
                 min_depth: float = 0.1, max_depth: float = 8.0, pixel_stride: int = 2):
        v = real_number(voxel_size)
        if not (math.isfinite(v) and v > 0):
            fail(_name("__init__"), ValueError, f"argument 'voxel_size' must be a positive number (metres), "
                                                f"got {voxel_size!r}")
        trunc = 4.0 * v if truncation is None else real_number(truncation)
        if not (math.isfinite(trunc) and trunc >= v):
            fail(_name("__init__"), ValueError, f"argument 'truncation' must be at least the voxel size ({v:g} m), "
                                                f"got {truncation!r}")
        lo, hi = real_number(min_depth), real_number(max_depth)
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
            fail(_name("__init__"), ValueError, f"arguments 'min_depth' and 'max_depth' must satisfy "
                                                f"0 < min_depth < max_depth, got {min_depth!r}, {max_depth!r}")
        mem = real_number(max_memory_mb)
        if not (math.isfinite(mem) and mem * 2**20 >= BYTES_PER_BLOCK):
            fail(_name("__init__"), ValueError, f"argument 'max_memory_mb' must be a finite number of MiB that holds "
                                                f"at least one block ({BYTES_PER_BLOCK / 2**20:.3f} MiB), got "
                                                f"{max_memory_mb!r}")
        whole = isinstance(pixel_stride, (int, np.integer)) and not isinstance(pixel_stride, bool)
        if not (whole and pixel_stride >= 1):
            fail(_name("__init__"), ValueError, f"argument 'pixel_stride' must be an integer >= 1, got "
                                                f"{pixel_stride!r}")
        self.voxel_size, self.truncation = float(v), float(trunc)
        self.min_depth, self.max_depth = float(lo), float(hi)
        self.pixel_stride = int(pixel_stride)
        self.max_blocks = min(int(mem * 2**20 // BYTES_PER_BLOCK), MAX_BLOCKS)
        self._calls = 0
        self._frames = 0  # (frames given to integrate: an empty volume's warning says which case it is)
        self._warned: set[str] = set()  # (each of integrate's warnings once per volume)
        self._lanes = True  # (False: the voxel-by-voxel and ray-by-ray kernels; the tests compare them)
        self._rays: dict = {}  # (camera, size) -> (rays, the longest ray's length)
        self._mc_tables = (wp.array(np.asarray(marching.MC_RANGE, np.int32), dtype=wp.int32, device="cpu"),
                           wp.array(np.asarray(marching.MC_TRI, np.int32), dtype=wp.int32, device="cpu"))
        self._allocate_blocks(min(_FIRST_BLOCKS, self.max_blocks))
        self._allocate_table(4 * _FIRST_BLOCKS)  # (grown 2x whenever it would be more than half full)
        self.counts = wp.zeros(3, dtype=wp.int32, device="cpu")

    # ------------------------------------------------------------------------------ storage

    @property
    def n_blocks(self) -> int:
        """Blocks allocated so far."""
        return int(self._n_blocks)

    @property
    def memory_bytes(self) -> int:
        """Bytes of the allocated blocks' voxels."""
        return self.n_blocks * BYTES_PER_BLOCK

    def _allocate_blocks(self, capacity: int) -> None:
        old = getattr(self, "coords", None)
        n = getattr(self, "_n_blocks", 0)
        coords = wp.zeros(capacity, dtype=wp.vec3i, device="cpu")
        stamp = wp.zeros(capacity, dtype=wp.int32, device="cpu")
        tw = wp.zeros(capacity * BLOCK_VOXELS, dtype=wp.vec2, device="cpu")  # (TSDF, weight) of each voxel
        colour = wp.zeros(capacity * BLOCK_VOXELS, dtype=wp.vec4, device="cpu")  # (RGB, its weight)
        if old is not None and n:
            for dst, src, m in ((coords, self.coords, n), (stamp, self.stamp, n), (tw, self.tw, n * BLOCK_VOXELS),
                                (colour, self.colour, n * BLOCK_VOXELS)):
                wp.copy(dst, src, count=m)
        self.coords, self.stamp, self.tw, self.colour = coords, stamp, tw, colour
        self._n_blocks = n
        self.capacity = capacity

    def _allocate_table(self, slots: int) -> None:
        size = 1 << max(10, math.ceil(math.log2(max(slots, 2))))
        self.table = wp.full(size, wp.vec4i(0, 0, 0, -1), dtype=wp.vec4i, device="cpu")
        self.mask = size - 1
        if self._n_blocks:
            wp_launch(K_.rehash, dim=1, inputs=[self.coords, self._n_blocks, self.table, self.mask], device="cpu")

    # ------------------------------------------------------------------------------ inputs

    def _camera(self, fn: str, camera, height: int, width: int):
        """(fx, fy, cx, cy, model id, dist vec8d, rays wp.array (H * W vec3), the longest ray's length:
        metres per unit of depth at most) of ``camera``: a (3, 3) K, a ``(K, dist)`` pair
        (radial-tangential, 5 coefficients) or a camera of ``gvnn_warp.cameras``."""
        dist = None
        if isinstance(camera, tuple) and len(camera) == 2:
            camera, dist = camera
            d = dist_array(_name(fn), "camera", dist)
            if d is None or d.shape != (5,) or not np.all(np.isfinite(d)):
                fail(_name(fn), ValueError, f"argument 'camera' as (K, dist) needs dist = 5 finite radial-tangential "
                                            f"coefficients (k1, k2, p1, p2, k3), got {dist!r}")
        if isinstance(camera, (list, tuple)):  # ((fx, fy, cx, cy) or a list: not a camera this takes)
            fail(_name(fn), TypeError, "argument 'camera' must be a (3, 3) K (numpy or torch), a (K, dist) pair or a "
                                       f"camera of gvnn_warp.cameras, got a {type(camera).__name__} of {len(camera)}")
        K, model, packed = lens_camera(_name(fn), camera, None, dist, name="camera")
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            fail(_name(fn), ValueError, f"argument 'camera' must have a finite (3, 3) K with fx, fy > 0, got {K}")
        mid = _lens.MODEL_IDS[model]
        packed = np.zeros(8) if packed is None else packed
        key = (K.tobytes(), packed.tobytes(), mid, height, width)
        cached = self._rays.get(key)
        if cached is None:
            if mid == 0:
                x, y = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
                r = np.stack([(x - K[0, 2]) / K[0, 0], (y - K[1, 2]) / K[1, 1], np.ones_like(x)], -1)
                rays = wp.array(r.reshape(-1, 3).astype(np.float32), dtype=wp.vec3, device="cpu")
            else:
                Kw = wp.array(K[None].astype(np.float32), dtype=wp.mat33, device="cpu")
                dw = wp.array(packed[None].astype(np.float32), dtype=wp.types.vector(8, wp.float32), device="cpu")
                rays = pixel_rays(Kw, dw, height, width, mid).flatten()
            if len(self._rays) > 8:
                self._rays.clear()
            r = rays.numpy()
            cached = self._rays[key] = (rays, float(np.max(np.linalg.norm(r[r[:, 2] > 0], axis=1), initial=1.0)))
        d8 = wp.types.vector(8, wp.float64)(*packed.tolist())
        return (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), mid, d8, *cached)

    @staticmethod
    def _pose(fn: str, T) -> np.ndarray:
        return rigid_pose(_name(fn), "T_world_cam", T)

    # ------------------------------------------------------------------------------ integration

    def integrate(self, depth, colour, camera, T_world_cam) -> IntegrateReport:
        """Fuse one frame: ``depth`` (H, W) or (1, H, W) metres (0, NaN, negative or out of
        [min_depth, max_depth]: no depth), ``colour`` (3, H, W) RGB in [0, 1] or None, ``camera``
        a (3, 3) K, a ``(K, dist)`` pair (radial-tangential: 5 coefficients k1, k2, p1, p2, k3) or a
        camera of ``gvnn_warp.cameras`` (any lens model), ``T_world_cam`` (4, 4). Returns an
        :class:`IntegrateReport`; a frame with no valid depth changes nothing (``valid_pixels`` 0)."""
        fn = "integrate"
        d = as_numpy(_name(fn), "depth", depth, (2, 3))
        if d.ndim == 3:
            if d.shape[0] != 1:
                fail(_name(fn), ValueError, f"argument 'depth' must be (H, W) or (1, H, W), got {d.shape}")
            d = d[0]
        H, W = d.shape
        if H < 2 or W < 2:
            fail(_name(fn), ValueError, f"argument 'depth' must be at least 2x2, got {d.shape}")
        has_colour = colour is not None
        if has_colour:
            c = as_numpy(_name(fn), "colour", colour, (3,))
            if c.shape != (3, H, W):
                hint = ", which looks channel-last (H, W, 3): transpose it" if c.shape == (H, W, 3) else ""
                fail(_name(fn), ValueError, f"argument 'colour' must be (3, {H}, {W}) like the depth, got "
                                            f"{c.shape}{hint}")
            c = colour_values(_name(fn), "colour", c, self._warned)  # (NaN and inf: black; 8-bit: said)
            image = wp.array(np.ascontiguousarray(c, np.float32).reshape(-1), dtype=wp.float32, device="cpu")
        else:
            image = wp.zeros(3, dtype=wp.float32, device="cpu")
        T = self._pose(fn, T_world_cam)
        fx, fy, cx, cy, model, dist, rays, scale = self._camera(fn, camera, H, W)
        dn = np.ascontiguousarray(d, np.float32)
        valid = int(np.count_nonzero((dn > self.min_depth) & (dn < self.max_depth)))
        self._frames += 1
        if valid == 0:
            return IntegrateReport(0, 0, 0, self.n_blocks)
        depth_w = wp.array(dn.reshape(-1), dtype=wp.float32, device="cpu")
        R_wc, t_wc = T[:3, :3], T[:3, 3]
        R_cw, t_cw = R_wc.T, -R_wc.T @ t_wc
        block_len = self.voxel_size * BLOCK

        # 1. the blocks the frame's truncation band passes through (sampled pixels)
        # a block must span a sampled pixel on each axis even at max_depth, or the samples skip blocks
        # (fine voxels): the stride at most the block's width in pixels there
        s = max(1, min(self.pixel_stride, int(min(fx, fy) * block_len / self.max_depth)))
        n_samp = (-(-W // s)) * (-(-H // s))
        samples = max(2, math.ceil(2 * self.truncation * scale / (0.5 * block_len)) + 1)
        cand = wp.empty(n_samp * samples, dtype=wp.vec3i, device="cpu")
        launch_chunks(K_.touched_blocks, n_samp, [depth_w, rays, wp.mat33(*R_wc.ravel()), wp.vec3(*t_wc), W, s,
                                              self.truncation, 1.0 / block_len, self.min_depth, self.max_depth,
                                              samples, cand])
        # 2. find or add them (one thread: it owns the table), growing the arrays as needed
        before = self.n_blocks
        active = wp.empty(cand.shape[0], dtype=wp.int32, device="cpu")
        while True:
            self._calls += 1
            self.counts.assign(np.array([self._n_blocks, 0, 0], np.int32))
            wp_launch(K_.insert_blocks, dim=1, inputs=[cand, cand.shape[0], self.table, self.mask, self.coords,
                                                       self.stamp, self._calls, active, self.counts], device="cpu")
            n_blocks, n_active, stop = (int(x) for x in self.counts.numpy())
            self._n_blocks = n_blocks
            if stop == 0:
                break
            if stop == 2:  # the table would be more than half full: 4x the blocks' slots (a quarter full)
                self._allocate_table(4 * (self.mask + 1) // 2)
                continue
            if self.capacity >= self.max_blocks:
                fail(_name(fn), MapFull,
                     f"the map needs more than {self.max_blocks} blocks of {BLOCK}^3 voxels "
                     f"({self.max_blocks * BYTES_PER_BLOCK / 2**20:.3g} MiB, max_memory_mb) at a voxel size of "
                     f"{self.voxel_size:g} m: use larger voxels"
                     + (" (the most blocks a map can index)" if self.max_blocks == MAX_BLOCKS else
                        " or allow more memory"))
            self._allocate_blocks(min(self.max_blocks, 2 * self.capacity))
        # 3. update every voxel of those blocks
        # (a block's row of 8 voxels as lanes, the same values as voxel by voxel)
        lanes = self._lanes and H * W <= I_.MAX_PIXELS
        launch_chunks(I_.integrate_rows if lanes else K_.integrate, n_active * BLOCK * BLOCK,
                      [active, self.coords, depth_w, image, int(has_colour), W, H, fx, fy, cx, cy, model, dist,
                       wp.mat33(*R_cw.ravel()), wp.vec3(*t_cw), self.voxel_size, self.truncation, self.min_depth,
                       self.max_depth, self.tw, self.colour])
        return IntegrateReport(valid, n_active, self.n_blocks - before, self.n_blocks)

    # ------------------------------------------------------------------------------ raycasting

    def raycast(self, camera, T_world_cam, height: int, width: int, *, start_depth=None,
                normals: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """The model seen by ``camera`` (as :meth:`integrate` takes it) at ``T_world_cam``: (depth
        (H, W) float32 metres, 0 where no surface; colour (3, H, W), trilinear between the voxels around
        the surface point that hold a colour (black if none does); normals (3, H, W) unit, camera
        frame, facing the camera, zero where unknown or at a depth edge; None with
        ``normals=False``), the first crossing of each pixel's ray from positive to negative TSDF
        within [min_depth, max_depth]; the normals from the rendered depth's neighbours (as
        KinectFusion's normal map).

        ``start_depth`` (H, W) or (1, H, W) metres, optional: where the surface is expected, e.g. the
        depth of the frame just integrated at this pose (frame-to-model tracking raycasts there). Each
        pixel's ray with a value that is positive and finite (0, NaN, negative, inf: no start) starts
        twice the truncation before it instead of at the nearest block: the crossing found is the
        first one from there (a surface of the model further in front along the ray, which that
        frame saw as free space, is passed over). If that ray reads a negative value with no
        positive one just before it (the start was behind the surface, or in a band stretched along
        a grazing ray), it marches again from the nearest block, as without a start. About half the
        march's steps.

        ``normals=False``: no normals (None in their place; frame-to-model tracking does not use them)."""
        fn = "raycast"
        if not (isinstance(height, int) and isinstance(width, int) and height >= 2 and width >= 2):
            fail(_name(fn), ValueError, f"arguments 'height' and 'width' must be integers >= 2, got {height!r}, "
                                        f"{width!r}")
        if not isinstance(normals, (bool, np.bool_)):
            fail(_name(fn), TypeError, f"argument 'normals' must be True or False, got {normals!r}")
        if start_depth is None:
            start = wp.empty(0, dtype=wp.float32, device="cpu")
        else:
            sd = as_numpy(_name(fn), "start_depth", start_depth, (2, 3))
            if sd.shape not in ((height, width), (1, height, width)):
                fail(_name(fn), ValueError, f"argument 'start_depth' must be ({height}, {width}) or (1, {height}, "
                                            f"{width}) like the raycast, got {sd.shape}")
            start = wp.array(np.ascontiguousarray(sd, np.float32).reshape(-1), dtype=wp.float32, device="cpu")
        T = self._pose(fn, T_world_cam)
        fx, fy, cx, cy, model, _, rays, _ = self._camera(fn, camera, height, width)
        n = height * width
        depth = wp.empty(n, dtype=wp.float32, device="cpu")
        colour = wp.empty(3 * n, dtype=wp.float32, device="cpu")
        R_wc, t_wc = T[:3, :3], T[:3, 3]
        R_cw, t_cw = wp.mat33(*R_wc.T.ravel()), wp.vec3(*(-R_wc.T @ t_wc))
        # the z range of the blocks over each tile of 8 x 8 (ideal) pixels: where each ray starts and stops
        margin = 0 if model == 0 else max(width, height) // _TILE  # (a lens's ideal pixels reach beyond the image)
        tiles_x, tiles_y = -(-width // _TILE) + 2 * margin, -(-height // _TILE) + 2 * margin
        n_tiles = tiles_x * tiles_y
        parts = max(1, min(get_num_threads(), self._n_blocks // _BLOCKS_PER_PART))  # (the threads share the blocks)
        near = wp.full(parts * n_tiles, 1.0e30, dtype=wp.float32, device="cpu")
        far = wp.zeros(parts * n_tiles, dtype=wp.float32, device="cpu")
        launch_chunks(R_.depth_range, parts, [self.coords, self._n_blocks, parts, R_cw, t_cw, fx, fy, cx, cy,
                                              self.voxel_size * BLOCK, self.min_depth, _TILE, margin, tiles_x,
                                              tiles_y, near, far], chunks_per_thread=1, grain=1)
        if parts > 1:
            launch_chunks(R_.merge_ranges, n_tiles, [parts, n_tiles, near, far])
        n_tiled = 64 * (-(-width // 8)) * (-(-height // 8))  # (the kernels run over 8 x 8 tiles of pixels)
        pose = [wp.mat33(*R_wc.ravel()), wp.vec3(*t_wc)]
        rest = [self.voxel_size, self.truncation, self.min_depth, self.max_depth, fx, fy, cx, cy, _TILE, margin,
                tiles_x, tiles_y, near, far, height, start, 2.0 * self.truncation, depth, colour]
        if self._lanes:  # (a tile's row of 8 rays at a time: the same values)
            launch_chunks(RL_.raycast_rows, n_tiled // 8, [self.table, self.mask, self.tw, self.colour, rays,
                                                           *pose, *rest], grain=256)  # (8 rays an element)
        else:
            launch_chunks(R_.raycast, n_tiled, [self.table, self.mask, self.tw, self.colour, rays, *pose, R_cw,
                                                *rest])
        normal = None
        if normals:
            normal = wp.empty(3 * n, dtype=wp.float32, device="cpu")
            launch_chunks(R_.depth_normals, n, [depth, rays, width, height, _NORMAL_JUMP, normal])
            normal = normal.numpy().reshape(3, height, width)
        return depth.numpy().reshape(height, width), colour.numpy().reshape(3, height, width), normal

    # ------------------------------------------------------------------------------ surfaces

    def _surface(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Marching cubes over every allocated block: (every edge crossing (N, 3), faces (M, 3),
        colours (N, 3)); some crossings are in no face (a neighbouring voxel is unobserved)."""
        n = self.n_blocks * BLOCK_VOXELS
        if n == 0:
            return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), np.zeros((0, 3), np.float32)
        mc_range, mc_tri = self._mc_tables
        nv = wp.empty(n, dtype=wp.int32, device="cpu")
        nt = wp.empty(n, dtype=wp.int32, device="cpu")
        table = [self.table, self.mask, self.coords, self.tw]
        launch_chunks(marching.mesh_count, n, [*table, mc_range, nv, nt])
        counts_v, counts_t = nv.numpy(), nt.numpy()
        first_v = np.concatenate([[0], np.cumsum(counts_v, dtype=np.int64)[:-1]]).astype(np.int32)
        first_t = np.concatenate([[0], np.cumsum(counts_t, dtype=np.int64)[:-1]]).astype(np.int32)
        total_v, total_t = int(counts_v.sum()), int(counts_t.sum())
        points = wp.empty(max(total_v, 1), dtype=wp.vec3, device="cpu")
        colours = wp.empty(max(total_v, 1), dtype=wp.vec3, device="cpu")
        edge_vertex = wp.empty(3 * n, dtype=wp.int32, device="cpu")
        launch_chunks(marching.mesh_vertices, n, [*table, self.colour, self.voxel_size,
                                        wp.array(first_v, dtype=wp.int32, device="cpu"), edge_vertex, points, colours])
        faces = wp.empty(max(total_t, 1), dtype=wp.vec3i, device="cpu")
        launch_chunks(marching.mesh_faces, n, [*table, mc_range, mc_tri,
                                               wp.array(first_t, dtype=wp.int32, device="cpu"), edge_vertex, faces])
        return points.numpy()[:total_v], faces.numpy()[:total_t].astype(np.int32), colours.numpy()[:total_v]

    def extract_mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Marching cubes over every allocated block: (vertices (N, 3) float32 world metres, faces
        (M, 3) int32 vertex indices, counter-clockwise seen from the free space, colours (N, 3) in
        [0, 1]). A vertex lies on an edge between two observed voxels of opposite sign whose values
        are not truncated, and is shared by the faces around it; a face needs its cell's eight
        voxels observed. Every vertex is in a face. A volume that no frame put depth in gives empty
        arrays and a warning (each :meth:`integrate` says so in its report: ``valid_pixels`` 0)."""
        if self.n_blocks == 0:
            why = ("no frame has been integrated" if self._frames == 0 else
                   f"none of the {self._frames} frames integrated has depth within [{self.min_depth:g}, "
                   f"{self.max_depth:g}] (the volume's units, metres for a sensor: depths in millimetres?)")
            warnings.warn(f"{_name('extract_mesh')}: {EMPTY_VOLUME} ({why}): the mesh is empty", UserWarning,
                          stacklevel=2)
        points, faces, colours = self._surface()
        used = np.zeros(points.shape[0], bool)
        used[faces.reshape(-1)] = True
        new_index = np.cumsum(used, dtype=np.int64) - 1
        return points[used], new_index[faces].astype(np.int32), colours[used]

    def extract_points(self) -> tuple[np.ndarray, np.ndarray]:
        """The surface as points: every zero crossing of the TSDF between two observed, untruncated
        neighbouring voxels (the mesh's vertices, and crossings at its borders that no face uses),
        (N, 3) world metres, and their colours (N, 3)."""
        points, _, colours = self._surface()
        return points, colours
