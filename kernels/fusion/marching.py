"""Marching cubes over the TSDF's blocks (see :mod:`gvnn_warp.kernels.fusion`): three passes over
every voxel - count the vertices on its edges and the triangles of its cell, write the vertices,
write the triangles - each launched in chunks by the host (``TSDFVolume.extract_mesh``; every
element writes only its own outputs). A vertex lies on the edge from a voxel to its neighbour along
+x, +y or +z (owned by that voxel, so the faces around it share it) where both are usable (observed,
not truncated) and of opposite signs; a cell makes triangles where its eight corners are usable.
"""

import warp as wp
from warp._src.geometry.marching_cubes import MC_CASE_TO_TRI_RANGE, MC_TRI_LOCAL_INDICES

from .hashing import BLOCK, BLOCK_VOXELS, find_voxel

wp.set_module_options({"enable_backward": False})  # (no gradients here: half the compile time)

FULL = wp.constant(0.999)  # |tsdf| at or above this is truncated: no surface between such voxels

# The marching cubes tables (Warp ships them, ``warp.geometry``'s marching cubes; bit c of a case is
# corner CORNER[c], set where the TSDF is >= 0): the triangles of case c are the edges
# tri[range[c]:range[c + 1]], three per triangle (``MC_RANGE``, ``MC_TRI``: passed to the kernels as
# arrays); edge e joins the voxel at EDGE_CELL[e] from the cell origin to its neighbour along axis
# EDGE_AXIS[e].
MC_RANGE = MC_CASE_TO_TRI_RANGE
MC_TRI = MC_TRI_LOCAL_INDICES
_EDGES = ((0, 0, 0, 0), (1, 0, 0, 1), (0, 1, 0, 0), (0, 0, 0, 1), (0, 0, 1, 0), (1, 0, 1, 1), (0, 1, 1, 0),
          (0, 0, 1, 1), (0, 0, 0, 2), (1, 0, 0, 2), (1, 1, 0, 2), (0, 1, 0, 2))
EDGE_CELL = wp.constant(wp.types.matrix((12, 3), wp.int32)(*[v for e in _EDGES for v in e[:3]]))
EDGE_AXIS = wp.constant(wp.types.vector(12, wp.int32)(*[e[3] for e in _EDGES]))
CORNER = wp.constant(wp.types.matrix((8, 3), wp.int32)(0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0,
                                                      0, 0, 1, 1, 0, 1, 1, 1, 1, 0, 1, 1))


@wp.func
def corner_value(table: wp.array(dtype=wp.vec4i), mask: int, blk: int,
                 b: wp.vec3i, local: wp.vec3i, tw: wp.array(dtype=wp.vec2)):
    """(index, usable) of the voxel at ``local`` (0..BLOCK on each axis) from block ``b`` (index
    ``blk``): its own block's unless it crosses into a neighbour; usable: observed and not truncated."""
    k = int(-1)
    if local[0] < BLOCK and local[1] < BLOCK and local[2] < BLOCK:
        k = blk * BLOCK_VOXELS + local[0] + BLOCK * (local[1] + BLOCK * local[2])
    else:
        k = find_voxel(table, mask, b * BLOCK + local)
    ok = bool(False)
    if k >= 0:
        ok = tw[k][1] > 0.0 and wp.abs(tw[k][0]) < FULL
    return k, ok


@wp.func
def voxel_of_element(coords: wp.array(dtype=wp.vec3i), e: int):
    """(block index, block coordinates, voxel inside the block (x fastest)) of voxel element ``e``."""
    blk = e // BLOCK_VOXELS
    local = e - blk * BLOCK_VOXELS
    return blk, coords[blk], wp.vec3i(local % BLOCK, (local // BLOCK) % BLOCK, local // (BLOCK * BLOCK))


@wp.func
def edge_crossing(table: wp.array(dtype=wp.vec4i), mask: int, blk: int, b: wp.vec3i, li: wp.vec3i, a: int,
                  tw: wp.array(dtype=wp.vec2)):
    """(index of the neighbour along axis ``a``, whether the edge from voxel ``li`` to it holds a
    vertex): both ends usable and of opposite signs (``li`` itself must be usable)."""
    step = wp.vec3i(0, 0, 0)
    step[a] = 1
    k1, ok1 = corner_value(table, mask, blk, b, li + step, tw)
    k0 = blk * BLOCK_VOXELS + li[0] + BLOCK * (li[1] + BLOCK * li[2])
    crossing = bool(False)
    if ok1:
        crossing = (tw[k0][0] >= 0.0) != (tw[k1][0] >= 0.0)
    return k1, crossing


@wp.func
def cell_case(table: wp.array(dtype=wp.vec4i), mask: int, blk: int, b: wp.vec3i, li: wp.vec3i,
              tw: wp.array(dtype=wp.vec2)):
    """(marching-cubes case, usable) of the cell whose origin is voxel ``li`` of block ``b``: bit c
    set where corner CORNER[c] has a TSDF >= 0; usable if all eight corners are (:func:`corner_value`)."""
    case = int(0)
    usable = bool(True)
    for c in range(8):
        corner = wp.vec3i(CORNER[c, 0], CORNER[c, 1], CORNER[c, 2])
        kc, okc = corner_value(table, mask, blk, b, li + corner, tw)
        if not okc:
            usable = False
        elif tw[kc][0] >= 0.0:
            case = case | (1 << c)
    return case, usable


@wp.kernel
def mesh_count(offset: int, table: wp.array(dtype=wp.vec4i), mask: int,
               coords: wp.array(dtype=wp.vec3i), tw: wp.array(dtype=wp.vec2), mc_range: wp.array(dtype=wp.int32),
               vertices: wp.array(dtype=wp.int32), triangles: wp.array(dtype=wp.int32)):
    """Marching cubes, first pass, per voxel: the vertices on its three edges towards +x, +y, +z
    (both ends usable, signs differ) and the triangles of the cell it is the origin of (all eight
    corners usable)."""
    e = offset + wp.tid()
    blk, b, li = voxel_of_element(coords, e)
    k0, ok0 = corner_value(table, mask, blk, b, li, tw)
    nv = int(0)
    if ok0:
        for a in range(3):
            _k1, crossing = edge_crossing(table, mask, blk, b, li, a, tw)
            if crossing:
                nv += 1
    vertices[e] = nv
    case, usable = cell_case(table, mask, blk, b, li, tw)
    nt = int(0)
    if usable:
        nt = (mc_range[case + 1] - mc_range[case]) // 3
    triangles[e] = nt


@wp.kernel
def mesh_vertices(offset: int, table: wp.array(dtype=wp.vec4i), mask: int,
                  coords: wp.array(dtype=wp.vec3i), tw: wp.array(dtype=wp.vec2), colour: wp.array(dtype=wp.vec4),
                  voxel: float, first: wp.array(dtype=wp.int32), edge_vertex: wp.array(dtype=wp.int32),
                  points: wp.array(dtype=wp.vec3), point_colours: wp.array(dtype=wp.vec3)):
    """Second pass, per voxel: its edges' vertices (where the linear interpolation of the TSDF is
    zero; colour interpolated alike) from index ``first[e]`` on, and their indices in ``edge_vertex``
    (3 per voxel, -1 where none)."""
    e = offset + wp.tid()
    blk, b, li = voxel_of_element(coords, e)
    k0, ok0 = corner_value(table, mask, blk, b, li, tw)
    n = first[e]
    gi = b * BLOCK + li
    for a in range(3):
        edge_vertex[3 * e + a] = -1
        if ok0:
            k1, crossing = edge_crossing(table, mask, blk, b, li, a, tw)
            if crossing:
                f0 = tw[k0][0]
                s = f0 / (f0 - tw[k1][0])
                pos = voxel * wp.vec3(float(gi[0]), float(gi[1]), float(gi[2]))
                pos[a] = pos[a] + s * voxel
                points[n] = pos
                c0 = colour[k0]
                c1 = colour[k1]
                point_colours[n] = (1.0 - s) * wp.vec3(c0[0], c0[1], c0[2]) + s * wp.vec3(c1[0], c1[1], c1[2])
                edge_vertex[3 * e + a] = n
                n += 1


@wp.kernel
def mesh_faces(offset: int, table: wp.array(dtype=wp.vec4i), mask: int,
               coords: wp.array(dtype=wp.vec3i), tw: wp.array(dtype=wp.vec2), mc_range: wp.array(dtype=wp.int32),
               mc_tri: wp.array(dtype=wp.int32), first: wp.array(dtype=wp.int32),
               edge_vertex: wp.array(dtype=wp.int32), faces: wp.array(dtype=wp.vec3i)):
    """Third pass, per voxel: the triangles of its cell from index ``first[e]`` on, each corner the
    vertex of the edge it lies on (owned by the edge's lower voxel, maybe in another block)."""
    e = offset + wp.tid()
    blk, b, li = voxel_of_element(coords, e)
    case, usable = cell_case(table, mask, blk, b, li, tw)
    if not usable:
        return
    start = mc_range[case]
    nt = (mc_range[case + 1] - start) // 3
    n = first[e]
    for t in range(nt):
        tri = wp.vec3i(0, 0, 0)
        for s in range(3):
            edge = mc_tri[start + 3 * t + s]
            owner = li + wp.vec3i(EDGE_CELL[edge, 0], EDGE_CELL[edge, 1], EDGE_CELL[edge, 2])
            ko = int(-1)
            if owner[0] < BLOCK and owner[1] < BLOCK and owner[2] < BLOCK:
                ko = blk * BLOCK_VOXELS + owner[0] + BLOCK * (owner[1] + BLOCK * owner[2])
            else:
                ko = find_voxel(table, mask, b * BLOCK + owner)
            tri[s] = edge_vertex[3 * ko + EDGE_AXIS[edge]]
        faces[n + t] = tri


__all__ = ["MC_RANGE", "MC_TRI", "mesh_count", "mesh_faces", "mesh_vertices"]
