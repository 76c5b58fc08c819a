"""The geometry ops: rotations, rigid motions and similarities (:mod:`gvnn_warp.kernels.geometry.lie`),
the pinhole camera and the camera models through lens distortion, registered as ``gvnn_warp::*``
custom ops (see :mod:`.bridge`).

These ops take already-validated, flattened, contiguous tensors; the public, documented entry
points are in :mod:`gvnn_warp.functional` and :mod:`gvnn_warp.cameras`. Each registration names
the public function and layer it serves.
"""

from __future__ import annotations

import torch

from ..kernels.geometry import kernels as gk
from ..kernels.geometry import lens
from .bridge import warp_op
from .registry import Output, Param, custom_op, lazy_ops, per_row, rows

_PARAMETRISATION = "no layer: a parametrisation used inside user modules"
_INVERSE = "no layer: the inverse map, applied to outputs rather than learnt through"

# ----------------------------------------------------------------------------- rotations, rigid motions

so3_exp = warp_op(
    "so3_exp", gk.so3_exp, ["omega"], [], [Output("R", "mat33", per_row(3, 3))], rows,
    function="so3_exp", layer="SO3",
)
so3_log = warp_op(
    "so3_log", gk.so3_log, ["R"], [], [Output("omega", "vec3", per_row(3))], rows,
    function="so3_log", layer=_INVERSE,
)
quaternion_to_matrix = warp_op(
    "quaternion_to_matrix", gk.quaternion_to_matrix, ["q"], [], [Output("R", "mat33", per_row(3, 3))], rows,
    function="quaternion_to_matrix", layer=_PARAMETRISATION,
)
euler_to_matrix = warp_op(
    "euler_to_matrix", gk.euler_to_matrix, ["angles"],
    [Param("a0", "int"), Param("a1", "int"), Param("a2", "int")], [Output("R", "mat33", per_row(3, 3))], rows,
    function="euler_to_matrix", layer=_PARAMETRISATION,
)
se3_to_matrix = warp_op(
    "se3_to_matrix", gk.se3_to_matrix, ["omega", "t"], [], [Output("T", "mat34", per_row(3, 4))], rows,
    function="se3_to_matrix", layer="SE3",
)
sim3_to_matrix = warp_op(
    "sim3_to_matrix", gk.sim3_to_matrix, ["omega", "t", "sigma"], [],
    [Output("T", "mat34", per_row(3, 4))], rows,
    function="sim3_to_matrix", layer="Sim3",
)
se3_exp = warp_op(
    "se3_exp", gk.se3_exp, ["omega", "u"], [], [Output("T", "mat34", per_row(3, 4))], rows,
    function="se3_exp", layer="no layer: SE3 covers the exponential map as gvnn's layer does",
)
se3_log = warp_op(
    "se3_log", gk.se3_log, ["T"], [],
    [Output("omega", "vec3", per_row(3)), Output("u", "vec3", per_row(3))], rows,
    function="se3_log", layer=_INVERSE,
)

# ----------------------------------------------------------------------------- the pinhole camera

# depth (B*H*W,), K (B, 3, 3) -> points (B*H*W, 3)
depth_to_points = warp_op(
    "depth_to_points", gk.depth_to_points, ["depth", "K"], [Param("H", "int"), Param("W", "int")],
    [Output("points", "vec3", per_row(3))], rows,
    function="depth_to_points", layer="GridGenerator3D",
)
# T (B, 3, 4), points (B*P, 3) -> (B*P, 3)
transform_points = warp_op(
    "transform_points", gk.transform_points, ["T", "points"], [Param("P", "int")],
    [Output("out", "vec3", lambda T, p, P: (p.shape[0], 3))], lambda T, p, P: p.shape[0],
    function="transform_points", layer="GridGenerator3D",
)
# points (B*P, 3), K (B, 3, 3) -> pixels (B*P, 2)
project_points = warp_op(
    "project_points", gk.project_points, ["points", "K"], [Param("P", "int"), Param("min_depth", "float")],
    [Output("pixels", "vec2", per_row(2))], rows,
    function="project_points", layer="PinholeProjection",
)

# ----------------------------------------------------------------------------- through a lens model
#
# K (B, 3, 3), dist (B, 8) as kernels.geometry.lens lays it out, and the model id. Their kernels take
# seconds to define (the lens models' custom adjoints): each registration gives a maker, called on the
# first launch, and the torch ops are defined on first use (lazy=True: the ops are this module's
# attributes through __getattr__ below; gvnn_warp.ops.lens defines them all).

_LENS = {"K": "mat33", "dist": "vec8"}
_valid = Output("valid", "bool", lambda t, *_: (t.shape[0],), differentiable=False)


# points (B*P, 3) -> pixels (B*P, 2), valid (B*P,)
warp_op(
    "project_points_camera", gk.project_points_lens, ["points", "K", "dist"],
    [Param("P", "int"), Param("min_depth", "float"), Param("model", "int")],
    [Output("pixels", "vec2", per_row(2)), _valid], rows, array_kinds={"points": "vec3", **_LENS}, lazy=True,
    function="project_points", layer="no layer: a camera object's project (gvnn_warp.cameras)",
)
# depth (B*H*W,) -> points (B*H*W, 3), valid (B*H*W,)
warp_op(
    "depth_to_points_camera", gk.depth_to_points_lens, ["depth", "K", "dist"],
    [Param("H", "int"), Param("W", "int"), Param("model", "int")],
    [Output("points", "vec3", per_row(3)), _valid], rows, array_kinds={"depth": "scalar", **_LENS}, lazy=True,
    function="depth_to_points", layer="no layer: depth_to_points given a camera object",
)
# pixels (B*P, 2), depth (B*P,) -> points (B*P, 3), valid (B*P,)
warp_op(
    "unproject_points", gk.unproject_points_lens, ["pixels", "depth", "K", "dist"],
    [Param("P", "int"), Param("model", "int")], [Output("points", "vec3", per_row(3)), _valid], rows,
    array_kinds={"pixels": "vec2", "depth": "scalar", **_LENS}, lazy=True,
    function="unproject_points", layer="no layer: a camera object's unproject (gvnn_warp.cameras)",
)
# pixels (B*P, 2) -> pixels (B*P, 2), valid (B*P,): ideal -> distorted image, and back
warp_op(
    "distort_points", gk.distort_pixels_lens, ["pixels", "K", "dist"],
    [Param("P", "int"), Param("model", "int")], [Output("out", "vec2", per_row(2)), _valid], rows,
    array_kinds={"pixels": "vec2", **_LENS}, lazy=True,
    function="distort_points", layer="no layer: a fixed resampling map, used once",
)
warp_op(
    "undistort_points", gk.undistort_pixels_lens, ["pixels", "K", "dist"],
    [Param("P", "int"), Param("model", "int")], [Output("out", "vec2", per_row(2)), _valid], rows,
    array_kinds={"pixels": "vec2", **_LENS}, lazy=True,
    function="undistort_points", layer="no layer: a fixed resampling map, used once",
)


# coeffs (N, n) -> (N, 1): each camera's domain bound on r^2 (lens.domain_limit: a polynomial's first
# positive root, found on the host), an op so that torch.compile(fullgraph=True) traces a lens camera
def _lens_domain_limit(coeffs: torch.Tensor, model: int) -> torch.Tensor:
    rows_ = coeffs.detach().to(torch.float64).cpu().numpy()
    padded = [list(r) + [0.0] * (5 - len(r)) if model == lens.RADTAN else list(r) for r in rows_]
    return torch.tensor([[lens.domain_limit(model, r)] for r in padded], dtype=coeffs.dtype).reshape(-1, 1)


def _lens_domain_limit_fake(coeffs, model):
    return coeffs.new_empty(coeffs.shape[0], 1)


lens_domain_limit = custom_op(
    "lens_domain_limit", _lens_domain_limit, _lens_domain_limit_fake,
    function="RadTanCamera", layer="no layer: a lens camera's domain bound (RadTanCamera, FisheyeCamera; not "
                                   "differentiable)",
)

__getattr__ = lazy_ops(__name__)  # (the ops registered with lazy=True)
