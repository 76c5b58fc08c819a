"""``@wp.func`` library of the voxel-block hash table and voxel lookups (no launches).

The table has a power-of-two number of slots, each a vec4i ``(x, y, z, index)``: a block's integer
coordinates and its index in the voxel arrays (-1: the slot is empty; one cache line holds both),
probed linearly from the hash of the coordinates. Blocks are only
ever added (never removed), so a lookup may stop at the first empty slot. A voxel is read through
its block: the voxel arrays hold ``BLOCK ** 3`` voxels
per block index, x fastest: ``tw`` (vec2: the TSDF and its weight, read together) and ``colour``
(vec4: RGB and its own weight, the updates inside the truncation band).
"""

import warp as wp

from ..core.kinds import vec8i

BLOCK = 8  # voxels per block side
BLOCK_VOXELS = BLOCK * BLOCK * BLOCK
SHIFT = 3  # log2(BLOCK)
MAX_PROBES = 1 << 20  # a lookup gives up after this many slots (a table is never more than half full)
SENTINEL = wp.constant(-(2**31))  # a block coordinate no block has: an unused candidate slot, no block yet


# MurmurHash3's finaliser constants 0x85EBCA6B and 0xC2B2AE35, written as the int32 of the same bits: Warp
# declares an integer literal as int32, and one above 2**31 made clang warn of the conversion at every
# compile of a module that hashes blocks
_FMIX1 = wp.constant(0x85EBCA6B - 2**32)
_FMIX2 = wp.constant(0xC2B2AE35 - 2**32)


@wp.func
def block_hash(b: wp.vec3i, mask: int):
    """Slot where the search for block ``b`` starts: three large primes, xor-ed (Teschner et al. 2003),
    then MurmurHash3's 32-bit finaliser, which spreads the low bits a power-of-two table keeps (walls
    of blocks otherwise cluster: 4-5 probes on average, 60+ at worst)."""
    h = (wp.uint32(b[0]) * wp.uint32(73856093)) ^ (wp.uint32(b[1]) * wp.uint32(19349669)) ^ (
        wp.uint32(b[2]) * wp.uint32(83492791))
    h = h ^ (h >> wp.uint32(16))
    h = h * wp.uint32(_FMIX1)
    h = h ^ (h >> wp.uint32(13))
    h = h * wp.uint32(_FMIX2)
    h = h ^ (h >> wp.uint32(16))
    return wp.int32(h & wp.uint32(mask))


@wp.func
def same(a: wp.vec3i, b: wp.vec3i):
    """a == b (component-wise; Warp has no != on vectors)."""
    return a[0] == b[0] and a[1] == b[1] and a[2] == b[2]


@wp.func
def find_block(table: wp.array(dtype=wp.vec4i), mask: int, b: wp.vec3i):
    """Index of block ``b``, -1 if it is not allocated."""
    h = block_hash(b, mask)
    found = int(-1)
    for _probe in range(MAX_PROBES):
        e = table[h]
        if e[3] < 0:
            break
        if e[0] == b[0] and e[1] == b[1] and e[2] == b[2]:
            found = e[3]
            break
        h = (h + 1) & mask
    return found


@wp.func
def voxel_block(i: wp.vec3i):
    """The block of voxel ``i`` (floor division by BLOCK: an arithmetic shift, right for negatives)."""
    return wp.vec3i(i[0] >> SHIFT, i[1] >> SHIFT, i[2] >> SHIFT)


@wp.func
def voxel_offset(i: wp.vec3i):
    """Index of voxel ``i`` inside its block (x fastest)."""
    lx = i[0] - ((i[0] >> SHIFT) << SHIFT)
    ly = i[1] - ((i[1] >> SHIFT) << SHIFT)
    lz = i[2] - ((i[2] >> SHIFT) << SHIFT)
    return lx + BLOCK * (ly + BLOCK * lz)


@wp.func
def find_voxel(table: wp.array(dtype=wp.vec4i), mask: int, i: wp.vec3i):
    """Index of voxel ``i`` in the voxel arrays, -1 if its block is not allocated."""
    blk = find_block(table, mask, voxel_block(i))
    out = int(-1)
    if blk >= 0:
        out = blk * BLOCK_VOXELS + voxel_offset(i)
    return out


@wp.func
def voxel_of_point(p: wp.vec3, inv_voxel: float):
    """The voxel whose centre is nearest to world point ``p``."""
    return wp.vec3i(int(wp.floor(p[0] * inv_voxel + 0.5)), int(wp.floor(p[1] * inv_voxel + 0.5)),
                    int(wp.floor(p[2] * inv_voxel + 0.5)))


@wp.func
def corner_voxels(table: wp.array(dtype=wp.vec4i), mask: int, i0: wp.vec3i):
    """Indices in the voxel arrays of the 8 voxels ``i0 + (c & 1, (c >> 1) & 1, (c >> 2) & 1)``, corner
    ``c`` in lane ``c`` (-1 where the block is not allocated). One block lookup per distinct block of
    the 8: one about 2 times in 3, two, four or eight at a block's edge (a lookup per voxel there made
    the raycast 3-7% slower)."""
    b0 = voxel_block(i0)
    lx = i0[0] - (b0[0] << SHIFT)
    ly = i0[1] - (b0[1] << SHIFT)
    lz = i0[2] - (b0[2] << SHIFT)
    # the axes on which the 8 voxels reach into the next block: corner c's block is corner (c & reach)'s,
    # found first (its bits are a subset of c's)
    reach = wp.where(lx == BLOCK - 1, 1, 0) + wp.where(ly == BLOCK - 1, 2, 0) + wp.where(lz == BLOCK - 1, 4, 0)
    blocks = vec8i(-1)
    out = vec8i(-1)
    for c in range(8):
        dx = c & 1
        dy = (c >> 1) & 1
        dz = (c >> 2) & 1
        cb = c & reach
        blk = int(-1)
        if cb == c:
            blk = find_block(table, mask, b0 + wp.vec3i(dx, dy, dz))
            blocks[c] = blk
        else:
            blk = blocks[cb]
        if blk >= 0:
            out[c] = blk * BLOCK_VOXELS + ((lx + dx) & (BLOCK - 1)) + BLOCK * (((ly + dy) & (BLOCK - 1))
                                                                         + BLOCK * ((lz + dz) & (BLOCK - 1)))
    return out


@wp.func
def voxel_cell(p: wp.vec3, inv_voxel: float):
    """(the voxel whose cell of 8 voxels (it and the next ones on each axis) holds world point ``p``,
    ``p``'s position in that cell, each coordinate in [0, 1] (1 only by rounding))."""
    g = p * inv_voxel
    f0 = wp.vec3(wp.floor(g[0]), wp.floor(g[1]), wp.floor(g[2]))
    return wp.vec3i(int(f0[0]), int(f0[1]), int(f0[2])), g - f0


@wp.func
def trilinear_grad_of(tw: wp.array(dtype=wp.vec2), kk: vec8i, t: wp.vec3, inv_voxel: float):
    """:func:`trilinear_grad` from the cell's voxels (:func:`corner_voxels`) and the position in it."""
    value = float(0.0)
    grad = wp.vec3(0.0)
    ok = bool(True)
    for c in range(8):
        dx = c & 1
        dy = (c >> 1) & 1
        dz = (c >> 2) & 1
        k = kk[c]
        w = float(0.0)
        if k >= 0:
            w = tw[k][1]
        if w <= 0.0:
            ok = False
        else:
            v = tw[k][0]
            wx = wp.where(dx == 1, t[0], 1.0 - t[0])
            wy = wp.where(dy == 1, t[1], 1.0 - t[1])
            wz = wp.where(dz == 1, t[2], 1.0 - t[2])
            sx = wp.where(dx == 1, 1.0, -1.0)
            sy = wp.where(dy == 1, 1.0, -1.0)
            sz = wp.where(dz == 1, 1.0, -1.0)
            value += wx * wy * wz * v
            grad += v * wp.vec3(sx * wy * wz, wx * sy * wz, wx * wy * sz)
    return value, grad * inv_voxel, ok


@wp.func
def trilinear_grad(table: wp.array(dtype=wp.vec4i), mask: int, tw: wp.array(dtype=wp.vec2), p: wp.vec3,
                   inv_voxel: float):
    """Trilinear TSDF at world point ``p`` from the 8 voxels around it and its gradient: (value, d value
    / d p (per metre; the gradient of the trilinear interpolant, exact where the TSDF is linear),
    ok); ``ok`` is False if one of them is unobserved (no block, or weight 0)."""
    i0, t = voxel_cell(p, inv_voxel)
    return trilinear_grad_of(tw, corner_voxels(table, mask, i0), t, inv_voxel)


@wp.func
def trilinear_colour_of(colour: wp.array(dtype=wp.vec4), kk: vec8i, t: wp.vec3):
    """:func:`trilinear_colour` from the cell's voxels (:func:`corner_voxels`) and the position in it."""
    rgb = wp.vec3(0.0)
    total = float(0.0)
    for c in range(8):
        k = kk[c]
        if k >= 0:
            cc = colour[k]
            if cc[3] > 0.0:
                wx = wp.where((c & 1) == 1, t[0], 1.0 - t[0])
                wy = wp.where(((c >> 1) & 1) == 1, t[1], 1.0 - t[1])
                wz = wp.where(((c >> 2) & 1) == 1, t[2], 1.0 - t[2])
                r = wx * wy * wz
                rgb += r * wp.vec3(cc[0], cc[1], cc[2])
                total += r
    if total > 0.0:
        rgb = rgb / total
    return rgb


@wp.func
def trilinear_colour(table: wp.array(dtype=wp.vec4i), mask: int, colour: wp.array(dtype=wp.vec4), p: wp.vec3,
                     inv_voxel: float):
    """Colour at world point ``p``: the trilinear weights of the 8 voxels around it, over those that
    hold a colour (colour weight > 0), renormalised; black if none does (or, at a point exactly on
    a voxel without colour, none of those with a weight above 0)."""
    i0, t = voxel_cell(p, inv_voxel)
    return trilinear_colour_of(colour, corner_voxels(table, mask, i0), t)


@wp.func
def trilinear(table: wp.array(dtype=wp.vec4i), mask: int, tw: wp.array(dtype=wp.vec2), p: wp.vec3,
              inv_voxel: float):
    """:func:`trilinear_grad`'s (value, ok), without the gradient."""
    value, _grad, ok = trilinear_grad(table, mask, tw, p, inv_voxel)
    return value, ok


@wp.func
def neighbour(table: wp.array(dtype=wp.vec4i), mask: int, blk: int, i: wp.vec3i,
              step: wp.vec3i):
    """Index of voxel ``i + step`` (a unit step) given ``blk``, the block index of ``i``: no lookup
    unless the step leaves the block."""
    j = i + step
    out = int(-1)
    if blk >= 0 and hashing_same_block(i, j):
        out = blk * BLOCK_VOXELS + voxel_offset(j)
    else:
        out = find_voxel(table, mask, j)
    return out


@wp.func
def hashing_same_block(i: wp.vec3i, j: wp.vec3i):
    """Voxels ``i`` and ``j`` lie in the same block."""
    return same(voxel_block(i), voxel_block(j))
