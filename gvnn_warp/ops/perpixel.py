"""Registration of the per-pixel and M-estimator Warp kernels as ``gvnn_warp::*`` custom ops.

Same style as :mod:`.geometry`: the ops take already-validated, contiguous tensors; the documented
entry points are in :mod:`gvnn_warp.functional.perpixel`. Each registration names the public
function and layer it serves.
"""

from __future__ import annotations

from ..kernels.perpixel import kernels as k
from .bridge import warp_op
from .registry import Output, Param


def _pixels(t, *_):
    """Launch size of image-sized kernels: B * H * W from a (B, K, H, W) first argument."""
    return t.shape[0] * t.shape[2] * t.shape[3]


def _numel(t, *_):
    return t.numel()


_SAMPLE_PARAMS = [Param("C", "int"), Param("H", "int"), Param("W", "int"), Param("padding", "int")]
_FIELD_PARAMS = [Param("H", "int"), Param("W", "int")]


def _field(channels):
    """Output (B, channels, H, W) of a kernel whose first argument is a (B, K, H, W) field."""
    return lambda p, *_: (p.shape[0], channels, p.shape[2], p.shape[3])


# image (B, C, H, W), flow (B, 2, H, W) -> (B, C, H, W)
flow_warp = warp_op(
    "flow_warp",
    k.flow_warp,
    ["image", "flow"],
    _SAMPLE_PARAMS,
    [Output("out", "scalar", lambda img, *_: tuple(img.shape))],
    _pixels,
    function="flow_warp",
    layer="FlowWarp",
)
# image (B, C, H, W), disparity (B, 1, H, W) -> (B, C, H, W)
disparity_warp = warp_op(
    "disparity_warp",
    k.disparity_warp,
    ["image", "disparity"],
    _SAMPLE_PARAMS,
    [Output("out", "scalar", lambda img, *_: tuple(img.shape))],
    _pixels,
    function="disparity_warp",
    layer="DisparityWarp",
)
# image (B, C, H, W), params (B, 6, H, W) -> (B, C, H, W)
affine_flow_warp = warp_op(
    "affine_flow_warp",
    k.affine_flow_warp,
    ["image", "params"],
    _SAMPLE_PARAMS,
    [Output("out", "scalar", lambda img, *_: tuple(img.shape))],
    _pixels,
    function="affine_flow_warp",
    layer="AffineFlowWarp",
)
# params (B, 6 | 3 | 9, H, W) -> flow (B, 2, H, W)
affine_flow = warp_op(
    "affine_flow", k.affine_flow, ["params"], _FIELD_PARAMS, [Output("flow", "scalar", _field(2))], _pixels,
    function="affine_flow", layer="AffineFlow",
)
se2_flow = warp_op(
    "se2_flow", k.se2_flow, ["params"], _FIELD_PARAMS, [Output("flow", "scalar", _field(2))], _pixels,
    function="se2_flow", layer="SE2Flow",
)
homography_flow = warp_op(
    "homography_flow",
    k.homography_flow,
    ["params"],
    _FIELD_PARAMS,
    [Output("flow", "scalar", _field(2))],
    _pixels,
    function="homography_flow",
    layer="HomographyFlow",
)
# params (B, 3, H, W) -> disparity (B, 1, H, W)
plane_disparity = warp_op(
    "plane_disparity",
    k.plane_disparity,
    ["params"],
    _FIELD_PARAMS,
    [Output("disparity", "scalar", _field(1))],
    _pixels,
    function="slanted_plane_disparity",
    layer="SlantedPlaneDisparity",
)


def _points_op(name, fk, layer):
    # points (B, H, W, 3), params (B, K, H, W) -> (B, H, W, 3)
    return warp_op(
        name,
        fk,
        ["points", "params"],
        [Param("hw", "int")],
        [Output("out", "vec3", lambda pts, *_: tuple(pts.shape))],
        lambda pts, *_: pts.numel() // 3,
        function=name,
        layer=layer,
    )


pointwise_se3 = _points_op("pointwise_se3", k.pointwise_se3, "PointwiseSE3")
pointwise_sim3 = _points_op("pointwise_sim3", k.pointwise_sim3, "PointwiseSim3")
pointwise_transform10 = _points_op("pointwise_transform10", k.pointwise_transform10, "PointwiseTransform10")

# theta (B, 2, 3) -> grid (B, H, W, 2)
affine_grid = warp_op(
    "affine_grid",
    k.affine_grid,
    ["theta"],
    [Param("H", "int"), Param("W", "int"), Param("align_corners", "int")],
    [Output("grid", "vec2", lambda th, H, W, a: (th.shape[0], H, W, 2))],
    lambda th, H, W, a: th.shape[0] * H * W,
    function="affine_grid",
    layer="AffineGridGenerator",
)

# x (n,) -> (n,)
_ROBUST_PARAMS = [Param("kind", "int"), Param("scale", "float")]
robust_rho = warp_op(
    "robust_rho",
    k.robust_rho,
    ["x"],
    _ROBUST_PARAMS,
    [Output("out", "scalar", lambda x, *_: tuple(x.shape))],
    _numel,
    function="robust_rho",
    layer="RobustLoss",
)
robust_psi = warp_op(
    "robust_psi",
    k.robust_psi,
    ["x"],
    _ROBUST_PARAMS,
    [Output("out", "scalar", lambda x, *_: tuple(x.shape))],
    _numel,
    function="robust_psi",
    layer="no layer: the M-estimator's derivative (IRLS weights); RobustLoss covers rho",
)
# field (B, K, H, W) -> per-element weighted penalties (B, K, H, W); their sum is the loss
smoothness = warp_op(
    "smoothness",
    k.smoothness,
    ["field"],
    [
        Param("H", "int"),
        Param("W", "int"),
        *_ROBUST_PARAMS,
        Param("weight_x", "float"),
        Param("weight_y", "float"),
    ],
    [Output("out", "scalar", lambda f, *_: tuple(f.shape))],
    _numel,
    function="smoothness_loss",
    layer="SmoothnessLoss",
)
