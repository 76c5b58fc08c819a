"""The adjoint of the 8-lane sampler for a block's channels (``@wp.func``, no launches here):
:func:`channel_grads_lanes`, what the hand-written adjoints of :mod:`.bilinear_block` and
:mod:`.lens_block` share, the sampler's part of their chain rule (:mod:`.pinhole_block` writes
the same steps out in its own adjoint: a call cost it 7-9%).
"""

import warp as wp

from ..core import lanes
from ..core.cache import float_overloads, specialise
from ..core.kinds import vec8d, vec8f
from . import sampler


@specialise("sampling.channel_grads_lanes", C=tuple(range(1, sampler.UNROLLED_CHANNELS + 1)))
def channel_grads_lanes(C: int | None, image_grad: bool) -> wp.Function:
    """``channel_grads8(image, g_out, g_image, src, dst, C, hw8, H, W, xs, ys, active) -> (gx, gy)``
    for this channel count (if at most ``sampler.UNROLLED_CHANNELS``; else read at run time: ``C``
    None) and ``image_grad`` (False: no image gradient code), float32 and float64 overloads.

    For 8 positions (xs, ys) padded as :func:`.lanes.sample_lanes` takes them, sampled where
    ``active`` is 1 from the channel planes ``src + c H W`` of ``image`` into ``out[dst + c hw8]``,
    and the incoming gradient ``g_out`` of ``out``: adds d loss / d image to ``g_image`` (unless it
    is empty) and returns d loss / d (xs, ys), summed over the channels (zero where a lane's taps
    are all masked; the caller selects the active lanes, which also drops a NaN incoming gradient
    there). The arrays must be contiguous (seen through :func:`.lanes.dense`)."""

    def make(T):
        return _channel_grads_lanes(T, C or 0, bool(image_grad))

    make.__qualname__ = f"channel_grads_lanes(C={C}, image_grad={bool(image_grad)})"
    return float_overloads(make)


def _channel_grads_lanes(T, static_c: int, static_image_grad: bool):
    vec8 = vec8f if T == wp.float32 else vec8d

    @wp.func
    def channel_grads8(image: wp.array(dtype=T), g_out: wp.array(dtype=vec8), g_image: wp.array(dtype=T), src: int,
                       dst: int, C: int, hw8: int, H: int, W: int, xs: vec8, ys: vec8, active: vec8):
        zeros = lanes.splat8(T(0.0))
        nc = C
        if wp.static(static_c > 0):
            nc = wp.static(static_c)  # a constant: the channel loop unrolls exactly
        # (views with compile-time strides: this function is not inlined into the kernel)
        img = sampler.dense(image)
        go = sampler.dense(g_out)
        gi = sampler.dense(g_image)
        # the taps, as sampler.sample_lanes has them; d out_c / dx = (v10 - v00) wy0 + (v11 - v01) wy1
        a00, a10, a01, a11, m00, m10, m01, m11, wx1, wy1 = sampler.taps_lanes(xs, ys, T(W), T(H))
        m00 = wp.cw_mul(m00, active)
        m10 = wp.cw_mul(m10, active)
        m01 = wp.cw_mul(m01, active)
        m11 = wp.cw_mul(m11, active)
        wx0 = lanes.splat8(T(1.0)) - wx1
        wy0 = lanes.splat8(T(1.0)) - wy1
        scatter = gi.shape[0] > 0
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
                g = go[dst + c * hw8]
                dx, dy = sampler.position_grad_lanes(img, src + c * H * W, g, a00, a10, a01, a11, m00, m10, m01,
                                                     m11, wx0, wx1, wy0, wy1)
                gx = gx + dx
                gy = gy + dy
                if wp.static(static_image_grad):
                    if scatter:
                        sampler.scatter_lanes(gi, src + c * H * W, g, a00, a10, a01, a11, m00, m10, m01, m11, w00,
                                              w10, w01, w11)
        for c in range(sampler.UNROLLED_CHANNELS, nc):
            g = go[dst + c * hw8]
            dx, dy = sampler.position_grad_lanes(img, src + c * H * W, g, a00, a10, a01, a11, m00, m10, m01, m11,
                                                 wx0, wx1, wy0, wy1)
            gx = gx + dx
            gy = gy + dy
            if wp.static(static_image_grad):
                if scatter:
                    sampler.scatter_lanes(gi, src + c * H * W, g, a00, a10, a01, a11, m00, m10, m01, m11, w00, w10,
                                          w01, w11)
        return gx, gy

    return channel_grads8


__all__ = ["channel_grads_lanes"]
