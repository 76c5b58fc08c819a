"""Kernels of the fused photometric objective: one pass that warps, compares, weights and reduces.

For every reference pixel u = (x, y) of batch item b with a valid depth d (finite, > min_depth),
the moved point P = pose * (d K^-1 [x, y, 1]) is projected into the live image; where P has
z > min_depth and its projection lies inside the live image (the ``valid`` rule of
``warp_frame_depth``, docs/conventions.md), the residual of channel c is
r_c = live_c(project(P)) - ref_c(u) (bilinear sample, zeros padding). Nothing per pixel is written:

- :data:`normal_equations_lanes` (forward only; used) and :data:`normal_equations_rows` (its plain
  one-pixel-at-a-time twin, the readable reference the tests compare it with): one thread per
  reference row sums the Gauss-Newton system of the row's residuals for a left-multiplied perturbation
  pose <- exp(delta) pose, delta = [omega, t]: the 21 upper-triangle entries of J^T W J, the 6 of
  J^T W r, the cost sum rho(r) and the pixel count, written once per row (:data:`ROW_STRIDE`
  float64 slots); :data:`normal_equations_reduce` adds the rows of each batch item in row order.
  The 8-lane kernel handles 8 pixels per step as length-8 vectors, which LLVM vectorises (about
  2x faster than the plain kernel here, most of it in the 27 running sums). Its running sums live
  in the row's own slots of a scratch array (``acc``, :data:`ROW_STRIDE` 8-lane vectors per row):
  carried through the loop in registers, LLVM split them into 232 scalars and rebuilt the vectors
  lane by lane every step. :func:`normal_equations_lanes_for` compiles it for one penalty (its
  branches fold away) and, for C = 1, with the channel loop unrolled: bitwise the same sums,
  14 instead of 22 ns per pixel (one thread, 320x240, Huber, measured side by side). Its steps
  read 8 straight values (the last step of a row its last 8 pixels), not clamped lanes: 8-10%
  faster again.
- :data:`photometric_rows` (forward and Warp adjoint): per row, the sum of rho(r_c) over its valid
  pixels and channels and their count; :data:`photometric_mean` divides by C * count per batch
  item.
  J is exact for the residual as sampled: (d live / d(u, v)) (d(u, v) / dP) (dP / d delta).
  An optional depth residual joins each pixel (see :func:`_normal_equations_rows`).

Row partial sums are written to disjoint slots and added in a fixed order, so results are
bitwise identical for any split of the rows over threads.
"""

import threading
from typing import Any

import warp as wp

from ..core import lanes
from ..core.kinds import LANES_MODULE_OPTIONS, FloatKernel
from ..geometry import camera, lie
from ..sampling import sampler
from ..sampling.kernels import INSIDE_TOLERANCE
from . import residual as ph

# float64 slots per row of the normal equations' partial sums: 21 (upper triangle of J^T W J,
# row-major), 6 (J^T W r), cost, count; padded to 32
ROW_STRIDE = wp.constant(32)
N_SUMS = wp.constant(29)
# the 8-lane kernel's spare scratch slot for its vectorisation seed (after the sums, in the row's slots)
SEED_SLOT = wp.constant(29)
assert N_SUMS <= SEED_SLOT < ROW_STRIDE
# Fewest pixels worth a separate chunk of a threaded launch (a chunk costs ~15-20 us).
_GRAIN_PIXELS = 16384

vec6d = wp.types.vector(length=6, dtype=wp.float64)
mat66d = wp.types.matrix(shape=(6, 6), dtype=wp.float64)


def _make_normal_equations_rows(static_depth: int, static_occlusion: int = 0):
    """The row kernel of the normal equations, with (static_depth 1) or without the depth term,
    with (static_occlusion 1) or without the occlusion test (compile-time: no per-pixel test)."""

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
        occlusion: wp.float64,
        rows: wp.array(dtype=wp.float64),
    ):
        # Element r = one reference row (flat (b, y)); ref_image/live_image flat (B, C, H, W),
        # ref_depth/live_depth flat (B, H, W). The per-pixel work is branch-free: invalid pixels
        # and residuals get weight 0 (their inputs replaced by harmless values first), so the
        # accumulators are never selected or copied (branches around them made the loop ~3x
        # slower: Warp joins every branch with a select of every variable it assigns).
        # (wp.isfinite() tests cost ~14 ns per pixel; the single compare below costs nothing.)
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
        # J^T W J, J^T W r, cost, count (a 6x6 matrix and a 6-vector: LLVM vectorises their
        # updates; 27 scalar accumulators were twice as slow)
        JtWJ = mat66d()
        JtWr = vec6d()
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
            if wp.static(static_occlusion != 0):
                # occlusion test: the diagonal taps 00 and 11, where inside the image, have live
                # depths within occlusion * z of the moved point's (a missing or NaN depth fails)
                lim = type(one)(occlusion) * q2
                ok = (
                    ok and (not k00 or wp.abs(q2 - live_depth[dep0 + i00]) <= lim)
                    and (not k11 or wp.abs(q2 - live_depth[dep0 + i11]) <= lim)
                )
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
                # finite residual and gradient (one compare: NaN and inf fail it, as would a sum
                # beyond 1e30)
                m = ok and wp.abs(res) + wp.abs(gu) + wp.abs(gv) < big
                rr = wp.where(m, res, zero)
                gp = ph.projection_gradient(wp.where(m, gu, zero), wp.where(m, gv, zero), fx, fy, s, inv_z, xn, yn)
                j0, j1, j2, j3, j4, j5 = ph.twist_jacobian(p, gp)
                w = wp.where(m, wp.float64(ph.irls_weight(rr, kind, c)), f0)
                wJ = vec6d(wp.float64(j0), wp.float64(j1), wp.float64(j2), wp.float64(j3), wp.float64(j4),
                           wp.float64(j5)) * w
                JtWJ = JtWJ + wp.outer(wJ, vec6d(wp.float64(j0), wp.float64(j1), wp.float64(j2), wp.float64(j3),
                                                 wp.float64(j4), wp.float64(j5)))
                JtWr = JtWr + wJ * wp.float64(rr)
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
                wJ = vec6d(wp.float64(j0), wp.float64(j1), wp.float64(j2), wp.float64(j3), wp.float64(j4),
                           wp.float64(j5)) * w
                JtWJ = JtWJ + wp.outer(wJ, vec6d(wp.float64(j0), wp.float64(j1), wp.float64(j2), wp.float64(j3),
                                                 wp.float64(j4), wp.float64(j5)))
                JtWr = JtWr + wJ * wp.float64(rd)
                cost += wp.where(md, wp.float64(ph.penalty(rd, kind, c)), f0)
        o = r * ROW_STRIDE
        for i in range(6):
            for j in range(i, 6):
                rows[o + i * (11 - i) // 2 + j] = JtWJ[i, j]  # row-major upper triangle
            rows[o + 21 + i] = JtWr[i]
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


@wp.func
def accumulate8(
    acc: wp.array(dtype=Any), a: int, wj0: Any, wj1: Any, wj2: Any, wj3: Any, wj4: Any, wj5: Any,
    j0: Any, j1: Any, j2: Any, j3: Any, j4: Any, j5: Any, r: Any,
):
    """Adds one 8-lane step's w J^T J (upper triangle, row-major) and w J^T r to the running sums
    acc[a:a + 27] (wj = w J, J = (j0, ..., j5), r the residuals), in the order of the slots."""
    acc[a + 0] = acc[a + 0] + wp.cw_mul(wj0, j0)
    acc[a + 1] = acc[a + 1] + wp.cw_mul(wj0, j1)
    acc[a + 2] = acc[a + 2] + wp.cw_mul(wj0, j2)
    acc[a + 3] = acc[a + 3] + wp.cw_mul(wj0, j3)
    acc[a + 4] = acc[a + 4] + wp.cw_mul(wj0, j4)
    acc[a + 5] = acc[a + 5] + wp.cw_mul(wj0, j5)
    acc[a + 6] = acc[a + 6] + wp.cw_mul(wj1, j1)
    acc[a + 7] = acc[a + 7] + wp.cw_mul(wj1, j2)
    acc[a + 8] = acc[a + 8] + wp.cw_mul(wj1, j3)
    acc[a + 9] = acc[a + 9] + wp.cw_mul(wj1, j4)
    acc[a + 10] = acc[a + 10] + wp.cw_mul(wj1, j5)
    acc[a + 11] = acc[a + 11] + wp.cw_mul(wj2, j2)
    acc[a + 12] = acc[a + 12] + wp.cw_mul(wj2, j3)
    acc[a + 13] = acc[a + 13] + wp.cw_mul(wj2, j4)
    acc[a + 14] = acc[a + 14] + wp.cw_mul(wj2, j5)
    acc[a + 15] = acc[a + 15] + wp.cw_mul(wj3, j3)
    acc[a + 16] = acc[a + 16] + wp.cw_mul(wj3, j4)
    acc[a + 17] = acc[a + 17] + wp.cw_mul(wj3, j5)
    acc[a + 18] = acc[a + 18] + wp.cw_mul(wj4, j4)
    acc[a + 19] = acc[a + 19] + wp.cw_mul(wj4, j5)
    acc[a + 20] = acc[a + 20] + wp.cw_mul(wj5, j5)
    acc[a + 21] = acc[a + 21] + wp.cw_mul(wj0, r)
    acc[a + 22] = acc[a + 22] + wp.cw_mul(wj1, r)
    acc[a + 23] = acc[a + 23] + wp.cw_mul(wj2, r)
    acc[a + 24] = acc[a + 24] + wp.cw_mul(wj3, r)
    acc[a + 25] = acc[a + 25] + wp.cw_mul(wj4, r)
    acc[a + 26] = acc[a + 26] + wp.cw_mul(wj5, r)


@wp.func
def channel8(
    live_image: wp.array(dtype=Any), base: int, ref_image: wp.array(dtype=Any), ref_i: int, xs: int, last: int,
    narrow: int, acc: wp.array(dtype=Any), a_row: int, i00: Any, i10: Any, i01: Any, i11: Any, m00: Any, m10: Any,
    m01: Any, m11: Any, wx1: Any, wy1: Any, ok: Any, q0: Any, q1: Any, q2: Any, inv_z: Any, xn: Any, yn: Any,
    fx: Any, fy: Any, s: Any, kind: int, c: Any,
):
    """One channel of an 8-lane step of the normal equations' row kernel that reads from pixel
    ``xs`` (:func:`.photometric.step_load8`): the residuals live(taps of plane ``base``) -
    ref[ref_i + xs ...], their Jacobians (exact for the bilinear
    interpolant as sampled) and IRLS weights, added to the running sums acc[a_row:a_row + 28]."""
    one = type(c)(1.0)
    zeros = lanes.splat8(type(c)(0.0))
    big = type(c)(1.0e30)
    val, gu, gv = lanes.interpolate8(
        sampler.gather_lanes(live_image, base, i00, m00), sampler.gather_lanes(live_image, base, i10, m10),
        sampler.gather_lanes(live_image, base, i01, m01), sampler.gather_lanes(live_image, base, i11, m11),
        wx1, wy1,
    )
    res = val - lanes.step_load8(ref_image, ref_i, xs, last, narrow)
    # finite residual and derivatives (NaN and inf fail the compare)
    m = wp.cw_mul(ok, lanes.open_mask8(wp.max(res, -res) + wp.max(gu, -gu) + wp.max(gv, -gv), -one, big))
    rr = lanes.select8(m, res, zeros)
    gus = lanes.select8(m, gu, zeros)
    gvs = lanes.select8(m, gv, zeros)
    # d r / dP = (gu, gv) d(u, v)/dP; J = [P x dr/dP, dr/dP]
    p0 = wp.cw_mul(gus, inv_z) * fx
    p1 = wp.cw_mul(gus * s + gvs * fy, inv_z)
    p2 = -wp.cw_mul(wp.cw_mul(gus, xn * fx + yn * s) + wp.cw_mul(gvs, yn) * fy, inv_z)
    j0 = wp.cw_mul(q1, p2) - wp.cw_mul(q2, p1)
    j1 = wp.cw_mul(q2, p0) - wp.cw_mul(q0, p2)
    j2 = wp.cw_mul(q0, p1) - wp.cw_mul(q1, p0)
    w = wp.cw_mul(ph.weight8(rr, kind, c), m)
    accumulate8(acc, a_row, wp.cw_mul(w, j0), wp.cw_mul(w, j1), wp.cw_mul(w, j2), wp.cw_mul(w, p0),
                wp.cw_mul(w, p1), wp.cw_mul(w, p2), j0, j1, j2, p0, p1, p2, rr)
    acc[a_row + 27] = acc[a_row + 27] + wp.cw_mul(ph.penalty8(rr, kind, c), m)


def _make_normal_equations_lanes(
    static_depth: int, static_occlusion: int = 0, static_channels: int = 0, static_kind: int = -1,
    static_narrow: int = -1,
):
    """The row kernel of the normal equations, 8 pixels of the row at a time (SIMD lanes, see
    :mod:`.photometric`); same arguments, values and row slots as
    :func:`_make_normal_equations_rows`'s kernel (up to rounding: its running sums are per lane,
    in the input float type, added in float64 at the end of the row). Every step reads 8
    straight values (:func:`.photometric.step_start`; the row's last, partial step reads its last
    8 pixels and masks those before its own), except in rows narrower than 8 pixels: those read
    clamped lanes. ``static_narrow`` 0 or 1 compiles one of the two in (1: rows narrower than 8
    pixels), -1 chooses per launch from W. Straight loads instead of clamped lanes everywhere:
    8-10% faster at 320x240."""

    @wp.kernel(module="unique", enable_backward=False, module_options=LANES_MODULE_OPTIONS)
    def _normal_equations_lanes(
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
        occlusion: wp.float64,
        rows: wp.array(dtype=wp.float64),
        acc: wp.array(dtype=Any),
    ):
        r = wp.tid() + offset  # one reference row, flat (b, y)
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
        fW = type(one)(W)
        fH = type(one)(H)
        fx = Kb[0, 0]
        s = Kb[0, 1]
        cx = Kb[0, 2]
        fy = Kb[1, 1]
        cy = Kb[1, 2]
        a0, ax = camera.row_rays(lie.pose_rotation(Tb), Kb, type(one)(py))
        t = lie.pose_translation(Tb)
        sw = type(one)(wp.sqrt(depth_weight))
        row = r * W
        ref0 = b * C * hw + py * W
        live0 = b * C * hw
        dep0 = b * hw
        last = W - 1
        ones = lanes.splat8(one)
        zeros = lanes.splat8(zero)
        # running sums per lane in this row's own slots of `acc` (memory, not registers: carried
        # through the loop as 29 vectors, LLVM kept them as 232 scalars and rebuilt the vectors
        # lane by lane every step, which made the sums half of the kernel's time)
        kindc = kind
        if wp.static(static_kind >= 0):  # the penalty compiled in: its branches fold away (~30% faster)
            kindc = wp.static(static_kind)
        narrow = wp.where(W < 8, 1, 0)
        if wp.static(static_narrow >= 0):
            narrow = wp.static(static_narrow)
        a_row = wp.max(r, 0) * ROW_STRIDE  # non-negative: the slot accesses need no negative-index wrap
        for k in range(N_SUMS):
            acc[a_row + k] = zeros
        for k8 in range((W + 7) // 8):
            x0 = k8 * 8
            xs = lanes.step_start(x0, W, narrow)  # the step reads pixels xs .. xs + 7
            x = lanes.iota8(xs, one)
            d = lanes.step_load8(ref_depth, row, xs, last, narrow)
            # lanes outside the step's own pixels x0 .. W - 1 and invalid depths are masked; their
            # depth is replaced by 1
            mdep = wp.cw_mul(lanes.open_mask8(d, zmin, big), lanes.closed_mask8(x, type(one)(x0), fW - one))
            dd = lanes.select8(mdep, d, ones)
            q0 = wp.cw_mul(lanes.splat8(a0[0]) + x * ax[0], dd) + lanes.splat8(t[0])
            q1 = wp.cw_mul(lanes.splat8(a0[1]) + x * ax[1], dd) + lanes.splat8(t[1])
            q2 = wp.cw_mul(lanes.splat8(a0[2]) + x * ax[2], dd) + lanes.splat8(t[2])
            front = lanes.open_mask8(q2, zmin, type(one)(3.0e38))
            inv_z = wp.cw_div(ones, lanes.select8(front, q2, ones))
            xn = wp.cw_mul(q0, inv_z)
            yn = wp.cw_mul(q1, inv_z)
            u = xn * fx + yn * s + lanes.splat8(cx)
            v = yn * fy + lanes.splat8(cy)
            ok = wp.cw_mul(
                wp.cw_mul(mdep, front),
                wp.cw_mul(lanes.closed_mask8(u, -tol, fW - one + tol), lanes.closed_mask8(v, -tol, fH - one + tol)),
            )
            us = lanes.select8(ok, u, zeros)
            vs = lanes.select8(ok, v, zeros)
            # taps as in sampler.sample_lanes: float addresses in the plane, 0/1 masks (in the image)
            i00, i10, i01, i11, m00, m10, m01, m11, wx1, wy1 = sampler.taps_lanes(us, vs, fW, fH)
            # a vectorisation seed, stored in a spare slot of the row's scratch and never read:
            # LLVM's SLP vectoriser grows its trees from stores, and the addresses feed only the
            # gathers' scalar loads. With a store of their own they come out as whole 8-lane
            # vectors: the step's machine code went from 797 to 703 instructions (lane moves and
            # extractions 154 -> 112), 14% faster, bitwise the same
            acc[a_row + SEED_SLOT] = i00 + i10 + i01 + i11
            if wp.static(static_occlusion != 0):
                # occlusion test: the diagonal taps 00 and 11, where inside the image, have live
                # depths within occlusion * z of the moved point's (a missing or NaN depth fails;
                # taps outside read z). Two taps catch a depth edge that splits them; all four
                # cost twice the gathers (the kernel's main cost) for ~4% less pose error.
                o00 = sampler.gather_lanes(live_depth, dep0, i00, m00) + wp.cw_mul(ones - m00, q2)
                o11 = sampler.gather_lanes(live_depth, dep0, i11, m11) + wp.cw_mul(ones - m11, q2)
                dev = wp.max(wp.max(q2 - o00, o00 - q2), wp.max(q2 - o11, o11 - q2))
                ok = wp.cw_mul(ok, lanes.closed_mask8(q2 * type(one)(occlusion) - dev, zero, big))
            acc[a_row + 28] = acc[a_row + 28] + ok
            if wp.static(static_channels == 1):
                channel8(live_image, live0, ref_image, ref0, xs, last, narrow, acc, a_row, i00, i10, i01, i11, m00,
                         m10, m01, m11, wx1, wy1, ok, q0, q1, q2, inv_z, xn, yn, fx, fy, s, kindc, c)
            else:
                for ch in range(C):
                    channel8(live_image, live0 + ch * hw, ref_image, ref0 + ch * hw, xs, last, narrow, acc, a_row, i00,
                             i10, i01, i11, m00, m10, m01, m11, wx1, wy1, ok, q0, q1, q2, inv_z, xn, yn, fx, fy, s,
                             kindc, c)
            if wp.static(static_depth != 0):
                # taps outside the image read 0, which is not a valid depth
                e00 = sampler.gather_lanes(live_depth, dep0, i00, m00)
                e10 = sampler.gather_lanes(live_depth, dep0, i10, m10)
                e01 = sampler.gather_lanes(live_depth, dep0, i01, m01)
                e11 = sampler.gather_lanes(live_depth, dep0, i11, m11)
                md = wp.cw_mul(
                    wp.cw_mul(ok, wp.cw_mul(lanes.open_mask8(e00, zmin, big), lanes.open_mask8(e10, zmin, big))),
                    wp.cw_mul(lanes.open_mask8(e01, zmin, big), lanes.open_mask8(e11, zmin, big)),
                )
                dv, gdu, gdv = lanes.interpolate8(
                    lanes.select8(md, e00, ones), lanes.select8(md, e10, ones), lanes.select8(md, e01, ones),
                    lanes.select8(md, e11, ones), wx1, wy1,
                )
                rd = wp.cw_mul(q2 - dv, md) * sw
                gdus = wp.cw_mul(gdu, md)
                gdvs = wp.cw_mul(gdv, md)
                # d r_d / dP = sw (e_z - (gdu, gdv) d(u, v)/dP)
                p0 = -wp.cw_mul(gdus, inv_z) * (fx * sw)
                p1 = -wp.cw_mul(gdus * s + gdvs * fy, inv_z) * sw
                p2 = (md + wp.cw_mul(wp.cw_mul(gdus, xn * fx + yn * s) + wp.cw_mul(gdvs, yn) * fy, inv_z)) * sw
                j0 = wp.cw_mul(q1, p2) - wp.cw_mul(q2, p1)
                j1 = wp.cw_mul(q2, p0) - wp.cw_mul(q0, p2)
                j2 = wp.cw_mul(q0, p1) - wp.cw_mul(q1, p0)
                w = wp.cw_mul(ph.weight8(rd, kindc, c), md)
                wj0 = wp.cw_mul(w, j0)
                wj1 = wp.cw_mul(w, j1)
                wj2 = wp.cw_mul(w, j2)
                wj3 = wp.cw_mul(w, p0)
                wj4 = wp.cw_mul(w, p1)
                wj5 = wp.cw_mul(w, p2)
                accumulate8(acc, a_row, wj0, wj1, wj2, wj3, wj4, wj5, j0, j1, j2, p0, p1, p2, rd)
                acc[a_row + 27] = acc[a_row + 27] + wp.cw_mul(ph.penalty8(rd, kindc, c), md)
        o = r * ROW_STRIDE
        for k in range(N_SUMS):
            rows[o + k] = lanes.hsum8(acc[a_row + k])

    return FloatKernel(
        _normal_equations_lanes, ref_image="scalar", ref_depth="scalar", live_image="scalar", live_depth="scalar",
        pose="mat34", K="mat33", acc="vec8",
    ).set_parallel(
        segment=lambda a: a["H"],  # rows of one batch item
        # forward only (no adjoint): every row writes its own ROW_STRIDE slots, so any split is exact
        scopes={"ref_image": "any", "ref_depth": "any", "live_image": "any", "live_depth": "any", "pose": "any",
                "K": "any"},
        forward=True,
        grain=lambda a: max(1, _GRAIN_PIXELS // max(1, a["W"])),
    )


#: the 8-lane row kernels of the normal equations, indexed by depth term (1) + 2 * occlusion test (1)
normal_equations_lanes = tuple(_make_normal_equations_lanes(k & 1, k >> 1) for k in range(4))
_LANES_SPECIALISED: dict[tuple, FloatKernel] = {}
_LANES_LOCK = threading.Lock()


def normal_equations_lanes_for(variant: int, C: int, kind: int, W: int) -> FloatKernel:
    """The 8-lane row kernel of :data:`normal_equations_lanes` [``variant``] compiled for one
    penalty ``kind`` (and for C = 1 with the channel loop unrolled, when ``C`` is 1) and for rows
    of ``W`` pixels (at least 8, or fewer): the same arguments and bitwise the same results,
    ~30% faster (built on first use, one Warp module each)."""
    key = (int(variant), 1 if C == 1 else 0, int(kind), int(W < 8))
    with _LANES_LOCK:
        k = _LANES_SPECIALISED.get(key)
        if k is None:
            k = _LANES_SPECIALISED[key] = _make_normal_equations_lanes(key[0] & 1, key[0] >> 1, key[1], key[2],
                                                                       key[3])
        return k


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


#: the row kernels of the normal equations, indexed like :data:`normal_equations_lanes`
normal_equations_rows = tuple(_make_normal_equations_rows(k & 1, k >> 1) for k in range(4))
normal_equations_reduce = FloatKernel(
    _normal_equations_reduce, JtWJ="scalar", JtWr="scalar", cost="scalar", count="scalar"
).set_parallel(scopes={"rows": "any"}, forward=True, grain=1 << 30)


# ----------------------------------------------------------------------------- photometric error


@wp.kernel(module="unique")
def _photometric_rows(
    offset: int,
    ref_image: wp.array(dtype=Any),
    ref_depth: wp.array(dtype=Any),
    live_image: wp.array(dtype=Any),
    pose: wp.array(dtype=Any),
    K: wp.array(dtype=Any),
    C: int,
    H: int,
    W: int,
    kind: int,
    scale: wp.float64,
    min_depth: wp.float64,
    row_sum: wp.array(dtype=Any),
    row_count: wp.array(dtype=Any),
):
    # Element r = one reference row (flat (b, y)): row_sum[r] = sum over its valid pixels and all
    # channels of rho(r_c), row_count[r] = its valid pixels (accumulated in place: a local sum
    # would be carried through Warp's dynamic loop, whose adjoint does not support it). Warp's
    # adjoint: per pixel, the hand-written adjoints of pixel_penalty (taps, residuals, scatter)
    # and project_moved_ray (point, projection); pose and K gradients of the row are summed in
    # registers (through row_rays' inputs) and written once.
    r = wp.tid() + offset
    b = r // H
    py = r - b * H
    hw = H * W
    Kb = K[b]
    Tb = pose[b]
    one = type(Kb[0, 0])(1.0)
    zmin = type(one)(min_depth)
    c = type(one)(scale)
    tol = type(one)(INSIDE_TOLERANCE)
    umax = type(one)(W - 1) + tol
    vmax = type(one)(H - 1) + tol
    a0, ax = camera.row_rays(lie.pose_rotation(Tb), Kb, type(one)(py))
    t = lie.pose_translation(Tb)
    row = r * W
    ref0 = b * C * hw + py * W
    live0 = b * C * hw
    row_sum[r] = type(one)(0.0)
    row_count[r] = type(one)(0.0)
    for px in range(W):
        d = ref_depth[row + px]
        # an invalid depth is replaced by 1 before any arithmetic: no value or gradient sees it
        depth_ok = d > zmin and d < type(d)(1.0e30)
        uvz = camera.project_moved_ray(a0, ax, t, Kb, type(d)(px), wp.where(depth_ok, d, one), zmin)
        u = uvz[0]
        v = uvz[1]
        ok = depth_ok and uvz[2] > zmin and u >= -tol and u <= umax and v >= -tol and v <= vmax
        e = ph.pixel_penalty(live_image, ref_image, live0, ref0 + px, C, hw, H, W, u, v, kind, c, ok)
        row_sum[r] += e
        row_count[r] += wp.where(ok, one, type(one)(0.0))


def _make_rows_mean(T, rows_mean=None):
    """float type ``T`` overload of rows_mean (custom adjoints need concrete types)."""

    @wp.func
    def rows_mean(row_sum: wp.array(dtype=T), row_count: wp.array(dtype=T), start: int, H: int, C: int):
        """(sum of row_sum[start:start + H] / (C n), n) with n the sum of row_count there, in row
        order; (0, 0) when n = 0. Gradient: 1 / (C n) to each row sum."""
        s = T(0.0)
        n = T(0.0)
        for h in range(H):
            s += row_sum[start + h]
            n += row_count[start + h]
        return wp.where(n > T(0.0), s / (T(C) * wp.where(n > T(0.0), n, T(1.0))), T(0.0)), n

    @wp.func_grad(rows_mean)
    def adj_rows_mean(
        row_sum: wp.array(dtype=T), row_count: wp.array(dtype=T), start: int, H: int, C: int,
        adj_ret_0: T, adj_ret_1: T,
    ):
        g_sum = wp.adjoint[row_sum]
        if g_sum.shape[0] > 0:
            n = T(0.0)
            for h in range(H):
                n += row_count[start + h]
            if n > T(0.0):
                g = adj_ret_0 / (T(C) * n)
                for h in range(H):
                    g_sum[start + h] += g

    return rows_mean


rows_mean = _make_rows_mean(wp.float64, _make_rows_mean(wp.float32))


@wp.kernel(module="unique")
def _photometric_mean(
    offset: int,
    row_sum: wp.array(dtype=Any),
    row_count: wp.array(dtype=Any),
    H: int,
    C: int,
    error: wp.array(dtype=Any),
    count: wp.array(dtype=Any),
):
    # Element b: error[b] = (sum of its H row sums) / (C count[b]), count[b] = its valid pixels.
    b = wp.tid() + offset
    e, n = rows_mean(row_sum, row_count, b * H, H, C)
    error[b] = e
    count[b] = n


# Threads. The row kernel's forward writes only its own row's slots; in the adjoint each row
# writes the gradients of its own reference pixels (ref_image, ref_depth: any split is exact),
# and scatters into the live image and sums pose and K gradients of its batch item ("segment").
photometric_rows = FloatKernel(
    _photometric_rows, ref_image="scalar", ref_depth="scalar", live_image="scalar", pose="mat34", K="mat33",
    row_sum="scalar", row_count="scalar",
).set_parallel(
    segment=lambda a: a["H"],  # rows of one batch item
    scopes={"ref_image": "element", "ref_depth": "element", "live_image": "segment", "pose": "segment",
            "K": "segment"},
    forward=True,
    grain=lambda a: max(1, _GRAIN_PIXELS // max(1, a["W"] * a["C"])),
)
photometric_mean = FloatKernel(
    _photometric_mean, row_sum="scalar", row_count="scalar", error="scalar", count="scalar"
).set_parallel(
    # element b reads and (adjoint) writes only rows [b H, (b + 1) H) of row_sum
    scopes={"row_sum": "element", "row_count": "element"},
    forward=True,
    grain=1 << 30,
)
