"""Bilinear sampler and the fused 3D spatial transformer (unproject -> move -> project -> sample).

The fused kernel is the point of this package: one pass over the depth map, no (B, H, W, 3)
point or (B, H, W, 2) grid intermediates, and its adjoint (Warp's) scatters image gradients and
accumulates depth, pose and intrinsics gradients in the same pass.
"""

from typing import Any

import warp as wp

from . import camera, lie, sampler
from .launch import FloatKernel

# A projection counts as inside the image when it lies in [-tol, W - 1 + tol] x [-tol, H - 1 + tol]
# (pixel units): all four bilinear taps are then real pixels, up to rounding (so the identity pose
# keeps the last row and column valid).
INSIDE_TOLERANCE = 1.0e-3


@wp.kernel
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
    g = grid[i]
    x = sampler.normalized_to_pixel(g[0], W, align_corners)
    y = sampler.normalized_to_pixel(g[1], H, align_corners)
    xs, ys, inside = sampler.sample_position(x, y, H, W, padding)
    for c in range(C):
        v = image.dtype(0.0)
        if inside:
            v = sampler.bilinear(image, (b * C + c) * H * W, H, W, xs, ys)
        out[(b * C + c) * hw + j] = v


@wp.kernel
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
    i = wp.tid() + offset  # flat (b, y, x) of the depth map's frame
    hw = H * W
    b = i // hw
    j = i - b * hw
    py = j // W
    px = j - py * W
    d = depth[i]
    zmin = type(d)(min_depth)
    one = type(d)(1.0)
    Kb = K[b]
    # Invalid depth (<= min, NaN, inf) is replaced by 1 *before* any arithmetic, so neither the
    # values nor Warp's adjoint ever see it (wp.where routes no gradient to the unused side).
    depth_ok = d > zmin and d < type(d)(1.0e30)
    d_safe = wp.where(depth_ok, d, one)
    q = lie.transform_point(pose[b], camera.unproject(Kb, type(d)(px), type(d)(py), d_safe))
    z_ok = q[2] > zmin
    ok = depth_ok and z_ok
    q_safe = wp.where(ok, q, wp.vector(q[0], q[1], one))
    uv = camera.project(Kb, q_safe)
    xs, ys, reachable = sampler.sample_position(uv[0], uv[1], H, W, padding)
    tol = type(d)(INSIDE_TOLERANCE)
    inside = uv[0] >= -tol and uv[0] <= type(d)(W - 1) + tol and uv[1] >= -tol and uv[1] <= type(d)(H - 1) + tol
    valid[i] = ok and inside
    for c in range(C):
        v = type(d)(0.0)
        if ok and reachable:
            v = sampler.bilinear(image, (b * C + c) * hw, H, W, xs, ys)
        out[(b * C + c) * hw + j] = v


bilinear_sample = FloatKernel(_bilinear_sample, image="scalar", grid="vec2", out="scalar")
warp_frame_depth = FloatKernel(
    _warp_frame_depth, image="scalar", depth="scalar", pose="mat34", K="mat33", out="scalar"
)
