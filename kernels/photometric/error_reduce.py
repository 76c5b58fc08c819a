"""The reductions of ``photometric_error``'s fast kernel (:mod:`.error`) and its backward scaling.

- :data:`ROW_SLOTS`: the float64 slots per reference row that :func:`.error.error_lanes`' kernel
  writes: S (sum of rho), n (valid pixels), dS/da0 (3), dS/dax (3), dS/dt (3), and dS/d(fx, s, cx,
  fy, cy) through the projection (5).
- :data:`error_reduce`: per batch item, the rows' slots summed in row order (float64): S_b, n_b,
  E_b = S_b / (C n_b), and dS/d pose (3x4) and dS/d K (3x3), the rays' part taken through (R, K)
  row by row.
- :data:`scale_segments`: the backward pass, out[i] = src[i] grad_output_b / (C n_b) (a scalar and
  a length-8 vector view of ``src`` and ``out`` each).

The reductions run in a fixed order, so results are bitwise identical for any split over threads.
"""

from typing import Any

import warp as wp

from ..core.kinds import FloatKernel

# float64 slots per row: S (sum of rho), n (valid pixels), dS/da0 (3), dS/dax (3), dS/dt (3),
# dS/d(fx, s, cx, fy, cy) through the projection (5)
ROW_SLOTS = wp.constant(16)


@wp.kernel(module="unique", enable_backward=False)
def _error_reduce(
    offset: int,
    rows: wp.array(dtype=wp.float64),
    pose: wp.array(dtype=Any),
    K: wp.array(dtype=Any),
    H: int,
    C: int,
    grad: int,
    error: wp.array(dtype=Any),
    count: wp.array(dtype=Any),
    g_pose: wp.array(dtype=Any),
    g_K: wp.array(dtype=Any),
):
    # Element b: its H rows' slots summed in row order (float64); error = S / (C n) (0 where
    # n = 0), count = n; with ``grad``, g_pose = dS/d pose (3x4) and g_K = dS/d K (3x3): the
    # translation's and the projection's parts are row sums, the rays' (a0, ax) = (R K^-1 [0, y, 1],
    # R K^-1 e_x) part goes through R and K row by row.
    b = wp.tid() + offset
    o = b * H * ROW_SLOTS
    s = wp.float64(0.0)
    n = wp.float64(0.0)
    for h in range(H):
        s = s + rows[o + h * ROW_SLOTS]
        n = n + rows[o + h * ROW_SLOTS + 1]
    error[b] = error.dtype(wp.where(n > wp.float64(0.0), s / (wp.float64(C) * wp.where(n > wp.float64(0.0), n,
                                                                                         wp.float64(1.0))),
                                    wp.float64(0.0)))
    count[b] = count.dtype(n)
    if grad != 0:
        Kb = K[b]
        Tb = pose[b]
        fx = wp.float64(Kb[0, 0])
        sk = wp.float64(Kb[0, 1])
        cx = wp.float64(Kb[0, 2])
        fy = wp.float64(Kb[1, 1])
        cy = wp.float64(Kb[1, 2])
        R = wp.matrix_from_rows(
            wp.vector(wp.float64(Tb[0, 0]), wp.float64(Tb[0, 1]), wp.float64(Tb[0, 2])),
            wp.vector(wp.float64(Tb[1, 0]), wp.float64(Tb[1, 1]), wp.float64(Tb[1, 2])),
            wp.vector(wp.float64(Tb[2, 0]), wp.float64(Tb[2, 1]), wp.float64(Tb[2, 2])),
        )
        gR = wp.mat33d()
        gt = wp.vec3d()
        # K: projection part (fx, s, cx, fy, cy), then the rays'
        kfx = wp.float64(0.0)
        ks = wp.float64(0.0)
        kcx = wp.float64(0.0)
        kfy = wp.float64(0.0)
        kcy = wp.float64(0.0)
        ga_x = wp.vec3d()  # sum of dS/dax over rows
        for h in range(H):
            p = o + h * ROW_SLOTS
            ga0 = wp.vec3d(rows[p + 2], rows[p + 3], rows[p + 4])
            gax = wp.vec3d(rows[p + 5], rows[p + 6], rows[p + 7])
            gt = gt + wp.vec3d(rows[p + 8], rows[p + 9], rows[p + 10])
            kfx = kfx + rows[p + 11]
            ks = ks + rows[p + 12]
            kcx = kcx + rows[p + 13]
            kfy = kfy + rows[p + 14]
            kcy = kcy + rows[p + 15]
            # a0 = R ray0, ray0 = K^-1 [0, y, 1] = ((-cx - s ry) / fx, ry, 1), ry = (y - cy) / fy
            ry = (wp.float64(h) - cy) / fy
            rx = (-cx - sk * ry) / fx
            gR = gR + wp.outer(ga0, wp.vec3d(rx, ry, wp.float64(1.0)))
            g0 = wp.transpose(R) * ga0  # dS/d ray0
            g_ry = g0[1] - g0[0] * sk / fx
            kfx = kfx - g0[0] * rx / fx
            kcx = kcx - g0[0] / fx
            ks = ks - g0[0] * ry / fx
            kfy = kfy - g_ry * ry / fy
            kcy = kcy - g_ry / fy
            ga_x = ga_x + gax
        # ax = R (1 / fx, 0, 0)
        gR = gR + wp.outer(ga_x, wp.vec3d(wp.float64(1.0) / fx, wp.float64(0.0), wp.float64(0.0)))
        kfx = kfx - (wp.transpose(R) * ga_x)[0] / (fx * fx)
        q = b * 12
        for i in range(3):
            for j in range(3):
                g_pose[q + i * 4 + j] = g_pose.dtype(gR[i, j])
            g_pose[q + i * 4 + 3] = g_pose.dtype(gt[i])
        k = b * 9
        for i in range(9):
            g_K[k + i] = g_K.dtype(0.0)
        g_K[k + 0] = g_K.dtype(kfx)
        g_K[k + 1] = g_K.dtype(ks)
        g_K[k + 2] = g_K.dtype(kcx)
        g_K[k + 4] = g_K.dtype(kfy)
        g_K[k + 5] = g_K.dtype(kcy)


error_reduce = FloatKernel(
    _error_reduce, pose="mat34", K="mat33", error="scalar", count="scalar", g_pose="scalar", g_K="scalar"
).set_parallel(scopes={"rows": "any", "pose": "any", "K": "any"}, forward=True, grain=1 << 30)


@wp.func
def segment_factor(grad_error: wp.array(dtype=Any), count: wp.array(dtype=Any), b: int, C: int):
    """grad_error[b] / (C count[b]), 0 where count[b] = 0: d error_b / d S_b times the incoming
    gradient."""
    nb = count[b]
    zero = type(nb)(0.0)
    return wp.where(nb > zero, grad_error[b] / (type(nb)(C) * wp.where(nb > zero, nb, type(nb)(1.0))), zero)


# values per element of scale_segments, and its fewest elements per chunk of a threaded launch
# (one piece below ~1 M values): splitting this copy pays for the chunks' fixed costs only from a
# few million values
SCALE_SPAN = wp.constant(2048)
SCALE_GRAIN = 512


@wp.kernel(module="unique", enable_backward=False)
def _scale_segments(
    offset: int,
    src: wp.array(dtype=Any),
    src8: wp.array(dtype=Any),
    grad_error: wp.array(dtype=Any),
    count: wp.array(dtype=Any),
    seg: int,
    n: int,
    C: int,
    out: wp.array(dtype=Any),
    out8: wp.array(dtype=Any),
):
    # Element k: out[i] = src[i] segment_factor(b) for i in [k SCALE_SPAN, (k + 1) SCALE_SPAN) ∩ [0, n),
    # b = i // seg (segment = batch item), one run per segment: one factor, the values before the
    # run's first multiple of 8 one by one, then 8 at a time through ``src8``/``out8`` (length-8
    # vector views of the same buffers, n // 8 long: one vector load, multiply and store each,
    # about twice as fast as 8 scalar copies), then the run's last few one by one. The vector
    # index i // 8 is taken of wp.max(i, 0), which the compiler knows is not negative (no
    # negative-index wrap, a shift). Every bound is written so that no int32 sum exceeds n
    # (< 2^31): i + SCALE_SPAN, i + 8 or i + 7 would wrap for n within a span of 2^31.
    i = (wp.tid() + offset) * SCALE_SPAN
    end = wp.min(i, n - SCALE_SPAN) + SCALE_SPAN
    while i < end:
        b = i // seg
        stop = b * seg + wp.min(seg, end - b * seg)
        f = segment_factor(grad_error, count, b, C)
        head = i + wp.min(stop - i, (8 - i % 8) % 8)
        while i < head:
            out[i] = src[i] * f
            i += 1
        while stop - i >= 8:
            j = wp.max(i, 0) // 8
            out8[j] = src8[j] * f
            i += 8
        while i < stop:
            out[i] = src[i] * f
            i += 1


scale_segments = FloatKernel(
    _scale_segments, src="scalar", src8="vec8", grad_error="scalar", count="scalar", out="scalar", out8="vec8"
).set_parallel(scopes={"src": "any", "src8": "any", "grad_error": "any", "count": "any"}, forward=True,
               grain=SCALE_GRAIN)


def scale_segments_dim(n: int) -> int:
    """The launch size of :data:`scale_segments` over ``n`` values."""
    return (n + SCALE_SPAN - 1) // SCALE_SPAN
