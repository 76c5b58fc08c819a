"""Registration of every Warp kernel as a ``gvnn_warp::*`` torch custom op (see :mod:`._bridge`).

These ops take already-validated, flattened, contiguous tensors; the public, documented entry
points are in :mod:`gvnn_warp.functional`. The ops through lens models are in :mod:`._lens_ops`,
registered on first use (:data:`PUBLIC` lists them too).
"""

from __future__ import annotations

from ..kernels.geometry import camera_kernels, lie_kernels
from ..kernels.sampling import kernels as sampling_kernels
from .bridge import Output, Param, warp_op


def _rows(t, *_):
    return t.shape[0]


def _per_row(*inner):
    return lambda t, *_: (t.shape[0], *inner)


so3_exp = warp_op("so3_exp", lie_kernels.so3_exp, ["omega"], [], [Output("R", "mat33", _per_row(3, 3))], _rows)
so3_log = warp_op("so3_log", lie_kernels.so3_log, ["R"], [], [Output("omega", "vec3", _per_row(3))], _rows)
quaternion_to_matrix = warp_op(
    "quaternion_to_matrix", lie_kernels.quaternion_to_matrix, ["q"], [],
    [Output("R", "mat33", _per_row(3, 3))], _rows,
)
euler_to_matrix = warp_op(
    "euler_to_matrix", lie_kernels.euler_to_matrix, ["angles"],
    [Param("a0", "int"), Param("a1", "int"), Param("a2", "int")],
    [Output("R", "mat33", _per_row(3, 3))], _rows,
)
se3_to_matrix = warp_op(
    "se3_to_matrix", lie_kernels.se3_to_matrix, ["omega", "t"], [], [Output("T", "mat34", _per_row(3, 4))], _rows
)
sim3_to_matrix = warp_op(
    "sim3_to_matrix", lie_kernels.sim3_to_matrix, ["omega", "t", "sigma"], [],
    [Output("T", "mat34", _per_row(3, 4))], _rows,
)
se3_exp = warp_op(
    "se3_exp", lie_kernels.se3_exp, ["omega", "u"], [], [Output("T", "mat34", _per_row(3, 4))], _rows
)
se3_log = warp_op(
    "se3_log", lie_kernels.se3_log, ["T"], [],
    [Output("omega", "vec3", _per_row(3)), Output("u", "vec3", _per_row(3))], _rows,
)

# depth (B*H*W,), K (B, 3, 3) -> points (B*H*W, 3)
depth_to_points = warp_op(
    "depth_to_points", camera_kernels.depth_to_points, ["depth", "K"], [Param("H", "int"), Param("W", "int")],
    [Output("points", "vec3", _per_row(3))], _rows,
)
# T (B, 3, 4), points (B*P, 3) -> (B*P, 3)
transform_points = warp_op(
    "transform_points", camera_kernels.transform_points, ["T", "points"], [Param("P", "int")],
    [Output("out", "vec3", lambda T, p, P: (p.shape[0], 3))], lambda T, p, P: p.shape[0],
)
# points (B*P, 3), K (B, 3, 3) -> pixels (B*P, 2)
project_points = warp_op(
    "project_points", camera_kernels.project_points, ["points", "K"],
    [Param("P", "int"), Param("min_depth", "float")],
    [Output("pixels", "vec2", _per_row(2))], _rows,
)
# image (B, C, H, W), grid (B*h*w, 2) -> (B, C, h*w)
bilinear_sample = warp_op(
    "bilinear_sample", sampling_kernels.bilinear_sample, ["image", "grid"],
    [Param("C", "int"), Param("H", "int"), Param("W", "int"), Param("hw", "int"),
     Param("align_corners", "int"), Param("padding", "int")],
    [Output("out", "scalar", lambda img, g, C, H, W, hw, a, p: (img.shape[0], C, hw))],
    lambda img, g, *_: g.shape[0],
)
# image (B, C, H, W), depth (B, 1, H, W), pose (B, 3, 4), K (B, 3, 3) -> (B, C, H, W), (B, 1, H, W) bool
warp_frame_depth = warp_op(
    "warp_frame_depth", sampling_kernels.warp_frame_depth, ["image", "depth", "pose", "K"],
    [Param("C", "int"), Param("H", "int"), Param("W", "int"), Param("min_depth", "float"),
     Param("padding", "int")],
    [
        Output("out", "scalar", lambda img, *_: tuple(img.shape)),
        Output("valid", "bool", lambda img, d, *_: tuple(d.shape), differentiable=False),
    ],
    lambda img, d, *_: d.shape[0] * d.shape[2],  # one thread per image row: B * H
)


def _lanes_kernel(C, H, W, hw, align_corners, padding):
    if not sampling_kernels.fits_lanes(hw, H, W):
        raise ValueError(f"bilinear_sample_lanes: needs hw % 8 == 0 and H*W <= 2^24, got hw={hw}, H*W={H * W}")
    return sampling_kernels.bilinear_sample_lanes(C, align_corners, padding)


# the same values, 8 output locations per thread (h*w % 8 == 0, H*W <= 2^24; SIMD arithmetic),
# a kernel compiled per (C, align_corners, padding); forward only: the backward is bilinear_sample's
bilinear_sample_lanes = warp_op(
    "bilinear_sample_lanes", None, ["image", "grid"],
    [Param("C", "int"), Param("H", "int"), Param("W", "int"), Param("hw", "int"),
     Param("align_corners", "int"), Param("padding", "int")],
    [Output("out", "vec8", lambda img, g, C, H, W, hw, a, p: (img.shape[0], C, hw))],
    lambda img, g, *_: g.shape[0] // sampling_kernels.sampler.LANES,
    backward_from=bilinear_sample,
    select=_lanes_kernel,
    array_kinds=sampling_kernels.LANES_ARRAY_KINDS,
)

# op -> (its public function in gvnn_warp, its nn.Module layer in gvnn_warp or why there is none);
# tests/test_ops_registry.py checks every registered op is here, exported and documented
PUBLIC = {
    "so3_exp": ("so3_exp", "SO3"),
    "so3_log": ("so3_log", "no layer: the inverse map, applied to outputs rather than learnt through"),
    "quaternion_to_matrix": ("quaternion_to_matrix", "no layer: a parametrisation used inside user modules"),
    "euler_to_matrix": ("euler_to_matrix", "no layer: a parametrisation used inside user modules"),
    "se3_to_matrix": ("se3_to_matrix", "SE3"),
    "sim3_to_matrix": ("sim3_to_matrix", "Sim3"),
    "se3_exp": ("se3_exp", "no layer: SE3 covers the exponential map as gvnn's layer does"),
    "se3_log": ("se3_log", "no layer: the inverse map, applied to outputs rather than learnt through"),
    "depth_to_points": ("depth_to_points", "GridGenerator3D"),
    "transform_points": ("transform_points", "GridGenerator3D"),
    "project_points": ("project_points", "PinholeProjection"),
    "project_points_camera": ("project_points", "no layer: a camera object's project (gvnn_warp.cameras)"),
    "depth_to_points_camera": ("depth_to_points", "no layer: depth_to_points given a camera object"),
    "unproject_points": ("unproject_points", "no layer: a camera object's unproject (gvnn_warp.cameras)"),
    "distort_points": ("distort_points", "no layer: a fixed resampling map, used once"),
    "undistort_points": ("undistort_points", "no layer: a fixed resampling map, used once"),
    "bilinear_sample": ("bilinear_sample", "BilinearSampler"),
    "bilinear_sample_lanes": ("bilinear_sample", "BilinearSampler"),  # its 8-lane forward fast path
    "warp_frame_depth": ("warp_frame_depth", "SpatialTransformer3D"),
    "warp_frame_depth_lens": ("warp_frame_depth", "SpatialTransformer3D"),  # with a distorted camera
    "pixel_rays": ("warp_frame_depth", "SpatialTransformer3D"),  # its rays through a distorted camera
}
