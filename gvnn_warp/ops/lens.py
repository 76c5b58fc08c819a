"""Registration of the torch custom ops that go through lens models (radial-tangential, fisheye):
the camera objects' projections (:mod:`gvnn_warp.cameras`), and the 3D spatial transformer and the
photometric error (:mod:`._photometric_ops`, whose :data:`PUBLIC` lists it) through a distorted
camera. Like :mod:`._ops`, whose conventions and helpers they share, but imported on first
use of a camera model: defining the lens models' custom adjoints makes Warp build their functions
(~1.5-3 s), which a user of pinhole layers should not wait for. So ``torch.ops.gvnn_warp.<op>`` of
these ops exists only once this module is imported: a program that loads a saved graph holding
them (``torch.export.load``) imports ``gvnn_warp._lens_ops`` first.
"""

from __future__ import annotations

from ..kernels.geometry import lens_kernels
from ..kernels.photometric import lens_kernels as plk
from ..kernels.sampling import lens_kernels as sampling_lens_kernels
from .bridge import Output, Param, warp_op
from .geometry import _per_row, _rows

# camera models (gvnn_warp.cameras): K (B, 3, 3), dist (B, 8) as kernels.lens lays it out, model id
_valid = Output("valid", "bool", lambda t, *_: (t.shape[0],), differentiable=False)
# points (B*P, 3) -> pixels (B*P, 2), valid (B*P,)
project_points_camera = warp_op(
    "project_points_camera", lens_kernels.project_points, ["points", "K", "dist"],
    [Param("P", "int"), Param("min_depth", "float"), Param("model", "int")],
    [Output("pixels", "vec2", _per_row(2)), _valid], _rows,
)
# depth (B*H*W,) -> points (B*H*W, 3), valid (B*H*W,)
depth_to_points_camera = warp_op(
    "depth_to_points_camera", lens_kernels.depth_to_points, ["depth", "K", "dist"],
    [Param("H", "int"), Param("W", "int"), Param("model", "int")],
    [Output("points", "vec3", _per_row(3)), _valid], _rows,
)
# pixels (B*P, 2), depth (B*P,) -> points (B*P, 3), valid (B*P,)
unproject_points = warp_op(
    "unproject_points", lens_kernels.unproject_points, ["pixels", "depth", "K", "dist"],
    [Param("P", "int"), Param("model", "int")],
    [Output("points", "vec3", _per_row(3)), _valid], _rows,
)
# pixels (B*P, 2) -> pixels (B*P, 2), valid (B*P,): ideal -> distorted image, and back
distort_points = warp_op(
    "distort_points", lens_kernels.distort_pixels, ["pixels", "K", "dist"],
    [Param("P", "int"), Param("model", "int")],
    [Output("out", "vec2", _per_row(2)), _valid], _rows,
)
undistort_points = warp_op(
    "undistort_points", lens_kernels.undistort_pixels, ["pixels", "K", "dist"],
    [Param("P", "int"), Param("model", "int")],
    [Output("out", "vec2", _per_row(2)), _valid], _rows,
)
# K (Bc, 3, 3), dist (Bc, 8) -> rays (Bc*H*W, 3): the undistorted ray (xn, yn, w) of every pixel
pixel_rays = warp_op(
    "pixel_rays", sampling_lens_kernels.pixel_rays, ["K", "dist"],
    [Param("H", "int"), Param("W", "int"), Param("model", "int")],
    [Output("rays", "vec3", lambda K, d, H, W, m: (K.shape[0] * H * W, 3))],
    lambda K, d, H, W, m: K.shape[0] * H * W,
)
# warp_frame_depth through a lens model: + dist (B, 8), rays (Bc*H*W, 3) (Bc = B, or 1 with ray_stride 0)
warp_frame_depth_lens = warp_op(
    "warp_frame_depth_lens", sampling_lens_kernels.warp_frame_depth_lens,
    ["image", "depth", "pose", "K", "dist", "rays"],
    [Param("C", "int"), Param("H", "int"), Param("W", "int"), Param("min_depth", "float"),
     Param("padding", "int"), Param("model", "int"), Param("ray_stride", "int")],
    [
        Output("out", "scalar", lambda img, *_: tuple(img.shape)),
        Output("valid", "bool", lambda img, d, *_: tuple(d.shape), differentiable=False),
    ],
    lambda img, d, *_: d.shape[0] * d.shape[2],  # one thread per image row: B * H
)
# photometric_rows through a distorted lens: + dist (B, 8), rays (Bc*H*W, 3) (ray_stride H*W, or 0: shared)
photometric_rows_lens = warp_op(
    "photometric_rows_lens",
    plk.photometric_rows_lens,
    ["ref_image", "ref_depth", "live_image", "pose", "K", "dist", "rays"],
    [Param("C", "int"), Param("H", "int"), Param("W", "int"), Param("kind", "int"), Param("scale", "float"),
     Param("min_depth", "float"), Param("model", "int"), Param("ray_stride", "int")],
    [
        Output("row_sum", "scalar", lambda img, d, *_: (d.shape[0] * d.shape[2],)),
        Output("row_count", "scalar", lambda img, d, *_: (d.shape[0] * d.shape[2],), differentiable=False),
    ],
    lambda img, d, *_: d.shape[0] * d.shape[2],
)
