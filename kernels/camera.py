"""Pinhole camera building blocks as generic ``@wp.func`` (no launches here).

K is read as ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` (``s`` the skew, usually 0); its lower
row is never read. Pixels are (x, y) = (column, row) with pixel centres at integer coordinates
starting from 0 (see ``docs/conventions.md``).
"""

from typing import Any

import warp as wp

# Points (and depths) must have z above this many metres to be projected / used; below it a
# warp marks the pixel invalid. The paper notes gradients of the projection degrade as z -> 0.
MIN_DEPTH = 1.0e-3


@wp.func
def pixel_ray(K: Any, x: Any, y: Any):
    """K^-1 [x, y, 1]: the ray through pixel (x, y), scaled to z = 1."""
    ry = (y - K[1, 2]) / K[1, 1]
    rx = (x - K[0, 2] - K[0, 1] * ry) / K[0, 0]
    return wp.vector(rx, ry, type(x)(1.0))


@wp.func
def unproject(K: Any, x: Any, y: Any, depth: Any):
    """The 3D point at z = depth seen at pixel (x, y): depth * K^-1 [x, y, 1]."""
    return pixel_ray(K, x, y) * depth


@wp.func
def project(K: Any, p: Any):
    """Pinhole projection (fx X/Z + s Y/Z + cx, fy Y/Z + cy). The caller guarantees Z > 0."""
    inv_z = type(p[2])(1.0) / p[2]
    xn = p[0] * inv_z
    yn = p[1] * inv_z
    return wp.vector(K[0, 0] * xn + K[0, 1] * yn + K[0, 2], K[1, 1] * yn + K[1, 2])


@wp.func
def project_clamped(K: Any, p: Any, min_depth: Any):
    """project() with Z replaced by min_depth where Z <= min_depth (or is NaN): always finite."""
    z = wp.where(p[2] > min_depth, p[2], min_depth)
    return project(K, wp.vector(p[0], p[1], z))
