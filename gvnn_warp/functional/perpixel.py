"""Per-pixel transformations, M-estimators and smoothness (gvnn paper, "Per-pixel Transformations"
and "M-estimators"), as Warp kernels differentiated by Warp's adjoints.

Every function takes float32 or float64 CPU tensors (all floating arguments of one call in the
same dtype), returns gradients for every floating tensor argument, validates its arguments with a
clear error naming the function and argument, and never modifies its inputs. Conventions
(pixel centres at integer coordinates, (x, y) = (column, row), ``[omega, t, sigma, p]`` order,
channel-first parameter fields) are in ``docs/conventions.md``.

Per-pixel parameter fields are ``(B, K, H, W)``: pixel (x, y) of batch item b uses
``params[b, :, y, x]`` at its own pixel coordinates (x, y), x in [0, W-1], y in [0, H-1].
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..kernels.perpixel.transforms import HOMOGRAPHY_MIN_DEN
from ..kernels.robust import KINDS as _ROBUST_CODES
from ..kernels.sampling.sampler import PADDING_MODES as _PADDING
from ..ops import perpixel as _ops
from ..ops.checks import ArgCheck

__all__ = [
    "HOMOGRAPHY_MIN_DEN",
    "ROBUST_KINDS",
    "affine_flow",
    "affine_flow_warp",
    "affine_grid",
    "disparity_warp",
    "flow_warp",
    "homography_flow",
    "pointwise_se3",
    "pointwise_sim3",
    "pointwise_transform10",
    "robust_psi",
    "robust_rho",
    "se2_flow",
    "slanted_plane_disparity",
    "smoothness_loss",
]

#: The M-estimators of :func:`robust_rho` / :func:`robust_psi` / :func:`smoothness_loss`.
ROBUST_KINDS = tuple(_ROBUST_CODES)


def _padding(chk: ArgCheck, padding_mode: str) -> int:
    return _PADDING[chk.option("padding_mode", padding_mode, tuple(_PADDING))]


def _robust_args(chk: ArgCheck, kind: str, scale: float, dtype: torch.dtype) -> tuple[int, float]:
    return _ROBUST_CODES[chk.option("kind", kind, ROBUST_KINDS)], chk.positive("scale", scale, dtype)


# ----------------------------------------------------------------------------- sampling


def flow_warp(image: Tensor, flow: Tensor, *, padding_mode: str = "zeros") -> Tensor:
    """Warp an image by a dense optic flow (the minimal 2-DoF per-pixel parameterisation).

    ``out[b, :, y, x]`` = ``image[b]`` sampled bilinearly at ``(x + flow[b, 0, y, x],
    y + flow[b, 1, y, x])`` in pixels (pixel centres at integer coordinates), i.e.
    ``grid_sample(image, grid, align_corners=True)`` with the grid of those positions, normalised.

    Args:
        image: (B, C, H, W) image to sample from.
        flow: (B, 2, H, W) displacement in pixels, (dx, dy) = (along the width, along the height).
        padding_mode: "zeros" (taps outside the image read 0) or "border" (the position is clamped
            into [0, W-1] x [0, H-1], with zero gradient to the flow when clamped).

    Returns:
        (B, C, H, W) warped image. Gradients flow to image and flow. A NaN flow samples 0 with
        zero gradient; so does an infinite one with "zeros" padding, while "border" clamps it to
        the border like ``grid_sample``.
    """
    chk = ArgCheck("flow_warp")
    chk.tensor("image", image, "B C H W", image=True)
    chk.tensor("flow", flow, "B 2 H W")
    pad = _padding(chk, padding_mode)
    _, C, H, W = image.shape
    return _ops.flow_warp(image.contiguous(), flow.contiguous(), C, H, W, pad)


def disparity_warp(image: Tensor, disparity: Tensor, *, padding_mode: str = "zeros") -> Tensor:
    """Reconstruct the left view of a rectified stereo pair from the right view and a disparity.

    ``out[b, :, y, x]`` = ``image[b]`` sampled bilinearly at ``(x - disparity[b, 0, y, x], y)``
    (pixels); ``flow_warp`` with flow (-d, 0).

    Args:
        image: (B, C, H, W) right image.
        disparity: (B, 1, H, W) disparity of the left view, in pixels (positive: the point appears
            further left in the right image).
        padding_mode: "zeros" or "border", as in :func:`flow_warp`.

    Returns:
        (B, C, H, W) reconstructed left image; gradients flow to image and disparity.
    """
    chk = ArgCheck("disparity_warp")
    chk.tensor("image", image, "B C H W", image=True)
    chk.tensor("disparity", disparity, "B 1 H W")
    pad = _padding(chk, padding_mode)
    _, C, H, W = image.shape
    return _ops.disparity_warp(image.contiguous(), disparity.contiguous(), C, H, W, pad)


def affine_flow_warp(image: Tensor, params: Tensor, *, padding_mode: str = "zeros") -> Tensor:
    """``flow_warp(image, affine_flow(params))`` fused into one Warp pass (no flow intermediate).

    ``out[b, :, y, x]`` = ``image[b]`` sampled at ``(a0 x + a1 y + a2, a3 x + a4 y + a5)`` with
    ``a = params[b, :, y, x]``.

    Args:
        image: (B, C, H, W) image to sample from.
        params: (B, 6, H, W) per-pixel affine parameters (see :func:`affine_flow`).
        padding_mode: "zeros" or "border", as in :func:`flow_warp`.

    Returns:
        (B, C, H, W) warped image; gradients flow to image and params.
    """
    chk = ArgCheck("affine_flow_warp")
    chk.tensor("image", image, "B C H W", image=True)
    chk.tensor("params", params, "B 6 H W")
    pad = _padding(chk, padding_mode)
    _, C, H, W = image.shape
    return _ops.affine_flow_warp(image.contiguous(), params.contiguous(), C, H, W, pad)


# ----------------------------------------------------------------------------- per-pixel flows


def affine_flow(params: Tensor) -> Tensor:
    """Over-parameterised affine optic flow (Nir et al.): a 6-DoF affine map per pixel.

    With ``a = params[b, :, y, x]``: x' = a0 x + a1 y + a2, y' = a3 x + a4 y + a5, and the flow is
    (x' - x, y' - y). Identity params [1, 0, 0, 0, 1, 0] give zero flow; [1, 0, tx, 0, 1, ty] the
    translation flow (tx, ty).

    Args:
        params: (B, 6, H, W).

    Returns:
        (B, 2, H, W) flow in pixels, for :func:`flow_warp`.
    """
    ArgCheck("affine_flow").tensor("params", params, "B 6 H W")
    _, _, H, W = params.shape
    return _ops.affine_flow(params.contiguous(), H, W)


def se2_flow(params: Tensor) -> Tensor:
    """Per-pixel SE(2) flow: rotation about the pixel origin (0, 0), then translation.

    With ``[theta, tx, ty] = params[b, :, y, x]``: x' = x cos(theta) - y sin(theta) + tx,
    y' = x sin(theta) + y cos(theta) + ty; the flow is (x' - x, y' - y). theta in radians
    (positive turns +x towards +y, i.e. clockwise on screen since y points down).

    Args:
        params: (B, 3, H, W).

    Returns:
        (B, 2, H, W) flow in pixels.
    """
    ArgCheck("se2_flow").tensor("params", params, "B 3 H W")
    _, _, H, W = params.shape
    return _ops.se2_flow(params.contiguous(), H, W)


def homography_flow(params: Tensor) -> Tensor:
    """Per-pixel 9-DoF homography flow (Hornacek et al.).

    With ``h = params[b, :, y, x]`` and w = h6 x + h7 y + h8: x' = (h0 x + h1 y + h2) / w,
    y' = (h3 x + h4 y + h5) / w; the flow is (x' - x, y' - y). Identity params
    [1, 0, 0, 0, 1, 0, 0, 0, 1] give zero flow.

    Near-singular denominators: where |w| < ``HOMOGRAPHY_MIN_DEN`` (1e-6) w is replaced by
    +-1e-6 with the sign of w (+ for w = 0). The output stays finite (for finite params) and no
    gradient flows through w there (h6, h7, h8 get 0); the numerator's gradient is that of the
    clamped map (large, 1e6 times the incoming gradient, but finite). Never NaN for finite params;
    NaN params give a NaN flow. The threshold is absolute, so the overall scale of ``h`` matters
    there: normalise it (e.g. h8 = 1, or ``|h| ~ 1``) to keep ``|w|`` far from 1e-6.

    Args:
        params: (B, 9, H, W), row-major 3x3 homographies per pixel (defined up to scale, but see
            the threshold above).

    Returns:
        (B, 2, H, W) flow in pixels.
    """
    ArgCheck("homography_flow").tensor("params", params, "B 9 H W")
    _, _, H, W = params.shape
    return _ops.homography_flow(params.contiguous(), H, W)


def slanted_plane_disparity(params: Tensor) -> Tensor:
    """Slanted-plane disparity (Bleyer et al.): d = a x + b y + c per pixel.

    Args:
        params: (B, 3, H, W), [a, b, c] per pixel.

    Returns:
        (B, 1, H, W) disparity in pixels, for :func:`disparity_warp`.
    """
    ArgCheck("slanted_plane_disparity").tensor("params", params, "B 3 H W")
    _, _, H, W = params.shape
    return _ops.plane_disparity(params.contiguous(), H, W)


# ----------------------------------------------------------------------------- per-pixel 3D


def _pointwise(fn: str, points: Tensor, params: Tensor, k: int, op) -> Tensor:
    chk = ArgCheck(fn)
    chk.tensor("points", points, "B H W 3")
    chk.tensor("params", params, f"B {k} H W")
    _, H, W, _ = points.shape
    return op(points.contiguous(), params.contiguous(), H * W)


def pointwise_se3(points: Tensor, params: Tensor) -> Tensor:
    """Per-pixel rigid transformation: p'_i = R(omega_i) p_i + t_i.

    Args:
        points: (B, H, W, 3) points (e.g. from ``depth_to_points``), or any 3-vector per pixel.
        params: (B, 6, H, W), ``[omega, t]`` per pixel: so(3) vector (axis * angle, radians;
            R = so3_exp(omega), exact with finite gradients at omega = 0) and translation.

    Returns:
        (B, H, W, 3) transformed points; gradients flow to points and params. A non-finite point
        (e.g. from a NaN depth) is passed through unchanged and its parameters get zero gradient
        (the same in :func:`pointwise_sim3` and :func:`pointwise_transform10`).
    """
    return _pointwise("pointwise_se3", points, params, 6, _ops.pointwise_se3)


def pointwise_sim3(points: Tensor, params: Tensor) -> Tensor:
    """Per-pixel similarity transformation: p'_i = s_i R(omega_i) p_i + t_i, s_i = exp(sigma_i).

    Args:
        points: (B, H, W, 3).
        params: (B, 7, H, W), ``[omega, t, sigma]`` per pixel.

    Returns:
        (B, H, W, 3) transformed points; gradients flow to points and params. Non-finite points
        pass through unchanged, with zero gradient to their parameters.
    """
    return _pointwise("pointwise_sim3", points, params, 7, _ops.pointwise_sim3)


def pointwise_transform10(points: Tensor, params: Tensor) -> Tensor:
    """Per-pixel 10-DoF transformation about an anchor (Sumner et al.):
    x'_i = s_i (R(omega_i) (x_i - p_i) + p_i) + t_i, s_i = exp(sigma_i).

    Args:
        points: (B, H, W, 3).
        params: (B, 10, H, W), ``[omega, t, sigma, p]`` per pixel (p the anchor point).

    Returns:
        (B, H, W, 3) transformed points; gradients flow to points and params. Non-finite points
        pass through unchanged, with zero gradient to their parameters.
    """
    return _pointwise("pointwise_transform10", points, params, 10, _ops.pointwise_transform10)


# ----------------------------------------------------------------------------- STN grid


def affine_grid(theta: Tensor, size, align_corners: bool = False) -> Tensor:
    """The 2D grid generator of the original spatial transformer network.

    Same values as ``torch.nn.functional.affine_grid(theta, size, align_corners)``: for output
    pixel (x, y), ``grid[b, y, x] = theta[b] @ [gx, gy, 1]`` where (gx, gy) are the normalised
    coordinates of the pixel (``linspace(-1, 1, W)``, scaled by (W - 1) / W unless
    ``align_corners``; 0 for a size of 1). Feed it to ``bilinear_sample`` / ``grid_sample`` with
    the same ``align_corners``.

    Args:
        theta: (B, 2, 3) affine matrices.
        size: (B, C, H, W) the output image size (a sequence of 4 non-negative ints; C unused).
        align_corners: as in ``torch.nn.functional.affine_grid``.

    Returns:
        (B, H, W, 2) normalised sampling grid; gradients flow to theta.
    """
    chk = ArgCheck("affine_grid")
    chk.tensor("theta", theta, "B 2 3")
    if not (
        isinstance(size, (tuple, list, torch.Size))
        and all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in size)
    ):
        chk.fail(TypeError, f"argument 'size' must be a sequence of non-negative ints (B, C, H, W), got {size!r}")
    chk.shape("size", tuple(size), "B * H W")
    return _ops.affine_grid(theta.contiguous(), chk.dim("H"), chk.dim("W"), int(bool(align_corners)))


# ----------------------------------------------------------------------------- M-estimators


def robust_rho(x: Tensor, kind: str, scale: float = 1.0) -> Tensor:
    """M-estimator penalty rho(x), elementwise (the gvnn paper's table).

    With c = ``scale``:

    - ``"huber"`` (c = epsilon): x^2/2 if |x| <= c, else c (|x| - c/2).
    - ``"cauchy"``: c^2/2 log(1 + (x/c)^2).
    - ``"geman_mcclure"``: (x^2/2) / (1 + (x/c)^2) (the paper's table is c = 1).
    - ``"tukey"``: c^2/6 (1 - (1 - (x/c)^2)^3) if |x| <= c, else c^2/6.

    The gradient (Warp's adjoint of this kernel) is :func:`robust_psi`.

    Args:
        x: tensor of any shape (residuals).
        kind: one of "huber", "cauchy", "geman_mcclure", "tukey".
        scale: positive real number (not learnable; it is not a tensor), within [1.1e-19, 1.8e19]
            for float32 input (c^2 must be a normal float32), [1.5e-154, 1.3e154] for float64.

    Returns:
        rho(x), same shape and dtype as x.
    """
    chk = ArgCheck("robust_rho")
    chk.tensor("x", x, "...")
    code, c = _robust_args(chk, kind, scale, x.dtype)
    return _ops.robust_rho(x.reshape(-1).contiguous(), code, c).reshape(x.shape)


def robust_psi(x: Tensor, kind: str, scale: float = 1.0) -> Tensor:
    """Influence function psi(x) = d rho(x) / dx in closed form, elementwise (see :func:`robust_rho`).

    - ``"huber"``: x if |x| <= c, else c sign(x).
    - ``"cauchy"``: x / (1 + (x/c)^2).
    - ``"geman_mcclure"``: x / (1 + (x/c)^2)^2.
    - ``"tukey"``: x (1 - (x/c)^2)^2 if |x| <= c, else 0.

    Args:
        x: tensor of any shape.
        kind: one of "huber", "cauchy", "geman_mcclure", "tukey".
        scale: positive real number, range as in :func:`robust_rho`.

    Returns:
        psi(x), same shape and dtype as x; differentiable (its gradient is rho'').
    """
    chk = ArgCheck("robust_psi")
    chk.tensor("x", x, "...")
    code, c = _robust_args(chk, kind, scale, x.dtype)
    return _ops.robust_psi(x.reshape(-1).contiguous(), code, c).reshape(x.shape)


def smoothness_loss(field: Tensor, kind: str = "huber", scale: float = 1.0) -> Tensor:
    """Robust smoothness regulariser of a per-pixel field (flow or per-pixel transform parameters).

    ``mean(rho(field[..., :, 1:] - field[..., :, :-1])) + mean(rho(field[..., 1:, :] - field[..., :-1, :]))``
    with rho = :func:`robust_rho` (``kind``, ``scale``): the mean penalty of the forward differences
    along x plus the mean along y, over all batch items and channels. A direction with no pairs
    (W == 1 or H == 1) contributes 0.

    Args:
        field: (B, K, H, W).
        kind: M-estimator, as in :func:`robust_rho` (default "huber", as in Patraucean et al.).
        scale: positive real number, range as in :func:`robust_rho`.

    Returns:
        0-dim tensor; gradient flows to field. The per-pixel penalties (already divided by the
        pair counts) come from one Warp kernel; only their final sum is taken in torch.
    """
    chk = ArgCheck("smoothness_loss")
    chk.tensor("field", field, "B K H W")
    code, c = _robust_args(chk, kind, scale, field.dtype)
    B, K, H, W = field.shape
    nx = B * K * H * (W - 1)
    ny = B * K * (H - 1) * W
    wx = 1.0 / nx if nx > 0 else 0.0
    wy = 1.0 / ny if ny > 0 else 0.0
    return _ops.smoothness(field.contiguous(), H, W, code, c, wx, wy).sum()
