"""The fast kernel of ``photometric_error``: its value and, in the same pass, its exact gradient.

The error of batch item b is E_b = S_b / (C n_b), S_b = sum of rho(r_c) over its valid pixels and
channels, n_b = its valid pixels (see :mod:`.error_rows` for the residuals and the valid rule).
E_b is one scalar per batch item, so the forward pass can compute dS_b / d(every input) while it
has every per-pixel quantity in registers, and the backward pass only scales those gradients by
grad_output_b / (C n_b) (:mod:`.error_reduce`). No replay of the forward, no adjoint, no atomics.

:func:`error_lanes` (``grad`` 0 or 1, a run-time argument): one thread per reference row, 8 pixels
of the row at a time as length-8 vectors (SIMD lanes, as the normal equations' kernel). With
``grad`` 1 it also writes, per reference pixel, dS/d depth and dS/d ref_c (= -rho'(r_c)) to
null-or-full buffers (every pixel is written, no zero-fill needed), and per row the 14 sums that
the pose and intrinsics gradients are made of (:data:`.error_reduce.ROW_SLOTS`). The gradient is
analytic: rho'(r_c) times the bilinear interpolant's derivative at the sample point (floor()
contributes nothing, as in grid_sample), times the projection's Jacobian (:func:`project8_grad`),
times the moved point's: q = (a0 + x ax) d + t with the row's rotated rays (a0, ax) =
:func:`..geometry.camera.row_rays`, so dS/dd = <dS/dq, a0 + x ax>, dS/da0 = sum d dS/dq,
dS/dax = sum x d dS/dq, dS/dt = sum dS/dq.

The live image's gradient (a scatter into the live image) is not computed here: callers that
need it run :data:`.error_rows.photometric_rows`' Warp adjoint, which also serves as the
reference the tests compare these gradients with.

Every row writes only its own slots and its own pixels, so results are bitwise identical for any
split over threads. The projection (pinhole) is one function, :func:`project8`, with its gradient
:func:`project8_grad` next to it.
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
from .error_reduce import ROW_SLOTS


@wp.func
def project8(a0: Any, ax: Any, t: Any, K: Any, x: Any, d: Any, zmin: Any):
    """The moved points q = (a0 + x ax) d + t of 8 pixels of a row (x, d: 8 lanes) projected with
    the pinhole K: returns (q0, q1, q2, inv_z, xn, yn, u, v) with xn = q0 / q2, yn = q1 / q2; where
    q2 <= zmin, q2 is replaced by 1 in inv_z (finite values for the caller to reject)."""
    one = type(K[0, 0])(1.0)
    ones = lanes.splat8(one)
    q0 = wp.cw_mul(lanes.splat8(a0[0]) + x * ax[0], d) + lanes.splat8(t[0])
    q1 = wp.cw_mul(lanes.splat8(a0[1]) + x * ax[1], d) + lanes.splat8(t[1])
    q2 = wp.cw_mul(lanes.splat8(a0[2]) + x * ax[2], d) + lanes.splat8(t[2])
    front = lanes.open_mask8(q2, zmin, type(one)(3.0e38))
    inv_z = wp.cw_div(ones, lanes.select8(front, q2, ones))
    xn = wp.cw_mul(q0, inv_z)
    yn = wp.cw_mul(q1, inv_z)
    u = xn * K[0, 0] + yn * K[0, 1] + lanes.splat8(K[0, 2])
    v = yn * K[1, 1] + lanes.splat8(K[1, 2])
    return q0, q1, q2, inv_z, xn, yn, u, v


@wp.func
def project8_grad(gu: Any, gv: Any, K: Any, inv_z: Any, xn: Any, yn: Any):
    """The gradient of :func:`project8` (u, v) for incoming (gu, gv) (8 lanes): returns
    (dq0, dq1, dq2) (to the moved point) and (dfx, ds, dcx, dfy, dcy) (to K's entries)."""
    gxn = gu * K[0, 0]
    gyn = gu * K[0, 1] + gv * K[1, 1]
    dq0 = wp.cw_mul(gxn, inv_z)
    dq1 = wp.cw_mul(gyn, inv_z)
    dq2 = -wp.cw_mul(wp.cw_mul(xn, gxn) + wp.cw_mul(yn, gyn), inv_z)
    return dq0, dq1, dq2, wp.cw_mul(gu, xn), wp.cw_mul(gu, yn), gu, wp.cw_mul(gv, yn), gv


@wp.func
def psi8(r: Any, kind: int, c: Any):
    """rho'(r) on 8 lanes (finite r): sign(r) (L1, 0 at 0), r (L2), the M-estimators' psi in
    closed forms without branches (as :func:`.robust.psi`)."""
    one = type(c)(1.0)
    ones = lanes.splat8(one)
    g = r
    if kind == ph.L1:
        g = wp.vector(
            lanes.above(r[0], type(c)(0.0)) - lanes.above(-r[0], type(c)(0.0)),
            lanes.above(r[1], type(c)(0.0)) - lanes.above(-r[1], type(c)(0.0)),
            lanes.above(r[2], type(c)(0.0)) - lanes.above(-r[2], type(c)(0.0)),
            lanes.above(r[3], type(c)(0.0)) - lanes.above(-r[3], type(c)(0.0)),
            lanes.above(r[4], type(c)(0.0)) - lanes.above(-r[4], type(c)(0.0)),
            lanes.above(r[5], type(c)(0.0)) - lanes.above(-r[5], type(c)(0.0)),
            lanes.above(r[6], type(c)(0.0)) - lanes.above(-r[6], type(c)(0.0)),
            lanes.above(r[7], type(c)(0.0)) - lanes.above(-r[7], type(c)(0.0)),
        )
    elif kind == ph.robust.HUBER:
        g = wp.min(wp.max(r, lanes.splat8(-c)), lanes.splat8(c))
    elif kind != ph.L2:
        u2 = wp.cw_mul(r, r) * (one / (c * c))
        w = wp.cw_div(ones, ones + u2)
        if kind == ph.robust.GEMAN_MCCLURE:
            w = wp.cw_mul(w, w)
        elif kind == ph.robust.TUKEY:
            z = ones - wp.min(u2, ones)
            w = wp.cw_mul(z, z)
        g = wp.cw_mul(r, w)
    return g


@wp.func
def store8(a: wp.array(dtype=Any), i: int, first: int, end: int, v: Any):
    """a[i + k] = v[k] for the lanes first <= k < end (a step's own pixels, see
    :func:`..core.lanes.step_start`). (Indices written as max(i, 0) + k let the compiler see they are
    not negative, so it drops Warp's negative-index wrap.)"""
    j = wp.max(i, 0)
    if first == 0 and end == 8:
        a[j] = v[0]
        a[j + 1] = v[1]
        a[j + 2] = v[2]
        a[j + 3] = v[3]
        a[j + 4] = v[4]
        a[j + 5] = v[5]
        a[j + 6] = v[6]
        a[j + 7] = v[7]
    else:
        for k in range(first, end):
            a[j + k] = v[k]


@wp.func
def channel8(
    live_plane: wp.array(dtype=Any), ref_image: wp.array(dtype=Any), ref_i: int, xs: int, last: int, narrow: int,
    i00: Any, i10: Any, i01: Any, i11: Any, m00: Any, m10: Any, m01: Any, m11: Any, wx1: Any, wy1: Any, ok: Any,
    kind: int, c: Any,
):
    """One channel of an 8-lane step that reads from pixel ``xs`` (:func:`..core.lanes.step_load8`):
    the residuals r = live(taps of ``live_plane``) - ref[ref_i + xs ...] where ``ok`` (and finite),
    and returns (rho(r), rho'(r), rho'(r) d live/du, rho'(r) d live/dv), 0 in masked lanes."""
    one = type(c)(1.0)
    zeros = lanes.splat8(type(c)(0.0))
    big = type(c)(1.0e30)
    val, gx, gy = lanes.interpolate8(
        sampler.gather_lanes(live_plane, 0, i00, m00), sampler.gather_lanes(live_plane, 0, i10, m10),
        sampler.gather_lanes(live_plane, 0, i01, m01), sampler.gather_lanes(live_plane, 0, i11, m11),
        wx1, wy1,
    )
    res = val - lanes.step_load8(ref_image, ref_i, xs, last, narrow)
    # finite residual and derivatives (NaN and inf fail the compare)
    m = wp.cw_mul(ok, lanes.open_mask8(wp.max(res, -res) + wp.max(gx, -gx) + wp.max(gy, -gy), -one, big))
    rr = lanes.select8(m, res, zeros)
    e = wp.cw_mul(wp.max(rr, -rr), m)
    if kind != ph.L1:
        e = wp.cw_mul(ph.penalty8(rr, kind, c), m)
    g = wp.cw_mul(psi8(rr, kind, c), m)
    return e, g, wp.cw_mul(g, lanes.select8(m, gx, zeros)), wp.cw_mul(g, lanes.select8(m, gy, zeros))


# vec8 running sums per row (memory, not registers: carried through the row loop as vectors, LLVM
# kept them as scalars and rebuilt them lane by lane every step): the ROW_SLOTS sums, then d/du and
# d/dv of the pixel over a run-time channel loop
ACC_SLOTS = wp.constant(18)


# channel counts and penalties compiled in (others run the generic kernel; each combination is a
# module of its own, compiled on first use)
STATIC_CHANNELS = (1, 3)
STATIC_KINDS = (ph.KINDS["l1"],)  # the default


@specialise("photometric.error_lanes", kind=STATIC_KINDS, channels=STATIC_CHANNELS)
def error_lanes_kernel(kind, channels, narrow: bool) -> FloatKernel:
    """The row kernel of photometric_error, 8 pixels at a time, with (``grad`` 1) or without the
    gradient; the penalty ``kind`` and channel count ``channels`` compiled in if in
    :data:`STATIC_KINDS` and :data:`STATIC_CHANNELS` (constants fold branches away, which the
    vectorised code needs to be fast), else (None) read at run time; ``narrow`` for rows narrower
    than 8 pixels (whose steps cannot read 8 straight values, see :func:`..core.lanes.step_start`).
    ``grad`` is a run-time flag, not a compiled-in one: a value-only variant compiled without the
    gradient's code came out as scalar code (LLVM's SLP vectoriser gave up on it), slower than
    this kernel with the gradient skipped. Made on first use, one Warp module each."""
    # (the kernel's own `kind` is its run-time argument: the compiled-in values get other names)
    static_kind, static_c, static_narrow = kind, channels, int(narrow)

    @wp.kernel(module="unique", enable_backward=False, module_options=LANES_MODULE_OPTIONS)
    def _error_lanes(
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
        grad: int,
        rows: wp.array(dtype=wp.float64),
        acc: wp.array(dtype=Any),
        g_ref: wp.array(dtype=Any),
        g_depth: wp.array(dtype=Any),
    ):
        # Element r = one reference row (flat (b, y)); images flat (B, C, H, W) (the live image
        # contiguous: it is read through a 2-D view of its memory), depth (B, H, W); rows:
        # ROW_SLOTS float64 per row; acc: ACC_SLOTS 8-lane vectors per row (scratch); g_ref
        # (B, C, H, W) and g_depth (B, H, W): dS/d ref_image, dS/d ref_depth, or null arrays (not
        # wanted). Masks are 0/1 lanes. A masked lane's depth and sample position are replaced
        # first, so the values built from them are finite and products with masks are exact; the
        # residual, which reads the reference image (NaN or inf possible), is dropped by a select.
        # The row's last, partial step reads the row's last 8 pixels (lanes.step_start) and
        # masks those before its own.
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
        fW = type(one)(W)
        fH = type(one)(H)
        kindc = kind
        if wp.static(static_kind is not None):  # compiled in: the penalty's branches fold away
            kindc = wp.static(static_kind)
        a0, ax = camera.row_rays(lie.pose_rotation(Tb), Kb, type(one)(py))
        t = lie.pose_translation(Tb)
        row = r * W
        ref0 = b * C * hw + py * W
        # the live image's planes, (B C, H W), read through a view made here (see sampler.planes_view)
        live_planes = sampler.planes_view(live_image, hw)
        last = W - 1
        want_ref = grad != 0 and g_ref.shape[0] > 0
        want_depth = grad != 0 and g_depth.shape[0] > 0
        ones = lanes.splat8(one)
        zeros = lanes.splat8(zero)
        a = r * ACC_SLOTS
        for k in range(ACC_SLOTS):
            acc[a + k] = zeros
        for k8 in range((W + 7) // 8):
            x0 = k8 * 8
            xs = lanes.step_start(x0, W, wp.static(static_narrow))  # the step reads pixels xs .. xs + 7
            first = x0 - xs  # the step's own pixels are lanes first .. end - 1
            end = wp.min(W - xs, 8)
            x = lanes.iota8(xs, one)
            d = lanes.step_load8(ref_depth, row, xs, last, wp.static(static_narrow))
            # lanes outside the step's own pixels and invalid depths are masked; their depth is replaced by 1
            mdep = lanes.open_mask8(d, zmin, big)
            if x0 + 8 > W:  # the row's last, partial block: its own pixels are x0 .. W - 1
                mdep = wp.cw_mul(mdep, lanes.closed_mask8(x, type(one)(x0), fW - one))
            dd = lanes.select8(mdep, d, ones)
            q0, q1, q2, inv_z, xn, yn, u, v = project8(a0, ax, t, Kb, x, dd, zmin)
            ok = wp.cw_mul(
                wp.cw_mul(mdep, lanes.open_mask8(q2, zmin, type(one)(3.0e38))),
                wp.cw_mul(lanes.closed_mask8(u, -tol, fW - one + tol), lanes.closed_mask8(v, -tol, fH - one + tol)),
            )
            us = lanes.select8(ok, u, zeros)
            vs = lanes.select8(ok, v, zeros)
            # taps as in sampler.sample_lanes: float addresses in the plane, 0/1 masks (in the image)
            i00, i10, i01, i11, m00, m10, m01, m11, wx1, wy1 = sampler.taps_lanes(us, vs, fW, fH)
            acc[a + 1] = acc[a + 1] + ok
            gu = lanes.splat8(zero)
            gv = lanes.splat8(zero)
            if wp.static(static_c is not None):  # channels unrolled: gu, gv stay in registers
                for ch in range(wp.static(static_c)):
                    e, g, cu, cv = channel8(live_planes[wp.max(b * C + ch, 0)], ref_image, ref0 + ch * hw, xs, last,
                                            wp.static(static_narrow),
                                            i00, i10, i01, i11, m00, m10, m01, m11, wx1, wy1, ok, kindc, c)
                    acc[a] = acc[a] + e
                    gu = gu + cu
                    gv = gv + cv
                    if want_ref:
                        store8(g_ref, ref0 + ch * hw + xs, first, end, -g)
            else:
                acc[a + 16] = zeros
                acc[a + 17] = zeros
                for ch in range(C):
                    e, g, cu, cv = channel8(live_planes[wp.max(b * C + ch, 0)], ref_image, ref0 + ch * hw, xs, last,
                                            wp.static(static_narrow),
                                            i00, i10, i01, i11, m00, m10, m01, m11, wx1, wy1, ok, kindc, c)
                    acc[a] = acc[a] + e
                    acc[a + 16] = acc[a + 16] + cu
                    acc[a + 17] = acc[a + 17] + cv
                    if want_ref:
                        store8(g_ref, ref0 + ch * hw + xs, first, end, -g)
                gu = acc[a + 16]
                gv = acc[a + 17]
            if grad != 0:
                dq0, dq1, dq2, dfx, ds, dcx, dfy, dcy = project8_grad(gu, gv, Kb, inv_z, xn, yn)
                if want_depth:
                    gd = (
                        wp.cw_mul(dq0, lanes.splat8(a0[0]) + x * ax[0])
                        + wp.cw_mul(dq1, lanes.splat8(a0[1]) + x * ax[1])
                        + wp.cw_mul(dq2, lanes.splat8(a0[2]) + x * ax[2])
                    )
                    store8(g_depth, row + xs, first, end, gd)
                w0 = wp.cw_mul(dq0, dd)
                w1 = wp.cw_mul(dq1, dd)
                w2 = wp.cw_mul(dq2, dd)
                acc[a + 2] = acc[a + 2] + w0
                acc[a + 3] = acc[a + 3] + w1
                acc[a + 4] = acc[a + 4] + w2
                acc[a + 5] = acc[a + 5] + wp.cw_mul(w0, x)
                acc[a + 6] = acc[a + 6] + wp.cw_mul(w1, x)
                acc[a + 7] = acc[a + 7] + wp.cw_mul(w2, x)
                acc[a + 8] = acc[a + 8] + dq0
                acc[a + 9] = acc[a + 9] + dq1
                acc[a + 10] = acc[a + 10] + dq2
                acc[a + 11] = acc[a + 11] + dfx
                acc[a + 12] = acc[a + 12] + ds
                acc[a + 13] = acc[a + 13] + dcx
                acc[a + 14] = acc[a + 14] + dfy
                acc[a + 15] = acc[a + 15] + dcy
        o = r * ROW_SLOTS
        n_slots = 2
        if grad != 0:
            n_slots = ROW_SLOTS
        for k in range(n_slots):
            rows[o + k] = lanes.hsum8(acc[a + k])

    return FloatKernel(
        _error_lanes, ref_image="scalar", ref_depth="scalar", live_image="scalar", pose="mat34", K="mat33",
        acc="vec8", g_ref="scalar", g_depth="scalar",
    ).set_parallel(
        segment=lambda a: a["H"],  # rows of one batch item
        # forward only (no adjoint): every row writes its own slots and its own pixels' gradients
        scopes={"ref_image": "any", "ref_depth": "any", "live_image": "any", "pose": "any", "K": "any"},
        forward=True,
        grain=lambda a: max(1, ph.GRAIN_PIXELS // max(1, a["W"])),
    )


def error_lanes(kind: int, C: int, W: int) -> FloatKernel:
    """The row kernel for a call with the penalty ``kind``, ``C`` channels and rows of ``W`` pixels
    (:func:`error_lanes_kernel` compiled for them); value only or value and gradient, by its
    ``grad`` argument."""
    return error_lanes_kernel(kind, C, W < 8)
