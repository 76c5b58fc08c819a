"""Camera models: pinhole, radial-tangential (OpenCV) and fisheye (cv2.fisheye), differentiable in
all their parameters, and the functions that move pixels and images between a distorted camera
and its ideal pinhole.

A camera object holds references to the tensors it is given (``K`` and ``dist``), so gradients
reach them. Every op of gvnn_warp that takes ``K`` also takes a camera object in its place. The
models, their domain (where a point counts as valid) and the unprojection's tolerance are in
``docs/conventions.md`` ("Camera models"); the pure-Warp functions are in
``gvnn_warp.kernels.lens``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ..kernels.geometry import lens
from ..kernels.geometry.camera import MIN_DEPTH
from ..ops import geometry as _ops
from ..ops.checks import ArgCheck


def lens_ops():
    """:mod:`gvnn_warp._lens_ops`, the ops through lens models, imported (and so registered) on
    first use: its kernels cost ~1.5-3 s to define, which pinhole users should not pay."""
    from ..ops import lens as _lens_ops

    return _lens_ops


__all__ = [
    "Camera",
    "FisheyeCamera",
    "PinholeCamera",
    "RadTanCamera",
    "distort_points",
    "undistort_image",
    "undistort_points",
    "unproject_points",
]


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
        """The (B, 8) distortion vectors the kernels take (see ``gvnn_warp.kernels.lens``);
        differentiable in ``dist``. The domain bounds (dist[:, 5]) are recomputed only when
        ``dist`` changes."""
        if self.model == lens.PINHOLE:
            return self.K.new_zeros(B, lens.DIST_SIZE)
        coeffs = self.dist if self.dist.dim() == 2 else self.dist.unsqueeze(0)
        key = (id(self.dist), self.dist._version, tuple(coeffs.shape))
        if self._limits is None or self._limits[0] != key:
            rows = coeffs.detach().to(torch.float64).numpy()
            padded = [list(r) + [0.0] * (5 - len(r)) for r in rows]
            lim = [lens.domain_limit(self.model, p if self.model == lens.RADTAN else r) for p, r in zip(padded, rows)]
            self._limits = (key, torch.tensor(lim, dtype=coeffs.dtype).unsqueeze(1))
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
        return _project(ArgCheck(f"{type(self).__name__}.project"), points, self, min_depth)

    def unproject(self, pixels: Tensor, depth: Tensor) -> Tensor:
        """Back-project pixels of this camera's image at the given depths (see
        :func:`unproject_points`, which this calls)."""
        return _unproject(ArgCheck(f"{type(self).__name__}.unproject"), pixels, depth, self)[0]


class PinholeCamera(Camera):
    """The ideal pinhole: ``PinholeCamera(K)``, K (3, 3) or (B, 3, 3). Every op gives exactly
    (bitwise) what it gives for the tensor ``K`` itself."""

    model = lens.PINHOLE
    n_coeffs = 0

    def __init__(self, K: Tensor):
        super().__init__(K, None)


class RadTanCamera(Camera):
    """OpenCV's radial-tangential model: ``RadTanCamera(K, dist)``, K (3, 3) or (B, 3, 3), dist
    (5,) or (B, 5) = (k1, k2, p1, p2, k3) as ``cv2.projectPoints`` takes them."""

    model = lens.RADTAN
    n_coeffs = 5

    def __init__(self, K: Tensor, dist: Tensor):
        super().__init__(K, dist)


class FisheyeCamera(Camera):
    """The equidistant (Kannala-Brandt) fisheye of ``cv2.fisheye``: ``FisheyeCamera(K, dist)``,
    K (3, 3) or (B, 3, 3) (cv2.fisheye's skew alpha is K[0, 1] / K[0, 0]), dist (4,) or (B, 4) =
    (k1, k2, k3, k4)."""

    model = lens.FISHEYE
    n_coeffs = 4

    def __init__(self, K: Tensor, dist: Tensor):
        super().__init__(K, dist)


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
        chk._fail(
            TypeError,
            f"argument '{name}' must be a (3, 3) or (B, 3, 3) torch.Tensor or a camera from gvnn_warp.cameras "
            f"(PinholeCamera, RadTanCamera, FisheyeCamera), got {type(K).__name__}",
        )
    Kb = (Kt.expand(B, 3, 3) if Kt.dim() == 2 else Kt).contiguous()
    return model, Kb, dist


def _flat(t: Tensor, inner: int) -> Tensor:
    return t.reshape(-1, *t.shape[t.dim() - inner :]).contiguous()


def _project(chk: ArgCheck, points: Tensor, camera, min_depth: float) -> tuple[Tensor, Tensor]:
    """project through any model (pixels, valid); the shared body of Camera.project and
    project_points(points, camera)."""
    chk.tensor("points", points, "B ... 3")
    model, Kb, dist = camera_args(chk, camera, "camera")
    min_depth = chk.positive("min_depth", min_depth)
    P = math.prod(points.shape[1:-1])
    pixels, valid = lens_ops().project_points_camera(_flat(points, 1), Kb, dist, P, min_depth, model)
    return pixels.reshape(*points.shape[:-1], 2), valid.reshape(points.shape[:-1])


def _unproject(chk: ArgCheck, pixels: Tensor, depth: Tensor, camera) -> tuple[Tensor, Tensor]:
    chk.tensor("pixels", pixels, "B ... 2")
    chk.tensor("depth", depth, "B ...")
    if tuple(depth.shape) != tuple(pixels.shape[:-1]):
        chk._fail(
            ValueError, f"argument 'depth' must have shape {tuple(pixels.shape[:-1])} (pixels' without the last "
            f"dimension), got {tuple(depth.shape)}",
        )
    model, Kb, dist = camera_args(chk, camera, "camera")
    P = math.prod(pixels.shape[1:-1])
    points, valid = lens_ops().unproject_points(_flat(pixels, 1), depth.reshape(-1).contiguous(), Kb, dist, P, model)
    return points.reshape(*pixels.shape[:-1], 3), valid.reshape(pixels.shape[:-1])


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
    return _unproject(ArgCheck("unproject_points"), pixels, depth, camera)[0]


def _camera_object_args(chk: ArgCheck, camera) -> tuple[int, Tensor, Tensor]:
    """:func:`camera_args` for functions whose ``camera`` must be a camera object (a bare K has no
    distortion to apply or undo)."""
    if not isinstance(camera, Camera):
        chk._fail(
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
    out, valid = op(_flat(pixels, 1), Kb, dist, P, model)
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
    return _pixels_op("distort_points", lens_ops().distort_points, pixels, camera)


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
    return _pixels_op("undistort_points", lens_ops().undistort_points, pixels, camera)


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
        chk._fail(ValueError, f"argument 'image' must be at least 2 x 2 pixels, got {tuple(image.shape)}")
    ys, xs = torch.meshgrid(
        torch.arange(H, dtype=image.dtype), torch.arange(W, dtype=image.dtype), indexing="ij"
    )
    ideal = torch.stack([xs, ys], dim=-1).reshape(1, H * W, 2).expand(B, H * W, 2).reshape(-1, 2).contiguous()
    src, ok = lens_ops().distort_points(ideal, Kb, dist, H * W, model)
    # align_corners=True normalisation: x = (gx + 1) / 2 (W - 1); a ray outside the domain reads 0
    scale = torch.tensor([2.0 / (W - 1), 2.0 / (H - 1)], dtype=image.dtype)
    grid = torch.where(ok.unsqueeze(-1), src * scale - 1.0, src.new_full((), 2.0)).contiguous()
    out = _ops.bilinear_sample(image.contiguous(), grid, C, H, W, H * W, 1, 0).reshape(B, C, H, W)
    tol = 1e-3
    inside = (src[:, 0] >= -tol) & (src[:, 0] <= W - 1 + tol) & (src[:, 1] >= -tol) & (src[:, 1] <= H - 1 + tol)
    return out, (ok & inside).reshape(B, 1, H, W)
