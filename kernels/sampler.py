"""Bilinear sampling building blocks as generic ``@wp.func`` (no launches here).

Images are flat 1-D arrays in (B, C, H, W) row-major order; ``plane`` is the flat offset of
one (b, c) channel plane. Sample positions are in pixels, (x, y) = (column, row), pixel centres
at integer coordinates. Taps outside the image read as 0 (``PADDING_ZEROS``); with
``PADDING_BORDER`` the position is first clamped into [0, W-1] x [0, H-1] (zero gradient to
the position when clamped), exactly as ``torch.nn.functional.grid_sample`` does.
"""

from typing import Any

import warp as wp

PADDING_ZEROS = wp.constant(0)
PADDING_BORDER = wp.constant(1)


@wp.func
def normalized_to_pixel(g: Any, size: int, align_corners: int):
    """grid_sample's un-normalisation: [-1, 1] -> pixels.

    align_corners=1: -1 and 1 are the centres of the first and last pixel, x = (g + 1)/2 (size - 1).
    align_corners=0: -1 and 1 are the outer edges of the image, x = ((g + 1) size - 1) / 2.
    """
    one = type(g)(1.0)
    half = type(g)(0.5)
    n = type(g)(size)
    if align_corners != 0:
        x = (g + one) * half * (n - one)
    else:
        x = ((g + one) * n - one) * half
    return x


@wp.func
def tap(img: wp.array(dtype=Any), plane: int, H: int, W: int, xi: int, yi: int):
    """One pixel of one channel plane, 0 outside the image."""
    v = img.dtype(0.0)
    if xi >= 0 and xi < W and yi >= 0 and yi < H:
        v = img[plane + yi * W + xi]
    return v


@wp.func
def sample_position(x: Any, y: Any, H: int, W: int, padding: int):
    """Apply the padding mode to a sample position; returns (x, y, inside) where inside is
    False when no tap can touch the image (also for NaN/inf), in which case the sample is 0."""
    zero = type(x)(0.0)
    one = type(x)(1.0)
    xs = x
    ys = y
    if padding == PADDING_BORDER:
        # Like grid_sample: clamp into [0, size-1], no gradient at or beyond the bounds; NaN stays
        # NaN (comparisons are false) and is then rejected below.
        xmax = type(x)(W - 1)
        ymax = type(x)(H - 1)
        xs = wp.where(x <= zero, zero, wp.where(x >= xmax, xmax, x))
        ys = wp.where(y <= zero, zero, wp.where(y >= ymax, ymax, y))
    inside = xs > -one and xs < type(x)(W) and ys > -one and ys < type(x)(H)
    return xs, ys, inside


@wp.func
def bilinear(img: wp.array(dtype=Any), plane: int, H: int, W: int, x: Any, y: Any):
    """Bilinear interpolation of one channel plane at (x, y), with zero taps outside.

    The caller guarantees -1 < x < W and -1 < y < H (see ``sample_position``). Weights follow
    grid_sample: with x0 = floor(x), the tap at x0 has weight (x0 + 1 - x).
    """
    fx0 = wp.floor(x)
    fy0 = wp.floor(y)
    x0 = int(fx0)
    y0 = int(fy0)
    wx1 = x - fx0
    wy1 = y - fy0
    wx0 = type(x)(1.0) - wx1
    wy0 = type(x)(1.0) - wy1
    return (
        tap(img, plane, H, W, x0, y0) * (wx0 * wy0)
        + tap(img, plane, H, W, x0 + 1, y0) * (wx1 * wy0)
        + tap(img, plane, H, W, x0, y0 + 1) * (wx0 * wy1)
        + tap(img, plane, H, W, x0 + 1, y0 + 1) * (wx1 * wy1)
    )
