"""The pinhole camera as torch functions (gvnn's 3D grid generator and projection layer): depth
to points, points moved by a pose, points to pixels; with a camera of :mod:`gvnn_warp.cameras` in
place of ``K``, through its lens model.

Every function takes float32 or float64 CPU tensors (all arguments of one call in the same
dtype), returns gradients for every floating argument through Warp's adjoints, validates its
arguments with a clear error, and never modifies its inputs. Conventions (pixel centres, (x, y)
order, units, minimum depth) are in ``docs/conventions.md``.
"""

from __future__ import annotations

import math

from torch import Tensor

from ..cameras.base import Camera, camera_args
from ..kernels.geometry import lens
from ..kernels.geometry.camera import MIN_DEPTH
from ..ops import geometry as _ops
from ..ops.checks import ArgCheck, flat

__all__ = ["MIN_DEPTH", "depth_to_points", "project_points", "transform_points"]


def depth_to_points(depth: Tensor, K: Tensor | Camera) -> Tensor:
    """The 3D grid generator: back-project a depth map, X = depth[y, x] * K^-1 [x, y, 1].

    Args:
        depth: (B, 1, H, W) depth (z, metres). Values pass through: a NaN depth gives a NaN point.
        K: (B, 3, 3) or (3, 3) intrinsics [[fx, s, cx], [0, fy, cy], [0, 0, 1]], or a camera
            from ``gvnn_warp.cameras``: then X = depth * (undistort(K^-1 [x, y, 1]), 1) (as
            ``unproject_points``; a pixel outside the model's domain gives depth * K^-1 [x, y, 1]
            with zero gradient). A ``PinholeCamera(K)`` gives exactly what ``K`` gives.

    Returns:
        (B, H, W, 3) points in the camera frame; x is the column, y the row, pixel centres at
        integer coordinates from 0.
    """
    chk = ArgCheck("depth_to_points")
    chk.tensor("depth", depth, "B 1 H W")
    model, Kb, dist = camera_args(chk, K)
    B, _, H, W = depth.shape
    d = depth.reshape(-1).contiguous()
    if model == lens.PINHOLE:
        return _ops.depth_to_points(d, Kb, H, W).reshape(B, H, W, 3)
    return _ops.depth_to_points_camera(d, Kb, dist, H, W, model)[0].reshape(B, H, W, 3)


def transform_points(T: Tensor, points: Tensor) -> Tensor:
    """Move points by a pose per batch item: R p + t.

    Args:
        T: (B, 3, 4) or (B, 4, 4) poses (a 4x4's last row is ignored).
        points: (B, ..., 3) points.

    Returns:
        (B, ..., 3) transformed points.
    """
    chk = ArgCheck("transform_points")
    T34 = chk.pose("T", T, "B 3|4 4")
    chk.tensor("points", points, "B ... 3")
    P = math.prod(points.shape[1:-1])
    out = _ops.transform_points(T34.contiguous(), flat(points, 1), P)
    return out.reshape(points.shape)


def project_points(points: Tensor, K: Tensor | Camera, *, min_depth: float = MIN_DEPTH) -> Tensor:
    """The pinhole projection layer: (fx X/Z + s Y/Z + cx, fy Y/Z + cy).

    Args:
        points: (B, ..., 3) points in the camera frame (metres).
        K: (B, 3, 3) or (3, 3) intrinsics; gradients flow to fx, fy, cx, cy and s (learnable
            intrinsics). Or a camera from ``gvnn_warp.cameras``: its model's projection, with
            gradients to K and every distortion coefficient; a point outside the model's domain
            gets a finite stand-in with no gradient (its ``project`` returns the valid mask). A
            ``PinholeCamera(K)`` gives exactly what ``K`` gives.
        min_depth: the smallest Z (metres) a point may have to count (see docs/conventions.md).

    Returns:
        (B, ..., 2) pixel coordinates (x, y). A point with finite Z > min_depth: its projection,
        and its gradient. A point with Z <= min_depth (behind or too close to the camera): the
        projection as if Z = min_depth, finite for finite X, Y, and no gradient (zero to the
        point and to K). A point whose Z is NaN or infinite (e.g. from a NaN depth): NaN (x, y),
        and no gradient (with a distorting camera: a finite stand-in). ``points[..., 2] >
        min_depth`` (False for NaN) marks the valid ones.
    """
    chk = ArgCheck("project_points")
    chk.tensor("points", points, "B ... 3")
    model, Kb, dist = camera_args(chk, K)
    min_depth = chk.positive("min_depth", min_depth)
    P = math.prod(points.shape[1:-1])
    if model == lens.PINHOLE:
        out = _ops.project_points(flat(points, 1), Kb, P, min_depth)
    else:
        out = _ops.project_points_camera(flat(points, 1), Kb, dist, P, min_depth, model)[0]
    return out.reshape(*points.shape[:-1], 2)
