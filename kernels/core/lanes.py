"""Helpers for kernels that handle 8 consecutive pixels at a time as Warp length-8 vectors ("lanes").

Warp compiles a thread's work as scalar code, except arithmetic on its fixed-length vector types,
which LLVM vectorises (SLP; see ``LANES_MODULE_OPTIONS`` in :mod:`.kinds`). A row kernel that
handles 8 consecutive pixels as length-8 vectors computes projections, taps, interpolation and
sums in SIMD registers; only the image reads and the per-lane tests are scalar. Masks are 0/1
vectors; every value a masked lane computes is finite (its inputs are replaced first), so
multiplying by the mask is exact. ``@wp.func`` only (no kernels); never imports torch.
"""

from typing import Any

import warp as wp


@wp.func
def splat8(s: Any):
    """(s, s, s, s, s, s, s, s)."""
    return wp.vector(s, s, s, s, s, s, s, s)


@wp.func
def iota8(x0: int, one: Any):
    """(x0, x0 + 1, ..., x0 + 7) in the float type of ``one``."""
    return wp.vector(
        type(one)(x0), type(one)(x0 + 1), type(one)(x0 + 2), type(one)(x0 + 3),
        type(one)(x0 + 4), type(one)(x0 + 5), type(one)(x0 + 6), type(one)(x0 + 7),
    )


@wp.func
def load8(a: wp.array(dtype=Any), base: int, x0: int, last: int):
    """a[base + min(x0 + k, last)] for k in 0..7 (lanes past ``last`` repeat it; x0 <= last). The
    indices are written as max(., 0) + k, so the compiler knows they are not negative and drops
    Warp's negative-index wrap (a compare and add per access)."""
    i = wp.max(base + x0, 0)
    n = wp.max(wp.min(last - x0, 7), 0)
    return wp.vector(
        a[i], a[i + wp.min(1, n)], a[i + wp.min(2, n)], a[i + wp.min(3, n)],
        a[i + wp.min(4, n)], a[i + wp.min(5, n)], a[i + wp.min(6, n)], a[i + wp.min(7, n)],
    )


@wp.func
def row8(a: wp.array(dtype=Any), i: int):
    """(a[i], ..., a[i + 7]): 8 straight values, all in the array (the caller's guarantee); the
    index written as max(i, 0) + k, as in :func:`load8`."""
    j = wp.max(i, 0)
    return wp.vector(a[j], a[j + 1], a[j + 2], a[j + 3], a[j + 4], a[j + 5], a[j + 6], a[j + 7])


@wp.func
def step_start(x0: int, W: int, narrow: int):
    """The first pixel that an 8-lane step at pixel ``x0`` of a W-pixel row reads: x0, but in the
    row's last, partial block W - 8, the row's last 8 pixels (overlapping the block before: the
    caller masks the lanes before x0), so that every step reads 8 straight values (:func:`row8`,
    faster than :func:`load8`'s clamped lanes); x0 in rows narrower than 8 (``narrow``, a compile-time constant)."""
    if narrow != 0:
        return x0
    return wp.min(x0, W - 8)


@wp.func
def step_load8(a: wp.array(dtype=Any), base: int, xs: int, last: int, narrow: int):
    """The 8 values a[base + xs + k] of a step that starts at ``xs`` (:func:`step_start`); in rows
    narrower than 8 (``narrow``), :func:`load8`'s lanes clamped to ``last``."""
    if narrow != 0:
        return load8(a, base, xs, last)
    return row8(a, base + xs)


@wp.func
def flag(cond: bool, one: Any):
    return wp.where(cond, one, type(one)(0.0))


@wp.func
def above(v: Any, lo: Any):
    """1 where v > lo, else 0 (NaN: 0)."""
    return wp.where(v > lo, type(lo)(1.0), type(lo)(0.0))


@wp.func
def at_least(v: Any, lo: Any):
    """1 where v >= lo, else 0 (NaN: 0)."""
    return wp.where(v >= lo, type(lo)(1.0), type(lo)(0.0))


@wp.func
def above8(v: Any, lo: Any):
    """1 where v > lo (NaN: 0), per lane (a select per lane, no ``and``: see :func:`open_mask8`)."""
    return wp.vector(above(v[0], lo), above(v[1], lo), above(v[2], lo), above(v[3], lo),
                     above(v[4], lo), above(v[5], lo), above(v[6], lo), above(v[7], lo))


@wp.func
def below(v: Any, hi: Any):
    """1 where v < hi, else 0 (NaN: 0)."""
    return wp.where(v < hi, type(hi)(1.0), type(hi)(0.0))


@wp.func
def at_least8(v: Any, lo: Any):
    """1 where v >= lo (NaN: 0), per lane."""
    return wp.vector(at_least(v[0], lo), at_least(v[1], lo), at_least(v[2], lo), at_least(v[3], lo),
                     at_least(v[4], lo), at_least(v[5], lo), at_least(v[6], lo), at_least(v[7], lo))


@wp.func
def below8(v: Any, hi: Any):
    """1 where v < hi (NaN: 0), per lane."""
    return wp.vector(below(v[0], hi), below(v[1], hi), below(v[2], hi), below(v[3], hi),
                     below(v[4], hi), below(v[5], hi), below(v[6], hi), below(v[7], hi))


@wp.func
def less8(a: Any, b: Any):
    """1 where a < b, lane by lane (NaN: 0)."""
    return wp.vector(below(a[0], b[0]), below(a[1], b[1]), below(a[2], b[2]), below(a[3], b[3]),
                     below(a[4], b[4]), below(a[5], b[5]), below(a[6], b[6]), below(a[7], b[7]))


@wp.func
def open_mask8(v: Any, lo: Any, hi: Any):
    """1 where lo < v < hi (NaN: 0), per lane. Products of per-lane selects, no ``and``: Warp
    turns ``and`` into branches, which LLVM does not vectorise."""
    return wp.cw_mul(above8(v, lo), above8(-v, -hi))


@wp.func
def closed_mask8(v: Any, lo: Any, hi: Any):
    """1 where lo <= v <= hi (NaN: 0), per lane (see :func:`open_mask8`)."""
    return wp.cw_mul(
        wp.vector(at_least(v[0], lo), at_least(v[1], lo), at_least(v[2], lo), at_least(v[3], lo),
                  at_least(v[4], lo), at_least(v[5], lo), at_least(v[6], lo), at_least(v[7], lo)),
        wp.vector(at_least(-v[0], -hi), at_least(-v[1], -hi), at_least(-v[2], -hi), at_least(-v[3], -hi),
                  at_least(-v[4], -hi), at_least(-v[5], -hi), at_least(-v[6], -hi), at_least(-v[7], -hi)),
    )


@wp.func
def select8(m: Any, a: Any, b: Any):
    """a where the mask m is 1, else b, per lane (a select: a NaN in the other input is dropped)."""
    z = type(m[0])(0.0)
    return wp.vector(
        wp.where(m[0] != z, a[0], b[0]), wp.where(m[1] != z, a[1], b[1]),
        wp.where(m[2] != z, a[2], b[2]), wp.where(m[3] != z, a[3], b[3]),
        wp.where(m[4] != z, a[4], b[4]), wp.where(m[5] != z, a[5], b[5]),
        wp.where(m[6] != z, a[6], b[6]), wp.where(m[7] != z, a[7], b[7]),
    )


@wp.func
def hsum8(v: Any):
    """The sum of the 8 lanes, in float64, in lane order."""
    return (
        wp.float64(v[0]) + wp.float64(v[1]) + wp.float64(v[2]) + wp.float64(v[3])
        + wp.float64(v[4]) + wp.float64(v[5]) + wp.float64(v[6]) + wp.float64(v[7])
    )


@wp.func
def any8(m: Any):
    """True if a lane of the 0/1 mask ``m`` is 1 (a float32 sum in a tree: exact, and shorter than
    :func:`hsum8`'s chain)."""
    return ((m[0] + m[1]) + (m[2] + m[3])) + ((m[4] + m[5]) + (m[6] + m[7])) > type(m[0])(0.0)


@wp.func
def interpolate8(v00: Any, v10: Any, v01: Any, v11: Any, wx1: Any, wy1: Any):
    """:func:`interpolate` on 8 lanes."""
    ones = splat8(type(wx1[0])(1.0))
    wx0 = ones - wx1
    wy0 = ones - wy1
    value = wp.cw_mul(wp.cw_mul(v00, wx0) + wp.cw_mul(v10, wx1), wy0) + wp.cw_mul(
        wp.cw_mul(v01, wx0) + wp.cw_mul(v11, wx1), wy1
    )
    gx = wp.cw_mul(v10 - v00, wy0) + wp.cw_mul(v11 - v01, wy1)
    gy = wp.cw_mul(v01 - v00, wx0) + wp.cw_mul(v11 - v10, wx1)
    return value, gx, gy
