"""The thin kernels of the TSDF's integration (see :mod:`gvnn_warp.kernels.fusion`; the host is
``gvnn_warp.fusion.TSDFVolume``): blocks touched by a depth image, block insertion, integration
(raycasting: :mod:`.raycasting`; marching cubes: :mod:`.marching`).

Every per-element kernel takes a leading ``offset`` (its launch covers elements ``offset + tid``),
so the host can cut a launch into chunks over threads; each element writes only its own outputs
(blocks of voxels are disjoint), so any split gives the same result. :func:`insert_blocks` is the
one serial kernel (it owns the hash table while it runs).

Images are flat (H * W) arrays, colour as three planes (3 * H * W); a camera is ``rays`` (H * W
vec3 ``(xn, yn, w)``: the pixel's ideal normalized coordinates, ``w`` 0 where it has none) for
going from pixels to 3D, and ``(fx, fy, cx, cy, model, dist)`` for projecting (a lens model of
:mod:`gvnn_warp.kernels.geometry.lens`, ``model`` 0 the pinhole).
"""

import warp as wp

from ..core.kinds import vec8d
from ..geometry.lens import dispatch
from . import hashing
from .hashing import BLOCK, BLOCK_VOXELS, SENTINEL

wp.set_module_options({"enable_backward": False})  # (no gradients here: half the compile time)

@wp.func
def project(p: wp.vec3, fx: float, fy: float, cx: float, cy: float, model: int, dist: vec8d):
    """Pixel (u, v) of camera point ``p`` (z > 0) through the lens, and whether it is in the lens's domain."""
    x = wp.float64(p[0] / p[2])
    y = wp.float64(p[1] / p[2])
    ok = dispatch.in_domain64(model, dist, x, y)
    xd, yd = dispatch.distort_value64(model, dist, x, y)
    return fx * float(xd) + cx, fy * float(yd) + cy, ok


@wp.func
def depth_bilinear(depth: wp.array(dtype=wp.float32), u: float, v: float, W: int, H: int, nearest: float,
                   min_depth: float, max_depth: float):
    """The depth at (u, v), bilinear between the 4 pixels around it when all are valid and within 5%
    of ``nearest`` (the nearest pixel's: the same surface), else ``nearest`` (no depth is mixed
    across an edge). On a slanted surface the nearest pixel's depth is off by up to half a pixel
    times the slope, which is what makes a TSDF built from nearest depths a staircase."""
    x0 = int(wp.floor(u))
    y0 = int(wp.floor(v))
    out = nearest
    if x0 >= 0 and y0 >= 0 and x0 + 1 < W and y0 + 1 < H:
        a = depth[y0 * W + x0]
        b = depth[y0 * W + x0 + 1]
        c = depth[(y0 + 1) * W + x0]
        d = depth[(y0 + 1) * W + x0 + 1]
        lo = wp.min(wp.min(a, b), wp.min(c, d))
        hi = wp.max(wp.max(a, b), wp.max(c, d))
        # (each one tested: min and max drop a NaN)
        valid = a > min_depth and b > min_depth and c > min_depth and d > min_depth and a < max_depth and (
            b < max_depth and c < max_depth and d < max_depth)
        if valid and hi - lo < 0.05 * nearest:
            fx = u - float(x0)
            fy = v - float(y0)
            out = (1.0 - fy) * ((1.0 - fx) * a + fx * b) + fy * ((1.0 - fx) * c + fx * d)
    return out


@wp.kernel
def touched_blocks(offset: int, depth: wp.array(dtype=wp.float32), rays: wp.array(dtype=wp.vec3),
                   R_wc: wp.mat33, t_wc: wp.vec3, W: int, stride: int, trunc: float, inv_block_len: float,
                   min_depth: float, max_depth: float, samples: int, out: wp.array(dtype=wp.vec3i)):
    """Blocks that the truncation band [d - trunc, d + trunc] of a sampled pixel's depth passes
    through (``samples`` points along it; consecutive repeats written once, the rest SENTINEL)."""
    e = offset + wp.tid()
    sw = (W + stride - 1) // stride
    px = (e % sw) * stride
    py = (e // sw) * stride
    k = py * W + px
    d = depth[k]
    r = rays[k]
    base = e * samples
    n = int(0)
    if d > min_depth and d < max_depth and r[2] > 0.0:
        direction = R_wc * wp.vec3(r[0], r[1], 1.0)
        prev = wp.vec3i(SENTINEL, 0, 0)
        for s in range(samples):
            z = d - trunc + 2.0 * trunc * float(s) / float(samples - 1)
            p = t_wc + z * direction
            b = wp.vec3i(int(wp.floor(p[0] * inv_block_len)), int(wp.floor(p[1] * inv_block_len)),
                         int(wp.floor(p[2] * inv_block_len)))
            if not hashing.same(b, prev):
                out[base + n] = b
                n += 1
                prev = b
    for s in range(n, samples):
        out[base + s] = wp.vec3i(SENTINEL, 0, 0)


@wp.kernel
def insert_blocks(candidates: wp.array(dtype=wp.vec3i), n_candidates: int, table: wp.array(dtype=wp.vec4i),
                  mask: int, coords: wp.array(dtype=wp.vec3i), stamp: wp.array(dtype=wp.int32), call: int,
                  active: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32)):
    """One thread: find or add every candidate block; list each block met in this call once in
    ``active``. ``counts``: [blocks, active, stop], stop 1 if a block did not fit in ``coords``, 2
    if the table would be more than half full (the host grows what is full and calls again: the
    blocks found are listed again under the next ``call``)."""
    n_blocks = counts[0]
    n_active = int(0)
    capacity = coords.shape[0]
    room = (mask + 1) // 2
    for i in range(n_candidates):
        b = candidates[i]
        if b[0] == SENTINEL:
            continue
        h = hashing.block_hash(b, mask)
        idx = int(-1)
        searching = bool(True)
        while searching:
            e = table[h]
            if e[3] < 0:
                if n_blocks >= capacity:
                    counts[2] = 1
                elif n_blocks >= room:
                    counts[2] = 2
                else:
                    table[h] = wp.vec4i(b[0], b[1], b[2], n_blocks)
                    coords[n_blocks] = b
                    idx = n_blocks
                    n_blocks += 1
                searching = False
            elif e[0] == b[0] and e[1] == b[1] and e[2] == b[2]:
                idx = e[3]
                searching = False
            else:
                h = (h + 1) & mask
        if idx >= 0:
            if stamp[idx] != call:
                stamp[idx] = call
                active[n_active] = idx
                n_active += 1
        if counts[2] != 0:
            break
    counts[0] = n_blocks
    counts[1] = n_active


@wp.kernel
def rehash(coords: wp.array(dtype=wp.vec3i), n_blocks: int, table: wp.array(dtype=wp.vec4i), mask: int):
    """One thread: put blocks [0, n_blocks) into an empty table."""
    for i in range(n_blocks):
        b = coords[i]
        h = hashing.block_hash(b, mask)
        while table[h][3] >= 0:
            h = (h + 1) & mask
        table[h] = wp.vec4i(b[0], b[1], b[2], i)


@wp.kernel
def integrate(offset: int, active: wp.array(dtype=wp.int32), coords: wp.array(dtype=wp.vec3i),
              depth: wp.array(dtype=wp.float32), image: wp.array(dtype=wp.float32), has_colour: int,
              W: int, H: int, fx: float, fy: float, cx: float, cy: float, model: int, dist: vec8d,
              R_cw: wp.mat33, t_cw: wp.vec3, voxel: float, trunc: float, min_depth: float, max_depth: float,
              tw: wp.array(dtype=wp.vec2),
              colour: wp.array(dtype=wp.vec4)):
    """Each row of BLOCK voxels along x of the active blocks (element = block * BLOCK^2 + row):
    each voxel's depth from the pixel its centre projects to (nearest; in the band, bilinear where
    the 4 pixels around agree: :func:`depth_bilinear`), its projective signed
    distance ``d - z`` truncated to [-trunc, trunc] (voxels more than ``trunc`` behind the surface
    are left alone), averaged in with weight 1 (KinectFusion's update); the pixel's colour likewise,
    for voxels inside the band, averaged with its own weight (free space keeps no colour: no surface
    is drawn there)."""
    e = offset + wp.tid()
    rows = BLOCK * BLOCK
    a = e // rows
    row = e - a * rows
    blk = active[a]
    b = coords[blk]
    i = wp.vec3i(b[0] * BLOCK, b[1] * BLOCK + row % BLOCK, b[2] * BLOCK + row // BLOCK)
    p = R_cw * (voxel * wp.vec3(float(i[0]), float(i[1]), float(i[2]))) + t_cw
    step = voxel * wp.vec3(R_cw[0, 0], R_cw[1, 0], R_cw[2, 0])  # one voxel along x, in the camera
    base = blk * BLOCK_VOXELS + row * BLOCK
    n = W * H
    for x in range(BLOCK):
        q = p + float(x) * step
        if q[2] > min_depth:
            u = float(0.0)
            v = float(0.0)
            ok = bool(True)
            if model == 0:
                u = fx * q[0] / q[2] + cx
                v = fy * q[1] / q[2] + cy
            else:
                u, v, ok = project(q, fx, fy, cx, cy, model, dist)
            iu = int(wp.floor(u + 0.5))
            iv = int(wp.floor(v + 0.5))
            if ok and iu >= 0 and iv >= 0 and iu < W and iv < H:
                pix = iv * W + iu
                d = depth[pix]
                if d > min_depth and d < max_depth:
                    sdf = d - q[2]
                    if wp.abs(sdf) < trunc:  # in the band: the depth at the projection itself
                        d = depth_bilinear(depth, u, v, W, H, d, min_depth, max_depth)
                        sdf = d - q[2]
                    if sdf >= -trunc:
                        k = base + x
                        old = tw[k]
                        w = old[1]
                        tw[k] = wp.vec2((old[0] * w + wp.min(sdf / trunc, 1.0)) / (w + 1.0), w + 1.0)
                        if has_colour != 0 and sdf < trunc:
                            c = wp.vec3(image[pix], image[n + pix], image[2 * n + pix])
                            old_c = colour[k]
                            wc = old_c[3]
                            mean = (wp.vec3(old_c[0], old_c[1], old_c[2]) * wc + c) / (wc + 1.0)
                            colour[k] = wp.vec4(mean[0], mean[1], mean[2], wc + 1.0)


__all__ = ["SENTINEL", "insert_blocks", "integrate", "rehash", "touched_blocks"]
