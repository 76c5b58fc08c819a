"""Kernels of the fused photometric objective: one pass that warps, compares, weights and reduces.

For every reference pixel u = (x, y) of batch item b with a valid depth d (finite, > min_depth),
the moved point P = pose * (d K^-1 [x, y, 1]) is projected into the live image; where P has
z > min_depth and its projection lies inside the live image (the ``valid`` rule of
``warp_frame_depth``, docs/conventions.md), the residual of channel c is
r_c = live_c(project(P)) - ref_c(u) (bilinear sample, zeros padding). Nothing per pixel is written:

- :data:`normal_equations_rows` (forward only): one thread per reference row sums, in float64
  registers, the Gauss-Newton system of the row's residuals for a left-multiplied perturbation
  pose <- exp(delta) pose, delta = [omega, t]: the 21 upper-triangle entries of J^T W J, the 6 of
  J^T W r, the cost sum rho(r) and the pixel count, written once per row (:data:`ROW_STRIDE`
  float64 slots); :data:`normal_equations_reduce` adds the rows of each batch item in row order.
  J is exact for the residual as sampled: (d live / d(u, v)) (d(u, v) / dP) (dP / d delta).
  An optional depth residual joins each pixel (see :func:`_normal_equations_rows`).

Row partial sums are written to disjoint slots and added in a fixed order, so results are
bitwise identical for any split of the rows over threads.
"""

from typing import Any

import warp as wp

from . import camera, lie
from . import photometric as ph
from .launch import FloatKernel
from .sampling_kernels import INSIDE_TOLERANCE

# float64 slots per row of the normal equations' partial sums: 21 (upper triangle of J^T W J,
# row-major), 6 (J^T W r), cost, count; padded to 32
ROW_STRIDE = wp.constant(32)
N_SUMS = wp.constant(29)
# Fewest pixels worth a separate chunk of a threaded launch (a chunk costs ~15-20 us).
_GRAIN_PIXELS = 16384


def _make_normal_equations_rows(static_depth: int):
    """The row kernel of the normal equations, with (static_depth 1) or without the depth term
    (compile-time: no per-pixel test)."""

    @wp.kernel(module="unique", enable_backward=False)
    def _normal_equations_rows(
        offset: int,
        ref_image: wp.array(dtype=Any),
        ref_depth: wp.array(dtype=Any),
        live_image: wp.array(dtype=Any),
        live_depth: wp.array(dtype=Any),
        pose: wp.array(dtype=Any),
        K: wp.array(dtype=Any),
        C: int,
        H: int,
        W: int,
        kind: int,
        scale: wp.float64,
        min_depth: wp.float64,
        depth_weight: wp.float64,
        rows: wp.array(dtype=wp.float64),
    ):
        # Element r = one reference row (flat (b, y)); ref_image/live_image flat (B, C, H, W),
        # ref_depth/live_depth flat (B, H, W). The per-pixel work is branch-free: invalid pixels
        # and residuals get weight 0 (their inputs replaced by harmless values first), so the
        # accumulators are never selected or copied (branches around them made the loop ~3x
        # slower: Warp joins every branch with a select of every variable it assigns).
        r = wp.tid() + offset
        b = r // H
        py = r - b * H
        hw = H * W
        Kb = K[b]
        Tb = pose[b]
        one = type(Kb[0, 0])(1.0)
        zero = type(one)(0.0)
        zmin = type(one)(min_depth)
        big = type(one)(1.0e30)
        c = type(one)(scale)
        tol = type(one)(INSIDE_TOLERANCE)
        umax = type(one)(W - 1) + tol
        vmax = type(one)(H - 1) + tol
        fx = Kb[0, 0]
        s = Kb[0, 1]
        cx = Kb[0, 2]
        fy = Kb[1, 1]
        cy = Kb[1, 2]
        a0, ax = camera.row_rays(lie.pose_rotation(Tb), Kb, type(one)(py))
        t = lie.pose_translation(Tb)
        sw = type(one)(wp.sqrt(depth_weight))
        row = r * W  # flat (b, y, 0) in (B, H, W)
        ref0 = b * C * hw + py * W  # flat (b, 0, y, 0) in (B, C, H, W)
        live0 = b * C * hw
        dep0 = b * hw
        f0 = wp.float64(0.0)
        # J^T W J upper triangle (hij), J^T W r (gi), cost, count: each its own variable (a
        # plain `a = f0` would alias f0, and `+=` would then update every alias)
        h00 = wp.float64(0.0)
        h01 = wp.float64(0.0)
        h02 = wp.float64(0.0)
        h03 = wp.float64(0.0)
        h04 = wp.float64(0.0)
        h05 = wp.float64(0.0)
        h11 = wp.float64(0.0)
        h12 = wp.float64(0.0)
        h13 = wp.float64(0.0)
        h14 = wp.float64(0.0)
        h15 = wp.float64(0.0)
        h22 = wp.float64(0.0)
        h23 = wp.float64(0.0)
        h24 = wp.float64(0.0)
        h25 = wp.float64(0.0)
        h33 = wp.float64(0.0)
        h34 = wp.float64(0.0)
        h35 = wp.float64(0.0)
        h44 = wp.float64(0.0)
        h45 = wp.float64(0.0)
        h55 = wp.float64(0.0)
        g0 = wp.float64(0.0)
        g1 = wp.float64(0.0)
        g2 = wp.float64(0.0)
        g3 = wp.float64(0.0)
        g4 = wp.float64(0.0)
        g5 = wp.float64(0.0)
        cost = wp.float64(0.0)
        count = wp.float64(0.0)
        for px in range(W):
            d = ref_depth[row + px]
            depth_ok = d > zmin and d < big
            x = type(one)(px)
            dd = wp.where(depth_ok, d, one)
            q0 = (a0[0] + ax[0] * x) * dd + t[0]
            q1 = (a0[1] + ax[1] * x) * dd + t[1]
            q2 = (a0[2] + ax[2] * x) * dd + t[2]
            front = q2 > zmin
            inv_z = one / wp.where(front, q2, one)
            xn = q0 * inv_z
            yn = q1 * inv_z
            u = fx * xn + s * yn + cx
            v = fy * yn + cy
            ok = depth_ok and front and u >= -tol and u <= umax and v >= -tol and v <= vmax
            us = wp.where(ok, u, zero)
            vs = wp.where(ok, v, zero)
            i00, i10, i01, i11, k00, k10, k01, k11, wx1, wy1 = ph.taps(us, vs, H, W)
            p = wp.vector(q0, q1, q2)
            count += wp.where(ok, wp.float64(1.0), f0)
            for ch in range(C):
                base = live0 + ch * hw
                val, gu, gv = ph.interpolate(
                    ph.read_tap(live_image, base + i00, k00),
                    ph.read_tap(live_image, base + i10, k10),
                    ph.read_tap(live_image, base + i01, k01),
                    ph.read_tap(live_image, base + i11, k11),
                    wx1,
                    wy1,
                )
                res = val - ref_image[ref0 + ch * hw + px]
                m = ok and wp.isfinite(res) and wp.isfinite(gu) and wp.isfinite(gv)
                rr = wp.where(m, res, zero)
                gp = ph.projection_gradient(wp.where(m, gu, zero), wp.where(m, gv, zero), fx, fy, s, inv_z, xn, yn)
                j0, j1, j2, j3, j4, j5 = ph.twist_jacobian(p, gp)
                w = wp.where(m, wp.float64(ph.irls_weight(rr, kind, c)), f0)
                e0 = wp.float64(j0)
                e1 = wp.float64(j1)
                e2 = wp.float64(j2)
                e3 = wp.float64(j3)
                e4 = wp.float64(j4)
                e5 = wp.float64(j5)
                w0 = w * e0
                w1 = w * e1
                w2 = w * e2
                w3 = w * e3
                w4 = w * e4
                w5 = w * e5
                h00 += w0 * e0
                h01 += w0 * e1
                h02 += w0 * e2
                h03 += w0 * e3
                h04 += w0 * e4
                h05 += w0 * e5
                h11 += w1 * e1
                h12 += w1 * e2
                h13 += w1 * e3
                h14 += w1 * e4
                h15 += w1 * e5
                h22 += w2 * e2
                h23 += w2 * e3
                h24 += w2 * e4
                h25 += w2 * e5
                h33 += w3 * e3
                h34 += w3 * e4
                h35 += w3 * e5
                h44 += w4 * e4
                h45 += w4 * e5
                h55 += w5 * e5
                r64 = wp.float64(rr)
                g0 += w0 * r64
                g1 += w1 * r64
                g2 += w2 * r64
                g3 += w3 * r64
                g4 += w4 * r64
                g5 += w5 * r64
                cost += wp.where(m, wp.float64(ph.penalty(rr, kind, c)), f0)
            if wp.static(static_depth != 0):
                e00 = ph.read_tap(live_depth, dep0 + i00, k00)
                e10 = ph.read_tap(live_depth, dep0 + i10, k10)
                e01 = ph.read_tap(live_depth, dep0 + i01, k01)
                e11 = ph.read_tap(live_depth, dep0 + i11, k11)
                # every tap inside the image (outside ones read 0) and a valid depth
                md = (
                    ok and e00 > zmin and e00 < big and e10 > zmin and e10 < big
                    and e01 > zmin and e01 < big and e11 > zmin and e11 < big
                )
                dv, gdu, gdv = ph.interpolate(
                    wp.where(md, e00, one), wp.where(md, e10, one), wp.where(md, e01, one), wp.where(md, e11, one),
                    wx1, wy1,
                )
                rd = wp.where(md, sw * (q2 - dv), zero)
                gq = ph.projection_gradient(gdu, gdv, fx, fy, s, inv_z, xn, yn)
                # d r_d / dP = sw (e_z - (gdu, gdv) d(u, v)/dP)
                gpd = wp.where(md, wp.vector(-gq[0] * sw, -gq[1] * sw, (one - gq[2]) * sw), wp.vector(zero, zero, zero))
                j0, j1, j2, j3, j4, j5 = ph.twist_jacobian(p, gpd)
                w = wp.where(md, wp.float64(ph.irls_weight(rd, kind, c)), f0)
                e0 = wp.float64(j0)
                e1 = wp.float64(j1)
                e2 = wp.float64(j2)
                e3 = wp.float64(j3)
                e4 = wp.float64(j4)
                e5 = wp.float64(j5)
                w0 = w * e0
                w1 = w * e1
                w2 = w * e2
                w3 = w * e3
                w4 = w * e4
                w5 = w * e5
                h00 += w0 * e0
                h01 += w0 * e1
                h02 += w0 * e2
                h03 += w0 * e3
                h04 += w0 * e4
                h05 += w0 * e5
                h11 += w1 * e1
                h12 += w1 * e2
                h13 += w1 * e3
                h14 += w1 * e4
                h15 += w1 * e5
                h22 += w2 * e2
                h23 += w2 * e3
                h24 += w2 * e4
                h25 += w2 * e5
                h33 += w3 * e3
                h34 += w3 * e4
                h35 += w3 * e5
                h44 += w4 * e4
                h45 += w4 * e5
                h55 += w5 * e5
                r64 = wp.float64(rd)
                g0 += w0 * r64
                g1 += w1 * r64
                g2 += w2 * r64
                g3 += w3 * r64
                g4 += w4 * r64
                g5 += w5 * r64
                cost += wp.where(md, wp.float64(ph.penalty(rd, kind, c)), f0)
        o = r * ROW_STRIDE
        rows[o + 0] = h00
        rows[o + 1] = h01
        rows[o + 2] = h02
        rows[o + 3] = h03
        rows[o + 4] = h04
        rows[o + 5] = h05
        rows[o + 6] = h11
        rows[o + 7] = h12
        rows[o + 8] = h13
        rows[o + 9] = h14
        rows[o + 10] = h15
        rows[o + 11] = h22
        rows[o + 12] = h23
        rows[o + 13] = h24
        rows[o + 14] = h25
        rows[o + 15] = h33
        rows[o + 16] = h34
        rows[o + 17] = h35
        rows[o + 18] = h44
        rows[o + 19] = h45
        rows[o + 20] = h55
        rows[o + 21] = g0
        rows[o + 22] = g1
        rows[o + 23] = g2
        rows[o + 24] = g3
        rows[o + 25] = g4
        rows[o + 26] = g5
        rows[o + 27] = cost
        rows[o + 28] = count

    return FloatKernel(
        _normal_equations_rows, ref_image="scalar", ref_depth="scalar", live_image="scalar", live_depth="scalar",
        pose="mat34", K="mat33",
    ).set_parallel(
        segment=lambda a: a["H"],  # rows of one batch item
        # forward only (no adjoint): every row writes its own ROW_STRIDE slots, so any split is exact
        scopes={"ref_image": "any", "ref_depth": "any", "live_image": "any", "live_depth": "any", "pose": "any",
                "K": "any"},
        forward=True,
        grain=lambda a: max(1, _GRAIN_PIXELS // max(1, a["W"])),
    )


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


#: the row kernels of the normal equations: without ([0]) and with ([1]) the depth term
normal_equations_rows = (_make_normal_equations_rows(0), _make_normal_equations_rows(1))
normal_equations_reduce = FloatKernel(
    _normal_equations_reduce, JtWJ="scalar", JtWr="scalar", cost="scalar", count="scalar"
).set_parallel(scopes={"rows": "any"}, forward=True, grain=1 << 30)
