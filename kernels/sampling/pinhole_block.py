"""A block of 8 pixels of one row of the pinhole 3D spatial transformer as 8-lane vector code,
with its hand-written adjoint (``@wp.func``, no launches here): :func:`warp_block8`, what
:func:`.kernels.warp_frame_depth_lanes` runs per block, forward and backward, and
:func:`row_lanes`, the row's gradient accumulators.

Forward: :data:`.kernels.warp_frame_depth`'s per-pixel work on 8 pixels at once (the projection of
:func:`gvnn_warp.kernels.geometry.camera.project_moved_ray` and the sampler of
:func:`.sampler.sample_channels`, the same operations in the same order: bitwise the same values
and ``valid``). Adjoint: vector arithmetic but for the image gradient's read-modify-writes. The
taps are read as vectors (:func:`.lanes.position_grad_lanes`) for d loss / d (x, y); with the
image gradient wanted, each channel's tap terms are vector products added lane by lane
(:func:`.lanes.scatter_lanes`; lanes may share a tap); the projection's chain rule (to the depth,
the row's rays, the translation and K) is vector code.

The block's gradients for the row's rays, translation and K are whole 8-lane vectors, added to
8-lane copies of them that the kernel makes once per row (:func:`row_lanes`); Warp's adjoint of
that function sums the lanes once per row, and the kernel's own adjoint takes the sums through
:func:`.camera.row_rays` and the pose. Summing each block's lanes in the block (as an earlier
version did) made LLVM vectorise the whole block adjoint 2 and 4 lanes wide instead of 8
(``benchmarks/RESULTS.md``). With Warp's automatic adjoint of the 8-lane forward,
forward+backward took 2.5x the row kernel's time.
"""

from typing import Any

import warp as wp

from ..core import lanes
from ..core.cache import float_overloads, specialise
from ..core.compat import func_grad
from ..core.kinds import vec8d, vec8f
from . import sampler

_LANES = sampler.LANES


@wp.func
def row_lanes(a0: Any, ax: Any, t: Any, Kb: Any):
    """A row's constants in 8 lanes, the gradient accumulators of :func:`warp_block8`: (a0_lanes,
    ax_lanes, t_lanes, k_lanes), 3x8, 3x8, 3x8 and 5x8 matrices whose rows are the components of the
    ray terms a0 and ax, of the translation t, and fx, skew, cx, fy and cy of K (the order the block
    adjoint's ``k_lanes`` gradient follows), each repeated in the 8 lanes. The blocks do not read
    them; their adjoints add 8-lane gradients to them (vector adds), and Warp's adjoint of this
    function sums the lanes into a0's, ax's, t's and K's, once per row."""
    return (
        wp.matrix_from_rows(lanes.splat8(a0[0]), lanes.splat8(a0[1]), lanes.splat8(a0[2])),
        wp.matrix_from_rows(lanes.splat8(ax[0]), lanes.splat8(ax[1]), lanes.splat8(ax[2])),
        wp.matrix_from_rows(lanes.splat8(t[0]), lanes.splat8(t[1]), lanes.splat8(t[2])),
        wp.matrix_from_rows(
            lanes.splat8(Kb[0, 0]), lanes.splat8(Kb[0, 1]), lanes.splat8(Kb[0, 2]), lanes.splat8(Kb[1, 1]),
            lanes.splat8(Kb[1, 2]),
        ),
    )


@specialise("sampling.pinhole_block8", C=tuple(range(1, sampler.UNROLLED_CHANNELS + 1)))
def warp_block8(C: int | None, padding: int, image_grad: bool = True) -> wp.Function:
    """The block function for this channel count (if at most ``sampler.UNROLLED_CHANNELS``; else
    read at run time: ``C`` None), ``padding`` and ``image_grad``, all compiled in (float32 and
    float64 overloads), made on first use. With ``image_grad`` False the adjoint has no image
    gradient code at all (the gradient is not written, whatever array it is given): the image is
    data, and its taps are plain vector reads."""

    def make(T):
        return _warp_block8(T, C or 0, int(padding), bool(image_grad))

    make.__qualname__ = f"warp_block8(C={C}, padding={padding}, image_grad={bool(image_grad)})"
    return float_overloads(make)


def _warp_block8(T, static_c: int, static_padding: int, static_image_grad: bool):
    """warp_block8's float type ``T`` overload (Warp custom adjoints need concrete types)."""
    vec3 = wp.types.vector(3, T)
    mat33 = wp.types.matrix((3, 3), T)
    vec8 = vec8f if T == wp.float32 else vec8d
    mat38 = wp.types.matrix((3, 8), T)
    mat58 = wp.types.matrix((5, 8), T)

    @wp.func
    def project8(depth: wp.array(dtype=vec8), e: int, x0: int, a0: vec3, ax: vec3, t: vec3, Kb: mat33, zmin: T):
        """The 8 pixels x0 .. x0 + 7 of depth block ``e`` moved and projected, as
        :func:`.camera.project_moved_ray` (with :func:`.camera.row_rays`' rays a0 + x ax): returns
        (u, v, ok, dd, x, xn, yn, inv_z), ``ok`` 1 where the depth is valid and the moved point in
        front, ``dd`` the depth with 1 in place of invalid values (<= min, NaN, inf, >= 1e30)."""
        one = T(1.0)
        d = depth[e]
        usable = lanes.open_mask8(d, zmin, T(1.0e30))
        dd = lanes.select8(usable, d, lanes.splat8(one))
        x = lanes.iota8(x0, one)
        q0 = wp.cw_mul(lanes.splat8(a0[0]) + ax[0] * x, dd) + lanes.splat8(t[0])
        q1 = wp.cw_mul(lanes.splat8(a0[1]) + ax[1] * x, dd) + lanes.splat8(t[1])
        q2 = wp.cw_mul(lanes.splat8(a0[2]) + ax[2] * x, dd) + lanes.splat8(t[2])
        front = lanes.above8(q2, zmin)
        inv_z = wp.cw_div(lanes.splat8(one), lanes.select8(front, q2, lanes.splat8(one)))
        xn = wp.cw_mul(q0, inv_z)
        yn = wp.cw_mul(q1, inv_z)
        u = Kb[0, 0] * xn + Kb[0, 1] * yn + lanes.splat8(Kb[0, 2])
        v = Kb[1, 1] * yn + lanes.splat8(Kb[1, 2])
        return u, v, wp.cw_mul(usable, front), dd, x, xn, yn, inv_z

    @wp.func
    def warp_block8(
        image: wp.array(dtype=T), depth: wp.array(dtype=vec8), out: wp.array(dtype=vec8),
        valid: wp.array(dtype=wp.bool), e: int, x0: int, a0: vec3, ax: vec3, t: vec3, Kb: mat33,
        a0_lanes: mat38, ax_lanes: mat38, t_lanes: mat38, k_lanes: mat58, src: int, dst: int, C: int, hw8: int,
        H: int, W: int, zmin: T,
    ):
        """Pixels x0 .. x0 + 7 of a row (depth block ``e``, flat (b, y, block), also the index of
        their first ``valid`` flag / 8): ``valid`` (valid depth, in front, inside the image within
        ``sampler.INSIDE_TOLERANCE``) and the bilinear samples of the channel planes ``src + c H W`` of
        ``image`` into ``out[dst + c hw8]`` (hw8 = H W / 8), 0 where the depth is invalid or the
        point behind ``zmin``. ``a0_lanes`` .. ``k_lanes``: :func:`row_lanes` of ``a0``, ``ax``, ``t``,
        ``Kb``, not read (the compiler drops them). Gradients (hand-written): to ``image``, ``depth``,
        and to ``a0``, ``ax``, ``t`` and ``Kb`` through ``a0_lanes`` .. ``k_lanes``."""
        tol = T(sampler.INSIDE_TOLERANCE)
        u, v, ok, dd, x, xn, yn, inv_z = project8(depth, e, x0, a0, ax, t, Kb, zmin)
        flags = wp.cw_mul(
            ok, wp.cw_mul(lanes.closed_mask8(u, -tol, T(W - 1) + tol), lanes.closed_mask8(v, -tol, T(H - 1) + tol))
        )
        first = e * wp.static(_LANES)
        for k in range(wp.static(_LANES)):
            valid[first + k] = flags[k] != T(0.0)
        xs, ys, inside = sampler.sample_position_lanes(u, v, H, W, wp.static(static_padding))
        nc = C
        if wp.static(static_c > 0):
            nc = wp.static(static_c)  # a constant: the channel loop unrolls exactly
        sampler.sample_lanes(image, out, src, dst, nc, H * W, hw8, H, W, xs, ys, wp.cw_mul(inside, ok), 1)

    @func_grad(warp_block8)
    def adj_warp_block8(
        image: wp.array(dtype=T), depth: wp.array(dtype=vec8), out: wp.array(dtype=vec8),
        valid: wp.array(dtype=wp.bool), e: int, x0: int, a0: vec3, ax: vec3, t: vec3, Kb: mat33,
        a0_lanes: mat38, ax_lanes: mat38, t_lanes: mat38, k_lanes: mat58, src: int, dst: int, C: int, hw8: int,
        H: int, W: int, zmin: T,
    ):
        zero = T(0.0)
        zeros = lanes.splat8(zero)
        u, v, ok, dd, x, xn, yn, inv_z = project8(depth, e, x0, a0, ax, t, Kb, zmin)
        xs, ys, inside = sampler.sample_position_lanes(u, v, H, W, wp.static(static_padding))
        active = wp.cw_mul(inside, ok)
        # (lanes_grad.channel_grads_lanes, written out: calling it, as bilinear_block does, made this
        # backward 7-9% slower with the image gradient)
        nc = C
        if wp.static(static_c > 0):
            nc = wp.static(static_c)
        # (views with compile-time strides: this function is not inlined into the kernel)
        img = sampler.dense(image)
        g_out = sampler.dense(wp.adjoint[out])
        g_image = sampler.dense(wp.adjoint[image])
        # the taps, as sampler.sample_lanes has them; d out_c / dx = (v10 - v00) wy0 + (v11 - v01) wy1
        a00, a10, a01, a11, m00, m10, m01, m11, wx1, wy1 = sampler.taps_lanes(xs, ys, T(W), T(H))
        m00 = wp.cw_mul(m00, active)
        m10 = wp.cw_mul(m10, active)
        m01 = wp.cw_mul(m01, active)
        m11 = wp.cw_mul(m11, active)
        wx0 = lanes.splat8(T(1.0)) - wx1
        wy0 = lanes.splat8(T(1.0)) - wy1
        scatter = g_image.shape[0] > 0
        # the taps' weights, as the sampler's
        w00 = wp.cw_mul(wx0, wy0)
        w10 = wp.cw_mul(wx1, wy0)
        w01 = wp.cw_mul(wx0, wy1)
        w11 = wp.cw_mul(wx1, wy1)
        gx = zeros
        gy = zeros
        # (the two loops written out: one helper function for their bodies made the backward ~10% slower)
        for c in range(wp.static(sampler.UNROLLED_CHANNELS)):
            if c < nc:
                g = g_out[dst + c * hw8]
                dx, dy = sampler.position_grad_lanes(img, src + c * H * W, g, a00, a10, a01, a11, m00, m10, m01,
                                                     m11, wx0, wx1, wy0, wy1)
                gx = gx + dx
                gy = gy + dy
                if wp.static(static_image_grad):
                    if scatter:
                        sampler.scatter_lanes(g_image, src + c * H * W, g, a00, a10, a01, a11, m00, m10, m01, m11,
                                              w00, w10, w01, w11)
        for c in range(sampler.UNROLLED_CHANNELS, nc):
            g = g_out[dst + c * hw8]
            dx, dy = sampler.position_grad_lanes(img, src + c * H * W, g, a00, a10, a01, a11, m00, m10, m01, m11,
                                                 wx0, wx1, wy0, wy1)
            gx = gx + dx
            gy = gy + dy
            if wp.static(static_image_grad):
                if scatter:
                    sampler.scatter_lanes(g_image, src + c * H * W, g, a00, a10, a01, a11, m00, m10, m01, m11, w00,
                                          w10, w01, w11)
        # lanes that are not active: no gradient at all (also for a NaN or inf incoming gradient there)
        gx = lanes.select8(active, gx, zeros)
        gy = lanes.select8(active, gy, zeros)
        gu = gx
        gv = gy
        if wp.static(static_padding == int(sampler.PADDING_BORDER)):
            # the border padding's clamp passes no gradient where it clamps (grid_sample's rule)
            # (a select: a NaN gradient from a NaN pixel there does not pass either)
            gu = lanes.select8(lanes.open_mask8(u, zero, T(W - 1)), gx, zeros)
            gv = lanes.select8(lanes.open_mask8(v, zero, T(H - 1)), gy, zeros)
        # through the projection (camera.project_moved_ray_grad on 8 lanes): u = fx xn + s yn + cx,
        # v = fy yn + cy, xn = q0 / q2, yn = q1 / q2, q = dd (a0 + x ax) + t; lanes that are not
        # active have gu = gv = 0 and contribute nothing
        gxn = Kb[0, 0] * gu
        gyn = Kb[0, 1] * gu + Kb[1, 1] * gv
        g0 = wp.cw_mul(gxn, inv_z)
        g1 = wp.cw_mul(gyn, inv_z)
        # (behind min_depth q_z was replaced by 1, a constant; the depth itself where it is invalid: selects,
        # as the row kernel's wp.where, so that nothing there can pass, whatever its values)
        g2 = lanes.select8(ok, -wp.cw_mul(wp.cw_mul(xn, gxn) + wp.cw_mul(yn, gyn), inv_z), zeros)
        g_depth = sampler.dense(wp.adjoint[depth])
        if g_depth.shape[0] > 0:
            r0 = lanes.splat8(a0[0]) + ax[0] * x
            r1 = lanes.splat8(a0[1]) + ax[1] * x
            r2 = lanes.splat8(a0[2]) + ax[2] * x
            g_d = wp.cw_mul(g0, r0) + wp.cw_mul(g1, r1) + wp.cw_mul(g2, r2)
            g_depth[e] = g_depth[e] + lanes.select8(ok, g_d, zeros)
        # the row's constants: whole 8-lane gradients (row_lanes' adjoint sums the lanes, once per row)
        gr0 = wp.cw_mul(g0, dd)
        gr1 = wp.cw_mul(g1, dd)
        gr2 = wp.cw_mul(g2, dd)
        wp.adjoint[a0_lanes] += wp.matrix_from_rows(gr0, gr1, gr2)
        wp.adjoint[ax_lanes] += wp.matrix_from_rows(wp.cw_mul(gr0, x), wp.cw_mul(gr1, x), wp.cw_mul(gr2, x))
        wp.adjoint[t_lanes] += wp.matrix_from_rows(g0, g1, g2)
        # (rows fx, skew, cx, fy, cy: row_lanes' order)
        wp.adjoint[k_lanes] += wp.matrix_from_rows(wp.cw_mul(gu, xn), wp.cw_mul(gu, yn), gu, wp.cw_mul(gv, yn), gv)

    @wp.func_replay(warp_block8)
    def replay_warp_block8(
        image: wp.array(dtype=T), depth: wp.array(dtype=vec8), out: wp.array(dtype=vec8),
        valid: wp.array(dtype=wp.bool), e: int, x0: int, a0: vec3, ax: vec3, t: vec3, Kb: mat33,
        a0_lanes: mat38, ax_lanes: mat38, t_lanes: mat38, k_lanes: mat58, src: int, dst: int, C: int, hw8: int,
        H: int, W: int, zmin: T,
    ):
        # the backward pass needs nothing the forward stored: skip projecting and sampling again
        pass

    return warp_block8


__all__ = ["row_lanes", "warp_block8"]
