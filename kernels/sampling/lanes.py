"""The bilinear sampler, 8 positions at a time (``@wp.func``, no launches here).

Warp compiles a CPU thread's work as scalar code, and LLVM does not vectorise the loop over
threads; it does vectorise straight-line arithmetic on Warp's fixed-length vector types (SLP).
The functions below take 8 consecutive sample positions as one length-8 vector per coordinate
(``vec8f`` / ``vec8d``): weights and tap addresses are computed 8 at a time in SIMD registers,
only the image reads are per lane. They give the same values, operation for operation, as
:func:`.scalar.sample_position` + :func:`.scalar.sample_channels` (the tests check it bitwise, for
any image values, NaN and inf included, and any positions). A kernel built on them writes its own
adjoint on the lanes from :func:`position_grad_lanes` and :func:`scatter_lanes` (the sampler's,
:mod:`.bilinear_block`; the spatial transformer's, :mod:`.pinhole_block`), or borrows a scalar
kernel's (the values being the same). Addresses are carried as floats: exact while an image
plane has at most 2^24 pixels (:data:`MAX_LANES_PLANE`; larger planes take the scalar kernels,
or, in the lens kernel, the pixel-by-pixel path).
Exported by :mod:`.sampler` too.
"""

from typing import Any

import warp as wp

from .scalar import PADDING_BORDER, UNROLLED_CHANNELS, sample_position

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
def gather_lanes32(a: wp.array(dtype=Any), base: int, idx: Any, mask: Any):
    """:func:`gather_lanes` with the indices left as signed 32-bit integers (no ``max(., 0)``; the
    same precondition: valid addresses in every lane, and so the same values). LLVM then reads the 8
    lanes with one 8-wide gather with 32-bit indices (``vgatherdps``) instead of two 4-wide ones with
    64-bit indices and their widening. On an Intel Xeon guest the spatial transformer's forward took
    3-17% less time with it, the sampler's alone 5-8% more, and the spatial transformer's backward
    more (``benchmarks/RESULTS.md``): :func:`blend_lanes` takes either."""
    zero = type(idx[0])(0.0)
    return type(idx)(
        wp.where(mask[0] != zero, a[base + int(idx[0])], zero),
        wp.where(mask[1] != zero, a[base + int(idx[1])], zero),
        wp.where(mask[2] != zero, a[base + int(idx[2])], zero),
        wp.where(mask[3] != zero, a[base + int(idx[3])], zero),
        wp.where(mask[4] != zero, a[base + int(idx[4])], zero),
        wp.where(mask[5] != zero, a[base + int(idx[5])], zero),
        wp.where(mask[6] != zero, a[base + int(idx[6])], zero),
        wp.where(mask[7] != zero, a[base + int(idx[7])], zero),
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
def position_grad_lanes(
    image: wp.array(dtype=Any), q: int, g: Any, a00: Any, a10: Any, a01: Any, a11: Any,
    m00: Any, m10: Any, m01: Any, m11: Any, wx0: Any, wx1: Any, wy0: Any, wy1: Any,
):
    """For an adjoint on the lanes: one channel plane's (at ``q``) share of d loss / d (x, y) for the
    8 positions of :func:`taps_lanes`' taps (``m``: their masks), given the incoming gradient ``g``:
    g ((v10 - v00) wy0 + (v11 - v01) wy1), g ((v01 - v00) wx0 + (v11 - v10) wx1)."""
    v00 = gather_lanes(image, q, a00, m00)
    v10 = gather_lanes(image, q, a10, m10)
    v01 = gather_lanes(image, q, a01, m01)
    v11 = gather_lanes(image, q, a11, m11)
    return (
        wp.cw_mul(g, wp.cw_mul(v10 - v00, wy0) + wp.cw_mul(v11 - v01, wy1)),
        wp.cw_mul(g, wp.cw_mul(v01 - v00, wx0) + wp.cw_mul(v11 - v10, wx1)),
    )


@wp.func
def scatter_lanes(
    g_image: wp.array(dtype=Any), q: int, g: Any, a00: Any, a10: Any, a01: Any, a11: Any,
    m00: Any, m10: Any, m01: Any, m11: Any, w00: Any, w10: Any, w01: Any, w11: Any,
):
    """For an adjoint on the lanes: one channel plane's (at ``q``) share of d loss / d image, g w
    added to each tap whose mask is set. The products are vector code, the read-modify-writes scalar
    (lanes may share a tap), lane after lane, each lane's taps in the scalar sampler's order. (The
    scalar kernels' adjoints run their pixels from last to first; lanes from last to first here,
    which would make the spatial transformer's image gradient bitwise its row kernel's, made its
    backward 13-30% slower.)"""
    zero = type(g[0])(0.0)
    c00 = wp.cw_mul(g, w00)
    c10 = wp.cw_mul(g, w10)
    c01 = wp.cw_mul(g, w01)
    c11 = wp.cw_mul(g, w11)
    b = wp.max(q, 0)
    for k in range(wp.static(LANES)):
        if m00[k] != zero:
            g_image[b + wp.max(int(a00[k]), 0)] += c00[k]
        if m10[k] != zero:
            g_image[b + wp.max(int(a10[k]), 0)] += c10[k]
        if m01[k] != zero:
            g_image[b + wp.max(int(a01[k]), 0)] += c01[k]
        if m11[k] != zero:
            g_image[b + wp.max(int(a11[k]), 0)] += c11[k]


@wp.func
def planes_view(a: wp.array(dtype=Any), plane_size: int):
    """A contiguous flat array of planes of ``plane_size`` values seen as a 2-D (plane, value)
    array over the same memory. Made in the kernel, its element stride is a compile-time constant,
    and so is that of a plane taken from it (``view[p]``, a 1-D array): :func:`gather_lanes` from
    such planes computes a tap's address once for every plane it reads (the flat array's run-time
    stride made the compiler multiply each plane's index anew)."""
    return wp.array(ptr=a.ptr, shape=(a.shape[0] // plane_size, plane_size), dtype=a.dtype)


@wp.func
def dense(a: wp.array(dtype=Any)):
    """A contiguous 1-D array (the caller's guarantee: the torch bridge's arrays and Warp's own
    allocations are) seen as a 1-D array made here, over the same memory: its element stride is a
    compile-time constant. For functions the compiler does not inline into their kernel (e.g.
    a large custom adjoint), where an argument's stride is read at run time: an integer multiply in
    every address, which held up a scatter's read-modify-writes (measured: the 8-lane spatial
    transformer's backward 0.8x as long with its arrays seen through this)."""
    return wp.array(ptr=a.ptr, shape=(a.shape[0],), dtype=a.dtype)


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
    w00: Any, w10: Any, w01: Any, w11: Any, index32: int,
):
    """One channel plane (at ``q``) of :func:`sample_lanes`: the weighted sum of the four masked
    taps, in :func:`sample_channels_values`'s order; ``index32`` (a constant at the call) 1: the
    taps read by :func:`gather_lanes32`, else :func:`gather_lanes` (the same values)."""
    if index32 != 0:
        return (
            wp.cw_mul(gather_lanes32(image, q, a00, m00), w00)
            + wp.cw_mul(gather_lanes32(image, q, a10, m10), w10)
            + wp.cw_mul(gather_lanes32(image, q, a01, m01), w01)
            + wp.cw_mul(gather_lanes32(image, q, a11, m11), w11)
        )
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
    index32: int,
):
    """out[dst + c hw_out] (8 lanes) = bilinear samples of image plane ``src + c hw_in`` (H x W)
    at the 8 positions (x, y) in [-1, W] x [-1, H], for c in [0, C); taps outside the image read
    0, and so do whole lanes where ``inside`` is 0 (see :func:`sample_position_lanes`).
    ``index32``: see :func:`blend_lanes` (measured on an Intel Xeon guest: the spatial
    transformer's forward 3-17% faster with 1, the sampler's alone 5-8% slower).
    Forward only (no custom adjoint: a kernel using it writes its own, as :mod:`.bilinear_block`,
    :mod:`.pinhole_block` and :mod:`.lens_block` do, or borrows a scalar kernel's)."""
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
            out[dst + c * hw_out] = blend_lanes(image, q, a00, a10, a01, a11, m00, m10, m01, m11, w00, w10, w01, w11,
                                                index32)
    for c in range(UNROLLED_CHANNELS, C):
        q = src + c * hw_in
        out[dst + c * hw_out] = blend_lanes(image, q, a00, a10, a01, a11, m00, m10, m01, m11, w00, w10, w01, w11,
                                            index32)


__all__ = [
    "LANES", "MAX_LANES_PLANE", "blend_lanes", "clamp_lanes", "dense", "floor_lanes", "gather_lanes", "gather_lanes32",
    "inside_flag", "normalized_to_pixel_lanes", "planes_view", "position_grad_lanes", "sample_lanes",
    "sample_position_lanes", "scatter_lanes", "taps_lanes",
]
