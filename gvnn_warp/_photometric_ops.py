"""Registration of the fused photometric objective's Warp kernels as ``gvnn_warp::*`` custom ops.

Same style as :mod:`._ops`: the ops take already-validated, contiguous tensors; the documented
entry points are in :mod:`gvnn_warp.photometric`.
"""

from __future__ import annotations

import torch

from ._bridge import _FLOAT_TYPES, Output, Param, _descriptor, _skip_lazy_dynamo_import, warp_op
from .kernels import photometric_kernels as pk
from .kernels import photometric_lens_kernels as plk
from .kernels.launch import RecordedLaunch

wp_float64 = _FLOAT_TYPES[torch.float64]

# images (B, C, H, W), depth (B, 1, H, W), pose (B, 3, 4), K (B, 3, 3) -> per-row partial sums:
# row_sum (B*H,) (differentiable), row_count (B*H,)
photometric_rows = warp_op(
    "photometric_rows",
    pk.photometric_rows,
    ["ref_image", "ref_depth", "live_image", "pose", "K"],
    [Param("C", "int"), Param("H", "int"), Param("W", "int"), Param("kind", "int"), Param("scale", "float"),
     Param("min_depth", "float")],
    [
        Output("row_sum", "scalar", lambda img, d, *_: (d.shape[0] * d.shape[2],)),
        Output("row_count", "scalar", lambda img, d, *_: (d.shape[0] * d.shape[2],), differentiable=False),
    ],
    lambda img, d, *_: d.shape[0] * d.shape[2],
)

# row_sum (B*H,), row_count (B*H,) -> error (B,) (differentiable), count (B,)
photometric_mean = warp_op(
    "photometric_mean",
    pk.photometric_mean,
    ["row_sum", "row_count"],
    [Param("H", "int"), Param("C", "int")],
    [
        Output("error", "scalar", lambda s, n, H, C: (s.shape[0] // H,)),
        Output("count", "scalar", lambda s, n, H, C: (s.shape[0] // H,), differentiable=False),
    ],
    lambda s, n, H, C: s.shape[0] // H,
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

# op -> (its public function in gvnn_warp, its layer); tests/test_ops_registry.py checks them
PUBLIC = {
    "photometric_rows": ("photometric_error", "PhotometricLoss"),
    "photometric_rows_lens": ("photometric_error", "PhotometricLoss"),
    "photometric_mean": ("photometric_error", "PhotometricLoss"),
}


def _ne_shapes(ref_image):
    B = ref_image.shape[0]
    return (B, 6, 6), (B, 6), (B,), (B,)


@torch.library.custom_op("gvnn_warp::photometric_normal_equations", mutates_args=())
def photometric_normal_equations(
    ref_image: torch.Tensor,
    ref_depth: torch.Tensor,
    live_image: torch.Tensor,
    live_depth: torch.Tensor,
    pose: torch.Tensor,
    K: torch.Tensor,
    kind: int,
    scale: float,
    min_depth: float,
    depth_weight: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """images (B, C, H, W), depths (B, 1, H, W) (live_depth: empty for none), pose (B, 3, 4),
    K (B, 3, 3) -> JtWJ (B, 6, 6), JtWr (B, 6), cost (B,), count (B,). Not differentiable."""
    B, C, H, W = ref_image.shape
    ft = _FLOAT_TYPES[ref_image.dtype]
    outs = [torch.empty(s, dtype=ref_image.dtype) for s in _ne_shapes(ref_image)]
    if B == 0:
        return tuple(outs)
    rows = torch.empty(B * H * pk.ROW_STRIDE, dtype=torch.float64)
    depth_term = live_depth.numel() > 0 and depth_weight > 0
    arrays = [
        _descriptor(t, "scalar", ft) for t in (ref_image, ref_depth, live_image, live_depth)
    ] + [_descriptor(pose, "mat34", ft), _descriptor(K, "mat33", ft)]
    rows_d = _descriptor(rows, "scalar", wp_float64)
    acc = torch.empty(B * H * pk.ROW_STRIDE * 8, dtype=ref_image.dtype)  # the row kernel's 8-lane running sums
    # the pure-Warp host function's launcher (one launch per thread, on Python threads: see there)
    if H * W > 0:
        RecordedLaunch(
            pk.normal_equations_lanes_for(int(depth_term), C, kind)[ft], B * H,
            [*arrays, C, H, W, kind, scale, min_depth, depth_weight, 0.0, rows_d,
             _descriptor(acc, "vec8", ft)], work=W, grain=pk._GRAIN_PIXELS,
        )()
    else:
        rows.zero_()
    out_d = [_descriptor(o, "scalar", ft) for o in outs]
    RecordedLaunch(pk.normal_equations_reduce[ft], B * pk.N_SUMS, [rows_d, H, *out_d], grain=pk._GRAIN_PIXELS)()
    return tuple(outs)


@photometric_normal_equations.register_fake
def _(ref_image, ref_depth, live_image, live_depth, pose, K, kind, scale, min_depth, depth_weight):
    return tuple(torch.empty(s, dtype=ref_image.dtype) for s in _ne_shapes(ref_image))


_skip_lazy_dynamo_import(photometric_normal_equations)


@torch.library.custom_op("gvnn_warp::photometric_normal_equations_lens", mutates_args=())
def photometric_normal_equations_lens(
    ref_image: torch.Tensor,
    ref_depth: torch.Tensor,
    live_image: torch.Tensor,
    live_depth: torch.Tensor,
    pose: torch.Tensor,
    K: torch.Tensor,
    dist: torch.Tensor,
    rays: torch.Tensor,
    kind: int,
    scale: float,
    min_depth: float,
    depth_weight: float,
    model: int,
    ray_stride: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """photometric_normal_equations through a distorted lens: + dist (B, 8), rays (Bc*H*W, 3) of
    ``pixel_rays`` (ray_stride H*W, or 0 when shared by the batch). Not differentiable."""
    B, C, H, W = ref_image.shape
    ft = _FLOAT_TYPES[ref_image.dtype]
    outs = [torch.empty(s, dtype=ref_image.dtype) for s in _ne_shapes(ref_image)]
    if B == 0:
        return tuple(outs)
    rows = torch.empty(B * H * pk.ROW_STRIDE, dtype=torch.float64)
    depth_term = live_depth.numel() > 0 and depth_weight > 0
    arrays = [_descriptor(t, "scalar", ft) for t in (ref_image, ref_depth, live_image, live_depth)] + [
        _descriptor(pose, "mat34", ft), _descriptor(K, "mat33", ft), _descriptor(dist, "vec8", ft),
        _descriptor(rays, "vec3", ft),
    ]
    rows_d = _descriptor(rows, "scalar", wp_float64)
    if H * W > 0:
        RecordedLaunch(
            plk.normal_equations_rows_lens[int(depth_term)][ft], B * H,
            [*arrays, C, H, W, kind, scale, min_depth, depth_weight, 0.0, model, ray_stride, rows_d], work=W,
            grain=pk._GRAIN_PIXELS,
        )()
    else:
        rows.zero_()
    out_d = [_descriptor(o, "scalar", ft) for o in outs]
    RecordedLaunch(pk.normal_equations_reduce[ft], B * pk.N_SUMS, [rows_d, H, *out_d], grain=pk._GRAIN_PIXELS)()
    return tuple(outs)


@photometric_normal_equations_lens.register_fake
def _(ref_image, ref_depth, live_image, live_depth, pose, K, dist, rays, kind, scale, min_depth, depth_weight, model,
      ray_stride):
    return tuple(torch.empty(s, dtype=ref_image.dtype) for s in _ne_shapes(ref_image))


_skip_lazy_dynamo_import(photometric_normal_equations_lens)
