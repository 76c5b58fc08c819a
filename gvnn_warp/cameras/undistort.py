"""Pixels and images between a distorted camera and its ideal pinhole (the same ``K``, no
distortion): :func:`distort_points`, :func:`undistort_points`, :func:`undistort_image`."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ..ops import geometry as _ops
from ..ops import sampling as _sampling_ops
from ..ops.checks import ArgCheck, flat
from .base import Camera, camera_args

__all__ = ["distort_points", "undistort_image", "undistort_points"]


def _camera_object_args(chk: ArgCheck, camera) -> tuple[int, Tensor, Tensor]:
    """:func:`camera_args` for functions whose ``camera`` must be a camera object (a bare K has no
    distortion to apply or undo)."""
    if not isinstance(camera, Camera):
        chk.fail(
            TypeError,
            "argument 'camera' must be a camera from gvnn_warp.cameras (PinholeCamera, RadTanCamera, "
            f"FisheyeCamera), got {type(camera).__name__}",
        )
    return camera_args(chk, camera, "camera")


def _pixels_op(fn: str, op, pixels: Tensor, camera) -> tuple[Tensor, Tensor]:
    chk = ArgCheck(fn)
    chk.tensor("pixels", pixels, "B ... 2")
    model, Kb, dist = _camera_object_args(chk, camera)
    P = math.prod(pixels.shape[1:-1])
    out, valid = op(flat(pixels, 1), Kb, dist, P, model)
    return out.reshape(pixels.shape), valid.reshape(pixels.shape[:-1])


def distort_points(pixels: Tensor, camera: Camera) -> tuple[Tensor, Tensor]:
    """Pixels of the ideal pinhole image (intrinsics ``camera.K``, no distortion) -> where the
    same rays land in the camera's distorted image: K distort(K^-1 [x, y, 1]).

    Args:
        pixels: (B, ..., 2) ideal-image pixel positions (x, y).
        camera: a camera from this module.

    Returns:
        pixels (B, ..., 2) in the distorted image, and valid (B, ...) bool: the ray lies inside
        the model's domain. Where not valid the input pixel is returned (a non-finite one as a
        finite stand-in) with zero gradient. Gradients flow to pixels, K and every coefficient.
    """
    return _pixels_op("distort_points", _ops.distort_points, pixels, camera)


def undistort_points(pixels: Tensor, camera: Camera) -> tuple[Tensor, Tensor]:
    """Pixels of the camera's distorted image -> the ideal pinhole image's (intrinsics
    ``camera.K``): K undistort(K^-1 [x, y, 1]), the inverse of :func:`distort_points`. Matches
    ``cv2.undistortPoints(pixels, K, dist, P=K)`` (``cv2.fisheye.undistortPoints`` for the fisheye).

    Args:
        pixels: (B, ..., 2) distorted-image pixel positions (x, y).
        camera: a camera from this module.

    Returns:
        pixels (B, ..., 2) in the ideal image, and valid (B, ...) bool: Newton's method converged
        (residual below 1e-10 in normalized units) to a point inside the model's domain. Where
        not valid the input pixel is returned (a non-finite one as a finite stand-in) with zero
        gradient.
        Gradients are the implicit-function ones through the solution (not through the
        iterations), for pixels, K and every coefficient.
    """
    return _pixels_op("undistort_points", _ops.undistort_points, pixels, camera)


def undistort_image(image: Tensor, camera: Camera) -> tuple[Tensor, Tensor]:
    """Resample a distorted image into the ideal pinhole image of the same size and intrinsics
    ``camera.K``: out[y, x] = image sampled bilinearly at :func:`distort_points` ((x, y)).

    Args:
        image: (B, C, H, W) image taken by ``camera``.
        camera: a camera from this module.

    Returns:
        image (B, C, H, W) and valid (B, 1, H, W) bool: the ray is inside the model's domain and
        lands within the distorted image's pixel-centre rectangle [0, W-1] x [0, H-1] (all four
        bilinear taps are pixels). Elsewhere the zero-padded sample (0 where the ray is outside
        the domain). Gradients flow to the image, K and every coefficient.
    """
    chk = ArgCheck("undistort_image")
    chk.tensor("image", image, "B C H W")
    model, Kb, dist = _camera_object_args(chk, camera)
    B, C, H, W = image.shape
    if H < 2 or W < 2:
        chk.fail(ValueError, f"argument 'image' must be at least 2 x 2 pixels, got {tuple(image.shape)}")
    ys, xs = torch.meshgrid(
        torch.arange(H, dtype=image.dtype), torch.arange(W, dtype=image.dtype), indexing="ij"
    )
    ideal = torch.stack([xs, ys], dim=-1).reshape(1, H * W, 2).expand(B, H * W, 2).reshape(-1, 2).contiguous()
    src, ok = _ops.distort_points(ideal, Kb, dist, H * W, model)
    # align_corners=True normalisation: x = (gx + 1) / 2 (W - 1); a ray outside the domain reads 0
    scale = torch.tensor([2.0 / (W - 1), 2.0 / (H - 1)], dtype=image.dtype)
    grid = torch.where(ok.unsqueeze(-1), src * scale - 1.0, src.new_full((), 2.0)).contiguous()
    out = _sampling_ops.bilinear_sample(image.contiguous(), grid, C, H, W, H * W, 1, 0).reshape(B, C, H, W)
    tol = 1e-3
    inside = (src[:, 0] >= -tol) & (src[:, 0] <= W - 1 + tol) & (src[:, 1] >= -tol) & (src[:, 1] <= H - 1 + tol)
    return out, (ok & inside).reshape(B, 1, H, W)
