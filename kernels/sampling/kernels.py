"""The sampling kernels: the bilinear sampler and the fused 3D spatial transformer (unproject ->
move -> project -> sample), pinhole and through a lens model.

The fused kernel is the point of this package: one pass over the depth map, no (B, H, W, 3)
point or (B, H, W, 2) grid intermediates, and its adjoint (Warp's) scatters image gradients and
accumulates depth, pose and intrinsics gradients in the same pass. One kernel body serves both
fronts (the torch op and :func:`.pipeline.warp_frame_depth`).

Speed. The per-pixel work is two building blocks with hand-shaped Warp adjoints
(:func:`.camera.project_moved_ray` and :func:`.sampler.sample_channels`, both ``@wp.func_grad``): tap
addresses and weights are computed once for all channels, and the backward pass does not re-sample
the image. ``warp_frame_depth`` runs one thread per image row (launch size B * H): per-row
quantities are computed once, and the pose and intrinsics gradients of a row are summed in
registers before one write; :func:`.launch.launch` splits launches over threads by batch item
(see :meth:`.launch.FloatKernel.set_parallel`).
:func:`bilinear_sample_lanes` is the sampler's twin that handles 8 locations per thread as
length-8 vectors, which LLVM turns into SIMD code (Warp's per-thread code is otherwise scalar): the
same values, and a hand-written adjoint on the lanes (:mod:`.bilinear_block`; the sampler's
gradients up to the order of sums). :func:`warp_frame_depth_lanes`
is the fused kernel with one thread per row whose pixels are projected and sampled 8 at a time
(:mod:`.pinhole_block`): bitwise :data:`warp_frame_depth`'s values, and a hand-written adjoint on
the same lanes (its gradients are the row kernel's up to the order of sums).

Through a lens model (radial-tangential, fisheye): :func:`pixel_rays_lens`, the pixel rays of a
camera (:mod:`.geometry.lens.rays`), and :func:`warp_frame_depth_lens`, the twin of
:data:`warp_frame_depth` that moves those rays and projects through the lens
(:mod:`.lens_block`). Both are made on first use through the cache: defining the lens models'
custom adjoints makes Warp build them (seconds), which the pinhole kernels must not wait for.
"""

from typing import Any

import warp as wp

from ..core.cache import specialise
from ..core.kinds import LANES_MODULE_OPTIONS, FloatKernel
from ..geometry import camera, lie
from ..geometry.lens import rays as lens_rays
from . import bilinear_block, lens_block, pinhole_block, sampler

# Fewest pixels worth a separate chunk of a threaded launch (~0.2 ms of work: a chunk costs
# ~20 us of launch and hand-over).
_GRAIN_PIXELS = 8192

# How the spatial transformers' row kernels (one thread per image row, launch B * H) may be split:
# segments are a batch item's rows; a row's adjoint writes its own depth pixels, and the image plane,
# pose and K of its item. The row kernel and the 8-lane kernel declare exactly this, the lens kernel
# this and its own arrays.
_ROW_SPLIT = {
    "segment": lambda a: a["H"],
    "scopes": {"image": "segment", "depth": "element", "pose": "segment", "K": "segment"},
    "grain": lambda a: max(1, _GRAIN_PIXELS // max(1, a["W"])),
}

@wp.kernel(module="unique")
def _bilinear_sample(
    offset: int,
    image: wp.array(dtype=Any),
    grid: wp.array(dtype=Any),
    C: int,
    H: int,
    W: int,
    hw: int,
    align_corners: int,
    padding: int,
    out: wp.array(dtype=Any),
):
    i = wp.tid() + offset  # flat (b, output location)
    b = i // hw
    j = i - b * hw
    g = grid[wp.max(i, 0)]
    x = sampler.normalized_to_pixel(g[0], W, align_corners)
    y = sampler.normalized_to_pixel(g[1], H, align_corners)
    xs, ys, inside = sampler.sample_position(x, y, H, W, padding)
    sampler.sample_channels(image, out, b * C * H * W, b * C * hw + j, C, H * W, hw, H, W, xs, ys, inside)


bilinear_sample = FloatKernel(_bilinear_sample, image="scalar", grid="vec2", out="scalar").set_parallel(
    segment=lambda a: a["hw"],  # batch items
    scopes={"image": "segment", "grid": "element"},
    grain=_GRAIN_PIXELS,
)


# the array kinds of every bilinear_sample_lanes kernel
LANES_ARRAY_KINDS = {"image": "scalar", "grid": "vec16", "out": "vec8"}


def fits_lanes(n_out: int, H: int, W: int) -> bool:
    """Whether :func:`bilinear_sample_lanes` applies: ``n_out`` output locations per batch item
    fill whole 8-lane blocks and an H x W plane's addresses are exact as float32."""
    return n_out % sampler.LANES == 0 and H * W <= sampler.MAX_LANES_PLANE


@specialise("sampling.bilinear_sample_lanes", C=tuple(range(1, sampler.UNROLLED_CHANNELS + 1)))
def bilinear_sample_lanes(C: int | None, align_corners: int, padding: int, image_grad: bool = True) -> FloatKernel:
    """:data:`bilinear_sample` with 8 output locations per thread, forward and backward.

    Compiled for this channel count (if at most ``sampler.UNROLLED_CHANNELS``; else read at run
    time: ``C`` None), ``align_corners``, ``padding`` and ``image_grad`` (False: an adjoint without
    the image's gradient, for a backward that does not want it): constants fold the branches away,
    which the vectorised code needs to be fast (made on first use, one kernel per combination).
    Same arguments; ``grid`` is read as 8 (x, y) pairs per element ("vec16") and ``out`` written as
    8 lanes per element ("vec8"), flat (b, c, block of 8 locations). For :func:`fits_lanes` sizes.
    Each element is :func:`.bilinear_block.sample_block8`: bitwise the values of
    :data:`bilinear_sample`, its gradients up to the order of sums (a hand-written adjoint on the
    lanes).
    """
    # compile-time constants (named apart from the kernel's arguments)
    static_c = C or 0
    block = bilinear_block.sample_block8(C, align_corners, padding, bool(image_grad))

    @wp.kernel(module="unique", module_options=LANES_MODULE_OPTIONS)
    def _bilinear_sample_lanes(
        offset: int,
        image: wp.array(dtype=Any),
        grid: wp.array(dtype=Any),
        C: int,
        H: int,
        W: int,
        hw: int,
        align_corners: int,
        padding: int,
        out: wp.array(dtype=Any),
    ):
        t = wp.tid() + offset  # flat (b, block of 8 output locations)
        hw8 = hw // wp.static(sampler.LANES)
        b = t // hw8
        nc = C
        if wp.static(static_c > 0):
            nc = wp.static(static_c)  # a constant: the channel loop unrolls exactly
        block(image, out, grid[t], b * nc * H * W, b * nc * hw8 + t - b * hw8, nc, hw8, H, W)

    return FloatKernel(_bilinear_sample_lanes, **LANES_ARRAY_KINDS).set_parallel(
        segment=lambda a: a["hw"] // sampler.LANES,  # batch items
        scopes={"image": "segment", "grid": "element"},
        grain=_GRAIN_PIXELS // sampler.LANES,
    )


@wp.kernel(module="unique")
def _warp_frame_depth(
    offset: int,
    image: wp.array(dtype=Any),
    depth: wp.array(dtype=Any),
    pose: wp.array(dtype=Any),
    K: wp.array(dtype=Any),
    C: int,
    H: int,
    W: int,
    min_depth: float,
    padding: int,
    out: wp.array(dtype=Any),
    valid: wp.array(dtype=wp.bool),
):
    # One thread per image row: element r = (b, y) covers the pixels [r W, (r + 1) W) of the depth
    # map's frame; per-row quantities are computed once, and Warp's adjoint sums a row's pose and
    # intrinsics gradients in registers before one write. Used by both fronts (the torch op and
    # .pipeline.warp_frame_depth): launch B * H elements.
    r = wp.tid() + offset  # flat (b, y)
    b = r // H
    py = r - b * H
    hw = H * W
    Kb = K[b]
    Tb = pose[b]
    zmin = type(Kb[0, 0])(min_depth)
    one = type(zmin)(1.0)
    tol = type(zmin)(sampler.INSIDE_TOLERANCE)
    umax = type(zmin)(W - 1) + tol
    vmax = type(zmin)(H - 1) + tol
    a0, ax = camera.row_rays(lie.pose_rotation(Tb), Kb, type(zmin)(py))
    t = lie.pose_translation(Tb)
    src = b * C * hw
    row = r * W
    dst = src + py * W
    for px in range(W):
        i = wp.max(row + px, 0)
        d = depth[i]
        # Invalid depth (<= min, NaN, inf) is replaced by 1 *before* any arithmetic, so neither the
        # values nor Warp's adjoint ever see it (wp.where routes no gradient to the unused side).
        depth_ok = d > zmin and d < type(d)(1.0e30)
        uvz = camera.project_moved_ray(a0, ax, t, Kb, type(d)(px), wp.where(depth_ok, d, one), zmin)
        ok = depth_ok and uvz[2] > zmin
        u = uvz[0]
        v = uvz[1]
        valid[i] = ok and u >= -tol and u <= umax and v >= -tol and v <= vmax
        xs, ys, reachable = sampler.sample_position(u, v, H, W, padding)
        sampler.sample_channels(image, out, src, dst + px, C, hw, hw, H, W, xs, ys, ok and reachable)


warp_frame_depth = FloatKernel(
    _warp_frame_depth, image="scalar", depth="scalar", pose="mat34", K="mat33", out="scalar"
).set_parallel(**_ROW_SPLIT)


def fits_row_lanes(H: int, W: int) -> bool:
    """Whether :func:`warp_frame_depth_lanes` applies: rows of whole 8-pixel blocks, and an H x W
    plane's addresses exact as float32."""
    return W % sampler.LANES == 0 and H * W <= sampler.MAX_LANES_PLANE


@specialise("sampling.warp_frame_depth_lanes", C=tuple(range(1, sampler.UNROLLED_CHANNELS + 1)))
def warp_frame_depth_lanes(C: int | None, padding: int, image_grad: bool = True) -> FloatKernel:
    """:data:`warp_frame_depth` with the pixels of a row taken 8 at a time, forward and backward.

    The same arguments and launch (one thread per row, B * H elements); ``depth`` is read and
    ``out`` written as 8 lanes per element ("vec8"), flat (b, y, block of 8 pixels) and (b, c,
    block); for :func:`fits_row_lanes` sizes. Each block is :func:`.pinhole_block.warp_block8`:
    the values and ``valid`` are bitwise those of :data:`warp_frame_depth`, the gradients its own
    up to the order of sums (a hand-written adjoint on the lanes): the row's pose and intrinsics
    gradients are summed over its blocks as 8-lane vectors (:func:`.pinhole_block.row_lanes`), and
    their lanes once per row. Compiled for this channel count (if at most
    ``sampler.UNROLLED_CHANNELS``; else read at run time: ``C`` None), ``padding`` and
    ``image_grad`` (made on first use, one kernel per combination). ``image_grad`` False: the same
    forward, an adjoint without the image's gradient (for a backward that does not want it; the
    image-as-data backward ~8% faster than with the code merely skipped at run time).
    """
    static_c = C or 0
    block = pinhole_block.warp_block8(C, padding, bool(image_grad))

    @wp.kernel(module="unique", module_options=LANES_MODULE_OPTIONS)
    def _warp_frame_depth_lanes(
        offset: int,
        image: wp.array(dtype=Any),
        depth: wp.array(dtype=Any),
        pose: wp.array(dtype=Any),
        K: wp.array(dtype=Any),
        C: int,
        H: int,
        W: int,
        min_depth: float,
        padding: int,
        out: wp.array(dtype=Any),
        valid: wp.array(dtype=wp.bool),
    ):
        # One thread per image row, as the row kernel: per-row work once, and one sum of the row's
        # gradients (a thread per block of 8 pixels made the forward ~1.4x slower: Warp's
        # per-element entry and the per-row set-up were paid per block)
        r = wp.tid() + offset  # flat (b, y)
        b = r // H
        py = r - b * H
        w8 = W // wp.static(sampler.LANES)
        hw8 = H * w8
        Kb = K[b]
        Tb = pose[b]
        zmin = type(Kb[0, 0])(min_depth)
        a0, ax = camera.row_rays(lie.pose_rotation(Tb), Kb, type(zmin)(py))
        t = lie.pose_translation(Tb)
        a0_lanes, ax_lanes, t_lanes, k_lanes = pinhole_block.row_lanes(a0, ax, t, Kb)  # the blocks' gradient sums
        nc = C
        if wp.static(static_c > 0):
            nc = wp.static(static_c)  # a constant: the channel loop unrolls exactly
        for k in range(w8):
            block(image, depth, out, valid, r * w8 + k, k * wp.static(sampler.LANES), a0, ax, t, Kb, a0_lanes,
                  ax_lanes, t_lanes, k_lanes, b * nc * H * W, b * nc * hw8 + py * w8 + k, nc, hw8, H, W, zmin)

    return FloatKernel(_warp_frame_depth_lanes, image="scalar", depth="vec8", pose="mat34", K="mat33",
                       out="vec8").set_parallel(**_ROW_SPLIT)


# ----------------------------------------------------------------------------- through a lens model


@specialise("sampling.pixel_rays_lens")
def pixel_rays_lens() -> FloatKernel:
    """The kernel of the pixel rays of cameras through their lens models (``rays.pixel_ray`` per
    pixel, element i = flat (b, y, x)), made on first use."""

    @wp.kernel(module="unique")
    def _pixel_rays(
        offset: int,
        K: wp.array(dtype=Any),
        dist: wp.array(dtype=Any),
        H: int,
        W: int,
        model: int,
        rays: wp.array(dtype=Any),
    ):
        # element i = flat (b, y, x): the ray of pixel (x, y) of camera b (see lens_rays)
        i = wp.tid() + offset
        b = i // (H * W)
        p = i - b * (H * W)
        y = p // W
        x = p - y * W
        Kb = K[b]
        rays[i] = lens_rays.pixel_ray(model, Kb, dist[b], type(Kb[0, 0])(x), type(Kb[0, 0])(y))

    return FloatKernel(_pixel_rays, K="mat33", dist="vec8", rays="vec3").set_parallel(
        segment=lambda a: a["H"] * a["W"],  # pixels of one camera
        scopes={"K": "segment", "dist": "segment"},
        grain=_GRAIN_PIXELS // 8,  # Newton's method: ~10x the work of a pixel of the warp
    )


@specialise("sampling.warp_frame_depth_lens")
def warp_frame_depth_lens() -> FloatKernel:
    """:data:`warp_frame_depth` through a lens model (+ ``dist``, the ``rays`` of
    :func:`pixel_rays_lens` and ``ray_stride``), made on first use."""
    block = lens_block.warp_block()

    @wp.kernel(module="unique", module_options=LANES_MODULE_OPTIONS)
    def _warp_frame_depth_lens(
        offset: int,
        image: wp.array(dtype=Any),
        depth: wp.array(dtype=Any),
        pose: wp.array(dtype=Any),
        K: wp.array(dtype=Any),
        dist: wp.array(dtype=Any),
        rays: wp.array(dtype=Any),
        C: int,
        H: int,
        W: int,
        min_depth: float,
        padding: int,
        model: int,
        ray_stride: int,
        out: wp.array(dtype=Any),
        valid: wp.array(dtype=wp.bool),
    ):
        # _warp_frame_depth through a lens model (see lens_block): the depth map's pixels are read
        # as precomputed rays (rays[b * ray_stride + y W + x]: ray_stride H * W for rays per batch
        # item, 0 for one camera shared by the batch), moved and projected with the distortion.
        # One thread per image row (launch B * H), as the pinhole kernel.
        r = wp.tid() + offset  # flat (b, y)
        b = r // H
        py = r - b * H
        Kb = K[b]
        Tb = pose[b]
        db = dist[b]
        zmin = type(Kb[0, 0])(min_depth)
        tol = type(zmin)(sampler.INSIDE_TOLERANCE)
        R = lie.pose_rotation(Tb)
        t = lie.pose_translation(Tb)
        row = r * W
        src = b * C * H * W
        dst = src + py * W
        ray0 = b * ray_stride + py * W
        for x0 in range(0, W, wp.static(lens_block.BLOCK)):
            block(
                image, depth, rays, out, valid, K, dist, row + x0, ray0 + x0,
                wp.min(W - x0, wp.static(lens_block.BLOCK)), b, src, dst + x0, C, H, W, padding, model, R, t, Kb,
                db, zmin, tol,
            )

    return FloatKernel(
        _warp_frame_depth_lens, image="scalar", depth="scalar", pose="mat34", K="mat33", dist="vec8", rays="vec3",
        out="scalar",
    ).set_parallel(
        segment=_ROW_SPLIT["segment"],
        # rays shared by the batch (ray_stride 0) gather the gradients of every item: "any"
        scopes={**_ROW_SPLIT["scopes"], "dist": "segment", "rays": "any"},
        grain=_ROW_SPLIT["grain"],
    )
