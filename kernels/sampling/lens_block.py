"""A block of up to 8 pixels of one row of the 3D spatial transformer through a lens model
(``@wp.func``, no launches here): :func:`warp_block`, what the lens variant of
:data:`.kernels.warp_frame_depth` runs per block. The block's rays are moved and projected as
8-lane vectors in the kernel's own float type (:mod:`gvnn_warp.kernels.geometry.lens.lanes`, SIMD
code), and only then sampled (:mod:`.sampler`), so that the image reads of the block are not each
held up by its own projection: a block of 8 whole pixels as lanes too (:func:`.sampler.sample_lanes`,
the same values as pixel by pixel; the forward 15% faster on an Intel Xeon guest), others pixel by
pixel. For float32 that projection is float32 arithmetic (within ~1e-4 px
of ``lens.rays.project_ray``'s), for float64 it is exact to rounding.
"""

import warp as wp

from ..core import lanes
from ..core.cache import float_overloads, specialise
from ..core.compat import func_grad
from ..core.kinds import vec8d, vec8f
from ..geometry.lens import dispatch
from ..geometry.lens import lanes as lens_lanes
from . import lanes_grad, sampler


@specialise("sampling.lens_warp_block")
def warp_block() -> wp.Function:
    """The block function (float32 and float64 overloads), made on first use: it has a custom
    adjoint, which Warp builds when it is defined (seconds)."""
    return float_overloads(_warp_block)


# pixels per block of warp_block: the projections of a block are computed before any of its
# samples, so the block's image reads are issued together instead of each waiting for its own
# projection's division and lens polynomial (a one-pixel-at-a-time loop is latency-bound: ~1.4x
# the time per pixel, see benchmarks/RESULTS.md, issue 19)
BLOCK = wp.constant(8)
_MAX_LANES_PLANE = wp.constant(sampler.MAX_LANES_PLANE)


@wp.func
def whole_block(n: int, dst0: int, hw: int):
    """Whether a block of ``n`` pixels whose outputs start at ``dst0`` (in planes of ``hw``) is 8
    whole pixels starting a group of 8 of every plane, in a plane whose tap addresses the lanes hold
    exactly (:data:`.sampler.MAX_LANES_PLANE`, for either float type): sampled, and its gradient
    taken, as lanes."""
    return n == BLOCK and dst0 % 8 == 0 and hw % 8 == 0 and hw <= _MAX_LANES_PLANE


def _warp_block(T):
    """warp_block's float type ``T`` overload (Warp custom adjoints need concrete types)."""
    f64 = wp.float64
    vec3 = wp.types.vector(3, T)
    mat33 = wp.types.matrix((3, 3), T)
    vec8 = vec8f if T == wp.float32 else vec8d
    block_values = lens_lanes.functions(False).block_lanes  # the forward's: no Jacobian
    block_lanes = lens_lanes.functions(True).block_lanes
    channel_grads = lanes_grad.channel_grads_lanes(None, True)  # (C read at run time)

    @wp.func
    def lanes_grad8(image: wp.array(dtype=T), g_image: wp.array(dtype=T), g_out_flat: wp.array(dtype=T), src: int,
                    dst8: int, C: int, hw8: int, H: int, W: int, xs: vec8, ys: vec8, active: vec8):
        """d loss / d (u, v) of 8 lanes sampled into the vec8 groups ``dst8 + c hw8`` of ``out``, and
        their image gradient (unless ``g_image`` is empty): :func:`.lanes_grad.channel_grads_lanes`."""
        g_out = wp.array(ptr=g_out_flat.ptr, shape=(g_out_flat.shape[0] // 8,), dtype=vec8)
        gx, gy = channel_grads(image, g_out, g_image, src, dst8, C, hw8, H, W, xs, ys, active)
        zeros = lanes.splat8(T(0.0))
        return lanes.select8(active, gx, zeros), lanes.select8(active, gy, zeros)

    @wp.func
    def warp_block(
        image: wp.array(dtype=T), depth: wp.array(dtype=T), rays: wp.array(dtype=vec3), out: wp.array(dtype=T),
        valid: wp.array(dtype=wp.bool), K: wp.array(dtype=mat33), dist: wp.array(dtype=vec8), i0: int, ray0: int,
        n: int, b: int, src: int, dst0: int, C: int, H: int, W: int, padding: int, model: int, R: mat33, t: vec3,
        Kb: mat33, db: vec8, min_depth: T, tol: T,
    ):
        """``n`` <= BLOCK consecutive pixels of one row of the 3D spatial transformer through the lens:
        pixel k (flat index ``i0 + k`` of ``depth`` and ``valid``, ray ``rays[ray0 + k]``) is the point
        ``depth (ray_x, ray_y, 1)`` moved by [R | t] and projected (the lanes of ``block_values``,
        ``rays.project_ray``'s formulas in the kernel's float type); ``valid``
        (valid depth, a ray, in the domain, inside the image within ``tol``) and the bilinear samples
        of the C channels of ``image`` (plane ``src``) into ``out[dst0 + k + c H W]``: 0 where the
        pixel is not active (valid depth, a ray, the moved point in front and in the domain); an
        active pixel that lands just outside the image reads zeros there (or the border, with border
        padding) as grid_sample does. Invalid depth (<= min, NaN, inf) or a pixel without a ray: depth
        1 stands in before any arithmetic, so neither the values nor the adjoint see it.

        All n projections come first, then the samples (see BLOCK): as 8 lanes when the block is 8
        pixels whose outputs start a group of 8 (``dst0`` and H W multiples of 8), else pixel by
        pixel, the same values. Hand-written adjoint in two
        phases: the projections with their Jacobians (lanes, ``block_lanes``), then the sampler's
        gradient (for such a block as lanes, :func:`.lanes_grad.channel_grads_lanes`; else pixel by
        pixel, :func:`.sampler.sample_channels_grad`: the same values) and per pixel through the Jacobian the
        gradients to R, t, depth, the ray, and to ``K[b]`` and ``dist[b]`` only when their adjoint
        arrays exist (a wanted gradient); the backward pass does not replay it (nothing the kernel
        computes after it reads its results)."""
        u8, v8, ok8, du0, du1, du2, dv0, dv1, dv2 = block_values(
            depth, rays, i0, ray0, n, model, R, t, Kb, db, min_depth
        )
        umax = T(W - 1) + tol
        vmax = T(H - 1) + tol
        hw = H * W
        whole = whole_block(n, dst0, hw)
        for k in range(n):
            u = u8[k]
            v = v8[k]
            ok = ok8[k] > T(0.0)
            valid[wp.max(i0 + k, 0)] = ok and u >= -tol and u <= umax and v >= -tol and v <= vmax
            if not whole:
                xs, ys, reachable = sampler.sample_position(u, v, H, W, padding)
                sampler.sample_channels(image, out, src, dst0 + k, C, hw, hw, H, W, xs, ys, ok and reachable)
        if whole:  # the 8 samples as lanes (the same values: sampler.sample_lanes)
            out8 = wp.array(ptr=out.ptr, shape=(out.shape[0] // 8,), dtype=vec8)
            xs8, ys8, inside8 = sampler.sample_position_lanes(u8, v8, H, W, padding)
            sampler.sample_lanes(image, out8, src, dst0 // 8, C, hw, hw // 8, H, W, xs8, ys8,
                                 wp.cw_mul(inside8, ok8), 1)

    @func_grad(warp_block)
    def adj_warp_block(
        image: wp.array(dtype=T), depth: wp.array(dtype=T), rays: wp.array(dtype=vec3), out: wp.array(dtype=T),
        valid: wp.array(dtype=wp.bool), K: wp.array(dtype=mat33), dist: wp.array(dtype=vec8), i0: int, ray0: int,
        n: int, b: int, src: int, dst0: int, C: int, H: int, W: int, padding: int, model: int, R: mat33, t: vec3,
        Kb: mat33, db: vec8, min_depth: T, tol: T,
    ):
        zero = T(0.0)
        # phase 1: the projections and their Jacobians d(u, v)/dq (rows du, dv)
        u8, v8, ok8, du0, du1, du2, dv0, dv1, dv2 = block_lanes(
            depth, rays, i0, ray0, n, model, R, t, Kb, db, min_depth
        )
        # phase 2, per pixel: the sampler's gradient d loss / d(u, v), then through the projection
        # (the lanes' Jacobian) and the motion to pose, depth and ray, K and coefficients if wanted
        g_depth = wp.adjoint[depth]
        g_rays = wp.adjoint[rays]
        gK = wp.adjoint[K]
        gd = wp.adjoint[dist]
        lens_wanted = gK.shape[0] > 0 or gd.shape[0] > 0
        # the block's pose gradients summed in registers, added to the kernel's once
        g_t = vec3()
        g_R = mat33()
        hw = H * W
        whole = whole_block(n, dst0, hw)
        gu8 = lanes.splat8(zero)
        gv8 = lanes.splat8(zero)
        reach8 = lanes.splat8(zero)
        if whole:  # the sampler's gradient of the 8 pixels as lanes (the forward sampled them so)
            xs8, ys8, reach8 = sampler.sample_position_lanes(u8, v8, H, W, padding)
            gu8, gv8 = lanes_grad8(image, wp.adjoint[image], wp.adjoint[out], src, dst0 // 8, C, hw // 8, H, W, xs8,
                                   ys8, wp.cw_mul(reach8, ok8))
        for k in range(n):
            if ok8[k] > zero:  # active: a valid depth (read raw below), a ray, in front, in the domain
                u = u8[k]
                v = v8[k]
                reachable = reach8[k] != zero
                gu = gu8[k]
                gv = gv8[k]
                if not whole:
                    xs, ys, reachable = sampler.sample_position(u, v, H, W, padding)
                    if reachable:
                        gu, gv = sampler.sample_channels_grad(
                            image, wp.adjoint[image], wp.adjoint[out], src, dst0 + k, C, hw, hw, H, W, xs, ys
                        )
                if reachable:
                    # the border padding's clamp passes no gradient where it clamps (grid_sample's rule)
                    if padding == sampler.PADDING_BORDER:
                        gu = wp.where(u <= zero or u >= T(W - 1), zero, gu)
                        gv = wp.where(v <= zero or v >= T(H - 1), zero, gv)
                    depth_i = depth[wp.max(i0 + k, 0)]
                    ray = rays[wp.max(ray0 + k, 0)]
                    P = vec3(ray[0] * depth_i, ray[1] * depth_i, depth_i)
                    gq = vec3(du0[k] * gu + dv0[k] * gv, du1[k] * gu + dv1[k] * gv, du2[k] * gu + dv2[k] * gv)
                    g_t = g_t + gq
                    g_R = g_R + wp.outer(gq, P)
                    gP = wp.transpose(R) * gq
                    if g_rays.shape[0] > 0:
                        j = wp.max(ray0 + k, 0)
                        g_rays[j] = g_rays[j] + vec3(gP[0] * depth_i, gP[1] * depth_i, zero)
                    if g_depth.shape[0] > 0:
                        j = wp.max(i0 + k, 0)
                        g_depth[j] = g_depth[j] + gP[0] * ray[0] + gP[1] * ray[1] + gP[2]
                    if lens_wanted:
                        # u = fx xd + s yd + cx, v = fy yd + cy, (xd, yd) = D(x, y), (x, y) = (q0, q1) / q2
                        d64 = dispatch.to64(db)
                        q = R * P + t
                        iz = f64(1.0) / f64(q[2])
                        x = f64(q[0]) * iz
                        y = f64(q[1]) * iz
                        xd, yd = dispatch.distort_value64(model, d64, x, y)
                        gu64 = f64(gu)
                        gv64 = f64(gv)
                        if gK.shape[0] > 0:
                            gK[b] = gK[b] + mat33(
                                T(gu64 * xd), T(gu64 * yd), gu, zero, T(gv64 * yd), gv, zero, zero, zero
                            )
                        if gd.shape[0] > 0:
                            gxd = f64(Kb[0, 0]) * gu64
                            gyd = f64(Kb[0, 1]) * gu64 + f64(Kb[1, 1]) * gv64
                            gd[b] = gd[b] + dispatch.from64(
                                dispatch.distort_vjp_dist64(model, d64, x, y, gxd, gyd), depth_i
                            )
        wp.adjoint[t] += g_t
        wp.adjoint[R] += g_R

    @wp.func_replay(warp_block)
    def replay_warp_block(
        image: wp.array(dtype=T), depth: wp.array(dtype=T), rays: wp.array(dtype=vec3), out: wp.array(dtype=T),
        valid: wp.array(dtype=wp.bool), K: wp.array(dtype=mat33), dist: wp.array(dtype=vec8), i0: int, ray0: int,
        n: int, b: int, src: int, dst0: int, C: int, H: int, W: int, padding: int, model: int, R: mat33, t: vec3,
        Kb: mat33, db: vec8, min_depth: T, tol: T,
    ):
        # the backward pass needs nothing the forward stored: skip projecting and sampling again
        pass

    return warp_block


__all__ = ["BLOCK", "warp_block"]
