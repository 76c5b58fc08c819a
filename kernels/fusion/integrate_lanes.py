"""The TSDF integration, the 8 voxels of a block's row as 8 lanes (a thin kernel and its
``@wp.func`` s; the host is ``gvnn_warp.fusion.TSDFVolume``).

:func:`.kernels.integrate` handles a row's 8 voxels one after another, each behind a chain of
tests (in front of the camera, inside the image, a valid depth, in the band, in front of it) that
LLVM compiles as branches. Here the row's projections, depth reads, signed distances and updates
are length-8 vectors (``kernels.core.lanes``), the tests are 0/1 masks, and the row's weights and
colours are read and written as whole rows (only where a lane changes: a row none of whose
voxels is updated is not written); a lens camera's projection (:func:`.kernels.project`) is
called lane by lane. The values are those of :func:`.kernels.integrate` bit for bit, operation
for operation (both built with the same compiler flags but the vectoriser's depth; the tests check
it); an image of more than :data:`MAX_PIXELS` pixels (the lanes carry pixel indices as float32)
takes that kernel.
"""

import warp as wp

from ..core.kinds import LANES_MODULE_OPTIONS, vec8d, vec8f
from ..core.lanes import above8, any8, at_least8, below8, iota8, less8, open_mask8, select8, splat8
from ..sampling.lanes import floor_lanes, gather_lanes
from .hashing import BLOCK, BLOCK_VOXELS
from .kernels import project

MAX_PIXELS = 1 << 24  # pixel indices are exact as float32 up to here


@wp.func
def depth_bilinear_lanes(depth: wp.array(dtype=wp.float32), u: vec8f, v: vec8f, W: int, H: int, nearest: vec8f,
                         mask: vec8f, min_depth: float, max_depth: float):
    """:func:`.kernels.depth_bilinear` on the lanes where ``mask`` is 1 (``nearest`` elsewhere)."""
    x0 = floor_lanes(u)
    y0 = floor_lanes(v)
    fW = float(W)
    inside = wp.cw_mul(wp.cw_mul(mask, at_least8(x0, 0.0)), wp.cw_mul(at_least8(y0, 0.0), below8(x0 + splat8(1.0), fW)))
    inside = wp.cw_mul(inside, below8(y0 + splat8(1.0), float(H)))
    i00 = select8(inside, wp.cw_mul(y0, splat8(fW)) + x0, splat8(0.0))
    a = gather_lanes(depth, 0, i00, inside)
    b = gather_lanes(depth, 1, i00, inside)
    c = gather_lanes(depth, W, i00, inside)
    d = gather_lanes(depth, W + 1, i00, inside)
    lo = wp.min(wp.min(a, b), wp.min(c, d))
    hi = wp.max(wp.max(a, b), wp.max(c, d))
    valid = wp.cw_mul(wp.cw_mul(open_mask8(a, min_depth, max_depth), open_mask8(b, min_depth, max_depth)),
                      wp.cw_mul(open_mask8(c, min_depth, max_depth), open_mask8(d, min_depth, max_depth)))
    use = wp.cw_mul(wp.cw_mul(inside, valid), less8(hi - lo, 0.05 * nearest))
    fx = u - x0
    fy = v - y0
    one = splat8(1.0)
    out = wp.cw_mul(one - fy, wp.cw_mul(one - fx, a) + wp.cw_mul(fx, b)) + wp.cw_mul(
        fy, wp.cw_mul(one - fx, c) + wp.cw_mul(fx, d))
    return select8(use, out, nearest)


@wp.kernel(module="unique", enable_backward=False, module_options=LANES_MODULE_OPTIONS)
def integrate_rows(offset: int, active: wp.array(dtype=wp.int32), coords: wp.array(dtype=wp.vec3i),
                   depth: wp.array(dtype=wp.float32), image: wp.array(dtype=wp.float32), has_colour: int,
                   W: int, H: int, fx: float, fy: float, cx: float, cy: float, model: int, dist: vec8d,
                   R_cw: wp.mat33, t_cw: wp.vec3, voxel: float, trunc: float, min_depth: float, max_depth: float,
                   tw: wp.array(dtype=wp.vec2), colour: wp.array(dtype=wp.vec4)):
    """:func:`.kernels.integrate` with the row's voxels as 8 lanes (a lens's projection lane by lane)."""
    # (the row as in :func:`.kernels.integrate`, written out: through a function the two share this
    # kernel took 1-8% longer in five A/B pairs)
    e = offset + wp.tid()
    rows = BLOCK * BLOCK
    a = e // rows
    row = e - a * rows
    blk = active[a]
    b = coords[blk]
    i = wp.vec3i(b[0] * BLOCK, b[1] * BLOCK + row % BLOCK, b[2] * BLOCK + row // BLOCK)
    p = R_cw * (voxel * wp.vec3(float(i[0]), float(i[1]), float(i[2]))) + t_cw
    step = voxel * wp.vec3(R_cw[0, 0], R_cw[1, 0], R_cw[2, 0])  # one voxel along x, in the camera
    base = wp.max(blk * BLOCK_VOXELS + row * BLOCK, 0)
    xs = iota8(0, float(1.0))
    qx = splat8(p[0]) + xs * step[0]
    qy = splat8(p[1]) + xs * step[1]
    qz = splat8(p[2]) + xs * step[2]
    front = above8(qz, min_depth)
    u = splat8(0.0)
    v = splat8(0.0)
    in_lens = front  # (a lens: where the point is in its domain)
    if model == 0:
        z = select8(front, qz, splat8(1.0))  # (a finite quotient in every lane)
        u = wp.cw_div(fx * qx, z) + splat8(cx)
        v = wp.cw_div(fy * qy, z) + splat8(cy)
    else:  # (the lens model lane by lane, in float64 as the voxel-by-voxel kernel does)
        for x in range(BLOCK):
            if front[x] != 0.0:
                ux, vx, ok = project(wp.vec3(qx[x], qy[x], qz[x]), fx, fy, cx, cy, model, dist)
                u[x] = ux
                v[x] = vx
                in_lens[x] = wp.where(ok, 1.0, 0.0)
    iu = floor_lanes(u + splat8(0.5))
    iv = floor_lanes(v + splat8(0.5))
    inside = wp.cw_mul(wp.cw_mul(in_lens, wp.cw_mul(at_least8(iu, 0.0), at_least8(iv, 0.0))),
                       wp.cw_mul(below8(iu, float(W)), below8(iv, float(H))))
    pix = select8(inside, wp.cw_mul(iv, splat8(float(W))) + iu, splat8(0.0))
    d = gather_lanes(depth, 0, pix, inside)
    valid = wp.cw_mul(inside, open_mask8(d, min_depth, max_depth))
    sdf = d - qz
    band = wp.cw_mul(valid, below8(wp.abs(sdf), trunc))
    if any8(band):  # in the band: the depth at the projection itself
        d = depth_bilinear_lanes(depth, u, v, W, H, d, band, min_depth, max_depth)
        sdf = d - qz
    update = wp.cw_mul(valid, at_least8(sdf, -trunc))
    if any8(update):
        t0 = vec8f(tw[base][0], tw[base + 1][0], tw[base + 2][0], tw[base + 3][0],
                   tw[base + 4][0], tw[base + 5][0], tw[base + 6][0], tw[base + 7][0])
        w0 = vec8f(tw[base][1], tw[base + 1][1], tw[base + 2][1], tw[base + 3][1],
                   tw[base + 4][1], tw[base + 5][1], tw[base + 6][1], tw[base + 7][1])
        w1 = w0 + splat8(1.0)
        t1 = wp.cw_div(wp.cw_mul(t0, w0) + wp.min(sdf / trunc, splat8(1.0)), w1)
        t1 = select8(update, t1, t0)
        w1 = select8(update, w1, w0)
        for x in range(BLOCK):
            tw[base + x] = wp.vec2(t1[x], w1[x])
        paint = wp.cw_mul(update, below8(sdf, trunc))
        if has_colour != 0 and any8(paint):
            n = W * H
            r = gather_lanes(image, 0, pix, paint)
            g = gather_lanes(image, n, pix, paint)
            bl = gather_lanes(image, 2 * n, pix, paint)
            c0 = vec8f(colour[base][0], colour[base + 1][0], colour[base + 2][0], colour[base + 3][0],
                       colour[base + 4][0], colour[base + 5][0], colour[base + 6][0], colour[base + 7][0])
            c1 = vec8f(colour[base][1], colour[base + 1][1], colour[base + 2][1], colour[base + 3][1],
                       colour[base + 4][1], colour[base + 5][1], colour[base + 6][1], colour[base + 7][1])
            c2 = vec8f(colour[base][2], colour[base + 1][2], colour[base + 2][2], colour[base + 3][2],
                       colour[base + 4][2], colour[base + 5][2], colour[base + 6][2], colour[base + 7][2])
            wc = vec8f(colour[base][3], colour[base + 1][3], colour[base + 2][3], colour[base + 3][3],
                       colour[base + 4][3], colour[base + 5][3], colour[base + 6][3], colour[base + 7][3])
            wc1 = wc + splat8(1.0)
            c0 = select8(paint, wp.cw_div(wp.cw_mul(c0, wc) + r, wc1), c0)
            c1 = select8(paint, wp.cw_div(wp.cw_mul(c1, wc) + g, wc1), c1)
            c2 = select8(paint, wp.cw_div(wp.cw_mul(c2, wc) + bl, wc1), c2)
            wc1 = select8(paint, wc1, wc)
            for x in range(BLOCK):
                colour[base + x] = wp.vec4(c0[x], c1[x], c2[x], wc1[x])


__all__ = ["MAX_PIXELS", "integrate_rows"]
