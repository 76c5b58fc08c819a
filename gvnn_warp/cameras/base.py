"""The base class of the camera models, the one entry for every op that takes intrinsics
(:func:`camera_args`), and the projections through any model (:meth:`Camera.project`,
:func:`unproject_points`).

A camera object holds references to the tensors it is given (``K`` and ``dist``), so gradients
reach them. The models, their domain (where a point counts as valid) and the unprojection's
tolerance are in ``docs/conventions.md`` ("Camera models"); the pure-Warp functions are in
``gvnn_warp.kernels.geometry.lens``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ..kernels.geometry import lens
from ..kernels.geometry.camera import MIN_DEPTH
from ..ops import geometry as _ops
from ..ops.checks import ArgCheck, flat

__all__ = ["Camera", "unproject_points"]


class Camera:
    """Base class of the camera models (use :class:`PinholeCamera`, :class:`RadTanCamera` or
    :class:`FisheyeCamera`). ``K``: (3, 3) or (B, 3, 3); ``dist``: (n,) or (B, n) or None."""

    model: int = lens.PINHOLE
    n_coeffs: int = 0

    def __init__(self, K: Tensor, dist: Tensor | None = None):
        chk = ArgCheck(type(self).__name__)
        chk.tensor("K", K, "3 3 or B 3 3")
        if self.n_coeffs:
            chk.tensor("dist", dist, f"{self.n_coeffs} or B {self.n_coeffs}")
        self.K = K
        self.dist = dist
        self._limits: tuple | None = None  # (key, (B or 1, 1) domain bounds), see _dist8

    @property
    def batch_size(self) -> int | None:
        """B if ``K`` or ``dist`` is batched, else None (one camera for every batch item)."""
        if self.K.dim() == 3:
            return self.K.shape[0]
        if self.dist is not None and self.dist.dim() == 2:
            return self.dist.shape[0]
        return None

    def __repr__(self) -> str:
        b = self.batch_size
        return f"{type(self).__name__}(dtype={self.K.dtype}" + (f", batch={b})" if b is not None else ")")

    def _dist8(self, B: int) -> Tensor:
        """The (B, 8) distortion vectors the kernels take (see ``gvnn_warp.kernels.geometry.lens``);
        differentiable in ``dist``. The domain bounds (dist[:, 5]) are recomputed only when
        ``dist`` changes."""
        if self.model == lens.PINHOLE:
            return self.K.new_zeros(B, lens.DIST_SIZE)
        coeffs = self.dist if self.dist.dim() == 2 else self.dist.unsqueeze(0)
        if torch.compiler.is_compiling():  # (an op in the graph: the bound follows the traced coefficients)
            limits = _ops.lens_domain_limit(coeffs.detach(), int(self.model))
        else:
            key = (id(self.dist), self.dist._version, tuple(coeffs.shape))
            if self._limits is None or self._limits[0] != key:
                self._limits = (key, _ops.lens_domain_limit(coeffs.detach(), int(self.model)))
            limits = self._limits[1]
        pad = coeffs.new_zeros(coeffs.shape[0], 5 - self.n_coeffs)
        tail = coeffs.new_zeros(coeffs.shape[0], 2)
        d = torch.cat([coeffs, pad, limits, tail], dim=1)
        return d.expand(B, lens.DIST_SIZE).contiguous() if d.shape[0] == 1 else d.contiguous()

    def project(self, points: Tensor, *, min_depth: float = MIN_DEPTH) -> tuple[Tensor, Tensor]:
        """Project camera-frame points to pixels.

        Args:
            points: (B, ..., 3) points (metres); B must match the camera's if it is batched.
            min_depth: a point needs Z > min_depth to count.

        Returns:
            pixels (B, ..., 2) and valid (B, ...) bool: the point is finite, has Z > min_depth and
            lies inside the model's domain. Where not valid the pixel is a finite stand-in (the
            undistorted projection with Z clamped to min_depth, non-finite coordinates as 0)
            with zero gradient.
        """
        chk = ArgCheck(f"{type(self).__name__}.project")
        chk.tensor("points", points, "B ... 3")
        model, Kb, dist = camera_args(chk, self, "camera")
        min_depth = chk.positive("min_depth", min_depth)
        P = math.prod(points.shape[1:-1])
        pixels, valid = _ops.project_points_camera(flat(points, 1), Kb, dist, P, min_depth, model)
        return pixels.reshape(*points.shape[:-1], 2), valid.reshape(points.shape[:-1])

    def unproject(self, pixels: Tensor, depth: Tensor) -> Tensor:
        """Back-project pixels of this camera's image at the given depths (see
        :func:`unproject_points`, which this calls)."""
        return _unproject(ArgCheck(f"{type(self).__name__}.unproject"), pixels, depth, self)


def camera_args(chk: ArgCheck, K, name: str = "K") -> tuple[int, Tensor, Tensor]:
    """The one entry for ops that take intrinsics: ``K`` is a (3, 3) / (B, 3, 3) tensor or a
    :class:`Camera`. Returns (model id, K (B, 3, 3) contiguous, dist (B, 8) contiguous), B bound
    by the call's earlier arguments (``chk.dim("B")``; 1 if none bound it and K is not batched).
    Errors name the function and ``name``."""
    if isinstance(K, Camera):
        chk.tensor(f"{name}.K", K.K, "3 3 or B 3 3")
        if K.n_coeffs:
            chk.tensor(f"{name}.dist", K.dist, f"{K.n_coeffs} or B {K.n_coeffs}")
        B = chk.dims["B"][0] if "B" in chk.dims else (K.batch_size or 1)
        Kt = K.K
        dist = K._dist8(B)
        model = K.model
    elif isinstance(K, torch.Tensor):
        chk.tensor(name, K, "3 3 or B 3 3")
        B = chk.dims["B"][0] if "B" in chk.dims else 1
        Kt = K
        dist = K.new_zeros(B, lens.DIST_SIZE)
        model = lens.PINHOLE
    else:
        chk.fail(
            TypeError,
            f"argument '{name}' must be a (3, 3) or (B, 3, 3) torch.Tensor or a camera from gvnn_warp.cameras "
            f"(PinholeCamera, RadTanCamera, FisheyeCamera), got {type(K).__name__}",
        )
    Kb = (Kt.expand(B, 3, 3) if Kt.dim() == 2 else Kt).contiguous()
    return model, Kb, dist


def _unproject(chk: ArgCheck, pixels: Tensor, depth: Tensor, camera) -> Tensor:
    chk.tensor("pixels", pixels, "B ... 2")
    chk.tensor("depth", depth, "B ...")
    if tuple(depth.shape) != tuple(pixels.shape[:-1]):
        chk.fail(
            ValueError, f"argument 'depth' must have shape {tuple(pixels.shape[:-1])} (pixels' without the last "
            f"dimension), got {tuple(depth.shape)}",
        )
    model, Kb, dist = camera_args(chk, camera, "camera")
    P = math.prod(pixels.shape[1:-1])
    points, _ = _ops.unproject_points(flat(pixels, 1), depth.reshape(-1).contiguous(), Kb, dist, P, model)
    return points.reshape(*pixels.shape[:-1], 3)


def unproject_points(pixels: Tensor, depth: Tensor, camera: Camera | Tensor) -> Tensor:
    """Back-project pixels: the camera-frame point at Z = depth seen at each pixel.

    Args:
        pixels: (B, ..., 2) pixel positions (x, y) in the camera's (distorted) image.
        depth: (B, ...) depths (Z, metres), passed through (a NaN depth gives a NaN point).
        camera: a camera from this module, or a K tensor (3, 3) / (B, 3, 3) (pinhole).

    Returns:
        (B, ..., 3) points depth * (undistort(K^-1 [x, y, 1]), 1). The distortion is inverted by
        Newton's method to a residual below 1e-10 (normalized units) and the gradient is the
        implicit-function one through the solution (docs/conventions.md). A pixel outside the
        model's domain (no undistorted point within it, or the solve does not converge) gives
        depth * K^-1 [x, y, 1] with zero gradient; :func:`undistort_points` reports which.
    """
    return _unproject(ArgCheck("unproject_points"), pixels, depth, camera)
