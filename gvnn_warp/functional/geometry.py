"""The functional torch API of gvnn_warp: global transformations and the 3D spatial transformer.

Every function takes float32 or float64 CPU tensors (all arguments of one call in the same
dtype), returns gradients for every floating argument through Warp's adjoints, validates its
arguments with a clear error, and never modifies its inputs. Conventions (pixel centres, (x, y)
order, ``[omega, t]`` order, quaternion order, units, valid masks) are in ``docs/conventions.md``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ..cameras.models import Camera, camera_args, lens_ops
from ..kernels.geometry import lens
from ..kernels.geometry.camera import MIN_DEPTH
from ..kernels.sampling import kernels as sampling_kernels
from ..kernels.sampling.sampler import PADDING_MODES as _PADDING
from ..ops import geometry as _ops
from ..ops.checks import ArgCheck

__all__ = [
    "MIN_DEPTH",
    "bilinear_sample",
    "depth_to_points",
    "euler_to_matrix",
    "project_points",
    "quaternion_to_matrix",
    "se3_exp",
    "se3_log",
    "se3_to_matrix",
    "sim3_to_matrix",
    "so3_exp",
    "so3_log",
    "transform_points",
    "warp_frame_depth",
]

_AXES = {"X": 0, "Y": 1, "Z": 2}
EULER_CONVENTIONS = tuple(
    a + b + c for a in "XYZ" for b in "XYZ" for c in "XYZ" if a != b and b != c
)  # 6 Tait-Bryan ("XYZ", ...) and 6 proper Euler ("ZYZ", ...) orders


def _flat(t: Tensor, inner: int) -> Tensor:
    """(..., *inner dims) -> contiguous (n, *inner dims)."""
    return t.reshape(-1, *t.shape[t.dim() - inner :]).contiguous()


def _pose34(chk: ArgCheck, name: str, T: Tensor, spec: str) -> Tensor:
    """Accept a (..., 3, 4) or (..., 4, 4) pose; return its top 3x4 block (last row ignored)."""
    chk.tensor(name, T, spec)
    return T[..., :3, :]


def _intrinsics(chk: ArgCheck, K: Tensor) -> Tensor:
    """Accept K as (3, 3) (shared) or (B, 3, 3); return a contiguous (B, 3, 3)."""
    chk.tensor("K", K, "3 3 or B 3 3")
    return (K.expand(chk.dim("B"), 3, 3) if K.dim() == 2 else K).contiguous()


class _Lens:
    """A camera as the fused kernels take it: ``model`` id, ``K`` (B, 3, 3), ``dist`` (B, 8) (see
    ``gvnn_warp.kernels.lens``), and the camera's own ``K_cam`` (Bc, 3, 3), ``dist_cam`` (Bc, 8),
    Bc = 1 when one camera serves the whole batch (its rays are then computed once)."""

    def __init__(self, chk: ArgCheck, camera):
        if isinstance(camera, Tensor):  # the pinhole K: nothing else to make (the calls stay as cheap)
            self.model, self.K, self.dist, self.K_cam, self.dist_cam = 0, _intrinsics(chk, camera), None, None, None
            return
        self.model, self.K, self.dist = camera_args(chk, camera)
        shared = not isinstance(camera, Camera) or camera.batch_size is None
        self.K_cam = self.K[:1] if shared else self.K
        self.dist_cam = self.dist[:1] if shared else self.dist

    def detached(self) -> _Lens:
        """The same camera with its tensors detached (for ops that are not differentiable)."""
        out = object.__new__(_Lens)
        out.model = self.model
        out.K, out.dist, out.K_cam, out.dist_cam = (t.detach() for t in (self.K, self.dist, self.K_cam, self.dist_cam))
        return out


_RAYS_CACHE: dict = {}  # (model, dtype, H, W, K bytes, dist bytes) -> rays, for cameras without gradients
_RAYS_CACHE_SIZE = 8


def _rays(cam: _Lens, H: int, W: int) -> tuple[Tensor, int]:
    """The undistorted rays of an H x W image's pixels (kernels.lens_rays) and the ray stride of
    the fused kernels (H * W per batch item, or 0: one camera shared by the batch). Cached by value
    for cameras whose K and dist need no gradient (the common, fixed camera): Newton's method then
    runs once per camera and image size."""
    Kc, dc = cam.K_cam, cam.dist_cam
    stride = 0 if Kc.shape[0] == 1 else H * W
    if Kc.requires_grad or dc.requires_grad or torch.compiler.is_compiling():
        return lens_ops().pixel_rays(Kc, dc, H, W, cam.model), stride
    key = (cam.model, Kc.dtype, H, W, Kc.numpy().tobytes(), dc.numpy().tobytes())
    rays = _RAYS_CACHE.pop(key, None)
    if rays is None:
        rays = lens_ops().pixel_rays(Kc, dc, H, W, cam.model)
        if len(_RAYS_CACHE) >= _RAYS_CACHE_SIZE:
            _RAYS_CACHE.pop(next(iter(_RAYS_CACHE)))
    _RAYS_CACHE[key] = rays
    return rays, stride


# ----------------------------------------------------------------------------- rotations


def so3_exp(omega: Tensor) -> Tensor:
    """Exponential map so(3) -> SO(3) (Rodrigues' formula), the paper's SO3 layer.

    Args:
        omega: (..., 3) rotation vectors, axis * angle in radians.

    Returns:
        (..., 3, 3) rotation matrices. Exact values and finite, exact gradients at omega = 0
        (Taylor branch below |omega| = 1e-2) and for every angle, including near and beyond pi.
    """
    ArgCheck("so3_exp").tensor("omega", omega, "... 3")
    return _ops.so3_exp(_flat(omega, 1)).reshape(*omega.shape[:-1], 3, 3)


def so3_log(R: Tensor) -> Tensor:
    """Logarithm SO(3) -> so(3), the inverse of :func:`so3_exp` (angle in [0, pi]).

    Args:
        R: (..., 3, 3) rotation matrices. A matrix that is not one (|R^T R - I|_F > 1e-5 or
            det R <= 0: scaled, sheared, a reflection, 0) stands for its nearest rotation in the
            Frobenius norm (U V^T from the SVD, the last singular value signed); where several
            are equally near (an orthogonal reflection) one of them, for 0 the identity. Finite
            values and gradients for every finite R; the gradient is that of the nearest
            rotation's log (its terms are left out where the nearest rotation is not unique).
            Matrices within 1e-5 of a rotation are used as they are (no projection, no cost).

    Returns:
        (..., 3) rotation vectors. Stable near 0 (series) and near pi (axis from the symmetric
        part); at exactly pi the sign of the axis is the one for which the antisymmetric part
        of R is non-negative along it (either is a valid logarithm).
    """
    ArgCheck("so3_log").tensor("R", R, "... 3 3")
    return _ops.so3_log(_flat(R, 2)).reshape(*R.shape[:-2], 3)


def quaternion_to_matrix(q: Tensor) -> Tensor:
    """Quaternion -> rotation matrix.

    Args:
        q: (..., 4) quaternions in (w, x, y, z) order, of any norm with |q|^2 in (1e-30, dtype
            max) (normalised inside; the gradient is that of q / |q|). Below that (a zero
            quaternion) the identity, with zero gradient.

    Returns:
        (..., 3, 3) rotation matrices.
    """
    ArgCheck("quaternion_to_matrix").tensor("q", q, "... 4")
    return _ops.quaternion_to_matrix(_flat(q, 1)).reshape(*q.shape[:-1], 3, 3)


def euler_to_matrix(angles: Tensor, convention: str = "XYZ") -> Tensor:
    """Euler angles -> rotation matrix, R = R_c0(a0) @ R_c1(a1) @ R_c2(a2) for convention "c0c1c2".

    Args:
        angles: (..., 3) angles in radians, in the order of ``convention``.
        convention: three axes from "X", "Y", "Z", no two consecutive equal: the six
            Tait-Bryan orders ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX") and the six proper
            Euler orders ("XYX", ..., "ZYZ"). R_X, R_Y, R_Z are right-handed rotations about
            the fixed axes, e.g. R_Z(a) = [[cos a, -sin a, 0], [sin a, cos a, 0], [0, 0, 1]].

    Returns:
        (..., 3, 3) rotation matrices.
    """
    chk = ArgCheck("euler_to_matrix")
    chk.tensor("angles", angles, "... 3")
    chk.option("convention", convention, EULER_CONVENTIONS)
    a0, a1, a2 = (_AXES[c] for c in convention)
    return _ops.euler_to_matrix(_flat(angles, 1), a0, a1, a2).reshape(*angles.shape[:-1], 3, 3)


# ----------------------------------------------------------------------------- rigid motions


def se3_to_matrix(xi: Tensor) -> Tensor:
    """The paper's SE3 layer: xi = [omega, t] -> [so3_exp(omega) | t].

    Note t is used as is (not V(omega) t as in the Lie exponential, :func:`se3_exp`), and not
    gvnn's original [R | R t].

    Args:
        xi: (..., 6) with omega = xi[..., :3] (radians) and t = xi[..., 3:] (metres).

    Returns:
        (..., 3, 4) poses acting on points as p -> R p + t.
    """
    ArgCheck("se3_to_matrix").tensor("xi", xi, "... 6")
    x = _flat(xi, 1)
    return _ops.se3_to_matrix(x[:, :3].contiguous(), x[:, 3:].contiguous()).reshape(*xi.shape[:-1], 3, 4)


def sim3_to_matrix(xi: Tensor) -> Tensor:
    """The Sim3 layer: xi = [omega, t, sigma] -> [exp(sigma) so3_exp(omega) | t].

    Args:
        xi: (..., 7): omega = xi[..., :3], t = xi[..., 3:6], log-scale sigma = xi[..., 6].

    Returns:
        (..., 3, 4) similarity transforms p -> s R p + t with s = exp(sigma).
    """
    ArgCheck("sim3_to_matrix").tensor("xi", xi, "... 7")
    x = _flat(xi, 1)
    T = _ops.sim3_to_matrix(x[:, :3].contiguous(), x[:, 3:6].contiguous(), x[:, 6].contiguous())
    return T.reshape(*xi.shape[:-1], 3, 4)


def se3_exp(xi: Tensor) -> Tensor:
    """The SE(3) Lie-group exponential: xi = [omega, u] -> [so3_exp(omega) | V(omega) u].

    Args:
        xi: (..., 6) twists, omega = xi[..., :3], u = xi[..., 3:].

    Returns:
        (..., 3, 4) poses. V(omega) = I + B [omega]x + C [omega]x^2 (series near 0).
    """
    ArgCheck("se3_exp").tensor("xi", xi, "... 6")
    x = _flat(xi, 1)
    return _ops.se3_exp(x[:, :3].contiguous(), x[:, 3:].contiguous()).reshape(*xi.shape[:-1], 3, 4)


def se3_log(T: Tensor) -> Tensor:
    """The SE(3) Lie-group logarithm, inverse of :func:`se3_exp`.

    Args:
        T: (..., 3, 4) or (..., 4, 4) poses (a 4x4's last row is ignored). A rotation block
            that is not a rotation is replaced by its nearest rotation, as in :func:`so3_log`.

    Returns:
        (..., 6) twists [omega, u] with |omega| in [0, pi] and u = V(omega)^-1 t.
    """
    T34 = _pose34(ArgCheck("se3_log"), "T", T, "... 3|4 4")
    omega, u = _ops.se3_log(_flat(T34, 2))
    return torch.cat([omega, u], dim=-1).reshape(*T.shape[:-2], 6)


# ----------------------------------------------------------------------------- camera layers


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
    flat = depth.reshape(-1).contiguous()
    if model == lens.PINHOLE:
        return _ops.depth_to_points(flat, Kb, H, W).reshape(B, H, W, 3)
    return lens_ops().depth_to_points_camera(flat, Kb, dist, H, W, model)[0].reshape(B, H, W, 3)


def transform_points(T: Tensor, points: Tensor) -> Tensor:
    """Move points by a pose per batch item: R p + t.

    Args:
        T: (B, 3, 4) or (B, 4, 4) poses (a 4x4's last row is ignored).
        points: (B, ..., 3) points.

    Returns:
        (B, ..., 3) transformed points.
    """
    chk = ArgCheck("transform_points")
    T34 = _pose34(chk, "T", T, "B 3|4 4")
    chk.tensor("points", points, "B ... 3")
    P = math.prod(points.shape[1:-1])
    out = _ops.transform_points(T34.contiguous(), _flat(points, 1), P)
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
        out = _ops.project_points(_flat(points, 1), Kb, P, min_depth)
    else:
        out = lens_ops().project_points_camera(_flat(points, 1), Kb, dist, P, min_depth, model)[0]
    return out.reshape(*points.shape[:-1], 2)


# ----------------------------------------------------------------------------- sampling


def bilinear_sample(
    image: Tensor, grid: Tensor, *, align_corners: bool = False, padding_mode: str = "zeros"
) -> Tensor:
    """Bilinear sampler of spatial transformer networks, implemented in Warp.

    Same semantics as ``torch.nn.functional.grid_sample(image, grid, mode="bilinear",
    padding_mode=padding_mode, align_corners=align_corners)``: ``grid[b, i, j] = (gx, gy)`` in
    [-1, 1], gx along the width. With ``align_corners=False`` -1 and 1 are the outer edges of the
    image: for W = 4, gx = -1 is pixel x = -0.5, gx = 0 is x = 1.5. With ``align_corners=True``
    they are the centres of the corner pixels: gx = -1 is x = 0, gx = 1 is x = W - 1.
    ``padding_mode="zeros"`` reads 0 outside; ``"border"`` clamps the position into the image.
    NaN grid values sample 0 with zero gradient; so do +-inf with "zeros", while "border" clamps
    them to the edge (as ``grid_sample`` does).

    Args:
        image: (B, C, H, W).
        grid: (B, h, w, 2) normalised (x, y) positions.

    Returns:
        (B, C, h, w) samples; gradients for image and grid.
    """
    chk = ArgCheck("bilinear_sample")
    chk.tensor("image", image, "B C H W")
    chk.tensor("grid", grid, "B h w 2")
    pad = _PADDING[chk.option("padding_mode", padding_mode, tuple(_PADDING))]
    B, C, H, W = image.shape
    h, w = grid.shape[1:3]
    if H * W == 0 and B * h * w > 0:
        chk._fail(ValueError, f"argument 'image' has no pixels to sample from (shape {tuple(image.shape)})")
    # 8 output locations per thread where they tile the output (SIMD weights; same results)
    op = _ops.bilinear_sample_lanes if sampling_kernels.fits_lanes(h * w, H, W) else _ops.bilinear_sample
    out = op(image.contiguous(), _flat(grid, 1), C, H, W, h * w, int(bool(align_corners)), pad)
    return out.reshape(B, C, h, w)


def warp_frame_depth(
    image: Tensor,
    depth: Tensor,
    pose: Tensor,
    K: Tensor | Camera,
    *,
    padding_mode: str = "zeros",
    min_depth: float = MIN_DEPTH,
) -> tuple[Tensor, Tensor]:
    """The 3D spatial transformer: warp ``image`` into the frame of ``depth``.

    For every pixel u = (x, y) of the depth's frame, warped(u) = image sampled bilinearly at
    project(K, pose * (depth(u) K^-1 [x, y, 1])), i.e. ``pose`` maps points from the depth's
    frame into the image's frame. One fused Warp pass (and one adjoint pass); same values as
    ``kornia.geometry.depth.warp_frame_depth(image, depth, pose_4x4, K)`` wherever valid.

    Args:
        image: (B, C, H, W) source image.
        depth: (B, 1, H, W) depth (z, metres) of the target frame.
        pose: (B, 3, 4) or (B, 4, 4) target-to-source transform (a 4x4's last row ignored).
        K: (B, 3, 3) or (3, 3) intrinsics, shared by both views; or a camera from
            ``gvnn_warp.cameras`` (both views taken by it): then u = (x, y) is a pixel of the
            distorted image, its ray is undistort(K^-1 [x, y, 1]) and the moved point is
            projected through the model (``camera.project``); gradients reach K and every
            distortion coefficient too. A pixel without a ray (outside the model's domain) counts
            as an invalid depth, a moved point outside the domain as one behind the camera. The
            rays are computed once per call, or once per camera value and image size when the
            camera needs no gradient (a small cache). ``PinholeCamera(K)`` is exactly ``K``.
        padding_mode: "zeros" or "border", how samples outside the image read.
        min_depth: depths and moved points must have z > min_depth (metres) to be used.

    Returns:
        warped: (B, C, H, W); 0 where the depth or the moved point is invalid; where the
            projection falls outside the image, the padded sample (as ``grid_sample``).
        valid: (B, 1, H, W) bool, true where the depth is finite and > min_depth, the moved point
            has z > min_depth, and its projection lies inside the image (within 1e-3 px of the
            pixel-centre rectangle [0, W-1] x [0, H-1]). Identity pose: all true, warped == image.

    Gradients flow to image, depth, pose and K; they are finite for every finite pose and
    every depth value (0, negative, NaN, inf included). Pixels with an invalid depth or moved
    point pass no gradient; pixels projecting outside the image pass the padded sample's (as
    ``grid_sample`` does), though ``valid`` is false there: mask the loss with ``valid``.
    """
    chk = ArgCheck("warp_frame_depth")
    chk.tensor("image", image, "B C H W")
    chk.tensor("depth", depth, "B 1 H W")
    pose34 = _pose34(chk, "pose", pose, "B 3|4 4")
    cam = _Lens(chk, K)
    pad = _PADDING[chk.option("padding_mode", padding_mode, tuple(_PADDING))]
    min_depth = chk.positive("min_depth", min_depth)
    _, C, H, W = image.shape
    if cam.model == 0:  # the pinhole: its own kernel (the row-linear fast path)
        return _ops.warp_frame_depth(
            image.contiguous(), depth.contiguous(), pose34.contiguous(), cam.K, C, H, W, min_depth, pad
        )
    rays, stride = _rays(cam, H, W)
    return lens_ops().warp_frame_depth_lens(
        image.contiguous(), depth.contiguous(), pose34.contiguous(), cam.K, cam.dist, rays,
        C, H, W, min_depth, pad, cam.model, stride,
    )
