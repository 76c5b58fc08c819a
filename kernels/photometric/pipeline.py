"""Host functions of the fused photometric objective on ``wp.array``s (no torch).

Shapes (as :func:`..sampling.pipeline.warp_frame_depth`): images (B, C, H, W), depths (B, 1, H, W),
pose (B,) of 3x4 matrices [R | t] mapping reference-camera points into the live camera,
K (B,) of 3x3 intrinsics; one float type (float32 or float64) throughout. Conventions
(pixel centres, K, minimum depth, valid rule): ``docs/conventions.md``.

:func:`photometric_normal_equations` is built to be called many times per frame pair (a
Gauss-Newton or Levenberg-Marquardt loop): pass the result of the previous call as ``out=``
and it allocates nothing and re-launches kernels recorded on the first call (a few microseconds
each) as long as the arrays passed are the same (update the pose array in place between
iterations, e.g. with ``pose.assign(...)``).
"""

from __future__ import annotations

import math

import warp as wp

from ..core import compat as _compat
from ..core import launch as _launch
from ..geometry.camera import MIN_DEPTH
from ..sampling.lanes import MAX_LANES_PLANE
from ..sampling.pipeline import (
    _expect,
    _expect_dist,
    _expect_float,
    _expect_matrices,
    _lens_model,
    _type_name,
    pixel_rays,
)
from .error_rows import photometric_mean, photometric_rows, photometric_rows_lens
from .normal_equations import normal_equations_rows, normal_equations_rows_lens
from .normal_equations_lanes import normal_equations_lanes
from .normal_equations_reduce import N_SUMS, ROW_STRIDE, normal_equations_reduce
from .residual import GRAIN_PIXELS, KINDS

#: penalties of :func:`photometric_normal_equations` (IRLS weights psi(r)/r; "l1" has none at 0)
NORMAL_EQUATIONS_KINDS = ("l2", "huber", "cauchy", "geman_mcclure", "tukey")


class NormalEquations:
    """The Gauss-Newton system returned by :func:`photometric_normal_equations` (unpacks as the
    tuple ``(JtWJ, JtWr, cost, count)``); pass it back as ``out=`` to reuse its buffers.

    Attributes:
        JtWJ: (B, 6, 6) sum of w J^T J (symmetric).
        JtWr: (B, 6) sum of w J^T r; the Gauss-Newton step is delta = -JtWJ^-1 JtWr.
        cost: (B,) sum of rho(r).
        count: (B,) number of reference pixels used (an integer stored as a float).
    """

    def __init__(self, JtWJ: wp.array, JtWr: wp.array, cost: wp.array, count: wp.array):
        self.JtWJ, self.JtWr, self.cost, self.count = JtWJ, JtWr, cost, count
        B = JtWJ.shape[0]
        self._rows: wp.array | None = None  # (B * H * ROW_STRIDE,) float64 row partial sums
        self._acc: wp.array | None = None  # (B * H * ROW_STRIDE,) 8-lane running sums of the row kernel
        self._key: tuple | None = None  # what the recorded launches depend on
        self._cmds: list = []  # the recorded launches
        self._args: tuple = ()  # the arguments of the call that recorded them
        self._B = B

    def __iter__(self):
        return iter((self.JtWJ, self.JtWr, self.cost, self.count))

    def __repr__(self) -> str:
        return f"NormalEquations(B={self._B}, dtype={self.JtWJ.dtype.__name__})"

    def numpy(self):
        """The four outputs as numpy arrays (copies)."""
        return tuple(a.numpy() for a in self)


def _flat(a: wp.array, n: int) -> wp.array:
    """A 1-D view of a contiguous array's ``n`` scalars (keeping ``a`` alive)."""
    return _compat.alias(a, a.dtype, (n,))


def _check_common(fn, ref_image, ref_depth, live_image, pose, K, min_depth):
    _expect(fn, "ref_image", isinstance(ref_image, wp.array) and ref_image.ndim == 4, "a 4-D (B, C, H, W) wp.array",
            getattr(ref_image, "shape", type(ref_image).__name__), TypeError if not isinstance(ref_image, wp.array)
            else ValueError)
    B, C, H, W = ref_image.shape
    _expect_float(fn, "ref_image", ref_image)
    ft = ref_image.dtype
    for name, a, shape in (("ref_depth", ref_depth, (B, 1, H, W)), ("live_image", live_image, (B, C, H, W))):
        _expect(fn, name, isinstance(a, wp.array), "a wp.array", type(a).__name__, TypeError)
        _expect(fn, name, tuple(a.shape) == shape, f"of shape {shape}", tuple(a.shape))
        _expect(fn, name, a.dtype == ft, f"of dtype {ft.__name__}", _type_name(a.dtype), TypeError)
    for name, a, n in (("pose", pose, 3), ("K", K, 3)):
        _expect(fn, name, isinstance(a, wp.array), "a wp.array", type(a).__name__, TypeError)
        _expect(fn, name, a.ndim == 1 and a.shape[0] == B, f"a ({B},) array of {n}x{4 if name == 'pose' else 3} "
                "matrices", tuple(a.shape))
    _expect_matrices(fn, "pose", pose, (3, 4), ft)
    _expect_matrices(fn, "K", K, (3, 3), ft)
    for name, a in (("ref_image", ref_image), ("ref_depth", ref_depth), ("live_image", live_image), ("pose", pose),
                    ("K", K)):
        _expect(fn, name, a.is_contiguous, "contiguous", "a strided array")
        _expect(fn, name, a.device.is_cpu, "on the CPU", str(a.device))
    _expect(fn, "min_depth", isinstance(min_depth, (int, float)) and 0 < min_depth < math.inf,
            "a positive finite number", repr(min_depth))
    _expect(fn, "ref_image", B * C * H * W < 2**31, "smaller than 2**31 elements", ref_image.shape)
    return B, C, H, W, ft


def _check_penalty(fn, robust, scale, kinds):
    _expect(fn, "robust", robust in kinds, f"one of {list(kinds)}", repr(robust))
    _expect(fn, "scale", isinstance(scale, (int, float)) and not isinstance(scale, bool) and 0 < scale < math.inf,
            "a positive finite number", repr(scale))


def _normal_equations_out(fn, out, B: int, H: int, ft) -> NormalEquations:
    """``out`` checked (a NormalEquations of an earlier call with the same B and float type), or new
    zeroed buffers; with its per-row sums sized for B x H rows."""
    if out is not None:
        ok = isinstance(out, NormalEquations) and out.JtWJ.shape == (B, 6, 6) and out.JtWJ.dtype == ft
        _expect(fn, "out", ok, f"a NormalEquations of an earlier call with B={B} and {ft.__name__}",
                "another" if isinstance(out, NormalEquations) else type(out).__name__, TypeError)
    else:
        out = NormalEquations(
            wp.zeros((B, 6, 6), dtype=ft, device="cpu"), wp.zeros((B, 6), dtype=ft, device="cpu"),
            wp.zeros(B, dtype=ft, device="cpu"), wp.zeros(B, dtype=ft, device="cpu"),
        )
    if out._rows is None or out._rows.shape[0] != B * H * ROW_STRIDE:
        out._rows = wp.zeros(B * H * ROW_STRIDE, dtype=wp.float64, device="cpu")
    return out


def photometric_normal_equations(
    ref_image: wp.array,
    ref_depth: wp.array,
    live_image: wp.array,
    pose: wp.array,
    K: wp.array,
    *,
    robust: str = "huber",
    scale: float = 1.0,
    live_depth: wp.array | None = None,
    depth_weight: float = 0.0,
    min_depth: float = MIN_DEPTH,
    occlusion: float = 0.0,
    out: NormalEquations | None = None,
    dist: wp.array | None = None,
    model="pinhole",
    rays: wp.array | None = None,
) -> NormalEquations:
    """The Gauss-Newton system of the photometric residuals, for a left-multiplied pose update.

    Residuals: for each reference pixel u with a valid depth whose moved point
    P = pose * (depth K^-1 [u, 1]) has z > min_depth and projects inside the live image (the
    ``valid`` rule of ``warp_frame_depth``), r_c = live_c(project(P)) - ref_c(u) for every
    channel c (bilinear sample). With ``live_depth`` and ``depth_weight > 0`` each such pixel
    adds the depth residual r_d = sqrt(depth_weight) (z(P) - live_depth(project(P))) (bilinear;
    skipped where any of the four taps lies outside the image or is not a valid depth), with the
    same penalty. With ``live_depth`` and ``occlusion > 0``, a pixel is skipped (occluded in the
    live view, or its sample straddles a depth edge) where one of the diagonal bilinear taps (00,
    11) inside the image has no valid live depth or one that differs from the moved point's z by
    more than ``occlusion * z`` (as Open3D's ``depth_diff_max`` on its nearest pixel, but
    relative). For the perturbation pose <- exp(delta) pose, delta = [omega, t] (radians,
    metres), J = dr/d delta at 0 (exact for the bilinear interpolant as sampled; dP/d omega =
    -[P]x, dP/dt = I), IRLS weights w = psi(r)/r (1 at r = 0; 1 for "l2"), and

        JtWJ = sum w J^T J (B, 6, 6),  JtWr = sum w J^T r (B, 6),  cost = sum rho(r) (B,),
        count = number of reference pixels used (B,),

    summed in float64 (row sums added in a fixed order: bitwise the same for any thread count),
    returned in the input's float type. The step is delta = -JtWJ^-1 JtWr, pose <- exp(delta)
    pose. Residuals or image gradients that are not finite (NaN/inf intensities) are skipped.

    Args:
        ref_image, live_image: (B, C, H, W) intensities.
        ref_depth: (B, 1, H, W) depth (z, metres) of the reference frame; 0, negative, NaN or
            inf: that pixel is skipped.
        pose: (B,) 3x4 matrices mapping reference-camera points into the live camera.
        K: (B,) 3x3 intrinsics, shared by both views.
        robust: "huber" (default), "cauchy", "geman_mcclure", "tukey" (``gvnn_warp.robust_rho``
            with ``scale``) or "l2" (r^2 / 2).
        scale: the M-estimator's scale (ignored by "l2").
        live_depth: (B, 1, H, W) depth of the live frame, for the depth term.
        depth_weight: >= 0; the depth residual's weight (0: no depth term).
        occlusion: >= 0; the relative depth difference of the occlusion test (0: no test; needs
            ``live_depth``).
        min_depth: metres (docs/conventions.md).
        out: the result of an earlier call with the same shapes and float type: its buffers are
            reused (and returned), and so are its recorded launches while the arrays passed are
            the same (same data pointers) and the scalar arguments unchanged.
        dist, model: a distorted lens (``model`` "radtan" or "fisheye", ``dist`` (B,) of
            length-8 vectors, :func:`.lens.pack_dist`): the reference pixels' rays are undistorted
            (computed on the call that records the launches, and reused with ``out=`` while the
            same ``K`` and ``dist`` arrays are passed) and J includes the distortion's Jacobian.
        rays: with a distorted ``model``, the rays ``pipeline.pixel_rays(K, dist, H, W, model)``
            computed once by the caller (e.g. per pyramid level of a fixed camera), else None.

    Returns:
        :class:`NormalEquations` ``(JtWJ, JtWr, cost, count)``. Not differentiable.
    """
    fn = "photometric_normal_equations"
    if model != "pinhole" and model != 0:
        return _normal_equations_lens(ref_image, ref_depth, live_image, pose, K, robust, scale, live_depth,
                                      depth_weight, min_depth, occlusion, out, dist, _lens_model(fn, model), rays)
    key = None
    if out is not None and isinstance(out, NormalEquations) and out._cmds:
        a = out._args
        if (  # the fastest path: the very same array objects and arguments, nothing allocated
            a[0] is ref_image and a[1] is ref_depth and a[2] is live_image and a[3] is pose and a[4] is K
            and a[5] is live_depth and a[6] == robust and a[7] == scale and a[8] == depth_weight
            and a[9] == min_depth and a[10] == _launch.get_num_threads() and a[11] == occlusion
        ):
            for cmd in out._cmds:
                cmd()
            return out
        try:
            key = _launch_key(ref_image, ref_depth, live_image, pose, K, live_depth,
                              (robust, scale, depth_weight, min_depth, occlusion, _launch.get_num_threads()))
        except AttributeError:  # not wp.arrays: the checks below say so
            pass
        if key is not None and out._key is not None and out._key[0] == key:
            # other array objects over the same memory (address, shape, strides, type)
            out._args = (ref_image, ref_depth, live_image, pose, K, live_depth, robust, scale, depth_weight,
                         min_depth, _launch.get_num_threads(), occlusion)
            for cmd in out._cmds:
                cmd()
            return out
    B, C, H, W, ft = _check_common(fn, ref_image, ref_depth, live_image, pose, K, min_depth)
    _check_penalty(fn, robust, scale, NORMAL_EQUATIONS_KINDS)
    _expect(fn, "depth_weight", isinstance(depth_weight, (int, float)) and 0 <= depth_weight < math.inf,
            "a finite number >= 0", repr(depth_weight))
    _expect(fn, "occlusion", isinstance(occlusion, (int, float)) and 0 <= occlusion < math.inf,
            "a finite number >= 0", repr(occlusion))
    if live_depth is not None:
        _expect(fn, "live_depth", isinstance(live_depth, wp.array), "a wp.array or None", type(live_depth).__name__,
                TypeError)
        _expect(fn, "live_depth", tuple(live_depth.shape) == (B, 1, H, W), f"of shape {(B, 1, H, W)}",
                tuple(live_depth.shape))
        _expect(fn, "live_depth", live_depth.dtype == ft, f"of dtype {ft.__name__}", _type_name(live_depth.dtype),
                TypeError)
        _expect(fn, "live_depth", live_depth.is_contiguous and live_depth.device.is_cpu, "contiguous, on the CPU",
                str(live_depth.device))
    out = _normal_equations_out(fn, out, B, H, ft)
    acc_type = _launch.element_type("vec8", ft)
    if out._acc is None or out._acc.shape[0] != B * H * ROW_STRIDE or out._acc.dtype != acc_type:
        out._acc = wp.empty(B * H * ROW_STRIDE, dtype=acc_type, device="cpu")
    n_pix = B * C * H * W
    no_depth = wp.zeros(0, dtype=ft, device="cpu")
    inputs = [
        _flat(ref_image, n_pix), _flat(ref_depth, B * H * W), _flat(live_image, n_pix),
        _flat(live_depth, B * H * W) if live_depth is not None else no_depth,
        pose, K, C, H, W, NORMAL_EQUATIONS_KINDS_CODES[robust], float(scale), float(min_depth), float(depth_weight),
        float(occlusion), out._rows, out._acc,
    ]
    outputs = [_flat(out.JtWJ, B * 36), _flat(out.JtWr, B * 6), out.cost, out.count]
    depth_term = live_depth is not None and depth_weight > 0
    occlusion_test = live_depth is not None and occlusion > 0
    if H * W <= MAX_LANES_PLANE:
        rows_kernel = normal_equations_lanes(depth_term, occlusion_test, C, NORMAL_EQUATIONS_KINDS_CODES[robust],
                                             W)[ft]
    else:  # (the lanes' float tap addresses are exact only up to MAX_LANES_PLANE pixels: the pixel-by-pixel kernel)
        rows_kernel, inputs = normal_equations_rows(depth_term, occlusion_test)[ft], inputs[:-1]
    out._cmds = [
        _launch.RecordedLaunch(rows_kernel, B * H, inputs, work=W, grain=GRAIN_PIXELS),
        _launch.RecordedLaunch(normal_equations_reduce[ft], B * N_SUMS, [out._rows, H, *outputs], grain=GRAIN_PIXELS),
    ]
    if key is None:
        key = _launch_key(ref_image, ref_depth, live_image, pose, K, live_depth,
                          (robust, scale, depth_weight, min_depth, occlusion, _launch.get_num_threads()))
    out._key = (key, inputs)  # the views stay alive with the recorded launches
    out._args = (ref_image, ref_depth, live_image, pose, K, live_depth, robust, scale, depth_weight, min_depth,
                 _launch.get_num_threads(), occlusion)
    for cmd in out._cmds:
        cmd()
    return out


NORMAL_EQUATIONS_KINDS_CODES = {k: KINDS[k] for k in NORMAL_EQUATIONS_KINDS}


def _launch_key(*arrays_and_args) -> tuple:
    """What the recorded launches depend on: every array's address, shape, strides and type
    (None stays None), and the scalar arguments (the last item)."""
    *arrays, args = arrays_and_args
    return (*((a.ptr, a.shape, a.strides, a.dtype) if a is not None else None for a in arrays), args)


#: penalties of :func:`photometric_error`
ERROR_KINDS = ("l1", "l2", "huber", "cauchy", "geman_mcclure", "tukey")


def photometric_error(
    ref_image: wp.array,
    ref_depth: wp.array,
    live_image: wp.array,
    pose: wp.array,
    K: wp.array,
    *,
    robust: str = "l1",
    scale: float = 1.0,
    min_depth: float = MIN_DEPTH,
    dist: wp.array | None = None,
    model="pinhole",
) -> tuple[wp.array, wp.array]:
    """The mean robust photometric error of the reference frame warped into the live image.

    For every reference pixel u with a valid depth whose moved point P = pose * (depth K^-1
    [u, 1]) has z > min_depth and projects inside the live image (the ``valid`` rule of
    ``warp_frame_depth``, docs/conventions.md), r_c = live_c(project(P)) - ref_c(u) per channel
    (bilinear sample); error = mean over those pixels and all channels of rho(r_c), count = the
    number of those pixels (error 0 where count is 0). Residuals that are not finite (NaN/inf
    intensities) count 0.

    Args:
        ref_image, live_image: (B, C, H, W) intensities.
        ref_depth: (B, 1, H, W) depth of the reference frame; 0, negative, NaN or inf: skipped.
        pose: (B,) 3x4 matrices mapping reference-camera points into the live camera.
        K: (B,) 3x3 intrinsics.
        robust: "l1" (|r|, default), "l2" (r^2 / 2), "huber", "cauchy", "geman_mcclure", "tukey"
            (``gvnn_warp.robust_rho`` with ``scale``).
        scale: the M-estimator's scale (ignored by "l1" and "l2").
        dist, model: a distorted lens (as :func:`photometric_normal_equations`); its rays are
            computed in the call (one more launch, recorded on a tape: gradients reach dist).

    Returns:
        error (B,) and count (B,) (float, integer-valued). ``error`` has a gradient buffer when an
        input does, so the call can be recorded on a ``wp.Tape``: one row-blocked kernel and a
        reduction over rows, differentiated by Warp (gradients to both images, depth, pose, K).
    """
    fn = "photometric_error"
    B, C, H, W, ft = _check_common(fn, ref_image, ref_depth, live_image, pose, K, min_depth)
    _check_penalty(fn, robust, scale, ERROR_KINDS)
    m = _lens_model(fn, model)
    if m != 0:
        _expect_dist(fn, dist, B, ft)
    grad = any(a.requires_grad for a in (ref_image, ref_depth, live_image, pose, K)) or (m != 0 and dist.requires_grad)
    row_sum = wp.zeros(B * H, dtype=ft, device="cpu", requires_grad=grad)
    row_count = wp.zeros(B * H, dtype=ft, device="cpu")
    error = wp.zeros(B, dtype=ft, device="cpu", requires_grad=grad)
    count = wp.zeros(B, dtype=ft, device="cpu")
    frames = [0, ref_image.flatten(), ref_depth.flatten(), live_image.flatten(), pose, K]
    penalty = [C, H, W, KINDS[robust], float(scale), float(min_depth)]
    if m == 0:
        kernel, inputs = photometric_rows[ft], [*frames, *penalty]
    else:
        rays = pixel_rays(K, dist, H, W, m)
        kernel, inputs = photometric_rows_lens()[ft], [*frames, dist, rays.flatten(), *penalty, m, H * W]
    _launch.wp_launch(kernel, dim=B * H, inputs=inputs, outputs=[row_sum, row_count], device="cpu")
    _launch.wp_launch(photometric_mean[ft], dim=B, inputs=[0, row_sum, row_count, H, C],
                      outputs=[error, count], device="cpu")
    return error, count


def _normal_equations_lens(ref_image, ref_depth, live_image, pose, K, robust, scale, live_depth, depth_weight,
                           min_depth, occlusion, out, dist, m, rays):
    """:func:`photometric_normal_equations` through a distorted lens ``m`` (see there)."""
    fn = "photometric_normal_equations"
    args = (ref_image, ref_depth, live_image, pose, K, live_depth, dist, rays, robust, scale, depth_weight,
            min_depth, occlusion, m, _launch.get_num_threads())
    if isinstance(out, NormalEquations) and out._cmds and len(out._args) == len(args) and all(
        a is b if isinstance(b, wp.array) or b is None else a == b for a, b in zip(out._args, args)
    ):
        for cmd in out._cmds:
            cmd()
        return out
    B, C, H, W, ft = _check_common(fn, ref_image, ref_depth, live_image, pose, K, min_depth)
    _check_penalty(fn, robust, scale, NORMAL_EQUATIONS_KINDS)
    _expect_dist(fn, dist, B, ft)
    _expect(fn, "depth_weight", isinstance(depth_weight, (int, float)) and 0 <= depth_weight < math.inf,
            "a finite number >= 0", repr(depth_weight))
    _expect(fn, "occlusion", isinstance(occlusion, (int, float)) and 0 <= occlusion < math.inf,
            "a finite number >= 0", repr(occlusion))
    if live_depth is not None:
        _expect(fn, "live_depth", isinstance(live_depth, wp.array) and tuple(live_depth.shape) == (B, 1, H, W)
                and live_depth.dtype == ft, f"a ({B}, 1, {H}, {W}) {ft.__name__} wp.array or None",
                getattr(live_depth, "shape", type(live_depth).__name__))
    out = _normal_equations_out(fn, out, B, H, ft)
    if rays is None:
        rays = pixel_rays(K, dist, H, W, m)  # computed once per recording (Newton's method per pixel)
    else:
        vec3 = wp.types.vector(3, ft)
        _expect(fn, "rays", isinstance(rays, wp.array) and rays.dtype == vec3 and rays.size == B * H * W
                and rays.is_contiguous, f"a contiguous wp.array of {B * H * W} {ft.__name__} vec3 (pixel_rays)",
                getattr(rays, "shape", type(rays).__name__), TypeError)
    n_pix = B * C * H * W
    no_depth = wp.zeros(0, dtype=ft, device="cpu")
    inputs = [
        _flat(ref_image, n_pix), _flat(ref_depth, B * H * W), _flat(live_image, n_pix),
        _flat(live_depth, B * H * W) if live_depth is not None else no_depth,
        pose, K, dist, rays.flatten(), C, H, W, NORMAL_EQUATIONS_KINDS_CODES[robust], float(scale),
        float(min_depth), float(depth_weight), float(occlusion), m, H * W, out._rows,
    ]
    outputs = [_flat(out.JtWJ, B * 36), _flat(out.JtWr, B * 6), out.cost, out.count]
    rows_kernel = normal_equations_rows_lens(live_depth is not None and depth_weight > 0,
                                             live_depth is not None and occlusion > 0)[ft]
    out._cmds = [
        _launch.RecordedLaunch(rows_kernel, B * H, inputs, work=W, grain=GRAIN_PIXELS),
        _launch.RecordedLaunch(normal_equations_reduce[ft], B * N_SUMS, [out._rows, H, *outputs], grain=GRAIN_PIXELS),
    ]
    out._key = (None, inputs, rays)  # the views and rays stay alive with the recorded launches
    out._args = args
    for cmd in out._cmds:
        cmd()
    return out
