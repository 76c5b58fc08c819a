"""The fused 3D spatial transformer through a lens model (radial-tangential, fisheye): the pixel
rays of a camera and :data:`warp_frame_depth_lens`, the twin of
:data:`.sampling_kernels.warp_frame_depth` that moves those rays and projects through the lens
(:mod:`.lens_rays`). A module of its own so that the pinhole transformer does not import the lens
models (defining their custom adjoints makes Warp build them: ~1.5-3 s on a slow host).
"""

from typing import Any

import warp as wp

from ..core.kinds import FloatKernel
from ..geometry import lie
from ..geometry.lens import rays as lens_rays
from .kernels import _GRAIN_PIXELS, INSIDE_TOLERANCE


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
    # element i = flat (b, y, x): the ray of pixel (x, y) of camera b (see lens_rays.pixel_ray)
    i = wp.tid() + offset
    b = i // (H * W)
    p = i - b * (H * W)
    y = p // W
    x = p - y * W
    Kb = K[b]
    rays[i] = lens_rays.pixel_ray(model, Kb, dist[b], type(Kb[0, 0])(x), type(Kb[0, 0])(y))


@wp.kernel(module="unique")
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
    # _warp_frame_depth through a lens model (see lens_rays): the depth map's pixels are read
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
    tol = type(zmin)(INSIDE_TOLERANCE)
    R = lie.pose_rotation(Tb)
    t = lie.pose_translation(Tb)
    row = r * W
    src = b * C * H * W
    dst = src + py * W
    ray0 = b * ray_stride + py * W
    for x0 in range(0, W, wp.static(lens_rays.BLOCK)):
        lens_rays.warp_block(
            image, depth, rays, out, valid, K, dist, row + x0, ray0 + x0, wp.min(W - x0, wp.static(lens_rays.BLOCK)),
            b, src, dst + x0, C, H, W, padding, model, R, t, Kb, db, zmin, tol,
        )


pixel_rays = FloatKernel(_pixel_rays, K="mat33", dist="vec8", rays="vec3").set_parallel(
    segment=lambda a: a["H"] * a["W"],  # pixels of one camera
    scopes={"K": "segment", "dist": "segment"},
    grain=_GRAIN_PIXELS // 8,  # Newton's method: ~10x the work of a pixel of the warp
)
warp_frame_depth_lens = FloatKernel(
    _warp_frame_depth_lens, image="scalar", depth="scalar", pose="mat34", K="mat33", dist="vec8", rays="vec3",
    out="scalar",
).set_parallel(
    segment=lambda a: a["H"],  # rows of one batch item
    # rays shared by the batch (ray_stride 0) gather the gradients of every item: "any"
    scopes={"image": "segment", "depth": "element", "pose": "segment", "K": "segment", "dist": "segment",
            "rays": "any"},
    grain=lambda a: max(1, _GRAIN_PIXELS // max(1, a["W"])),
)
