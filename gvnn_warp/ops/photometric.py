"""The fused photometric objective's ops, registered as ``gvnn_warp::*`` custom ops (see
:mod:`.bridge`): the row kernels and their mean (pinhole and through a lens model), and the
hand-written ops of the fast path (:func:`photometric_error`, with the gradients computed in its
forward pass) and of the Gauss-Newton normal equations (recorded launches, replayed per call).

The ops take already-validated, contiguous tensors; the documented entry points are in
:mod:`gvnn_warp.functional.photometric`. Each registration names the public function and layer
it serves.
"""

from __future__ import annotations

import threading

import torch

from ..kernels.core.launch import RecordedLaunch, get_num_threads, launch
from ..kernels.photometric import error, error_reduce, error_rows, normal_equations, normal_equations_lanes
from ..kernels.photometric import normal_equations_reduce as ne_reduce
from ..kernels.photometric.residual import GRAIN_PIXELS
from ..kernels.sampling.lanes import MAX_LANES_PLANE
from .bridge import WARP_FLOAT, descriptor, null_array, warp_op
from .registry import Output, Param, custom_op, define_op, lazy_ops

wp_float64 = WARP_FLOAT[torch.float64]
_LOSS = {"function": "photometric_error", "layer": "PhotometricLoss"}
_NOT_DIFFERENTIABLE = "no layer: not differentiable (a Gauss-Newton system for a pose update)"

# images (B, C, H, W), depth (B, 1, H, W), pose (B, 3, 4), K (B, 3, 3) -> per-row partial sums:
# row_sum (B*H,) (differentiable), row_count (B*H,)
photometric_rows = warp_op(
    "photometric_rows",
    error_rows.photometric_rows,
    ["ref_image", "ref_depth", "live_image", "pose", "K"],
    [Param("C", "int"), Param("H", "int"), Param("W", "int"), Param("kind", "int"), Param("scale", "float"),
     Param("min_depth", "float")],
    [
        Output("row_sum", "scalar", lambda img, d, *_: (d.shape[0] * d.shape[2],)),
        Output("row_count", "scalar", lambda img, d, *_: (d.shape[0] * d.shape[2],), differentiable=False),
    ],
    lambda img, d, *_: d.shape[0] * d.shape[2],
    **_LOSS,
)


# photometric_rows through a distorted lens: + dist (B, 8), rays (Bc*H*W, 3) (ray_stride H*W, or 0: shared);
# its kernel made on the first launch, its torch op defined on first use (see gvnn_warp.ops.lens)
warp_op(
    "photometric_rows_lens",
    error_rows.photometric_rows_lens,
    ["ref_image", "ref_depth", "live_image", "pose", "K", "dist", "rays"],
    [Param("C", "int"), Param("H", "int"), Param("W", "int"), Param("kind", "int"), Param("scale", "float"),
     Param("min_depth", "float"), Param("model", "int"), Param("ray_stride", "int")],
    [
        Output("row_sum", "scalar", lambda img, d, *_: (d.shape[0] * d.shape[2],)),
        Output("row_count", "scalar", lambda img, d, *_: (d.shape[0] * d.shape[2],), differentiable=False),
    ],
    lambda img, d, *_: d.shape[0] * d.shape[2],
    array_kinds={"ref_image": "scalar", "ref_depth": "scalar", "live_image": "scalar", "pose": "mat34", "K": "mat33",
                 "dist": "vec8", "rays": "vec3"},
    lazy=True, **_LOSS,
)

# row_sum (B*H,), row_count (B*H,) -> error (B,) (differentiable), count (B,)
photometric_mean = warp_op(
    "photometric_mean",
    error_rows.photometric_mean,
    ["row_sum", "row_count"],
    [Param("H", "int"), Param("C", "int")],
    [
        Output("error", "scalar", lambda s, n, H, C: (s.shape[0] // H,)),
        Output("count", "scalar", lambda s, n, H, C: (s.shape[0] // H,), differentiable=False),
    ],
    lambda s, n, H, C: s.shape[0] // H,
    **_LOSS,
)


def _ne_shapes(ref_image):
    B = ref_image.shape[0]
    return (B, 6, 6), (B, 6), (B,), (B,)


class _Recorded(threading.local):
    """Per thread, the normal equations' recorded launches (the row kernel, the reduction) and
    their scratch buffers, by what they depend on other than data addresses: the kernel, the
    shapes, the scalar arguments and the thread count. A call with new tensors of the same shapes
    only points the launches at them (``RecordedLaunch.set_arg`` with array descriptors), which
    spares it the ~0.2 ms of recording two launches (a Gauss-Newton loop calls with new tensors
    each time). At most :data:`SIZE` entries (least recently used dropped), e.g. the levels of a
    pyramid, of at most :data:`MAX_BYTES` of scratch each (larger calls take milliseconds: they
    record their launches each time). Per thread, so threads never share a scratch buffer; a
    thread's entries (up to 32 MiB of scratch, and the copy of the last non-contiguous input
    of each) live as long as the thread, and ``_RECORDED.entries.clear()`` drops the calling
    thread's."""

    SIZE = 8
    MAX_BYTES = 4 << 20

    def __init__(self):
        self.entries: dict[tuple, tuple] = {}


_RECORDED = _Recorded()


def _run_normal_equations(rows_kernel, ref_image, arrays: list, scalars: list, outs: list, acc: bool) -> None:
    """Run ``rows_kernel`` (its array inputs ``arrays`` (tensors and element kinds), then
    ``scalars``, then the float64 row sums (B*H*ROW_STRIDE,) and, with ``acc``, 8-lane scratch of
    the same length) and the reduction into ``outs`` (JtWJ, JtWr, cost, count)."""
    B, C, H, W = ref_image.shape
    ft = WARP_FLOAT[ref_image.dtype]
    # (the kernel is the float type's overload; C, H and W are among the scalars)
    key = (rows_kernel, B, *(t.numel() for t, _ in arrays), *scalars, get_num_threads())
    # the inputs' addresses (None: not contiguous, a copy each call)
    pointers = [t.data_ptr() if t.is_contiguous() else None for t, _ in arrays]
    out_d = [descriptor(o, "scalar", ft) for o in outs]
    entries = _RECORDED.entries
    entry = entries.pop(key, None)
    if entry is None:
        rows = torch.empty(B * H * ne_reduce.ROW_STRIDE, dtype=torch.float64)
        scratch = [rows]
        rows_d = descriptor(rows, "scalar", wp_float64)
        extra = [rows_d]
        if acc:  # the row kernel's 8-lane running sums
            scratch.append(torch.empty(B * H * ne_reduce.ROW_STRIDE * 8, dtype=ref_image.dtype))
            extra.append(descriptor(scratch[-1], "vec8", ft))
        # the pure-Warp host function's launcher (one launch per thread, on Python threads: see there)
        inputs = [descriptor(t, kind, ft) for t, kind in arrays]
        entry = (scratch, RecordedLaunch(rows_kernel, B * H, [*inputs, *scalars, *extra], work=W,
                                         grain=GRAIN_PIXELS),
                 RecordedLaunch(ne_reduce.normal_equations_reduce[ft], B * ne_reduce.N_SUMS, [rows_d, H, *out_d],
                                grain=GRAIN_PIXELS),
                 pointers)
        keep = sum(t.numel() * t.element_size() for t in scratch) <= _Recorded.MAX_BYTES
    else:
        keep = True  # (only entries within MAX_BYTES are kept)
        _, rows_launch, reduce_launch, last = entry
        for i, (t, kind) in enumerate(arrays):  # (in a Gauss-Newton loop, only the pose changes)
            if pointers[i] is None or pointers[i] != last[i]:
                rows_launch.set_arg(i, descriptor(t, kind, ft))
                last[i] = pointers[i]
        for i, d in enumerate(out_d):
            reduce_launch.set_arg(2 + i, d)
    entry[1]()
    entry[2]()
    # back into the cache once run (a call of the same key in between, on this thread, cannot
    # re-point it), the most recently used last
    if keep and _Recorded.SIZE > 0:
        while len(entries) >= _Recorded.SIZE:
            del entries[next(iter(entries))]
        entries[key] = entry


def _normal_equations(
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
    outs = [torch.empty(s, dtype=ref_image.dtype) for s in _ne_shapes(ref_image)]
    if B * H * W == 0:  # nothing to sum
        for o in outs:
            o.zero_()
        return tuple(outs)
    depth_term = live_depth.numel() > 0 and depth_weight > 0
    arrays = [(t, "scalar") for t in (ref_image, ref_depth, live_image, live_depth)] + [(pose, "mat34"), (K, "mat33")]
    lanes = H * W <= MAX_LANES_PLANE  # (else the lanes' float tap addresses are not exact: pixel by pixel)
    rows_kernel = (normal_equations_lanes.normal_equations_lanes(depth_term, False, C, kind, W) if lanes else
                   normal_equations.normal_equations_rows(depth_term, False))
    _run_normal_equations(rows_kernel[WARP_FLOAT[ref_image.dtype]], ref_image, arrays,
                          [C, H, W, kind, scale, min_depth, depth_weight, 0.0], outs, acc=lanes)
    return tuple(outs)


def _normal_equations_fake(ref_image, *_):
    return tuple(torch.empty(s, dtype=ref_image.dtype) for s in _ne_shapes(ref_image))


_RECORDED_SPLIT = ("launches through RecordedLaunch, which replays its own recorded split "
                   "(tests/functional/test_photometric.py checks its results for any thread count)")
photometric_normal_equations = custom_op(
    "photometric_normal_equations", _normal_equations, _normal_equations_fake,
    function="photometric_normal_equations", layer=_NOT_DIFFERENTIABLE, untested={"scopes": _RECORDED_SPLIT},
)


def _normal_equations_lens(
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
    outs = [torch.empty(s, dtype=ref_image.dtype) for s in _ne_shapes(ref_image)]
    if B * H * W == 0:  # nothing to sum
        for o in outs:
            o.zero_()
        return tuple(outs)
    depth_term = live_depth.numel() > 0 and depth_weight > 0
    arrays = [(t, "scalar") for t in (ref_image, ref_depth, live_image, live_depth)] + [
        (pose, "mat34"), (K, "mat33"), (dist, "vec8"), (rays, "vec3")]
    rows_kernel = normal_equations.normal_equations_rows_lens(depth_term, False)
    _run_normal_equations(rows_kernel[WARP_FLOAT[ref_image.dtype]], ref_image, arrays,
                          [C, H, W, kind, scale, min_depth, depth_weight, 0.0, model, ray_stride], outs, acc=False)
    return tuple(outs)


# its kernel made on the first call, its torch op defined on first use (see gvnn_warp.ops.lens)
custom_op(
    "photometric_normal_equations_lens", _normal_equations_lens, _normal_equations_fake, lazy=True,
    function="photometric_normal_equations", layer=_NOT_DIFFERENTIABLE, untested={"scopes": _RECORDED_SPLIT},
)


# ----------------------------------------------------------------------------- photometric_error, fast path
#
# One forward op computes the error, the count and, for the inputs autograd will want (``needs``,
# bit k for input k of (ref_image, ref_depth, live_image, pose, K)), the gradients of the
# per-batch sums S_b = C n_b error_b, all in one pass (kernels/photometric/error.py); the
# backward op only scales them by grad_error_b / (C n_b). The live image's gradient (a scatter) is
# the Warp adjoint of photometric_rows, run by the backward op when asked for. photometric_rows
# and photometric_mean above stay as the reference the tests compare this path with.

_NEED_REF, _NEED_DEPTH, _NEED_LIVE, _NEED_POSE, _NEED_K = (1 << k for k in range(5))
_NEED_FUSED = _NEED_REF | _NEED_DEPTH | _NEED_POSE | _NEED_K  # the gradients the forward pass computes


def _error_shapes(ref_image, needs):
    B, C, H, W = ref_image.shape
    return [
        (B,), (B,),
        (B, C, H, W) if needs & _NEED_REF else (0,),
        (B, 1, H, W) if needs & _NEED_DEPTH else (0,),
        (B, 3, 4) if needs & _NEED_FUSED else (0,),
        (B, 3, 3) if needs & _NEED_FUSED else (0,),
    ]


def _error(
    ref_image: torch.Tensor,
    ref_depth: torch.Tensor,
    live_image: torch.Tensor,
    pose: torch.Tensor,
    K: torch.Tensor,
    kind: int,
    scale: float,
    min_depth: float,
    needs: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """images (B, C, H, W), depth (B, 1, H, W), pose (B, 3, 4), K (B, 3, 3) -> error (B,), count (B,),
    and the gradients of S = C count error wanted by ``needs`` (else empty): dS/d ref_image
    (B, C, H, W), dS/d ref_depth (B, 1, H, W), dS/d pose (B, 3, 4) and dS/d K (B, 3, 3) (the last two
    whenever any of the four is wanted)."""
    B, C, H, W = ref_image.shape
    ft = WARP_FLOAT[ref_image.dtype]
    # every entry of the gradient buffers is written by the kernels: no zero-fill
    outs = [torch.empty(s, dtype=ref_image.dtype) for s in _error_shapes(ref_image, needs)]
    if B == 0:
        return tuple(outs)
    grad = int(needs & _NEED_FUSED != 0)
    rows = torch.empty(B * H * error_reduce.ROW_SLOTS, dtype=torch.float64)
    rows_d = descriptor(rows, "scalar", wp_float64)
    if H * W > 0:
        arrays = [descriptor(t, "scalar", ft) for t in (ref_image, ref_depth, live_image)] + [
            descriptor(pose, "mat34", ft), descriptor(K, "mat33", ft)]
        acc = torch.empty(B * H * error.ACC_SLOTS * 8, dtype=ref_image.dtype)  # the rows' running sums
        launch(error.error_lanes(kind, C, W)[ft], B * H, [*arrays, C, H, W, kind, scale, min_depth, grad],
               [rows_d, descriptor(acc, "vec8", ft), descriptor(outs[2], "scalar", ft),
                descriptor(outs[3], "scalar", ft)])
    else:
        rows.zero_()
    launch(error_reduce.error_reduce[ft], B,
           [rows_d, descriptor(pose, "mat34", ft), descriptor(K, "mat33", ft), H, C, grad],
           [descriptor(o, "scalar", ft) for o in (outs[0], outs[1], outs[4], outs[5])])
    return tuple(outs)


def _error_fake(ref_image, ref_depth, live_image, pose, K, kind, scale, min_depth, needs):
    return tuple(torch.empty(s, dtype=ref_image.dtype) for s in _error_shapes(ref_image, needs))


def _views8(t: torch.Tensor, ft) -> list:
    """A contiguous tensor's scalar and length-8 vector descriptors (what :data:`.scale_segments`
    reads and writes through); keep ``t`` alive while they are used."""
    return [descriptor(t, "scalar", ft), descriptor(t, "vec8", ft)]


def _error_backward_impl(
    grad_error: torch.Tensor,
    count: torch.Tensor,
    g_ref: torch.Tensor,
    g_depth: torch.Tensor,
    g_pose: torch.Tensor,
    g_K: torch.Tensor,
    ref_image: torch.Tensor,
    ref_depth: torch.Tensor,
    live_image: torch.Tensor,
    pose: torch.Tensor,
    K: torch.Tensor,
    kind: int,
    scale: float,
    min_depth: float,
    needs: int,
) -> list[torch.Tensor]:
    """The gradients of (ref_image, ref_depth, live_image, pose, K) wanted by ``needs`` (others
    empty): the forward's dS/d x scaled by grad_error_b / (C count_b); the live image's by the
    Warp adjoint of photometric_rows."""
    B, C, H, W = ref_image.shape
    ft = WARP_FLOAT[ref_image.dtype]
    grad_error = grad_error.contiguous()
    ge = descriptor(grad_error, "scalar", ft)
    n_d = descriptor(count, "scalar", ft)
    out = []
    for k, (src, like) in enumerate(zip((g_ref, g_depth, None, g_pose, g_K), (ref_image, ref_depth, live_image, pose,
                                                                             K))):
        if not needs >> k & 1:
            out.append(like.new_empty(0))
        elif src is None:  # the live image: below
            out.append(torch.zeros(like.shape, dtype=like.dtype))
        else:
            g = torch.empty(like.shape, dtype=like.dtype)
            n = g.numel()
            if n:
                src = src.contiguous()  # (the op's own forward outputs are; a direct caller's may not be)
                launch(error_reduce.scale_segments[ft], error_reduce.scale_segments_dim(n),
                       [*_views8(src, ft), ge, n_d, n // max(B, 1), n, C], _views8(g, ft))
            out.append(g)
    if needs & _NEED_LIVE and B * H * W > 0:
        # d error_b / d row_sum = grad_error_b / (C n_b) for the rows of b, then the rows' adjoint
        adj_rows = torch.empty(B * H, dtype=ref_image.dtype)
        ones = torch.ones(B * H, dtype=ref_image.dtype)  # alive while its descriptor is used
        launch(error_reduce.scale_segments[ft], error_reduce.scale_segments_dim(B * H),
               [*_views8(ones, ft), ge, n_d, H, B * H, C], _views8(adj_rows, ft))
        scratch = [torch.empty(B * H, dtype=ref_image.dtype) for _ in range(2)]
        arrays = [descriptor(t, "scalar", ft) for t in (ref_image, ref_depth, live_image)] + [
            descriptor(pose, "mat34", ft), descriptor(K, "mat33", ft)]
        params = [C, H, W, kind, scale, min_depth]
        null_s, null_34, null_33 = null_array("scalar", ft), null_array("mat34", ft), null_array("mat33", ft)
        launch(error_rows.photometric_rows[ft], B * H, [*arrays, *params],
               [descriptor(s, "scalar", ft) for s in scratch],
               adjoint=True, adj_inputs=[null_s, null_s, descriptor(out[2], "scalar", ft), null_34, null_33, *params],
               adj_outputs=[descriptor(adj_rows, "scalar", ft), null_s])
    return out


def _error_backward_fake(grad_error, count, g_ref, g_depth, g_pose, g_K, ref_image, ref_depth, live_image, pose, K,
                         kind, scale, min_depth, needs):
    return [t.new_empty(t.shape if needs >> k & 1 else (0,)) for k, t in
            enumerate((ref_image, ref_depth, live_image, pose, K))]


def _no_second_order(ctx, *grads):
    raise NotImplementedError(
        "gvnn_warp.photometric_error: second-order gradients are not supported (its gradient is computed in the "
        "forward pass and only scaled by the backward, which has no gradient of its own)"
    )


# the backward op of photometric_error (part of its registration, not an op of its own in OPS)
photometric_error_backward = define_op("photometric_error_backward", _error_backward_impl, _error_backward_fake,
                                       autograd=(_no_second_order, lambda ctx, inputs, output: None))


def _error_setup_context(ctx, inputs, output):
    ref_image, ref_depth, live_image, pose, K, kind, scale, min_depth, needs = inputs
    _, count, g_ref, g_depth, g_pose, g_K = output
    ctx.mark_non_differentiable(count, g_ref, g_depth, g_pose, g_K)
    # gradients of the outputs other than the error are never used: autograd passes None rather than
    # a zero-filled tensor of each output's size (g_depth and g_ref are image-sized)
    ctx.set_materialize_grads(False)
    ctx.save_for_backward(count, g_ref, g_depth, g_pose, g_K, ref_image, ref_depth, live_image, pose, K)
    ctx.params = (kind, scale, min_depth, needs)


def _error_backward(ctx, grad_error, *unused):
    kind, scale, min_depth, needs = ctx.params
    saved = ctx.saved_tensors
    wanted = sum(1 << k for k in range(5) if ctx.needs_input_grad[k])
    if wanted & ~needs:
        raise RuntimeError(
            "gvnn_warp.photometric_error: a gradient was asked for an input that did not require grad when the "
            "forward pass ran (its gradient was not computed then)"
        )
    if grad_error is None:
        grad_error = saved[0].new_zeros(saved[0].shape)
    grads = photometric_error_backward(grad_error, *saved, kind, scale, min_depth, wanted)
    return (*(g if ctx.needs_input_grad[k] else None for k, g in enumerate(grads)), None, None, None, None)


photometric_error = custom_op(
    "photometric_error", _error, _error_fake, autograd=(_error_backward, _error_setup_context), **_LOSS,
)

__getattr__ = lazy_ops(__name__)  # (the ops registered with lazy=True)
