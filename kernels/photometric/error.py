"""The fast kernels of ``photometric_error``: its value and, in the same pass, its exact gradient.

The error of batch item b is E_b = S_b / (C n_b), S_b = sum of rho(r_c) over its valid pixels and
channels, n_b = its valid pixels (see :mod:`.photometric_kernels` for the residuals and the valid
rule). E_b is one scalar per batch item, so the forward pass can compute dS_b / d(every input)
while it has every per-pixel quantity in registers, and the backward pass only scales those
gradients by grad_output_b / (C n_b). No replay of the forward, no adjoint, no atomics:

- :data:`error_lanes` (``grad`` 0 or 1, a run-time argument): one thread per reference row,
  8 pixels of the row at a time as length-8 vectors (SIMD lanes, as the normal equations'
  kernel). With ``grad`` 1 it also writes, per reference pixel, dS/d depth and dS/d ref_c (= -rho'(r_c)) to
  null-or-full buffers (every pixel is written, no zero-fill needed), and per row the 14 sums
  that the pose and intrinsics gradients are made of (:data:`ROW_SLOTS`).
  The gradient is analytic: rho'(r_c) times the bilinear interpolant's derivative at the sample
  point (floor() contributes nothing, as in grid_sample), times the projection's Jacobian
  (:func:`project8_grad`), times the moved point's: q = (a0 + x ax) d + t with the row's rotated
  rays (a0, ax) = :func:`.camera.row_rays`, so dS/dd = <dS/dq, a0 + x ax>, dS/da0 = sum d dS/dq,
  dS/dax = sum x d dS/dq, dS/dt = sum dS/dq.
- :data:`error_reduce`: per batch item, the rows' slots summed in row order (float64): S_b, n_b,
  E_b, and dS/d pose (3x4) and dS/d K (3x3), the rays' part taken through (R, K) row by row.
- :data:`scale_segments`: the backward pass, out[i] = src[i] grad_output_b / (C n_b) (a scalar and
  a length-8 vector view of ``src`` and ``out`` each).

The live image's gradient (a scatter into the live image) is not computed here: callers that
need it run :data:`.photometric_kernels.photometric_rows`' Warp adjoint, which also serves as the
reference the tests compare these gradients with.

Every row writes only its own slots and its own pixels, and the reductions run in a fixed order,
so results are bitwise identical for any split over threads. The projection (pinhole) is one
function, :func:`project8`, with its gradient :func:`project8_grad` next to it.
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

# float64 slots per row: S (sum of rho), n (valid pixels), dS/da0 (3), dS/dax (3), dS/dt (3),
# dS/d(fx, s, cx, fy, cy) through the projection (5)
ROW_SLOTS = wp.constant(16)
# Fewest pixels worth a separate chunk of a threaded launch.
GRAIN_PIXELS = 16384


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
    :func:`.photometric.step_start`). (Indices written as max(i, 0) + k let the compiler see they are
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
    """One channel of an 8-lane step that reads from pixel ``xs`` (:func:`.photometric.step_load8`):
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


def _make_error_lanes(static_kind: int = -1, static_c: int = 0, static_narrow: int = 0):
    """The row kernel of photometric_error, 8 pixels at a time, with (``grad`` 1) or without the
    gradient; the penalty ``static_kind`` (>= 0) and channel count ``static_c`` (> 0) compiled in, or
    read at run time; ``static_narrow`` 1 for rows narrower than 8 pixels (whose steps cannot read
    8 straight values, see :func:`.photometric.step_start`). ``grad`` is a run-time flag, not a
    compiled-in one: a value-only variant compiled without the gradient's code came out as scalar
    code (LLVM's SLP vectoriser gave up on it) and ran 2-2.4x slower than this kernel with the
    gradient skipped."""

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
        # The row's last, partial step reads the row's last 8 pixels (photometric.step_start) and
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
        if wp.static(static_kind >= 0):  # compiled in: the penalty's branches fold away
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
            if wp.static(static_c > 0):  # channels unrolled: gu, gv stay in registers
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
        grain=lambda a: max(1, GRAIN_PIXELS // max(1, a["W"])),
    )


# channel counts and penalties compiled in (others run the generic kernel; each combination is a
# module of its own, compiled on first use)
STATIC_CHANNELS = (1, 3)
STATIC_KINDS = (ph.KINDS["l1"],)  # the default
_ERROR_KERNELS: dict[tuple[int, int, int], FloatKernel] = {}
_ERROR_LOCK = threading.Lock()


def error_lanes(kind: int, C: int, W: int) -> FloatKernel:
    """The row kernel (value only or value and gradient, by its ``grad`` argument), compiled for
    the penalty ``kind`` if in :data:`STATIC_KINDS` and the channel count ``C`` if in
    :data:`STATIC_CHANNELS` (constants fold branches away, which the vectorised code needs to be
    fast), else reading them at run time, and for rows of ``W`` pixels: at least 8 (the usual
    kernel) or fewer; made on first use."""
    key = (int(kind) if kind in STATIC_KINDS else -1, C if C in STATIC_CHANNELS else 0, int(W < 8))
    with _ERROR_LOCK:  # one kernel per key, also when threads ask at once
        if key not in _ERROR_KERNELS:
            _ERROR_KERNELS[key] = _make_error_lanes(*key)
        return _ERROR_KERNELS[key]


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
# (one piece below ~1 M values): splitting this copy did not pay for the chunks' fixed costs at
# 0.6 M values (B=8 240x320 depth gradients: 0.33-0.52 ms in one piece, 0.39-0.58 in two, 0.67-0.94
# cut into 8 chunks on 2 threads) and broke even at 2.5 M
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
    # vector views of the same buffers, n // 8 long: one vector load, multiply and store each;
    # B=8 240x320 depth gradients: 214 -> 105 us against 8 scalar copies per step), then the
    # run's last few one by one. The vector index i // 8 is taken of wp.max(i, 0), which the
    # compiler knows is not negative (no negative-index wrap, a shift). Every bound is written so
    # that no int32 sum exceeds n (< 2^31): i + SCALE_SPAN, i + 8 or i + 7 would wrap for n within a
    # span of 2^31.
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
