"""Per-pixel transformations of the gvnn paper as generic ``@wp.func`` (no launches here).

Parameter fields are channel-first ``(B, K, H, W)`` tensors read as flat 1-D arrays: parameter
``k`` of pixel ``j = y * W + x`` of batch item ``b`` is ``params[(b * K + k) * H * W + j]``
(:func:`channel`). Pixel positions are (x, y) = (column, row) with pixel centres at integer
coordinates (``docs/conventions.md``). 2D maps return the moved position ``(x', y')``; the flow is
``(x' - x, y' - y)``.
"""

from typing import Any

import warp as wp

from ..geometry import lie
from ..sampling import sampler

# |denominator| of the homography below which it is clamped to +-HOMOGRAPHY_MIN_DEN (sign kept, 0
# counts as positive): the position stays finite and no gradient flows to the denominator there.
HOMOGRAPHY_MIN_DEN = 1.0e-6


@wp.func
def pixel_index(i: int, H: int, W: int):
    """Flat index ``i`` of a (B, H, W) grid -> (b, j, x, y): batch item, index ``j = y W + x``
    within the item, column and row."""
    hw = H * W
    b = i // hw
    j = i - b * hw
    py = j // W
    return b, j, j - py * W, py


@wp.func
def channel(a: wp.array(dtype=Any), b: int, k: int, K: int, hw: int, j: int):
    """Element ``(b, k, j)`` of a flat channel-first ``(B, K, H*W)`` array."""
    return a[(b * K + k) * hw + j]


# ----------------------------------------------------------------------------- 2D maps


@wp.func
def affine_point(x: Any, y: Any, a0: Any, a1: Any, a2: Any, a3: Any, a4: Any, a5: Any):
    """(a0 x + a1 y + a2, a3 x + a4 y + a5): the over-parameterised affine optic flow."""
    return a0 * x + a1 * y + a2, a3 * x + a4 * y + a5


@wp.func
def se2_point(x: Any, y: Any, theta: Any, tx: Any, ty: Any):
    """Rotation by theta about the origin, then translation: (x c - y s + tx, x s + y c + ty)."""
    c = wp.cos(theta)
    s = wp.sin(theta)
    return x * c - y * s + tx, x * s + y * c + ty


@wp.func
def safe_denominator(d: Any):
    """d, or +-HOMOGRAPHY_MIN_DEN (sign of d, + for 0) where |d| < HOMOGRAPHY_MIN_DEN (NaN stays NaN).

    ``wp.where`` routes no gradient to the side it does not select, so the clamped value has zero
    gradient with respect to d."""
    m = type(d)(HOMOGRAPHY_MIN_DEN)
    clamped = wp.where(d < type(d)(0.0), -m, m)
    return wp.where(wp.abs(d) < m, clamped, d)  # NaN is not < m: it passes through


@wp.func
def homography_point(x: Any, y: Any, h0: Any, h1: Any, h2: Any, h3: Any, h4: Any, h5: Any, h6: Any, h7: Any, h8: Any):
    """((h0 x + h1 y + h2) / w, (h3 x + h4 y + h5) / w) with w = h6 x + h7 y + h8 (clamped)."""
    inv_w = type(x)(1.0) / safe_denominator(h6 * x + h7 * y + h8)
    return (h0 * x + h1 * y + h2) * inv_w, (h3 * x + h4 * y + h5) * inv_w


@wp.func
def plane_disparity(x: Any, y: Any, a: Any, b: Any, c: Any):
    """Slanted-plane disparity d = a x + b y + c."""
    return a * x + b * y + c


@wp.func
def grid_coordinate(i: Any, n: int, align_corners: int):
    """Normalised coordinate of pixel index ``i`` (as a float) of ``n`` in the base grid of
    ``torch.nn.functional.affine_grid``: ``linspace(-1, 1, n)``, times (n - 1) / n unless
    ``align_corners``; 0 when n == 1."""
    one = type(i)(1.0)
    fn = type(i)(n)
    g = type(i)(0.0)
    if n > 1:
        if align_corners != 0:
            g = type(i)(2.0) * i / (fn - one) - one
        else:
            g = (type(i)(2.0) * i + one) / fn - one
    return g


# ----------------------------------------------------------------------------- 3D maps


@wp.func
def finite_or_zero(p: Any):
    """(p, True) for a finite point, else (0, False): an invalid point (NaN/inf, e.g. from a NaN
    depth) is transformed as the origin, so its parameters get 0 gradient rather than 0 * NaN."""
    ok = wp.isfinite(p)
    return wp.where(ok, p, type(p)()), ok


@wp.func
def se3_point(p: Any, omega: Any, t: Any):
    """R(omega) p + t: the per-pixel SE3 transformation."""
    return lie.so3_exp(omega) * p + t


@wp.func
def sim3_point(p: Any, omega: Any, t: Any, sigma: Any):
    """exp(sigma) R(omega) p + t: the per-pixel Sim3 transformation."""
    return (lie.so3_exp(omega) * p) * wp.exp(sigma) + t


@wp.func
def transform10_point(p: Any, omega: Any, t: Any, sigma: Any, anchor: Any):
    """exp(sigma) (R(omega) (p - anchor) + anchor) + t: the per-pixel 10-DoF transformation."""
    return (lie.so3_exp(omega) * (p - anchor) + anchor) * wp.exp(sigma) + t


# ----------------------------------------------------------------------------- sampling


@wp.func
def sample_pixel(
    image: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
    b: int,
    C: int,
    H: int,
    W: int,
    j: int,
    x: Any,
    y: Any,
    padding: int,
):
    """out[b, c, j] = bilinear sample of image[b, c] at pixel position (x, y), for every channel c
    (image and out both (B, C, H, W), flat).

    Same semantics as ``grid_sample(align_corners=True)`` in pixel units: padding ``PADDING_ZEROS``
    reads 0 outside the image, ``PADDING_BORDER`` clamps the position (zero position gradient
    when clamped); a position no tap can reach (or NaN) samples 0 with zero gradient. The
    channels are sampled by :func:`.sampler.sample_channels` (hand-written adjoint).
    """
    hw = H * W
    xs, ys, inside = sampler.sample_position(x, y, H, W, padding)
    base = b * C * hw
    sampler.sample_channels(image, out, base, base + j, C, hw, hw, H, W, xs, ys, inside)
