"""A block of 8 output locations of the bilinear sampler as 8-lane vector code, with its
hand-written adjoint (``@wp.func``, no launches here): :func:`sample_block8`, what
:func:`.kernels.bilinear_sample_lanes` runs per element, forward and backward.

Forward: :func:`.lanes.sample_lanes` at the 8 (x, y) pairs of the grid, bitwise the values of the
scalar kernel :data:`.kernels.bilinear_sample`. Adjoint: the scalar kernel's gradients (the same
rules: none where a sample is outside, none through the border padding's clamp, a NaN or inf
incoming gradient of an inactive lane passes nothing), computed as :mod:`.pinhole_block`'s are:
the taps read as vectors (:func:`.lanes.position_grad_lanes`), the image gradient added lane by
lane (:func:`.lanes.scatter_lanes`), the grid's as one 16-lane vector; equal to the scalar
kernel's up to the order of sums.
"""

import warp as wp

from ..core import lanes
from ..core.cache import float_overloads, specialise
from ..core.compat import func_grad
from ..core.kinds import vec8d, vec8f, vec16d, vec16f
from . import lanes_grad, sampler


@specialise("sampling.bilinear_block8", C=tuple(range(1, sampler.UNROLLED_CHANNELS + 1)))
def sample_block8(C: int | None, align_corners: int, padding: int, image_grad: bool = True) -> wp.Function:
    """The block function for this channel count (if at most ``sampler.UNROLLED_CHANNELS``; else
    read at run time: ``C`` None), ``align_corners``, ``padding`` and ``image_grad`` (False: the
    adjoint has no image gradient code), all compiled in (float32 and float64 overloads)."""

    def make(T):
        return _sample_block8(T, C or 0, int(align_corners), int(padding), bool(image_grad))

    make.__qualname__ = (f"sample_block8(C={C}, align_corners={align_corners}, padding={padding}, "
                         f"image_grad={bool(image_grad)})")
    return float_overloads(make)


def _sample_block8(T, static_c: int, static_align: int, static_padding: int, static_image_grad: bool):
    """sample_block8's float type ``T`` overload (Warp custom adjoints need concrete types)."""
    vec8 = vec8f if T == wp.float32 else vec8d
    vec16 = vec16f if T == wp.float32 else vec16d
    channel_grads = lanes_grad.channel_grads_lanes(static_c or None, static_image_grad)

    @wp.func
    def positions8(g: vec16, H: int, W: int):
        """The 8 (x, y) grid pairs as pixel positions (x, y) and their padded positions (xs, ys, inside)."""
        x = sampler.normalized_to_pixel_lanes(vec8(g[0], g[2], g[4], g[6], g[8], g[10], g[12], g[14]), W,
                                              wp.static(static_align))
        y = sampler.normalized_to_pixel_lanes(vec8(g[1], g[3], g[5], g[7], g[9], g[11], g[13], g[15]), H,
                                              wp.static(static_align))
        xs, ys, inside = sampler.sample_position_lanes(x, y, H, W, wp.static(static_padding))
        return x, y, xs, ys, inside

    @wp.func
    def sample_block8(image: wp.array(dtype=T), out: wp.array(dtype=vec8), g: vec16, src: int, dst: int, C: int,
                      hw8: int, H: int, W: int):
        """The 8 samples of the grid pairs ``g`` of the channel planes ``src + c H W`` of ``image``
        into ``out[dst + c hw8]``. Gradients (hand-written): to ``image`` and ``g``."""
        x, y, xs, ys, inside = positions8(g, H, W)
        nc = C
        if wp.static(static_c > 0):
            nc = wp.static(static_c)  # a constant: the channel loop unrolls exactly
        sampler.sample_lanes(image, out, src, dst, nc, H * W, hw8, H, W, xs, ys, inside, 0)

    @func_grad(sample_block8)
    def adj_sample_block8(image: wp.array(dtype=T), out: wp.array(dtype=vec8), g: vec16, src: int, dst: int,
                          C: int, hw8: int, H: int, W: int):
        zero = T(0.0)
        zeros = lanes.splat8(zero)
        x, y, xs, ys, inside = positions8(g, H, W)
        gx, gy = channel_grads(image, wp.adjoint[out], wp.adjoint[image], src, dst, C, hw8, H, W, xs, ys, inside)
        # samples outside: no gradient at all (also for a NaN or inf incoming gradient there)
        gx = lanes.select8(inside, gx, zeros)
        gy = lanes.select8(inside, gy, zeros)
        if wp.static(static_padding == int(sampler.PADDING_BORDER)):
            # the border padding's clamp passes no gradient where it clamps (grid_sample's rule)
            gx = lanes.select8(lanes.open_mask8(x, zero, T(W - 1)), gx, zeros)
            gy = lanes.select8(lanes.open_mask8(y, zero, T(H - 1)), gy, zeros)
        # through the un-normalisation (the scalar adjoint's order of products)
        half = T(0.5)
        if wp.static(static_align != 0):
            gx = gx * T(W - 1) * half
            gy = gy * T(H - 1) * half
        else:
            gx = gx * half * T(W)
            gy = gy * half * T(H)
        wp.adjoint[g] += vec16(gx[0], gy[0], gx[1], gy[1], gx[2], gy[2], gx[3], gy[3], gx[4], gy[4], gx[5], gy[5],
                               gx[6], gy[6], gx[7], gy[7])

    @wp.func_replay(sample_block8)
    def replay_sample_block8(image: wp.array(dtype=T), out: wp.array(dtype=vec8), g: vec16, src: int, dst: int,
                             C: int, hw8: int, H: int, W: int):
        # the backward pass needs nothing the forward stored: skip sampling again
        pass

    return sample_block8


__all__ = ["sample_block8"]
