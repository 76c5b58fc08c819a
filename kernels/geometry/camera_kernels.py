"""Thin per-element kernels for the 3D grid generator, rigid transform and projection layers."""

from typing import Any

import warp as wp

from ..core.kinds import FloatKernel
from . import camera, lie


@wp.kernel
def _depth_to_points(
    offset: int,
    depth: wp.array(dtype=Any),
    K: wp.array(dtype=Any),
    H: int,
    W: int,
    points: wp.array(dtype=Any),
):
    i = wp.tid() + offset  # flat (b, y, x)
    b = i // (H * W)
    r = i - b * (H * W)
    y = r // W
    x = r - y * W
    d = depth[i]
    points[i] = camera.unproject(K[b], type(d)(x), type(d)(y), d)


@wp.kernel
def _transform_points(
    offset: int, T: wp.array(dtype=Any), points: wp.array(dtype=Any), P: int, out: wp.array(dtype=Any)
):
    i = wp.tid() + offset  # flat (b, point)
    out[i] = lie.transform_point(T[i // P], points[i])


@wp.kernel
def _project_points(
    offset: int,
    points: wp.array(dtype=Any),
    K: wp.array(dtype=Any),
    P: int,
    min_depth: float,
    pixels: wp.array(dtype=Any),
):
    i = wp.tid() + offset  # flat (b, point)
    p = points[i]
    pixels[i] = camera.project_point(K[i // P], p, type(p[0])(min_depth))


# Adjoint scopes (see :meth:`.launch.FloatKernel.set_parallel`): per-point inputs are written back
# only at the element's own point; a batch item's K or T gathers the gradients of all its points
# ("any": cut into fixed pieces with partial buffers. They are also "segment" with segments of P
# or H*W points; declaring so would split batches more freely, but would change the rounding of
# large launches with several batch items, which this refactor keeps bitwise as it was).
depth_to_points = FloatKernel(_depth_to_points, depth="scalar", K="mat33", points="vec3").set_parallel(
    scopes={"depth": "element", "K": "any"}
)
transform_points = FloatKernel(_transform_points, T="mat34", points="vec3", out="vec3").set_parallel(
    scopes={"T": "any", "points": "element"}
)
project_points = FloatKernel(_project_points, points="vec3", K="mat33", pixels="vec2").set_parallel(
    scopes={"points": "element", "K": "any"}
)
