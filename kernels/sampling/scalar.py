"""The bilinear sampler, one position per call (``@wp.func``, no launches here).

Images are flat 1-D arrays in (B, C, H, W) row-major order; ``plane`` is the flat offset of
one (b, c) channel plane. Sample positions are in pixels, (x, y) = (column, row), pixel centres
at integer coordinates. Taps outside the image read as 0 (``PADDING_ZEROS``); with
``PADDING_BORDER`` the position is first clamped into [0, W-1] x [0, H-1] (zero gradient to
the position when clamped), exactly as ``torch.nn.functional.grid_sample`` does.

:func:`sample_channels` samples every channel of one position at once with a hand-shaped Warp
adjoint (``@wp.func_grad``): the tap addresses and weights are computed once for all channels,
the image gradient is scattered directly, and the forward replay in the backward pass is skipped.
It is what the sampling kernels use; :func:`bilinear` remains the single-plane building block.
The same for 8 positions at once: :mod:`.lanes`. Both are exported by :mod:`.sampler`.
"""

from typing import Any

import warp as wp

from ..core.cache import float_overloads
from ..core.compat import func_grad

PADDING_ZEROS = wp.constant(0)
PADDING_BORDER = wp.constant(1)
# padding_mode names (as grid_sample spells them) -> the codes kernels take
PADDING_MODES = {"zeros": int(PADDING_ZEROS), "border": int(PADDING_BORDER)}

# A projection counts as inside the image (the ``valid`` flag of the spatial transformers) when it
# lies in [-tol, W - 1 + tol] x [-tol, H - 1 + tol] (pixel units): all four bilinear taps are then
# real pixels, up to rounding (so the identity pose keeps the last row and column valid).
INSIDE_TOLERANCE = 1.0e-3


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


# Channels sampled by straight-line code in sample_channels (the rest, if any, by a loop).
UNROLLED_CHANNELS = 4


@wp.func
def bilinear_taps(src: int, H: int, W: int, x: Any, y: Any):
    """The four taps of a bilinear sample at (x, y) (-1 < x < W, -1 < y < H) of the H x W plane at
    flat offset ``src``: their addresses ``p00, p10, p01, p11`` (clamped into the image, so always
    valid), whether each is inside the image ``k00 ... k11`` (a tap outside reads 0), and the
    weights along each axis ``wx0, wx1, wy0, wy1`` (tap (i, j) has weight ``wxi * wyj``, as in
    grid_sample: with x0 = floor(x), the tap at x0 has weight x0 + 1 - x)."""
    fx0 = wp.floor(x)
    fy0 = wp.floor(y)
    x0 = int(fx0)
    y0 = int(fy0)
    wx1 = x - fx0
    wy1 = y - fy0
    wx0 = type(x)(1.0) - wx1
    wy0 = type(x)(1.0) - wy1
    kx0 = x0 >= 0
    kx1 = x0 < W - 1
    ky0 = y0 >= 0
    ky1 = y0 < H - 1
    ra = src + wp.max(y0, 0) * W
    rb = src + wp.min(y0 + 1, H - 1) * W
    xa = wp.max(x0, 0)
    xb = wp.min(x0 + 1, W - 1)
    # wp.max(..., 0): indices known non-negative spare Warp's negative-index wrap-around
    p00 = wp.max(ra + xa, 0)
    p10 = wp.max(ra + xb, 0)
    p01 = wp.max(rb + xa, 0)
    p11 = wp.max(rb + xb, 0)
    return p00, p10, p01, p11, ky0 and kx0, ky0 and kx1, ky1 and kx0, ky1 and kx1, wx0, wx1, wy0, wy1


@wp.func
def sample_channels_values(
    image: wp.array(dtype=Any),
    out: wp.array(dtype=Any),
    src: int,
    dst: int,
    C: int,
    hw_in: int,
    hw_out: int,
    H: int,
    W: int,
    x: Any,
    y: Any,
):
    """The forward of :func:`sample_channels` where active (see there)."""
    zero = type(x)(0.0)
    p00, p10, p01, p11, k00, k10, k01, k11, wx0, wx1, wy0, wy1 = bilinear_taps(src, H, W, x, y)
    w00 = wx0 * wy0
    w10 = wx1 * wy0
    w01 = wx0 * wy1
    w11 = wx1 * wy1
    if k00 and k11:
        # all four taps inside (the common case): no per-tap tests
        for c in range(wp.static(UNROLLED_CHANNELS)):
            if c < C:
                q = c * hw_in
                out[wp.max(dst + c * hw_out, 0)] = (
                    image[wp.max(p00 + q, 0)] * w00
                    + image[wp.max(p10 + q, 0)] * w10
                    + image[wp.max(p01 + q, 0)] * w01
                    + image[wp.max(p11 + q, 0)] * w11
                )
    else:
        for c in range(wp.static(UNROLLED_CHANNELS)):
            if c < C:
                q = c * hw_in
                out[wp.max(dst + c * hw_out, 0)] = (
                    wp.where(k00, image[wp.max(p00 + q, 0)], zero) * w00
                    + wp.where(k10, image[wp.max(p10 + q, 0)], zero) * w10
                    + wp.where(k01, image[wp.max(p01 + q, 0)], zero) * w01
                    + wp.where(k11, image[wp.max(p11 + q, 0)], zero) * w11
                )
    for c in range(UNROLLED_CHANNELS, C):
        q = c * hw_in
        out[dst + c * hw_out] = (
            wp.where(k00, image[p00 + q], zero) * w00
            + wp.where(k10, image[p10 + q], zero) * w10
            + wp.where(k01, image[p01 + q], zero) * w01
            + wp.where(k11, image[p11 + q], zero) * w11
        )


@wp.func
def sample_channels_grad(
    image: wp.array(dtype=Any),
    g_image: wp.array(dtype=Any),
    g_out: wp.array(dtype=Any),
    src: int,
    dst: int,
    C: int,
    hw_in: int,
    hw_out: int,
    H: int,
    W: int,
    x: Any,
    y: Any,
):
    """The adjoint of :func:`sample_channels` where active: adds d loss / d image into ``g_image``
    given ``g_out`` = d loss / d out, and returns (d loss / dx, d loss / dy).

    d out_c / d image[tap] = tap weight; d out_c / dx = (v10 - v00) wy0 + (v11 - v01) wy1, and
    likewise for y (the derivative of the weights; floor() contributes nothing). A null
    ``g_image`` (no elements: that gradient is not wanted) is left alone, which saves the scatter.
    """
    zero = type(x)(0.0)
    p00, p10, p01, p11, k00, k10, k01, k11, wx0, wx1, wy0, wy1 = bilinear_taps(src, H, W, x, y)
    w00 = wx0 * wy0
    w10 = wx1 * wy0
    w01 = wx0 * wy1
    w11 = wx1 * wy1
    gx = zero
    gy = zero
    inside = k00 and k11
    scatter = g_image.shape[0] > 0
    # the taps written to (inside the image and wanted)
    s00 = k00 and scatter
    s10 = k10 and scatter
    s01 = k01 and scatter
    s11 = k11 and scatter
    for c in range(wp.static(UNROLLED_CHANNELS)):
        if c < C:
            q = c * hw_in
            g = g_out[wp.max(dst + c * hw_out, 0)]
            i00 = wp.max(p00 + q, 0)
            i10 = wp.max(p10 + q, 0)
            i01 = wp.max(p01 + q, 0)
            i11 = wp.max(p11 + q, 0)
            if inside:
                # all four taps inside (the common case): no per-tap tests
                v00 = image[i00]
                v10 = image[i10]
                v01 = image[i01]
                v11 = image[i11]
                if scatter:
                    g_image[i00] += g * w00
                    g_image[i10] += g * w10
                    g_image[i01] += g * w01
                    g_image[i11] += g * w11
                gx += g * ((v10 - v00) * wy0 + (v11 - v01) * wy1)
                gy += g * ((v01 - v00) * wx0 + (v11 - v10) * wx1)
            else:
                v00 = wp.where(k00, image[i00], zero)
                v10 = wp.where(k10, image[i10], zero)
                v01 = wp.where(k01, image[i01], zero)
                v11 = wp.where(k11, image[i11], zero)
                if s00:
                    g_image[i00] += g * w00
                if s10:
                    g_image[i10] += g * w10
                if s01:
                    g_image[i01] += g * w01
                if s11:
                    g_image[i11] += g * w11
                gx += g * ((v10 - v00) * wy0 + (v11 - v01) * wy1)
                gy += g * ((v01 - v00) * wx0 + (v11 - v10) * wx1)
    for c in range(UNROLLED_CHANNELS, C):
        q = c * hw_in
        g = g_out[dst + c * hw_out]
        v00 = wp.where(k00, image[p00 + q], zero)
        v10 = wp.where(k10, image[p10 + q], zero)
        v01 = wp.where(k01, image[p01 + q], zero)
        v11 = wp.where(k11, image[p11 + q], zero)
        if s00:
            g_image[p00 + q] += g * w00
        if s10:
            g_image[p10 + q] += g * w10
        if s01:
            g_image[p01 + q] += g * w01
        if s11:
            g_image[p11 + q] += g * w11
        gx += g * ((v10 - v00) * wy0 + (v11 - v01) * wy1)
        gy += g * ((v01 - v00) * wx0 + (v11 - v10) * wx1)
    return gx, gy


def _sample_channels(T):
    """sample_channels' float type ``T`` overload (Warp custom adjoints need concrete types)."""

    @wp.func
    def sample_channels(
        image: wp.array(dtype=T),
        out: wp.array(dtype=T),
        src: int,
        dst: int,
        C: int,
        hw_in: int,
        hw_out: int,
        H: int,
        W: int,
        x: T,
        y: T,
        active: wp.bool,
    ):
        """out[dst + c hw_out] = bilinear sample of image plane ``src + c hw_in`` (H x W) at pixel
        position (x, y), for c in [0, C); 0 where ``active`` is false.

        Same values as :func:`bilinear` per plane (taps outside the image read 0). When active,
        the caller guarantees -1 < x < W and -1 < y < H (see :func:`sample_position`).
        Gradients: to the image (scattered to the four taps), to x and y; none to the rest.
        """
        if active:
            sample_channels_values(image, out, src, dst, C, hw_in, hw_out, H, W, x, y)
        else:
            for c in range(wp.static(UNROLLED_CHANNELS)):
                if c < C:
                    out[wp.max(dst + c * hw_out, 0)] = T(0.0)
            for c in range(UNROLLED_CHANNELS, C):
                out[dst + c * hw_out] = T(0.0)

    @func_grad(sample_channels)
    def adj_sample_channels(
        image: wp.array(dtype=T),
        out: wp.array(dtype=T),
        src: int,
        dst: int,
        C: int,
        hw_in: int,
        hw_out: int,
        H: int,
        W: int,
        x: T,
        y: T,
        active: wp.bool,
    ):
        if active:
            gx, gy = sample_channels_grad(
                image, wp.adjoint[image], wp.adjoint[out], src, dst, C, hw_in, hw_out, H, W, x, y
            )
            wp.adjoint[x] += gx
            wp.adjoint[y] += gy

    @wp.func_replay(sample_channels)
    def replay_sample_channels(
        image: wp.array(dtype=T),
        out: wp.array(dtype=T),
        src: int,
        dst: int,
        C: int,
        hw_in: int,
        hw_out: int,
        H: int,
        W: int,
        x: T,
        y: T,
        active: wp.bool,
    ):
        # The backward pass needs nothing the forward stored: skip re-sampling every channel.
        pass

    return sample_channels


sample_channels = float_overloads(_sample_channels)


__all__ = [
    "INSIDE_TOLERANCE", "PADDING_BORDER", "PADDING_MODES", "PADDING_ZEROS", "UNROLLED_CHANNELS", "bilinear",
    "bilinear_taps", "normalized_to_pixel", "sample_channels", "sample_channels_grad", "sample_channels_values",
    "sample_position", "tap",
]
