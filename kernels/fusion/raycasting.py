"""The raycasting kernels of the TSDF (see :mod:`gvnn_warp.kernels.fusion`; the host is
``gvnn_warp.fusion.TSDFVolume.raycast``): the depth range of the blocks over each tile of pixels,
the march of each pixel's ray to the first crossing, and the normals of the rendered depth.
Conventions as in :mod:`.kernels` (a leading ``offset``, flat images, a camera as ``rays`` and
``(fx, fy, cx, cy)``).
"""

import warp as wp

from ..core.kinds import vec8i
from . import hashing
from .hashing import BLOCK, BLOCK_VOXELS, SENTINEL, find_block, voxel_block, voxel_offset

wp.set_module_options({"enable_backward": False})  # (no gradients here: half the compile time)


@wp.kernel
def depth_range(offset: int, coords: wp.array(dtype=wp.vec3i), n_blocks: int, parts: int, R_cw: wp.mat33,
                t_cw: wp.vec3, fx: float, fy: float, cx: float, cy: float, block_len: float, min_depth: float,
                tile: int, margin: int, tiles_x: int, tiles_y: int, near: wp.array(dtype=wp.float32),
                far: wp.array(dtype=wp.float32)):
    """Element ``part`` of ``parts`` (every ``parts``-th block, its own ``tiles_x * tiles_y``
    slice of ``near`` and ``far``; :func:`merge_ranges` then takes the slices' extremes): for each
    tile of ``tile`` x ``tile`` ideal pixels (``fx xn + cx``, ``fy yn + cy`` of the ray; ``margin``
    tiles around the image for lenses), the nearest and farthest z of the blocks whose bounding box
    projects onto it (``far`` 0: no block; ``near`` must start large). A block that reaches the
    near plane covers every tile from ``min_depth`` on."""
    part = offset + wp.tid()
    base = part * tiles_x * tiles_y
    for bi in range(part, n_blocks, parts):  # (every parts-th block: the parts' work alike)
        b = coords[bi]
        o = block_len * wp.vec3(float(b[0]), float(b[1]), float(b[2]))
        zlo = float(1.0e30)
        zhi = float(-1.0e30)
        ulo = float(1.0e30)
        uhi = float(-1.0e30)
        vlo = float(1.0e30)
        vhi = float(-1.0e30)
        behind = bool(False)
        for c in range(8):
            corner = o + block_len * wp.vec3(float(c & 1), float((c >> 1) & 1), float((c >> 2) & 1))
            q = R_cw * corner + t_cw
            zlo = wp.min(zlo, q[2])
            zhi = wp.max(zhi, q[2])
            if q[2] <= min_depth:
                behind = True
            else:
                u = fx * q[0] / q[2] + cx
                v = fy * q[1] / q[2] + cy
                ulo = wp.min(ulo, u)
                uhi = wp.max(uhi, u)
                vlo = wp.min(vlo, v)
                vhi = wp.max(vhi, v)
        if zhi <= min_depth:
            continue
        tx0 = int(0)
        tx1 = tiles_x - 1
        ty0 = int(0)
        ty1 = tiles_y - 1
        if not behind:
            tx0 = wp.max(tx0, int(wp.floor(ulo / float(tile))) + margin)
            tx1 = wp.min(tx1, int(wp.floor(uhi / float(tile))) + margin)
            ty0 = wp.max(ty0, int(wp.floor(vlo / float(tile))) + margin)
            ty1 = wp.min(ty1, int(wp.floor(vhi / float(tile))) + margin)
        zlo = wp.max(zlo, min_depth)
        for ty in range(ty0, ty1 + 1):
            for tx in range(tx0, tx1 + 1):
                k = base + ty * tiles_x + tx
                near[k] = wp.min(near[k], zlo)
                far[k] = wp.max(far[k], zhi)


@wp.kernel
def merge_ranges(offset: int, parts: int, n_tiles: int, near: wp.array(dtype=wp.float32),
                 far: wp.array(dtype=wp.float32)):
    """Tile ``k``: :func:`depth_range`'s parts' nearest and farthest z, into the first part's slice."""
    k = offset + wp.tid()
    for part in range(1, parts):
        near[k] = wp.min(near[k], near[part * n_tiles + k])
        far[k] = wp.max(far[k], far[part * n_tiles + k])


@wp.func
def block_exit(p: wp.vec3, direction: wp.vec3, inv_direction: wp.vec3, b: wp.vec3i, voxel: float,
               block_len: float):
    """Ray parameter from ``p`` to where the ray ``p + t direction`` leaves the space of block ``b``
    (its voxels' cells: [(BLOCK b - 1/2) voxel, (BLOCK (b + 1) - 1/2) voxel) on each axis);
    ``inv_direction``: the reciprocals of ``direction``'s components (used where they are not 0)."""
    t = float(1.0e30)
    for a in range(3):
        lo = float(b[a]) * block_len - 0.5 * voxel
        if direction[a] > 0.0:
            t = wp.min(t, (lo + block_len - p[a]) * inv_direction[a])
        elif direction[a] < 0.0:
            t = wp.min(t, (lo - p[a]) * inv_direction[a])
    return wp.max(t, 0.0)


@wp.func
def set_pixel(k: int, depth: float, rgb: wp.vec3, out_depth: wp.array(dtype=wp.float32),
              out_colour: wp.array(dtype=wp.float32)):
    """Pixel ``k`` of the raycast's outputs: its depth and colour (three planes; 0 and black: no surface)."""
    n_pix = out_depth.shape[0]
    out_depth[k] = depth
    out_colour[k] = rgb[0]
    out_colour[n_pix + k] = rgb[1]
    out_colour[2 * n_pix + k] = rgb[2]


@wp.func
def ray_range(r: wp.vec3, k: int, fx: float, fy: float, cx: float, cy: float, tile: int, margin: int, tiles_x: int,
              tiles_y: int, near: wp.array(dtype=wp.float32), far: wp.array(dtype=wp.float32), min_depth: float,
              max_depth: float, start: wp.array(dtype=wp.float32), start_margin: float):
    """Where pixel ``k``'s ray (``r``) marches: (ok: it has a ray and its tile a range, t the start,
    t_tile the tile's near end, t_end its far end, hinted: t is from ``start``) (see :func:`raycast`)."""
    ok = bool(r[2] > 0.0)
    t = float(0.0)
    t_tile = float(0.0)
    t_end = float(0.0)
    hinted = bool(False)  # started from ``start``: a negative value read with no positive one just before it
    # (the first value, or the first after unobserved voxels) sends the ray back to t_tile, once
    if ok:
        tx = int(wp.floor((fx * r[0] + cx) / float(tile))) + margin
        ty = int(wp.floor((fy * r[1] + cy) / float(tile))) + margin
        if tx < 0 or ty < 0 or tx >= tiles_x or ty >= tiles_y:
            ok = False
        else:
            t_end = wp.min(max_depth, far[ty * tiles_x + tx])
            t_tile = wp.max(min_depth, near[ty * tiles_x + tx])
            t = t_tile
            if start.shape[0] > 0:
                s0 = start[k]
                if s0 > 0.0 and s0 < 1.0e30 and s0 - start_margin > t:  # (NaN fails)
                    t = s0 - start_margin
                    hinted = True
            if t_end <= t_tile:
                ok = False
    return ok, t, t_tile, t_end, hinted


@wp.func
def ray_steps(R_wc: wp.mat33, r: wp.vec3, voxel: float, trunc: float):
    """(direction (world, z = 1 in the camera), its length (metres per unit of z), the reciprocals of
    its components (0 where a component is 0), a voxel and the march's band step in units of t)."""
    direction = R_wc * wp.vec3(r[0], r[1], 1.0)
    scale = wp.length(direction)  # metres per unit of z
    inv_scale = 1.0 / scale
    inv_direction = wp.vec3(0.0)
    for a in range(3):
        if direction[a] != 0.0:
            inv_direction[a] = 1.0 / direction[a]
    voxel_t = voxel * inv_scale  # a voxel, in units of t
    band_t = 0.8 * trunc * inv_scale
    return direction, scale, inv_direction, voxel_t, band_t


@wp.func
def refine_hit(table: wp.array(dtype=wp.vec4i), mask: int, tw: wp.array(dtype=wp.vec2), t_wc: wp.vec3,
               direction: wp.vec3, scale: float, voxel: float, crossed: bool, prev_t: float, prev_f: float,
               cross_t: float, cross_f: float):
    """After a march: (the crossing's ray parameter, 0 if none; the cell of 8 voxels the Newton step
    read and their indices (:func:`.hashing.corner_voxels`), for :func:`hit_colour`), from the last
    positive value (``prev_t``, ``prev_f``) and the first non-positive one (``cross_t``,
    ``cross_f``) when ``crossed``."""
    inv_voxel = 1.0 / voxel
    hit = float(0.0)
    bracket = bool(False)  # the Newton step did not apply: refine by bracketing
    cell = wp.vec3i(SENTINEL, 0, 0)
    kk = vec8i(-1)
    if crossed:
        # where the nearest voxels' values cross zero (their linear interpolation; the depth if
        # neither refinement applies, e.g. an unobserved voxel among the 8 of a trilinear value)
        t0 = prev_t + (cross_t - prev_t) * prev_f / (prev_f - cross_f)
        hit = t0
        # one Newton step on the trilinear values from there: exact where the TSDF is linear along
        # the ray; accepted when it moves less than a voxel and the value falls along the ray, as at
        # a front surface
        cell, frac = hashing.voxel_cell(t_wc + t0 * direction, inv_voxel)
        kk = hashing.corner_voxels(table, mask, cell)
        f0, g0, ok0 = hashing.trilinear_grad_of(tw, kk, frac, inv_voxel)
        slope = wp.dot(g0, direction)  # d value / d t
        bracket = True
        if ok0 and slope < 0.0:
            t1 = t0 - f0 / slope
            if wp.abs(t1 - t0) * scale < voxel:
                hit = t1
                bracket = False
    if bracket:
        # else refine with trilinear values: bracket the crossing between two samples whose trilinear
        # values straddle zero (the nearest voxels' values that stopped the march may disagree with
        # them by up to half a voxel: move the bracket by half voxels, at most 4 times), then
        # interpolate linearly between them
        ta = prev_t
        tb = cross_t
        fa, oka = hashing.trilinear(table, mask, tw, t_wc + ta * direction, inv_voxel)
        fb, okb = hashing.trilinear(table, mask, tw, t_wc + tb * direction, inv_voxel)
        half = 0.5 * voxel / scale
        for _move in range(4):
            if oka and okb and fa > 0.0 and fb > 0.0:
                ta = tb
                fa = fb
                tb = tb + half
                fb, okb = hashing.trilinear(table, mask, tw, t_wc + tb * direction, inv_voxel)
            elif oka and okb and fa <= 0.0 and fb <= 0.0:
                tb = ta
                fb = fa
                ta = ta - half
                fa, oka = hashing.trilinear(table, mask, tw, t_wc + ta * direction, inv_voxel)
        if oka and okb and fa > 0.0 and fb <= 0.0:
            hit = ta + (tb - ta) * fa / (fa - fb)
    return hit, cell, kk


@wp.func
def hit_colour(table: wp.array(dtype=wp.vec4i), mask: int, colour: wp.array(dtype=wp.vec4), q: wp.vec3,
               inv_voxel: float, cell: wp.vec3i, kk: vec8i):
    """The colour at surface point ``q`` (:func:`.hashing.trilinear_colour`), its cell's voxels taken
    from :func:`refine_hit`'s when it is the same cell (most hits: no second block lookup)."""
    c, frac = hashing.voxel_cell(q, inv_voxel)
    voxels = kk
    if not hashing.same(c, cell):
        voxels = hashing.corner_voxels(table, mask, c)
    return hashing.trilinear_colour_of(colour, voxels, frac)


@wp.kernel
def raycast(offset: int, table: wp.array(dtype=wp.vec4i), mask: int,
            tw: wp.array(dtype=wp.vec2), colour: wp.array(dtype=wp.vec4),
            rays: wp.array(dtype=wp.vec3), R_wc: wp.mat33, t_wc: wp.vec3, R_cw: wp.mat33, voxel: float, trunc: float,
            min_depth: float, max_depth: float, fx: float, fy: float, cx: float, cy: float, tile: int, margin: int,
            tiles_x: int, tiles_y: int, near: wp.array(dtype=wp.float32), far: wp.array(dtype=wp.float32), H: int,
            start: wp.array(dtype=wp.float32), start_margin: float,
            out_depth: wp.array(dtype=wp.float32), out_colour: wp.array(dtype=wp.float32)):
    """Each pixel: march its ray through the z range of the blocks that project onto its tile
    (:func:`depth_range`) - a block at a time where there is none, by the distance the TSDF promises
    inside blocks - to the first crossing from positive to negative (refined by a Newton step on the
    trilinear values, or else linearly between trilinear values that bracket it). Writes the
    crossing's depth (0: none) and colour (three planes; trilinear, :func:`hit_colour`). The normals
    come from the depth image (:func:`depth_normals`). ``start`` (one per pixel, or empty): a depth
    at which the pixel's surface is expected; where it is positive and finite the ray starts
    ``start_margin`` (in z) before it if that is beyond its tile's range, and goes back to the
    tile's range if it reads a negative value with no positive one just before it."""
    # pixels in 8 x 8 tiles (element = tile * 64 + pixel of the tile): neighbouring rays, which
    # read the same voxels, run one after the other (the voxels are read from memory once)
    e = offset + wp.tid()
    n_pix = out_depth.shape[0]
    W = n_pix // H
    tiles_w = (W + 7) // 8
    tile_k = e // 64
    px = (tile_k % tiles_w) * 8 + (e % 8)
    py = (tile_k // tiles_w) * 8 + (e % 64) // 8
    if px >= W or py >= H:
        return
    k = py * W + px
    set_pixel(k, 0.0, wp.vec3(0.0), out_depth, out_colour)
    r = rays[k]
    ok, t, t_tile, t_end, hinted = ray_range(r, k, fx, fy, cx, cy, tile, margin, tiles_x, tiles_y, near, far,
                                             min_depth, max_depth, start, start_margin)
    if not ok:
        return
    direction, scale, inv_direction, voxel_t, band_t = ray_steps(R_wc, r, voxel, trunc)
    inv_voxel = 1.0 / voxel
    block_len = voxel * float(BLOCK)
    prev_t = float(0.0)
    prev_f = float(0.0)
    have_prev = bool(False)
    last = wp.vec3i(SENTINEL, 0, 0)  # the block looked up last, and its index
    blk = int(-1)
    crossed = bool(False)
    cross_t = float(0.0)
    cross_f = float(0.0)
    while t < t_end:
        p = t_wc + t * direction
        i = hashing.voxel_of_point(p, inv_voxel)
        bc = voxel_block(i)
        if not hashing.same(bc, last):
            last = bc
            blk = find_block(table, mask, bc)
        if blk < 0:  # no block: on to where the ray leaves this block's space
            have_prev = False
            t += block_exit(p, direction, inv_direction, bc, voxel, block_len) + 0.01 * voxel_t
            continue
        kk = blk * BLOCK_VOXELS + voxel_offset(i)
        if tw[kk][1] <= 0.0:
            have_prev = False
            t += voxel_t
            continue
        f = tw[kk][0]
        if f <= 0.0 and hinted and not have_prev:
            # (the start fell behind the first surface, or inside a band stretched along a grazing ray:
            # march from the tile's range as without a start; where the full march would find no
            # crossing either, this one finds none)
            hinted = False
            t = t_tile
            continue
        if f <= 0.0:
            crossed = have_prev  # (a negative value first: the back of a surface, or inside it: no hit)
            cross_t = t
            cross_f = f
            break
        prev_t = t
        prev_f = f
        have_prev = True
        t += wp.max(voxel_t, band_t * f)
    hit, cell, corners = refine_hit(table, mask, tw, t_wc, direction, scale, voxel, crossed, prev_t, prev_f,
                                    cross_t, cross_f)
    if hit > 0.0:  # (its colour: trilinear, from the voxels around the hit that hold one)
        set_pixel(k, hit, hit_colour(table, mask, colour, t_wc + hit * direction, inv_voxel, cell, corners),
                  out_depth, out_colour)


@wp.kernel
def depth_normals(offset: int, depth: wp.array(dtype=wp.float32), rays: wp.array(dtype=wp.vec3), W: int, H: int,
                  max_jump: float, normal: wp.array(dtype=wp.float32)):
    """Unit normals (camera frame, facing the camera) of a depth image from its neighbours' points
    (the cross product of the central differences along x and y, as KinectFusion's normal map);
    zero where a neighbour has no depth or lies more than ``max_jump`` (relative) farther or nearer;
    ``normal`` three planes of H * W (x, y, z)."""
    k = offset + wp.tid()
    x = k % W
    y = k // W
    n_pix = W * H
    normal[k] = 0.0
    normal[n_pix + k] = 0.0
    normal[2 * n_pix + k] = 0.0
    if x < 1 or y < 1 or x >= W - 1 or y >= H - 1:
        return
    d = depth[k]
    dl = depth[k - 1]
    dr = depth[k + 1]
    du = depth[k - W]
    dd = depth[k + W]
    if d <= 0.0 or dl <= 0.0 or dr <= 0.0 or du <= 0.0 or dd <= 0.0:
        return
    lim = max_jump * d
    if wp.abs(dl - d) > lim or wp.abs(dr - d) > lim or wp.abs(du - d) > lim or wp.abs(dd - d) > lim:
        return
    rl = rays[k - 1]
    rr = rays[k + 1]
    ru = rays[k - W]
    rd = rays[k + W]
    px = dr * wp.vec3(rr[0], rr[1], 1.0) - dl * wp.vec3(rl[0], rl[1], 1.0)
    py = dd * wp.vec3(rd[0], rd[1], 1.0) - du * wp.vec3(ru[0], ru[1], 1.0)
    n = wp.cross(py, px)
    if wp.length(n) <= 0.0:
        return
    n = wp.normalize(n)
    r = rays[k]
    if wp.dot(n, wp.vec3(r[0], r[1], 1.0)) > 0.0:  # (facing the camera)
        n = -n
    normal[k] = n[0]
    normal[n_pix + k] = n[1]
    normal[2 * n_pix + k] = n[2]


__all__ = ["block_exit", "set_pixel", "depth_normals", "depth_range", "merge_ranges", "raycast"]
