"""Bilinear sampling building blocks as generic ``@wp.func`` (no launches here).

Images are flat 1-D arrays in (B, C, H, W) row-major order; ``plane`` is the flat offset of
one (b, c) channel plane. Sample positions are in pixels, (x, y) = (column, row), pixel centres
at integer coordinates. Taps outside the image read as 0 (``PADDING_ZEROS``); with
``PADDING_BORDER`` the position is first clamped into [0, W-1] x [0, H-1] (zero gradient to
the position when clamped), exactly as ``torch.nn.functional.grid_sample`` does.

:func:`sample_channels` samples every channel of one position at once with a hand-shaped Warp
adjoint (``@wp.func_grad``): the tap addresses and weights are computed once for all channels,
the image gradient is scattered directly, and the forward replay in the backward pass is skipped.
It is what the sampling kernels use; :func:`bilinear` remains the single-plane building block.
:func:`sample_lanes` (with :func:`sample_position_lanes`, :func:`normalized_to_pixel_lanes`) does
the same for 8 positions at once, as length-8 vectors (forward only; see the section below).
"""

from typing import Any

import warp as wp

PADDING_ZEROS = wp.constant(0)
PADDING_BORDER = wp.constant(1)
# padding_mode names (as grid_sample spells them) -> the codes kernels take
PADDING_MODES = {"zeros": int(PADDING_ZEROS), "border": int(PADDING_BORDER)}


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


def _make_sample_channels(T, sample_channels=None):
    """float type ``T`` overload of sample_channels (Warp custom adjoints need concrete types).

    The parameter named like the function is the overload made before, so that Warp registers
    this one next to it (overloads are found through the defining scope).
    """

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

    @wp.func_grad(sample_channels)
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


sample_channels = _make_sample_channels(wp.float64, _make_sample_channels(wp.float32))


# ----------------------------------------------------------------------------- 8 lanes at a time
#
# Warp compiles a CPU thread's work as scalar code, and LLVM does not vectorise the loop over
# threads; it does vectorise straight-line arithmetic on Warp's fixed-length vector types (SLP).
# The functions below take 8 consecutive sample positions as one length-8 vector per coordinate
# (``vec8f`` / ``vec8d``): weights and tap addresses are computed 8 at a time in SIMD registers,
# only the image reads are per lane. They give the same values, operation for operation, as
# :func:`sample_position` + :func:`sample_channels` (the tests check it bitwise, for any image
# values, NaN and inf included, and any positions), so the forward-only kernel built on them
# shares the scalar kernel's adjoint. Addresses are carried as floats: exact while an image plane
# has at most 2^24 pixels (:data:`MAX_LANES_PLANE`; larger planes take the scalar kernel).

LANES = 8
MAX_LANES_PLANE = 1 << 24


@wp.func
def floor_lanes(v: Any):
    """Element-wise floor of a length-8 vector."""
    return type(v)(
        wp.floor(v[0]), wp.floor(v[1]), wp.floor(v[2]), wp.floor(v[3]),
        wp.floor(v[4]), wp.floor(v[5]), wp.floor(v[6]), wp.floor(v[7]),
    )


@wp.func
def clamp_lanes(v: Any, lo: Any, hi: Any):
    """Element-wise clamp of a vector into [lo, hi] (scalars); NaN goes to lo."""
    return wp.min(wp.max(v, type(v)(lo)), type(v)(hi))


@wp.func
def inside_flag(x: Any, y: Any, H: int, W: int, padding: int):
    """1 where :func:`sample_position` calls the position (x, y) inside, else 0 (as a float)."""
    xs, ys, inside = sample_position(x, y, H, W, padding)
    return wp.where(inside, type(x)(1.0), type(x)(0.0))


@wp.func
def gather_lanes(a: wp.array(dtype=Any), base: int, idx: Any, mask: Any):
    """(a[base + idx[k]] where mask[k] != 0, else 0) for the 8 lanes; ``idx`` holds float-valued
    indices (valid, non-negative addresses also where masked). A select, not a product with the
    mask, so a NaN or inf pixel behind a masked tap gives 0, like :func:`sample_channels`'s
    ``wp.where``. The indices are written as max(base, 0) + max(idx, 0): the compiler then knows
    they are not negative and drops Warp's negative-index wrap (a compare and add per access)."""
    zero = type(idx[0])(0.0)
    b = wp.max(base, 0)
    return type(idx)(
        wp.where(mask[0] != zero, a[b + wp.max(int(idx[0]), 0)], zero),
        wp.where(mask[1] != zero, a[b + wp.max(int(idx[1]), 0)], zero),
        wp.where(mask[2] != zero, a[b + wp.max(int(idx[2]), 0)], zero),
        wp.where(mask[3] != zero, a[b + wp.max(int(idx[3]), 0)], zero),
        wp.where(mask[4] != zero, a[b + wp.max(int(idx[4]), 0)], zero),
        wp.where(mask[5] != zero, a[b + wp.max(int(idx[5]), 0)], zero),
        wp.where(mask[6] != zero, a[b + wp.max(int(idx[6]), 0)], zero),
        wp.where(mask[7] != zero, a[b + wp.max(int(idx[7]), 0)], zero),
    )


@wp.func
def taps_lanes(x: Any, y: Any, fW: Any, fH: Any):
    """The bilinear taps of 8 positions (x, y) in [-1, W) x [-1, H) (a precondition: the masks are
    exact there and only there; ``fW``, ``fH``: W, H as floats). Returns (a00, a10, a01, a11, m00,
    m10, m01, m11, wx1, wy1): the float addresses y W + x of the taps (x0, y0), (x0 + 1, y0),
    (x0, y0 + 1), (x0 + 1, y0 + 1) in a plane, clamped into it (valid addresses also for taps
    outside), their 0/1 masks (1 where the tap is in the image) and the fractional parts of x and
    y. For :func:`gather_lanes`."""
    one = type(fW)(1.0)
    zero = type(fW)(0.0)
    ones = type(x)(one)
    fx0 = floor_lanes(x)
    fy0 = floor_lanes(y)
    # fx0 is an integer in [-1, W - 1]: tap column fx0 is in the image iff fx0 >= 0, fx0 + 1 iff
    # fx0 <= W - 2 (exact as clamps, which vectorise); likewise rows
    mx0 = clamp_lanes(fx0 + ones, zero, one)
    mx1 = clamp_lanes(type(x)(fW - one) - fx0, zero, one)
    my0 = clamp_lanes(fy0 + ones, zero, one)
    my1 = clamp_lanes(type(x)(fH - one) - fy0, zero, one)
    xa = clamp_lanes(fx0, zero, fW - one)
    xb = clamp_lanes(fx0 + ones, zero, fW - one)
    ra = clamp_lanes(fy0, zero, fH - one) * fW
    rb = clamp_lanes(fy0 + ones, zero, fH - one) * fW
    return (
        ra + xa, ra + xb, rb + xa, rb + xb,
        wp.cw_mul(my0, mx0), wp.cw_mul(my0, mx1), wp.cw_mul(my1, mx0), wp.cw_mul(my1, mx1),
        x - fx0, y - fy0,
    )


@wp.func
def planes_view(a: wp.array(dtype=Any), plane_size: int):
    """A contiguous flat array of planes of ``plane_size`` values seen as a 2-D (plane, value)
    array over the same memory. Made in the kernel, its element stride is a compile-time constant,
    and so is that of a plane taken from it (``view[p]``, a 1-D array): :func:`gather_lanes` from
    such planes computes a tap's address once for every plane it reads (the flat array's run-time
    stride made the compiler multiply each plane's index anew)."""
    return wp.array(ptr=a.ptr, shape=(a.shape[0] // plane_size, plane_size), dtype=a.dtype)


@wp.func
def normalized_to_pixel_lanes(g: Any, size: int, align_corners: int):
    """:func:`normalized_to_pixel` on 8 lanes (the same operations in the same order)."""
    one = type(g)(type(g[0])(1.0))
    half = type(g[0])(0.5)
    n = type(g[0])(size)
    if align_corners != 0:
        x = (g + one) * half * (n - type(n)(1.0))
    else:
        x = ((g + one) * n - one) * half
    return x


@wp.func
def sample_position_lanes(x: Any, y: Any, H: int, W: int, padding: int):
    """:func:`sample_position` on 8 lanes: returns (xs, ys, inside) with ``inside`` 1 or 0 per
    lane exactly where :func:`sample_position` says inside or not (NaN: 0). The positions are
    also clamped into [-1, W] x [-1, H] (NaN to -1), which keeps the tap arithmetic finite for
    the lanes that are not inside."""
    zero = type(x[0])(0.0)
    one = type(x[0])(1.0)
    xs = x
    ys = y
    if padding == PADDING_BORDER:
        xs = clamp_lanes(x, zero, type(zero)(W - 1))
        ys = clamp_lanes(y, zero, type(zero)(H - 1))
    inside = type(x)(
        inside_flag(x[0], y[0], H, W, padding), inside_flag(x[1], y[1], H, W, padding),
        inside_flag(x[2], y[2], H, W, padding), inside_flag(x[3], y[3], H, W, padding),
        inside_flag(x[4], y[4], H, W, padding), inside_flag(x[5], y[5], H, W, padding),
        inside_flag(x[6], y[6], H, W, padding), inside_flag(x[7], y[7], H, W, padding),
    )
    return clamp_lanes(xs, -one, type(zero)(W)), clamp_lanes(ys, -one, type(zero)(H)), inside


@wp.func
def blend_lanes(
    image: wp.array(dtype=Any), q: int,
    a00: Any, a10: Any, a01: Any, a11: Any, m00: Any, m10: Any, m01: Any, m11: Any,
    w00: Any, w10: Any, w01: Any, w11: Any,
):
    """One channel plane (at ``q``) of :func:`sample_lanes`: the weighted sum of the four masked
    taps, in :func:`sample_channels_values`'s order."""
    return (
        wp.cw_mul(gather_lanes(image, q, a00, m00), w00)
        + wp.cw_mul(gather_lanes(image, q, a10, m10), w10)
        + wp.cw_mul(gather_lanes(image, q, a01, m01), w01)
        + wp.cw_mul(gather_lanes(image, q, a11, m11), w11)
    )


@wp.func
def sample_lanes(
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
    inside: Any,
):
    """out[dst + c hw_out] (8 lanes) = bilinear samples of image plane ``src + c hw_in`` (H x W)
    at the 8 positions (x, y) in [-1, W] x [-1, H], for c in [0, C); taps outside the image read
    0, and so do whole lanes where ``inside`` is 0 (see :func:`sample_position_lanes`).
    Forward only (no custom adjoint: kernels using it borrow the scalar kernel's)."""
    one = type(x[0])(1.0)
    zero = type(one)(0.0)
    ones = type(x)(one)
    fW = type(one)(W)
    fH = type(one)(H)
    fx0 = floor_lanes(x)
    fy0 = floor_lanes(y)
    wx1 = x - fx0
    wy1 = y - fy0
    wx0 = ones - wx1
    wy0 = ones - wy1
    # 0/1 masks: tap column x0 is inside iff 0 <= x0 <= W - 1, x0 + 1 iff -1 <= x0 <= W - 2
    # (x0 is integral), likewise rows; a masked tap reads 0 (gather_lanes); addresses are clamped
    mx0 = wp.cw_mul(clamp_lanes(fx0 + ones, zero, one), clamp_lanes(type(x)(fW) - fx0, zero, one))
    mx1 = wp.cw_mul(clamp_lanes(fx0 + ones + ones, zero, one), clamp_lanes(type(x)(fW - one) - fx0, zero, one))
    my0 = wp.cw_mul(clamp_lanes(fy0 + ones, zero, one), clamp_lanes(type(x)(fH) - fy0, zero, one))
    my1 = wp.cw_mul(clamp_lanes(fy0 + ones + ones, zero, one), clamp_lanes(type(x)(fH - one) - fy0, zero, one))
    xa = clamp_lanes(fx0, zero, fW - one)
    xb = clamp_lanes(fx0 + ones, zero, fW - one)
    ra = clamp_lanes(fy0, zero, fH - one) * fW
    rb = clamp_lanes(fy0 + ones, zero, fH - one) * fW
    a00 = ra + xa
    a10 = ra + xb
    a01 = rb + xa
    a11 = rb + xb
    m00 = wp.cw_mul(inside, wp.cw_mul(mx0, my0))
    m10 = wp.cw_mul(inside, wp.cw_mul(mx1, my0))
    m01 = wp.cw_mul(inside, wp.cw_mul(mx0, my1))
    m11 = wp.cw_mul(inside, wp.cw_mul(mx1, my1))
    w00 = wp.cw_mul(wx0, wy0)
    w10 = wp.cw_mul(wx1, wy0)
    w01 = wp.cw_mul(wx0, wy1)
    w11 = wp.cw_mul(wx1, wy1)
    for c in range(wp.static(UNROLLED_CHANNELS)):
        if c < C:
            q = src + c * hw_in
            out[dst + c * hw_out] = blend_lanes(image, q, a00, a10, a01, a11, m00, m10, m01, m11, w00, w10, w01, w11)
    for c in range(UNROLLED_CHANNELS, C):
        q = src + c * hw_in
        out[dst + c * hw_out] = blend_lanes(image, q, a00, a10, a01, a11, m00, m10, m01, m11, w00, w10, w01, w11)
