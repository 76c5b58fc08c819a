"""The TSDF raycast, the 8 rays of a tile's row marched together as 8 lanes (a thin kernel and its
``@wp.func`` s; the host is ``gvnn_warp.fusion.TSDFVolume.raycast``).

:func:`.raycasting.raycast` marches one ray at a time: each step is a chain of tests (a block, an
observed voxel, a negative value) that LLVM compiles as branches. Here a thread marches the 8
neighbouring rays of a row of an 8 x 8 tile in lockstep: positions, voxels, blocks and steps are
length-8 vectors (``kernels.core.lanes``), the tests 0/1 masks; only the block lookups (one per
distinct block the row enters: neighbouring rays mostly enter the same) and the voxel reads are
lane by lane. A lane that has stopped waits for the others. Each ray's start
(:func:`.raycasting.ray_range`) and its crossing's refinement (:func:`.raycasting.refine_hit`) are
the scalar kernel's own functions, and every step the same operations, so the outputs are the
scalar kernel's bit for bit (both built with the same compiler flags but the vectoriser's
depth; the tests check it). Block indices ride in float32 lanes, voxel indices in int32 ones,
exact for any map the host allows (fewer than 2^22 blocks).
"""

import warp as wp

from ..core.kinds import LANES_MODULE_OPTIONS, vec8f, vec8i
from ..core.lanes import above8, any8, at_least8, less8, select8, splat8
from ..sampling.lanes import floor_lanes
from .hashing import BLOCK, BLOCK_VOXELS, SENTINEL, find_block
from .raycasting import hit_colour, ray_range, ray_steps, refine_hit, set_pixel

mat83i = wp.types.matrix(shape=(8, 3), dtype=wp.int32)  # a row of 8 lanes' vec3i / vec8i
mat88i = wp.types.matrix(shape=(8, 8), dtype=wp.int32)


@wp.func
def exit_axis(p: vec8f, d: vec8f, inv_d: vec8f, b: vec8f, t: vec8f, voxel: float, block_len: float):
    """One axis of :func:`.raycasting.block_exit` on 8 lanes: min(t, the ray parameter from ``p`` to
    the side of block ``b``'s space it moves towards) (``t`` where the ray does not move on this axis)."""
    lo = b * block_len - splat8(0.5 * voxel)
    towards_hi = wp.cw_mul(lo + splat8(block_len) - p, inv_d)
    towards_lo = wp.cw_mul(lo - p, inv_d)
    out = select8(above8(d, 0.0), wp.min(t, towards_hi), t)
    return select8(above8(-d, 0.0), wp.min(t, towards_lo), out)


@wp.func
def equal8(a: vec8f, b: vec8f):
    """1 where a == b, else 0, per lane."""
    one = float(1.0)
    zero = float(0.0)
    return vec8f(
        wp.where(a[0] == b[0], one, zero), wp.where(a[1] == b[1], one, zero), wp.where(a[2] == b[2], one, zero),
        wp.where(a[3] == b[3], one, zero), wp.where(a[4] == b[4], one, zero), wp.where(a[5] == b[5], one, zero),
        wp.where(a[6] == b[6], one, zero), wp.where(a[7] == b[7], one, zero),
    )


@wp.func
def voxel_index8(blk: vec8f, local: vec8f):
    """blk * BLOCK_VOXELS + local as 8 int32 lanes (both non-negative integers)."""
    b = vec8i(int(blk[0]), int(blk[1]), int(blk[2]), int(blk[3]), int(blk[4]), int(blk[5]), int(blk[6]), int(blk[7]))
    o = vec8i(int(local[0]), int(local[1]), int(local[2]), int(local[3]), int(local[4]), int(local[5]),
              int(local[6]), int(local[7]))
    return b * BLOCK_VOXELS + o


@wp.kernel(module="unique", enable_backward=False, module_options=LANES_MODULE_OPTIONS)
def raycast_rows(offset: int, table: wp.array(dtype=wp.vec4i), mask: int,
                 tw: wp.array(dtype=wp.vec2), colour: wp.array(dtype=wp.vec4),
                 rays: wp.array(dtype=wp.vec3), R_wc: wp.mat33, t_wc: wp.vec3, voxel: float, trunc: float,
                 min_depth: float, max_depth: float, fx: float, fy: float, cx: float, cy: float, tile: int,
                 margin: int, tiles_x: int, tiles_y: int, near: wp.array(dtype=wp.float32),
                 far: wp.array(dtype=wp.float32), H: int, start: wp.array(dtype=wp.float32), start_margin: float,
                 out_depth: wp.array(dtype=wp.float32), out_colour: wp.array(dtype=wp.float32)):
    """:func:`.raycasting.raycast` with a row of 8 rays per element (element = tile * 8 + row of the
    8 x 8 tiles of pixels, row by row, as the scalar kernel orders its pixels)."""
    e = offset + wp.tid()
    n_pix = out_depth.shape[0]
    W = n_pix // H
    tiles_w = (W + 7) // 8
    tile_k = e // 8
    px0 = (tile_k % tiles_w) * 8
    py = (tile_k // tiles_w) * 8 + e % 8
    if py >= H:
        return
    lanes = wp.min(8, W - px0)
    zero = splat8(0.0)
    one = splat8(1.0)
    t = zero  # each lane's ray: where it is, its tile's range, whether it started from ``start``
    t_tile = zero
    t_end = zero
    hinted = zero
    active = zero
    dx = zero  # its direction, the reciprocals of its components, a voxel and the band step in t
    dy = zero
    dz = zero
    ix = zero
    iy = zero
    iz = zero
    voxel_t = zero
    band_t = zero
    scale = zero
    for lane in range(lanes):
        k = py * W + px0 + lane
        r = rays[k]
        ok, t0, tt, te, hi = ray_range(r, k, fx, fy, cx, cy, tile, margin, tiles_x, tiles_y, near, far,
                                       min_depth, max_depth, start, start_margin)
        if ok:
            direction, sc, inv_direction, vt, bt = ray_steps(R_wc, r, voxel, trunc)
            t[lane] = t0
            t_tile[lane] = tt
            t_end[lane] = te
            hinted[lane] = wp.where(hi, 1.0, 0.0)
            active[lane] = wp.where(t0 < te, 1.0, 0.0)
            dx[lane] = direction[0]
            dy[lane] = direction[1]
            dz[lane] = direction[2]
            ix[lane] = inv_direction[0]
            iy[lane] = inv_direction[1]
            iz[lane] = inv_direction[2]
            voxel_t[lane] = vt
            band_t[lane] = bt
            scale[lane] = sc
    inv_voxel = 1.0 / voxel
    block_len = voxel * float(BLOCK)
    prev_t = zero
    prev_f = zero
    have_prev = zero
    crossed = zero
    cross_t = zero
    cross_f = zero
    last_x = splat8(float(SENTINEL))  # each lane's block looked up last, and its index
    last_y = zero
    last_z = zero
    blk = splat8(-1.0)
    while any8(active):
        px = splat8(t_wc[0]) + wp.cw_mul(t, dx)
        py_ = splat8(t_wc[1]) + wp.cw_mul(t, dy)
        pz = splat8(t_wc[2]) + wp.cw_mul(t, dz)
        gx = floor_lanes(px * inv_voxel + splat8(0.5))  # the nearest voxel
        gy = floor_lanes(py_ * inv_voxel + splat8(0.5))
        gz = floor_lanes(pz * inv_voxel + splat8(0.5))
        bx = floor_lanes(gx * 0.125)  # its block (BLOCK = 8)
        by = floor_lanes(gy * 0.125)
        bz = floor_lanes(gz * 0.125)
        local = (gx - bx * 8.0) + (gy - by * 8.0) * 8.0 + (gz - bz * 8.0) * 64.0
        changed = wp.cw_mul(active, one - wp.cw_mul(wp.cw_mul(equal8(bx, last_x), equal8(by, last_y)),
                                                     equal8(bz, last_z)))
        if any8(changed):  # (lane by lane; a block looked up once per step)
            seen_x = float(SENTINEL)
            seen_y = float(0.0)
            seen_z = float(0.0)
            seen = float(-1.0)
            for lane in range(8):
                if changed[lane] != 0.0:
                    if bx[lane] != seen_x or by[lane] != seen_y or bz[lane] != seen_z:
                        seen_x = bx[lane]
                        seen_y = by[lane]
                        seen_z = bz[lane]
                        seen = float(find_block(table, mask, wp.vec3i(int(seen_x), int(seen_y), int(seen_z))))
                    blk[lane] = seen
            last_x = select8(changed, bx, last_x)
            last_y = select8(changed, by, last_y)
            last_z = select8(changed, bz, last_z)
        has_block = wp.cw_mul(active, at_least8(blk, 0.0))
        kk = voxel_index8(select8(has_block, blk, zero), local)
        f = vec8f(tw[kk[0]][0], tw[kk[1]][0], tw[kk[2]][0], tw[kk[3]][0], tw[kk[4]][0], tw[kk[5]][0], tw[kk[6]][0],
                  tw[kk[7]][0])
        w = vec8f(tw[kk[0]][1], tw[kk[1]][1], tw[kk[2]][1], tw[kk[3]][1], tw[kk[4]][1], tw[kk[5]][1], tw[kk[6]][1],
                  tw[kk[7]][1])
        no_block = active - has_block
        observed = wp.cw_mul(has_block, above8(w, 0.0))
        unobserved = has_block - observed
        negative = observed - wp.cw_mul(observed, above8(f, 0.0))
        restart = wp.cw_mul(wp.cw_mul(negative, hinted), one - have_prev)
        cross = negative - restart
        forward = observed - negative
        t_next = t
        if any8(no_block):  # (to where the ray leaves the block's space)
            out = splat8(1.0e30)
            out = exit_axis(px, dx, ix, bx, out, voxel, block_len)
            out = exit_axis(py_, dy, iy, by, out, voxel, block_len)
            out = exit_axis(pz, dz, iz, bz, out, voxel, block_len)
            exit_t = wp.max(out, zero)
            t_next = select8(no_block, t + (exit_t + voxel_t * 0.01), t)
        t_next = select8(unobserved, t + voxel_t, t_next)
        t_next = select8(restart, t_tile, t_next)
        t_next = select8(forward, t + wp.max(voxel_t, wp.cw_mul(band_t, f)), t_next)
        crossed = select8(cross, have_prev, crossed)
        cross_t = select8(cross, t, cross_t)
        cross_f = select8(cross, f, cross_f)
        prev_t = select8(forward, t, prev_t)
        prev_f = select8(forward, f, prev_f)
        have_prev = select8(no_block + unobserved, zero, select8(forward, one, have_prev))
        hinted = select8(restart, zero, hinted)
        t = t_next
        active = wp.cw_mul(active - cross, less8(t, t_end))
    hits = zero
    cells = mat83i()  # each lane's refinement's cell of 8 voxels, and their indices
    voxels = mat88i()
    for lane in range(lanes):
        if crossed[lane] != 0.0:
            hit, cell, kk = refine_hit(table, mask, tw, t_wc, wp.vec3(dx[lane], dy[lane], dz[lane]), scale[lane], voxel,
                                       True, prev_t[lane], prev_f[lane], cross_t[lane], cross_f[lane])
            hits[lane] = hit
            cells[lane] = cell
            voxels[lane] = kk
    for lane in range(lanes):  # (the colours read after every lane's refinement: their cache misses overlap)
        if hits[lane] > 0.0:
            q = t_wc + hits[lane] * wp.vec3(dx[lane], dy[lane], dz[lane])
            set_pixel(py * W + px0 + lane, hits[lane],
                      hit_colour(table, mask, colour, q, inv_voxel, cells[lane], voxels[lane]), out_depth, out_colour)
        else:
            set_pixel(py * W + px0 + lane, 0.0, wp.vec3(0.0), out_depth, out_colour)


__all__ = ["raycast_rows"]
