"""The sampling ops: the bilinear sampler and the fused 3D spatial transformer, pinhole and
through a lens model (with the pixel rays of a distorted camera), registered as
``gvnn_warp::*`` custom ops (see :mod:`.bridge`).

These ops take already-validated, flattened, contiguous tensors; the public, documented entry
points are in :mod:`gvnn_warp.functional`. Each registration names the public function and
layer it serves.
"""

from __future__ import annotations

from ..kernels.sampling import kernels as sampling_kernels
from .bridge import warp_op
from .registry import Output, Param, lazy_ops

_SAMPLE_PARAMS = [Param("C", "int"), Param("H", "int"), Param("W", "int"), Param("hw", "int"),
                  Param("align_corners", "int"), Param("padding", "int")]

# image (B, C, H, W), grid (B*h*w, 2) -> (B, C, h*w)
bilinear_sample = warp_op(
    "bilinear_sample", sampling_kernels.bilinear_sample, ["image", "grid"], _SAMPLE_PARAMS,
    [Output("out", "scalar", lambda img, g, C, H, W, hw, a, p: (img.shape[0], C, hw))],
    lambda img, g, *_: g.shape[0],
    function="bilinear_sample", layer="BilinearSampler",
)


def _lanes_kernel(C, H, W, hw, align_corners, padding, image_grad=True):
    if not sampling_kernels.fits_lanes(hw, H, W):
        raise ValueError(f"bilinear_sample_lanes: needs hw % 8 == 0 and H*W <= 2^24, got hw={hw}, H*W={H * W}")
    return sampling_kernels.bilinear_sample_lanes(C, align_corners, padding, image_grad)


def _lanes_backward_kernel(needs, *params):
    # without the image's gradient (bit 0 of needs), the variant compiled without its code
    return _lanes_kernel(*params, image_grad=bool(needs & 1))


# the same values, 8 output locations per thread (h*w % 8 == 0, H*W <= 2^24; SIMD arithmetic),
# a kernel compiled per (C, align_corners, padding), with its own (hand-written) adjoint
bilinear_sample_lanes = warp_op(
    "bilinear_sample_lanes", None, ["image", "grid"], _SAMPLE_PARAMS,
    [Output("out", "vec8", lambda img, g, C, H, W, hw, a, p: (img.shape[0], C, hw))],
    lambda img, g, *_: g.shape[0] // sampling_kernels.sampler.LANES,
    select=_lanes_kernel, backward_select=_lanes_backward_kernel, array_kinds=sampling_kernels.LANES_ARRAY_KINDS,
    function="bilinear_sample", layer="BilinearSampler",  # its 8-lane fast path
)

_WARPED = [
    Output("out", "scalar", lambda img, *_: tuple(img.shape)),
    Output("valid", "bool", lambda img, d, *_: tuple(d.shape), differentiable=False),
]


def _image_rows(img, d, *_):
    return d.shape[0] * d.shape[2]  # one thread per image row: B * H


# image (B, C, H, W), depth (B, 1, H, W), pose (B, 3, 4), K (B, 3, 3) -> (B, C, H, W), (B, 1, H, W) bool
warp_frame_depth = warp_op(
    "warp_frame_depth", sampling_kernels.warp_frame_depth, ["image", "depth", "pose", "K"],
    [Param("C", "int"), Param("H", "int"), Param("W", "int"), Param("min_depth", "float"), Param("padding", "int")],
    _WARPED, _image_rows,
    function="warp_frame_depth", layer="SpatialTransformer3D",
)


def _row_lanes_kernel(C, H, W, min_depth, padding, image_grad=True):
    if not sampling_kernels.fits_row_lanes(H, W):
        raise ValueError(f"warp_frame_depth_lanes: needs W % 8 == 0 and H*W <= 2^24, got H={H}, W={W}")
    return sampling_kernels.warp_frame_depth_lanes(C, padding, image_grad)


def _row_lanes_backward_kernel(needs, *params):
    # without the image's gradient (bit 0 of needs), the variant compiled without its code
    return _row_lanes_kernel(*params, image_grad=bool(needs & 1))


# the same values, a row's pixels 8 at a time (W % 8 == 0, H*W <= 2^24; SIMD arithmetic), a kernel
# compiled per (C, padding), with its own (hand-written) adjoint
warp_frame_depth_lanes = warp_op(
    "warp_frame_depth_lanes", None, ["image", "depth", "pose", "K"],
    [Param("C", "int"), Param("H", "int"), Param("W", "int"), Param("min_depth", "float"), Param("padding", "int")],
    [Output("out", "vec8", lambda img, *_: tuple(img.shape)), _WARPED[1]],
    _image_rows, select=_row_lanes_kernel, backward_select=_row_lanes_backward_kernel,
    array_kinds={"image": "scalar", "depth": "vec8", "pose": "mat34", "K": "mat33", "out": "vec8"},
    function="warp_frame_depth", layer="SpatialTransformer3D",  # its 8-lane fast path
)

# ----------------------------------------------------------------------------- through a lens model
#
# Their kernels take seconds to define (the lens models' custom adjoints): each registration gives a
# maker, called on the first launch, and the torch ops are defined on first use (lazy=True: the ops are
# this module's attributes through __getattr__ below; gvnn_warp.ops.lens defines them all).


# K (Bc, 3, 3), dist (Bc, 8) -> rays (Bc*H*W, 3): the undistorted ray (xn, yn, w) of every pixel
warp_op(
    "pixel_rays", sampling_kernels.pixel_rays_lens, ["K", "dist"],
    [Param("H", "int"), Param("W", "int"), Param("model", "int")],
    [Output("rays", "vec3", lambda K, d, H, W, m: (K.shape[0] * H * W, 3))], lambda K, d, H, W, m: K.shape[0] * H * W,
    array_kinds={"K": "mat33", "dist": "vec8"}, lazy=True,
    function="warp_frame_depth", layer="SpatialTransformer3D",  # its rays through a distorted camera
)
# warp_frame_depth through a lens model: + dist (B, 8), rays (Bc*H*W, 3) (Bc = B, or 1 with ray_stride 0)
warp_op(
    "warp_frame_depth_lens", sampling_kernels.warp_frame_depth_lens,
    ["image", "depth", "pose", "K", "dist", "rays"],
    [Param("C", "int"), Param("H", "int"), Param("W", "int"), Param("min_depth", "float"), Param("padding", "int"),
     Param("model", "int"), Param("ray_stride", "int")],
    _WARPED, _image_rows,
    array_kinds={"image": "scalar", "depth": "scalar", "pose": "mat34", "K": "mat33", "dist": "vec8", "rays": "vec3"},
    lazy=True, function="warp_frame_depth", layer="SpatialTransformer3D",  # with a distorted camera
)

__getattr__ = lazy_ops(__name__)  # (the ops registered with lazy=True)
