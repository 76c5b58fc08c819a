"""Host functions that run gvnn_warp pipelines on ``wp.array``s, with no torch involved.

They check their arguments, allocate outputs (with gradients when the inputs have them) and
launch the same kernels the torch layers use, so a ``wp.Tape`` records them::

    tape = wp.Tape()
    with tape:
        warped, valid = warp_frame_depth(image, depth, pose, K)
        loss = masked_squared_error(warped, target, valid)
    tape.backward(loss=loss)          # pose.grad, image.grad, depth.grad, K.grad

Shapes: image (B, C, H, W), depth (B, 1, H, W), pose (B,) of 3x4 matrices [R | t] (mapping the
depth's frame into the image's), K (B,) of 3x3 intrinsics; float32 or float64 throughout. A
lens model other than the pinhole is given as ``model`` (a name of :data:`.lens.MODEL_IDS` or
its id) and ``dist`` (B,) of length-8 distortion vectors (:func:`.lens.pack_dist`); gradients
then reach ``dist.grad`` too. Conventions are in ``docs/conventions.md``.
"""

from __future__ import annotations

from typing import Any

import warp as wp

from ..core import compat as _compat
from ..core.launch import wp_launch
from ..geometry import lens
from ..geometry.camera import MIN_DEPTH
from . import kernels as sampling_kernels
from .sampler import PADDING_MODES as _PADDING


def _expect(fn: str, name: str, cond: bool, what: str, got, exc: type[Exception] = ValueError) -> None:
    if not cond:
        raise exc(f"gvnn_warp.kernels.{fn}: argument '{name}' must be {what}, got {got}")


def _expect_arrays(fn: str, **arrays) -> None:
    """Each of ``arrays`` (argument name -> value) a ``wp.array`` (a numpy array or torch tensor is
    named as such: these functions take Warp arrays, e.g. ``wp.from_numpy``, ``wp.from_torch``)."""
    for name, a in arrays.items():
        _expect(fn, name, isinstance(a, wp.array), "a wp.array (wp.from_numpy / wp.from_torch make one)",
                f"{type(a).__module__.split('.')[0]}.{type(a).__name__}", TypeError)


def _channel_last_hint(shape) -> str:
    """For a 4-D image refused by a shape test: a hint when it looks (B, H, W, C)."""
    return ", which looks channel-last (B, H, W, C): images are (B, C, H, W)" if (
        len(shape) == 4 and shape[3] in (1, 3, 4) and shape[1] > 4) else ""


def _type_name(t) -> str:
    shape, scalar = _compat.matrix_shape(t), _compat.scalar_type(t)
    if shape is not None:  # vector / matrix types: "3x4 float64"
        return f"{'x'.join(map(str, shape))} {scalar.__name__}"
    return getattr(t, "__name__", repr(t))


def _expect_float(fn: str, name: str, a: wp.array) -> None:
    ok = a.dtype in (wp.float32, wp.float64)
    _expect(fn, name, ok, "of dtype float32 or float64", _type_name(a.dtype), TypeError)


def _expect_matrices(fn: str, name: str, a: wp.array, shape: tuple[int, int], ft) -> None:
    ok = _compat.matrix_shape(a.dtype) == shape and _compat.scalar_type(a.dtype) is ft
    _expect(fn, name, ok, f"an array of {shape[0]}x{shape[1]} {ft.__name__} matrices", _type_name(a.dtype), TypeError)


def _lens_model(fn: str, model) -> int:
    """A model name or id -> its id (:data:`.lens.MODEL_IDS`)."""
    ids = lens.MODEL_IDS
    ok = model in ids or (isinstance(model, int) and not isinstance(model, bool) and model in ids.values())
    _expect(fn, "model", ok, f"one of {list(ids)} (or its id)", repr(model))
    return ids[model] if isinstance(model, str) else int(model)


def _expect_dist(fn: str, dist, B: int, ft) -> None:
    _expect(fn, "dist", isinstance(dist, wp.array), "a wp.array of length-8 distortion vectors (lens.pack_dist)",
            type(dist).__name__, TypeError)
    _expect(fn, "dist", dist.ndim == 1 and dist.shape[0] == B, f"a ({B},) array of length-8 vectors", dist.shape)
    ok = _compat.matrix_shape(dist.dtype) == (8,) and _compat.scalar_type(dist.dtype) is ft
    _expect(fn, "dist", ok, f"an array of length-8 {ft.__name__} vectors", _type_name(dist.dtype), TypeError)


def pixel_rays(K: wp.array, dist: wp.array, H: int, W: int, model) -> wp.array:
    """The undistorted rays (B, H, W) of vec3 ``(xn, yn, w)`` of every pixel of B cameras (see
    :mod:`.geometry.lens.rays`; ``w`` 0 where the pixel has no ray). Recordable on a ``wp.Tape`` (gradients
    to K and dist through the implicit function theorem)."""
    fn = "pixel_rays"
    m = _lens_model(fn, model)
    _expect(fn, "K", isinstance(K, wp.array) and K.ndim == 1, "a (B,) array of 3x3 matrices", getattr(K, "shape", K))
    ft = _compat.scalar_type(K.dtype)
    _expect_matrices(fn, "K", K, (3, 3), ft)
    _expect_dist(fn, dist, K.shape[0], ft)
    B = K.shape[0]
    vec3 = wp.types.vector(3, ft)
    rays = wp.zeros((B, H, W), dtype=vec3, device=K.device, requires_grad=K.requires_grad or dist.requires_grad)
    wp_launch(sampling_kernels.pixel_rays_lens()[ft], dim=B * H * W, inputs=[0, K, dist, H, W, m],
              outputs=[rays.flatten()], device=K.device, record_tape=rays.requires_grad)
    return rays


def _lanes_view(a: wp.array) -> wp.array:
    """A contiguous float array (its gradient too, if it has one) seen as 8-lane vectors over the same
    memory (a tape's adjoint launch then reads and adds to the original's gradient)."""
    vec8 = wp.types.vector(8, a.dtype)
    n = a.size // 8
    grad = _compat.alias(a.grad, vec8, (n,)) if a.grad is not None else None
    return _compat.alias(a, vec8, (n,), grad)


def warp_frame_depth(
    image: wp.array,
    depth: wp.array,
    pose: wp.array,
    K: wp.array,
    *,
    dist: wp.array | None = None,
    model="pinhole",
    padding_mode: str = "zeros",
    min_depth: float = MIN_DEPTH,
) -> tuple[wp.array, wp.array]:
    """The 3D spatial transformer on Warp arrays (same semantics as ``gvnn_warp.warp_frame_depth``).

    Returns ``warped`` (B, C, H, W) and ``valid`` (B, 1, H, W) of ``wp.bool``. ``warped`` has a
    gradient buffer when any input does, so the call can be recorded on a ``wp.Tape``. With a
    distorted ``model`` ("radtan", "fisheye"), ``dist`` (B,) holds each item's distortion vector;
    the rays of the depth's pixels are computed first (:func:`pixel_rays`, one more launch).
    """
    fn = "warp_frame_depth"
    _expect_arrays(fn, image=image, depth=depth, pose=pose, K=K)
    _expect(fn, "image", image.ndim == 4, "a 4-D (B, C, H, W) array", image.shape)
    B, C, H, W = image.shape
    _expect(fn, "depth", tuple(depth.shape) == (B, 1, H, W), f"of shape {(B, 1, H, W)}",
            f"{depth.shape}{_channel_last_hint(image.shape)}")
    _expect(fn, "pose", pose.ndim == 1 and pose.shape[0] == B, f"a ({B},) array of 3x4 matrices", pose.shape)
    _expect(fn, "K", K.ndim == 1 and K.shape[0] == B, f"a ({B},) array of 3x3 matrices", K.shape)
    _expect(fn, "padding_mode", padding_mode in _PADDING, f"one of {list(_PADDING)}", repr(padding_mode))
    _expect_float(fn, "image", image)
    ft = image.dtype
    _expect(fn, "depth", depth.dtype == ft, f"of dtype {ft.__name__}", _type_name(depth.dtype), TypeError)
    _expect_matrices(fn, "pose", pose, (3, 4), ft)
    _expect_matrices(fn, "K", K, (3, 3), ft)
    _expect(fn, "min_depth", 0 < min_depth < float("inf"), "a positive finite number", repr(min_depth))
    m = _lens_model(fn, model)
    if m != 0:
        _expect_dist(fn, dist, B, ft)
    requires_grad = image.requires_grad or depth.requires_grad or pose.requires_grad or K.requires_grad
    requires_grad = requires_grad or (m != 0 and dist.requires_grad)
    warped = wp.zeros((B, C, H, W), dtype=ft, device=image.device, requires_grad=requires_grad)
    valid = wp.zeros((B, 1, H, W), dtype=wp.bool, device=image.device)
    common = [image.flatten(), depth.flatten(), pose, K]
    params = [C, H, W, float(min_depth), _PADDING[padding_mode]]
    out = warped.flatten()
    if m == 0 and sampling_kernels.fits_row_lanes(H, W):
        # the 8-lane kernel, as the torch op takes it: depth and output seen 8 values an element
        kernel = sampling_kernels.warp_frame_depth_lanes(C, _PADDING[padding_mode])[ft]
        inputs = [0, common[0], _lanes_view(common[1]), pose, K, *params]
        out = _lanes_view(out)
    elif m == 0:
        kernel, inputs = sampling_kernels.warp_frame_depth[ft], [0, *common, *params]
    else:
        rays = pixel_rays(K, dist, H, W, m)
        kernel = sampling_kernels.warp_frame_depth_lens()[ft]
        inputs = [0, *common, dist, rays.flatten(), *params, m, H * W]
    wp_launch(
        kernel,
        dim=B * H,  # one thread per image row, as in the torch op
        inputs=inputs,
        outputs=[out, valid.flatten()],
        device=image.device,
        # a launch with no gradient to pass is not recorded: a tape's backward would run its adjoint for
        # nothing (and the lens kernels' hand-written adjoints crashed on arrays without gradients)
        record_tape=requires_grad,
    )
    return warped, valid


@wp.kernel
def _masked_squared_error(
    a: wp.array(dtype=Any), b: wp.array(dtype=Any), valid: wp.array(dtype=wp.bool), hw: int, C: int,
    loss: wp.array(dtype=Any),
):
    i = wp.tid()  # flat (b, c, pixel)
    pix = (i // (C * hw)) * hw + i % hw
    if valid[pix]:
        r = a[i] - b[i]
        wp.atomic_add(loss, 0, r * r * a.dtype(0.5))


def masked_squared_error(a: wp.array, b: wp.array, valid: wp.array) -> wp.array:
    """0.5 * sum over valid pixels and all channels of (a - b)^2, as a 1-element array.

    a, b: (B, C, H, W) of one float type; valid: (B, 1, H, W) of ``wp.bool``.
    """
    fn = "masked_squared_error"
    _expect_arrays(fn, a=a, b=b, valid=valid)
    _expect(fn, "a", a.ndim == 4, "a 4-D (B, C, H, W) array", a.shape)
    _expect_float(fn, "a", a)
    _expect(fn, "b", b.dtype == a.dtype, f"of dtype {_type_name(a.dtype)}", _type_name(b.dtype), TypeError)
    _expect(fn, "valid", valid.dtype == wp.bool, "of dtype bool", _type_name(valid.dtype), TypeError)
    _expect(fn, "b", tuple(b.shape) == tuple(a.shape), f"of shape {tuple(a.shape)}", b.shape)
    B, C, H, W = a.shape
    _expect(fn, "valid", tuple(valid.shape) == (B, 1, H, W), f"of shape {(B, 1, H, W)}", valid.shape)
    loss = wp.zeros(1, dtype=a.dtype, device=a.device, requires_grad=a.requires_grad or b.requires_grad)
    wp_launch(
        _masked_squared_error, dim=a.size, inputs=[a.flatten(), b.flatten(), valid.flatten(), H * W, C],
        outputs=[loss], device=a.device,
    )
    return loss
