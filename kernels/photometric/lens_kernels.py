"""The fused photometric objective through a distorted lens model (radtan, fisheye).

The same objective as :mod:`.photometric_kernels` (residuals, valid rule, penalties, row partial
sums, float64 normal equations), for a camera ``(model, K, dist)`` of :mod:`.lens`: the reference
pixels are read as precomputed undistorted rays (:func:`.lens_rays.pixel_ray`, ``rays[b *
ray_stride + y W + x]``; ray_stride 0 when one camera serves the batch) and the moved points are
projected through the lens (:func:`.lens_rays.project_ray` / :func:`.lens_rays.project_ray_jacobian`).
A ray with w = 0 (no undistortion inside the model's domain) counts as an invalid depth; a moved
point outside the domain as one behind the camera. The normal equations' Jacobian includes the
distortion's: J = (d live / d(u, v)) (d(u, v) / dP) (dP / d delta) with d(u, v)/dP through the lens.

Kept apart from :mod:`.photometric_kernels` (whose pinhole kernels use the row linearity of
:func:`.camera.row_rays` and stay as they are); the two outputs (row slots, row sums) are the
same, so the reductions there serve both.
"""

from typing import Any

import warp as wp

from ..core.launch import FloatKernel
from ..geometry import lie
from ..geometry.lens import rays as lens_rays
from ..sampling.kernels import INSIDE_TOLERANCE
from . import residual as ph
from .normal_equations import _GRAIN_PIXELS, ROW_STRIDE, mat66d, vec6d


@wp.kernel(module="unique")
def _photometric_rows_lens(
    offset: int,
    ref_image: wp.array(dtype=Any),
    ref_depth: wp.array(dtype=Any),
    live_image: wp.array(dtype=Any),
    pose: wp.array(dtype=Any),
    K: wp.array(dtype=Any),
    dist: wp.array(dtype=Any),
    rays: wp.array(dtype=Any),
    C: int,
    H: int,
    W: int,
    kind: int,
    scale: wp.float64,
    min_depth: wp.float64,
    model: int,
    ray_stride: int,
    row_sum: wp.array(dtype=Any),
    row_count: wp.array(dtype=Any),
):
    # .photometric_kernels._photometric_rows through the lens: per reference row, the sum of
    # rho(r_c) over its valid pixels and channels and their count (Warp's adjoint: the hand-written
    # ones of pixel_penalty and lens_rays.project_ray)
    r = wp.tid() + offset
    b = r // H
    py = r - b * H
    hw = H * W
    Kb = K[b]
    Tb = pose[b]
    db = dist[b]
    one = type(Kb[0, 0])(1.0)
    zero = type(one)(0.0)
    zmin = type(one)(min_depth)
    c = type(one)(scale)
    tol = type(one)(INSIDE_TOLERANCE)
    umax = type(one)(W - 1) + tol
    vmax = type(one)(H - 1) + tol
    R = lie.pose_rotation(Tb)
    t = lie.pose_translation(Tb)
    row = r * W
    ray0 = b * ray_stride + py * W
    ref0 = b * C * hw + py * W
    live0 = b * C * hw
    row_sum[r] = zero
    row_count[r] = zero
    for px in range(W):
        d = ref_depth[row + px]
        ray = rays[wp.max(ray0 + px, 0)]
        depth_ok = d > zmin and d < type(d)(1.0e30) and ray[2] > zero
        uvz, in_domain = lens_rays.project_ray(model, R, t, Kb, db, ray, wp.where(depth_ok, d, one), zmin)
        u = uvz[0]
        v = uvz[1]
        ok = depth_ok and in_domain and u >= -tol and u <= umax and v >= -tol and v <= vmax
        e = ph.pixel_penalty(live_image, ref_image, live0, ref0 + px, C, hw, H, W, u, v, kind, c, ok)
        row_sum[r] += e
        row_count[r] += wp.where(ok, one, zero)


def _make_normal_equations_rows_lens(static_depth: int, static_occlusion: int = 0):
    """.photometric_kernels' plain row kernel of the normal equations through the lens, with
    (static_depth 1) or without the depth term, with or without the occlusion test."""

    @wp.kernel(module="unique", enable_backward=False)
    def _normal_equations_rows_lens(
        offset: int,
        ref_image: wp.array(dtype=Any),
        ref_depth: wp.array(dtype=Any),
        live_image: wp.array(dtype=Any),
        live_depth: wp.array(dtype=Any),
        pose: wp.array(dtype=Any),
        K: wp.array(dtype=Any),
        dist: wp.array(dtype=Any),
        rays: wp.array(dtype=Any),
        C: int,
        H: int,
        W: int,
        kind: int,
        scale: wp.float64,
        min_depth: wp.float64,
        depth_weight: wp.float64,
        occlusion: wp.float64,
        model: int,
        ray_stride: int,
        rows: wp.array(dtype=wp.float64),
    ):
        r = wp.tid() + offset
        b = r // H
        py = r - b * H
        hw = H * W
        Kb = K[b]
        Tb = pose[b]
        db = dist[b]
        one = type(Kb[0, 0])(1.0)
        zero = type(one)(0.0)
        zmin = type(one)(min_depth)
        big = type(one)(1.0e30)
        c = type(one)(scale)
        tol = type(one)(INSIDE_TOLERANCE)
        umax = type(one)(W - 1) + tol
        vmax = type(one)(H - 1) + tol
        R = lie.pose_rotation(Tb)
        t = lie.pose_translation(Tb)
        sw = type(one)(wp.sqrt(depth_weight))
        row = r * W
        ray0 = b * ray_stride + py * W
        ref0 = b * C * hw + py * W
        live0 = b * C * hw
        dep0 = b * hw
        f0 = wp.float64(0.0)
        JtWJ = mat66d()
        JtWr = vec6d()
        cost = wp.float64(0.0)
        count = wp.float64(0.0)
        for px in range(W):
            d = ref_depth[row + px]
            ray = rays[wp.max(ray0 + px, 0)]
            depth_ok = d > zmin and d < big and ray[2] > zero
            u, v, p, in_domain, du, dv = lens_rays.project_ray_jacobian(
                model, R, t, Kb, db, ray, wp.where(depth_ok, d, one), zmin
            )
            q2 = p[2]
            ok = depth_ok and in_domain and u >= -tol and u <= umax and v >= -tol and v <= vmax
            us = wp.where(ok, u, zero)
            vs = wp.where(ok, v, zero)
            i00, i10, i01, i11, k00, k10, k01, k11, wx1, wy1 = ph.taps(us, vs, H, W)
            if wp.static(static_occlusion != 0):
                lim = type(one)(occlusion) * q2
                ok = (
                    ok and (not k00 or wp.abs(q2 - live_depth[dep0 + i00]) <= lim)
                    and (not k11 or wp.abs(q2 - live_depth[dep0 + i11]) <= lim)
                )
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
                m = ok and wp.abs(res) + wp.abs(gu) + wp.abs(gv) < big
                rr = wp.where(m, res, zero)
                gp = du * wp.where(m, gu, zero) + dv * wp.where(m, gv, zero)
                j0, j1, j2, j3, j4, j5 = ph.twist_jacobian(p, gp)
                w = wp.where(m, wp.float64(ph.irls_weight(rr, kind, c)), f0)
                J = vec6d(wp.float64(j0), wp.float64(j1), wp.float64(j2), wp.float64(j3), wp.float64(j4),
                          wp.float64(j5))
                JtWJ = JtWJ + wp.outer(J * w, J)
                JtWr = JtWr + J * (w * wp.float64(rr))
                cost += wp.where(m, wp.float64(ph.penalty(rr, kind, c)), f0)
            if wp.static(static_depth != 0):
                e00 = ph.read_tap(live_depth, dep0 + i00, k00)
                e10 = ph.read_tap(live_depth, dep0 + i10, k10)
                e01 = ph.read_tap(live_depth, dep0 + i01, k01)
                e11 = ph.read_tap(live_depth, dep0 + i11, k11)
                md = (
                    ok and e00 > zmin and e00 < big and e10 > zmin and e10 < big
                    and e01 > zmin and e01 < big and e11 > zmin and e11 < big
                )
                dval, gdu, gdv = ph.interpolate(
                    wp.where(md, e00, one), wp.where(md, e10, one), wp.where(md, e01, one), wp.where(md, e11, one),
                    wx1, wy1,
                )
                rd = wp.where(md, sw * (q2 - dval), zero)
                # d r_d / dP = sw (e_z - (gdu, gdv) d(u, v)/dP)
                gq = du * gdu + dv * gdv
                gpd = wp.where(md, wp.vector(-gq[0] * sw, -gq[1] * sw, (one - gq[2]) * sw), wp.vector(zero, zero, zero))
                j0, j1, j2, j3, j4, j5 = ph.twist_jacobian(p, gpd)
                w = wp.where(md, wp.float64(ph.irls_weight(rd, kind, c)), f0)
                J = vec6d(wp.float64(j0), wp.float64(j1), wp.float64(j2), wp.float64(j3), wp.float64(j4),
                          wp.float64(j5))
                JtWJ = JtWJ + wp.outer(J * w, J)
                JtWr = JtWr + J * (w * wp.float64(rd))
                cost += wp.where(md, wp.float64(ph.penalty(rd, kind, c)), f0)
        o = r * ROW_STRIDE
        for i in range(6):
            for j in range(i, 6):
                rows[o + i * (11 - i) // 2 + j] = JtWJ[i, j]  # row-major upper triangle
            rows[o + 21 + i] = JtWr[i]
        rows[o + 27] = cost
        rows[o + 28] = count

    return FloatKernel(
        _normal_equations_rows_lens, ref_image="scalar", ref_depth="scalar", live_image="scalar",
        live_depth="scalar", pose="mat34", K="mat33", dist="vec8", rays="vec3",
    ).set_parallel(
        segment=lambda a: a["H"],
        # forward only (no adjoint): every row writes its own ROW_STRIDE slots, so any split is exact
        scopes={"ref_image": "any", "ref_depth": "any", "live_image": "any", "live_depth": "any", "pose": "any",
                "K": "any", "dist": "any", "rays": "any"},
        forward=True,
        grain=lambda a: max(1, _GRAIN_PIXELS // max(1, a["W"])),
    )


#: the row kernels of the normal equations through a lens, indexed by depth term (1) + 2 * occlusion test (1)
normal_equations_rows_lens = tuple(_make_normal_equations_rows_lens(k & 1, k >> 1) for k in range(4))

# Threads: as .photometric_kernels.photometric_rows; the rays, shared by the batch when ray_stride
# is 0, gather gradients from every item ("any").
photometric_rows_lens = FloatKernel(
    _photometric_rows_lens, ref_image="scalar", ref_depth="scalar", live_image="scalar", pose="mat34", K="mat33",
    dist="vec8", rays="vec3", row_sum="scalar", row_count="scalar",
).set_parallel(
    segment=lambda a: a["H"],
    scopes={"ref_image": "element", "ref_depth": "element", "live_image": "segment", "pose": "segment",
            "K": "segment", "dist": "segment", "rays": "any"},
    forward=True,
    grain=lambda a: max(1, _GRAIN_PIXELS // max(1, a["W"] * a["C"])),
)
