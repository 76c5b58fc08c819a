"""The row slots of the photometric normal equations and their reduction per batch item.

Every row kernel of the normal equations (:mod:`.normal_equations`: one pixel at a time, pinhole
or through a lens; :mod:`.normal_equations_lanes`: 8 pixels at a time) writes one reference row's
sums to :data:`ROW_STRIDE` float64 slots of its own: the 21 upper-triangle entries of J^T W J
(row-major), the 6 of J^T W r, the cost sum rho(r) and the pixel count (:data:`N_SUMS` in all).
:data:`normal_equations_reduce` adds the rows of each batch item in row order, so results are
bitwise identical for any split of the rows over threads.
"""

from typing import Any

import warp as wp

from ..core.kinds import FloatKernel

# float64 slots per row of the normal equations' partial sums: 21 (upper triangle of J^T W J,
# row-major), 6 (J^T W r), cost, count; padded to 32
ROW_STRIDE = wp.constant(32)
N_SUMS = wp.constant(29)
# the 8-lane kernel's spare scratch slot for its vectorisation seed (after the sums, in the row's slots)
SEED_SLOT = wp.constant(29)
assert N_SUMS <= SEED_SLOT < ROW_STRIDE

vec6d = wp.types.vector(length=6, dtype=wp.float64)
mat66d = wp.types.matrix(shape=(6, 6), dtype=wp.float64)


@wp.kernel(module="unique", enable_backward=False)
def _normal_equations_reduce(
    offset: int,
    rows: wp.array(dtype=wp.float64),
    H: int,
    JtWJ: wp.array(dtype=Any),
    JtWr: wp.array(dtype=Any),
    cost: wp.array(dtype=Any),
    count: wp.array(dtype=Any),
):
    # Element e = (b, k): slot k of batch item b summed over its H rows in row order; outputs
    # flat: JtWJ (B, 6, 6) (both triangles), JtWr (B, 6), cost (B,), count (B,).
    e = wp.tid() + offset
    b = e // N_SUMS
    k = e - b * N_SUMS
    acc = wp.float64(0.0)
    o = b * H * ROW_STRIDE + k
    for h in range(H):
        acc = acc + rows[o + h * ROW_STRIDE]
    v = cost.dtype(acc)
    if k < 21:
        i = int(0)  # noqa: UP018 (a Warp variable, not a constant)
        while k >= (i + 1) * (12 - i) // 2:  # first slot of triangle row i + 1
            i += 1
        j = k - i * (11 - i) // 2
        JtWJ[b * 36 + i * 6 + j] = v
        JtWJ[b * 36 + j * 6 + i] = v
    elif k < 27:
        JtWr[b * 6 + k - 21] = v
    elif k == 27:
        cost[b] = v
    else:
        count[b] = v


normal_equations_reduce = FloatKernel(
    _normal_equations_reduce, JtWJ="scalar", JtWr="scalar", cost="scalar", count="scalar"
).set_parallel(scopes={"rows": "any"}, forward=True, grain=1 << 30)
