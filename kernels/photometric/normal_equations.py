"""The Gauss-Newton normal equations of the photometric residuals, one pixel at a time.

For every reference pixel u = (x, y) of batch item b with a valid depth d (finite, > min_depth),
the moved point P = pose * (d K^-1 [x, y, 1]) is projected into the live image; where P has
z > min_depth and its projection lies inside the live image (the ``valid`` rule of
``warp_frame_depth``, docs/conventions.md), the residual of channel c is
r_c = live_c(project(P)) - ref_c(u) (bilinear sample, zeros padding); optionally a depth residual
joins each pixel, and an occlusion test drops pixels (see :func:`normal_equations_rows`'s kernel).
Nothing per pixel is written: one thread per reference row sums the Gauss-Newton system of the
row's residuals for a left-multiplied perturbation pose <- exp(delta) pose, delta = [omega, t]
(J is exact for the residual as sampled: (d live / d(u, v)) (d(u, v) / dP) (dP / d delta)), into
the row's slots that :mod:`.normal_equations_reduce` adds per batch item.

- :func:`normal_equations_rows`: the plain kernel, pinhole; the readable reference that the 8-lane
  kernel the pinhole calls use (:mod:`.normal_equations_lanes`) is tested against.
- :func:`normal_equations_rows_lens` (made on first use): the same for a camera ``(model, K,
  dist)`` of :mod:`..geometry.lens`: the reference pixels are read as precomputed undistorted rays
  (``rays[b * ray_stride + y W + x]``, :func:`..geometry.lens.rays.pixel_ray`; ray_stride 0 when one
  camera serves the batch) and the moved points are projected through the lens
  (:func:`..geometry.lens.rays.project_ray_jacobian`), so J includes the distortion's Jacobian. A
  ray with w = 0 (no undistortion inside the model's domain) counts as an invalid depth; a moved
  point outside the domain as one behind the camera. The pinhole kernels use the row linearity of
  :func:`..geometry.camera.row_rays` instead.

Forward only; every row writes only its own slots, so results are bitwise identical for any split
of the rows over threads.
"""

from typing import Any

import warp as wp

from ..core.cache import specialise
from ..core.kinds import FloatKernel
from ..geometry import camera, lie
from ..geometry.lens import rays as lens_rays
from ..sampling.sampler import INSIDE_TOLERANCE
from . import residual as ph
from .normal_equations_reduce import ROW_STRIDE, mat66d, vec6d


@specialise("photometric.normal_equations_rows")
def normal_equations_rows(depth: bool, occlusion: bool) -> FloatKernel:
    """The row kernel of the normal equations (pinhole, one pixel at a time), with or without the
    ``depth`` term and the ``occlusion`` test (compiled in: no per-pixel test). Made on first use."""
    # (the kernel's own `occlusion` is its run-time threshold: the compiled-in flags get other names)
    static_depth, static_occlusion = depth, occlusion

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
            if wp.static(static_occlusion):
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
            if wp.static(static_depth):
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
        grain=lambda a: max(1, ph.GRAIN_PIXELS // max(1, a["W"])),
    )


@specialise("photometric.normal_equations_rows_lens")
def normal_equations_rows_lens(depth: bool, occlusion: bool) -> FloatKernel:
    """:func:`normal_equations_rows` through a distorted lens (see the module docstring): its
    arguments, with ``dist`` (B,) and ``rays`` after ``K`` and ``model``, ``ray_stride`` after
    ``occlusion``. Made on first use."""
    static_depth, static_occlusion = depth, occlusion

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
            if wp.static(static_occlusion):
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
            if wp.static(static_depth):
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
        grain=lambda a: max(1, ph.GRAIN_PIXELS // max(1, a["W"])),
    )
