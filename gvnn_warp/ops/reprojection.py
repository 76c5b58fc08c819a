"""The ops of the self-supervised reprojection objective and the edge-aware smoothness (kernels:
:mod:`gvnn_warp.kernels.reprojection.kernels`, definitions in its package docstring), registered as
``gvnn_warp::*`` custom ops (see :mod:`.bridge`). They take validated, flattened, contiguous
tensors; the public entry points are :func:`gvnn_warp.reprojection_loss` and
:func:`gvnn_warp.edge_aware_smoothness`.
"""

from __future__ import annotations

from ..kernels.reprojection import kernels as rk
from .bridge import warp_op
from .registry import Output, Param

_SHAPE = [Param("S", "int"), Param("C", "int"), Param("H", "int"), Param("W", "int"), Param("alpha", "float")]


def _pixels(target, *_):
    return target.shape[0] * target.shape[2] * target.shape[3]


def _pixel_map(target, *_):
    return (target.shape[0], target.shape[2], target.shape[3])


# target (B, C, H, W), warped (B, S, C, H, W), sources (B, S, C, H, W), front (B, S, H, W) or
# empty, depth (B, H, W), pose (B*S, 3, 4), K (B*S, 3, 3) -> choice (B, H, W) int32: the chosen
# candidate of every pixel, best (B, H, W) its error (0 where excluded), and a scratch (B, H, W)
# (forward only; one thread per target row)
reprojection_choice = warp_op(
    "reprojection_choice", rk.reprojection_choice, ["target", "warped", "sources", "front", "depth", "pose", "K"],
    [*_SHAPE, Param("automask", "int"), Param("min_depth", "float"), Param("use_front", "int")],
    [Output("choice", "int32", _pixel_map, differentiable=False),
     Output("best", "scalar", _pixel_map, differentiable=False),
     Output("scratch", "scalar", _pixel_map, differentiable=False)],
    lambda target, *_: target.shape[0] * target.shape[2],
    function="reprojection_loss", layer="ReprojectionLoss",  # the choice of each pixel's candidate
    untested={"gradients": "its output is an index (not differentiable)"},
)

# target, warped, sources, choice, best -> pe (B, H, W) of the chosen candidates, weight (B, H, W) 1 / 0
_ERROR = (["target", "warped", "sources", "choice", "best"], _SHAPE,
          [Output("pe", "scalar", _pixel_map), Output("weight", "scalar", _pixel_map, differentiable=False)], _pixels)
reprojection_error = warp_op(
    "reprojection_error", rk.reprojection_error, *_ERROR, function="reprojection_loss", layer="ReprojectionLoss",
)
# the same, its forward copying the choice kernel's values (``best``): what reprojection_loss calls
reprojection_error_copy = warp_op(
    "reprojection_error_copy", None, *_ERROR, backward_from=reprojection_error,
    select=lambda *_: rk.reprojection_error_copy, array_kinds=rk.reprojection_error.array_kinds,
    function="reprojection_loss", layer="ReprojectionLoss",
)

# value (B, n), weight (B, n) -> mean (B,) over the weighted entries, count (B,)
per_item_mean = warp_op(
    "per_item_mean", rk.per_item_mean, ["value", "weight"], [Param("n", "int")],
    [Output("mean", "scalar", lambda v, *_: (v.shape[0],)),
     Output("count", "scalar", lambda v, *_: (v.shape[0],), differentiable=False)],
    lambda v, *_: v.shape[0],
    function="reprojection_loss", layer="ReprojectionLoss",  # its mean over the valid pixels
)

# disparity (B, 1, H, W) -> mean (B,)
disparity_mean = warp_op(
    "disparity_mean", rk.disparity_mean, ["disparity"], [Param("n", "int")],
    [Output("mean", "scalar", lambda d, *_: (d.shape[0],))], lambda d, *_: d.shape[0],
    function="edge_aware_smoothness", layer="EdgeAwareSmoothness",
)

# disparity (B, 1, H, W), image (B, C, H, W), mean (B,) -> row_sum (B, H)
smoothness_rows = warp_op(
    "smoothness_rows", rk.smoothness_rows, ["disparity", "image", "mean"],
    [Param("C", "int"), Param("H", "int"), Param("W", "int")],
    [Output("row_sum", "scalar", lambda d, i, m, C, H, W: (d.shape[0], H))], lambda d, *_: d.shape[0] * d.shape[2],
    function="edge_aware_smoothness", layer="EdgeAwareSmoothness",
)

# row_sum (B, H) -> total (B,)
rows_total = warp_op(
    "rows_total", rk.rows_total, ["row_sum"], [Param("H", "int")],
    [Output("total", "scalar", lambda r, *_: (r.shape[0],))], lambda r, *_: r.shape[0],
    function="edge_aware_smoothness", layer="EdgeAwareSmoothness",
)
