"""The photometric error row by row, differentiated by Warp: the reference kernels of ``photometric_error``.

For every reference pixel u = (x, y) of batch item b with a valid depth d (finite, > min_depth),
the moved point P = pose * (d K^-1 [x, y, 1]) is projected into the live image; where P has
z > min_depth and its projection lies inside the live image (the ``valid`` rule of
``warp_frame_depth``, docs/conventions.md), the residual of channel c is
r_c = live_c(project(P)) - ref_c(u) (bilinear sample, zeros padding).

- :data:`photometric_rows` (forward and Warp adjoint): per reference row, the sum of rho(r_c) over
  its valid pixels and channels and their count; :data:`photometric_mean` divides by C * count per
  batch item. Warp's adjoint gives the gradients to every input, the live image's (a scatter)
  included: the torch op's backward runs it for that one, and the tests compare the fused
  kernels of :mod:`.error` with it.
- :func:`photometric_rows_lens` (made on first use): the same for a camera ``(model, K, dist)`` of
  :mod:`..geometry.lens`: the reference pixels are read as precomputed undistorted rays
  (``rays[b * ray_stride + y W + x]``, :func:`..geometry.lens.rays.pixel_ray`; ray_stride 0 when one
  camera serves the batch) and the moved points are projected through the lens
  (:func:`..geometry.lens.rays.project_ray`). A ray with w = 0 (no undistortion inside the model's
  domain) counts as an invalid depth; a moved point outside the domain as one behind the camera.
  Its outputs are :data:`photometric_rows`', so :data:`photometric_mean` serves both.

Every row writes only its own slots, and the mean adds them in row order, so results are bitwise
identical for any split of the rows over threads.
"""

from typing import Any

import warp as wp

from ..core.cache import float_overloads, specialise
from ..core.compat import func_grad
from ..core.kinds import FloatKernel
from ..geometry import camera, lie
from ..geometry.lens import rays as lens_rays
from ..sampling.sampler import INSIDE_TOLERANCE
from . import residual as ph


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
    grain=lambda a: max(1, ph.GRAIN_PIXELS // max(1, a["W"] * a["C"])),
)


@specialise("photometric.photometric_rows_lens")
def photometric_rows_lens() -> FloatKernel:
    """:data:`photometric_rows` through a distorted lens (see the module docstring): its arguments
    and outputs, with ``dist`` (B,) and ``rays`` after ``K`` and ``model``, ``ray_stride`` after
    ``min_depth``. Made on first use."""
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
        # _photometric_rows through the lens: per reference row, the sum of rho(r_c) over its valid
        # pixels and channels and their count (Warp's adjoint: the hand-written ones of
        # pixel_penalty and lens_rays.project_ray)
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

    # Threads: as photometric_rows; the rays, shared by the batch when ray_stride is 0, gather
    # gradients from every item ("any").
    return FloatKernel(
        _photometric_rows_lens, ref_image="scalar", ref_depth="scalar", live_image="scalar", pose="mat34",
        K="mat33", dist="vec8", rays="vec3", row_sum="scalar", row_count="scalar",
    ).set_parallel(
        segment=lambda a: a["H"],
        scopes={"ref_image": "element", "ref_depth": "element", "live_image": "segment", "pose": "segment",
                "K": "segment", "dist": "segment", "rays": "any"},
        forward=True,
        grain=lambda a: max(1, ph.GRAIN_PIXELS // max(1, a["W"] * a["C"])),
    )


def _rows_mean(T):
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

    @func_grad(rows_mean)
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


rows_mean = float_overloads(_rows_mean)


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


photometric_mean = FloatKernel(
    _photometric_mean, row_sum="scalar", row_count="scalar", error="scalar", count="scalar"
).set_parallel(
    # element b reads and (adjoint) writes only rows [b H, (b + 1) H) of row_sum
    scopes={"row_sum": "element", "row_count": "element"},
    forward=True,
    grain=1 << 30,
)
