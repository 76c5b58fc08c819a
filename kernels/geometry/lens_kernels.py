"""Thin per-element kernels over :mod:`.lens`: projection, back-projection, distortion of pixels.

Each takes the camera as ``K`` (mat33 per batch item), ``dist`` (vec8 per batch item, the layout
of :mod:`.lens`) and ``model`` (an int, the same for the whole launch).
"""

from typing import Any

import warp as wp

from ..core.kinds import FloatKernel
from . import lens


@wp.kernel
def _project_points(
    offset: int,
    points: wp.array(dtype=Any),
    K: wp.array(dtype=Any),
    dist: wp.array(dtype=Any),
    P: int,
    min_depth: float,
    model: int,
    pixels: wp.array(dtype=Any),
    valid: wp.array(dtype=bool),
):
    i = wp.tid() + offset  # flat (b, point)
    b = i // P
    p = points[i]
    uv, ok = lens.project(model, K[b], dist[b], p, type(p[0])(min_depth))
    pixels[i] = uv
    valid[i] = ok


@wp.kernel
def _depth_to_points(
    offset: int,
    depth: wp.array(dtype=Any),
    K: wp.array(dtype=Any),
    dist: wp.array(dtype=Any),
    H: int,
    W: int,
    model: int,
    points: wp.array(dtype=Any),
    valid: wp.array(dtype=bool),
):
    i = wp.tid() + offset  # flat (b, y, x)
    b = i // (H * W)
    r = i - b * (H * W)
    y = r // W
    x = r - y * W
    d = depth[i]
    p, ok = lens.unproject(model, K[b], dist[b], type(d)(x), type(d)(y), d)
    points[i] = p
    valid[i] = ok


@wp.kernel
def _unproject_points(
    offset: int,
    pixels: wp.array(dtype=Any),
    depth: wp.array(dtype=Any),
    K: wp.array(dtype=Any),
    dist: wp.array(dtype=Any),
    P: int,
    model: int,
    points: wp.array(dtype=Any),
    valid: wp.array(dtype=bool),
):
    i = wp.tid() + offset  # flat (b, point)
    b = i // P
    uv = pixels[i]
    p, ok = lens.unproject(model, K[b], dist[b], uv[0], uv[1], depth[i])
    points[i] = p
    valid[i] = ok


@wp.kernel
def _distort_pixels(
    offset: int,
    pixels: wp.array(dtype=Any),
    K: wp.array(dtype=Any),
    dist: wp.array(dtype=Any),
    P: int,
    model: int,
    out: wp.array(dtype=Any),
    valid: wp.array(dtype=bool),
):
    i = wp.tid() + offset  # flat (b, point): ideal pixel -> distorted-image pixel
    b = i // P
    uv, ok = lens.distort_pixel(model, K[b], dist[b], pixels[i])
    out[i] = uv
    valid[i] = ok


@wp.kernel
def _undistort_pixels(
    offset: int,
    pixels: wp.array(dtype=Any),
    K: wp.array(dtype=Any),
    dist: wp.array(dtype=Any),
    P: int,
    model: int,
    out: wp.array(dtype=Any),
    valid: wp.array(dtype=bool),
):
    i = wp.tid() + offset  # flat (b, point): distorted-image pixel -> ideal pixel
    b = i // P
    uv, ok = lens.undistort_pixel(model, K[b], dist[b], pixels[i])
    out[i] = uv
    valid[i] = ok


# Adjoint scopes: per-point inputs are written back only at the element's own point; a batch item's
# K and dist gather the gradients of all its points ("any", as in camera_kernels).
project_points = FloatKernel(
    _project_points, points="vec3", K="mat33", dist="vec8", pixels="vec2", valid="bool"
).set_parallel(scopes={"points": "element", "K": "any", "dist": "any"})
depth_to_points = FloatKernel(
    _depth_to_points, depth="scalar", K="mat33", dist="vec8", points="vec3", valid="bool"
).set_parallel(scopes={"depth": "element", "K": "any", "dist": "any"})
unproject_points = FloatKernel(
    _unproject_points, pixels="vec2", depth="scalar", K="mat33", dist="vec8", points="vec3", valid="bool"
).set_parallel(scopes={"pixels": "element", "depth": "element", "K": "any", "dist": "any"})
distort_pixels = FloatKernel(
    _distort_pixels, pixels="vec2", K="mat33", dist="vec8", out="vec2", valid="bool"
).set_parallel(scopes={"pixels": "element", "K": "any", "dist": "any"})
undistort_pixels = FloatKernel(
    _undistort_pixels, pixels="vec2", K="mat33", dist="vec8", out="vec2", valid="bool"
).set_parallel(scopes={"pixels": "element", "K": "any", "dist": "any"})
