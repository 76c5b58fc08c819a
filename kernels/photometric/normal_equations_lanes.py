"""The Gauss-Newton normal equations of the photometric residuals, 8 pixels of a row at a time.

The 8-lane twin of :mod:`.normal_equations`' one-pixel-at-a-time row kernel (pinhole; the same
residuals, Jacobians, weights and row slots, :mod:`.normal_equations_reduce`): one thread per
reference row handles 8 pixels per step as length-8 vectors, which LLVM vectorises (about 2x
faster than the plain kernel here, most of it in the 27 running sums). Its running sums live in
the row's own slots of a scratch array (``acc``, :data:`ROW_STRIDE` 8-lane vectors per row):
carried through the loop in registers, LLVM split them into 232 scalars and rebuilt the vectors
lane by lane every step. :func:`normal_equations_lanes` picks the variant for a call: compiled
for one penalty (its branches fold away), for C = 1 with the channel loop unrolled, and with
straight loads (every step reads 8 straight values) unless the rows are narrower than 8 pixels:
bitwise the same sums as the generic variant.

Forward only. Every row writes only its own slots, so results are bitwise identical for any split
of the rows over threads.
"""

from typing import Any

import warp as wp

from ..core import lanes
from ..core.cache import specialise
from ..core.kinds import LANES_MODULE_OPTIONS, FloatKernel
from ..geometry import camera, lie
from ..sampling import sampler
from ..sampling.sampler import INSIDE_TOLERANCE
from . import residual as ph
from .normal_equations_reduce import N_SUMS, ROW_STRIDE, SEED_SLOT

#: channel counts compiled in (C = 1: the aligner's); other counts run a loop
STATIC_CHANNELS = (1,)


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
    ``xs`` (:func:`..core.lanes.step_load8`): the residuals live(taps of plane ``base``) -
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


@specialise("photometric.normal_equations_lanes", channels=STATIC_CHANNELS)
def normal_equations_lanes_kernel(depth: bool, occlusion: bool, channels, kind, narrow) -> FloatKernel:
    """The row kernel of the normal equations, 8 pixels of the row at a time (SIMD lanes), with or
    without the ``depth`` term and the ``occlusion`` test; same arguments, values and row slots as
    :func:`.normal_equations.normal_equations_rows`' kernel (up to rounding: its running sums are
    per lane, in the input float type, added in float64 at the end of the row). Compiled for the
    channel count ``channels`` if in :data:`STATIC_CHANNELS` (the channel loop unrolled), the
    penalty ``kind`` (its branches fold away) and ``narrow`` (True: rows narrower than 8 pixels,
    which read clamped lanes; False: every step reads 8 straight values, see
    :func:`..core.lanes.step_start`; the row's last, partial step reads its last 8 pixels and masks
    those before its own); each None: read at run time (``C``, ``kind``, W < 8). Bitwise the same
    sums for every choice. Made on first use, one Warp module each."""
    # (the kernel's own `kind` is its run-time argument: the compiled-in values get other names)
    static_depth, static_occlusion, static_channels, static_kind = depth, occlusion, channels, kind
    static_narrow = None if narrow is None else int(narrow)

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
        if wp.static(static_kind is not None):  # the penalty compiled in: its branches fold away
            kindc = wp.static(static_kind)
        narrow = wp.where(W < 8, 1, 0)
        if wp.static(static_narrow is not None):
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
            # vectors (fewer lane moves and extractions; bitwise the same)
            acc[a_row + SEED_SLOT] = i00 + i10 + i01 + i11
            if wp.static(static_occlusion):
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
            if wp.static(static_depth):
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
        grain=lambda a: max(1, ph.GRAIN_PIXELS // max(1, a["W"])),
    )


def normal_equations_lanes(depth: bool, occlusion: bool, C: int, kind: int, W: int) -> FloatKernel:
    """The 8-lane row kernel for a call with ``C`` channels, the penalty ``kind`` and rows of ``W``
    pixels (:func:`normal_equations_lanes_kernel` compiled for them), with or without the ``depth``
    term and the ``occlusion`` test."""
    return normal_equations_lanes_kernel(depth, occlusion, C, kind, W < 8)
