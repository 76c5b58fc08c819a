"""Direct RGB-D odometry: a coarse-to-fine Levenberg-Marquardt aligner on the fused photometric
normal equations (:func:`gvnn_warp.kernels.photometric_normal_equations`).

:class:`DirectAligner` estimates the rigid motion ``T`` (4x4, float64) that maps points of the
reference camera into the live camera - the ``pose`` of ``warp_frame_depth(live_image, ref_depth,
pose, K)`` - by minimising the robust photometric error ``sum rho(live(project(T X)) - ref(u))``
over the reference pixels ``u`` with valid depth (``X`` their back-projected points). Conventions
(pixel centres, intrinsics, poses, valid depths): ``docs/conventions.md``.

Shapes: images ``(C, H, W)`` or ``(B, C, H, W)`` float intensities (e.g. in [0, 1]); depths
``(1, H, W)`` / ``(B, 1, H, W)`` metres, where 0, NaN, inf and negative values mean "no depth";
numpy arrays or torch tensors (CPU), float32 or float64 (computed in float32). Results come back
as the kind of the reference image (numpy or torch), poses always float64.

How it works
------------
1. Each frame is turned into a pyramid once (:meth:`DirectAligner.prepare`, Warp kernels of
   :mod:`gvnn_warp.kernels.pyramid`): by default the colour channels are mixed into one intensity
   (ITU-R BT.601 luma for C = 3, the channel mean otherwise; ``color=True`` keeps every channel),
   then ``levels - 1`` halvings: 2x2 means of the intensities, and depths averaged over the taps
   on the nearest surface of each 2x2 block (no depth invented across depth edges). The
   intrinsics of level ``l`` follow the pixel-centre convention, ``x_l = (x + 0.5) / 2^l - 0.5``.
2. From the coarsest level to the finest, Levenberg-Marquardt on the Gauss-Newton system of
   the robust (IRLS) photometric residuals, for a left-multiplied update ``T <- exp(delta) T``,
   ``delta = [omega, t]``: the step solves ``(JtWJ + lambda diag(JtWJ)) delta = -JtWr``; it is
   accepted if the cost per valid pixel goes down (then ``lambda`` shrinks by ``lm_down``), else
   rejected (``lambda`` grows by ``lm_up``). Every trial is one fused pass over the level. The
   whole step (accept/reject, damping, the 6x6 solve, the pose update, the stop test) runs in a
   Warp kernel (:mod:`gvnn_warp.kernels.lm`), so a trial is a few recorded launches.
3. A level stops after ``iterations[l]`` trials, or when a step moves the image by less than
   ``tolerance`` pixels of that level: ``f_l (|omega| + |t| / z)`` with ``f_l`` the level's focal
   length and ``z`` the mean valid reference depth, or when ``lambda`` exceeds ``1e8`` (no step
   lowers the cost), or (if ``min_decrease > 0``) when an accepted step lowered the cost per
   pixel by less than that fraction. A step shorter than ``take_step / 2^l`` pixels of level
   ``l`` (``take_step`` in pixels of the finest level; at least ``tolerance``) is taken without
   evaluating it and ends the level: near the optimum a Gauss-Newton step is reliable, and the
   evaluation would cost a full pass (at the finest level this halves the work).

``info`` (a dict) reports per level (coarse to fine) the trials made, the final cost per valid
pixel and the fraction of the level's pixels that were valid, and ``converged``: the finest level
ended on a step below ``10 tolerance`` pixels with at least ``min_valid_fraction`` of its pixels
valid. A pair with too few valid pixels at a level skips that level; at the finest level it is
reported as not converged and ``T`` is the best estimate so far (the initial pose if nothing
could be estimated): never NaN, never an exception for bad data inside valid arrays.

For frame-to-frame tracking, build each frame's pyramid once and reuse it::

    aligner = DirectAligner(K)
    prev = aligner.prepare(image0, depth0)
    for image, depth in frames:
        cur = aligner.prepare(image, depth)
        T_cur_prev, info = aligner.align_frames(prev, cur)
        prev = cur

A frame's pyramid lives in buffers the aligner owns and reuses once the :class:`Frame` is gone
(a tracker drops one frame per step), and each (level, frame pair) keeps its recorded launches,
so steady-state tracking allocates nothing. One aligner is not meant to be used from several
threads at once (use one aligner per thread).

Import needs no torch; torch is imported only when a tensor comes in.
"""

from __future__ import annotations

import functools
import math
import numbers
import weakref
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from ..kernels import pyramid as _pyramid
from ..kernels.core import compat as _compat
from ..kernels.core import launch as _launch
from ..kernels.geometry import lens as _lens
from ..kernels.geometry.camera import MIN_DEPTH
from ..kernels.photometric import lm as _lm
from ..kernels.photometric import normal_equations as _pk

__all__ = ["DirectAligner", "Frame"]

_LUMA = (0.299, 0.587, 0.114)
_ROBUST = ("huber", "cauchy", "geman_mcclure", "tukey", "l2")
_MIN_SIDE = 4  # smallest side (pixels) of a pyramid level
_AUTO_MIN_SIDE = 6  # levels=None: the coarsest level's shorter side is 6-11 pixels
_MIN_VALID_PIXELS = 24  # below this a level's system is not trusted, whatever the fraction
_LAMBDA_MAX = 1e8
_RIGID_TOLERANCE = 1e-3  # an init's |R^T R - I| and last-row deviation (chained float32 poses: ~1e-6)
_OCCLUSION_LEVELS = 2  # the occlusion test runs at the finest this many levels (see DirectAligner's 'occlusion')
_POOL_SIZE = 4  # pyramids of dropped frames kept per frame size for reuse
_GRAIN = 32768  # pyramid launches split over threads in pieces of at least this many pixels
_SYSTEM_CACHE = 64  # normal-equation outputs (with recorded launches) kept per batch size and frame size


def _fail(fn: str, exc: type[Exception], msg: str):
    raise exc(f"gvnn_warp.odometry.{fn}: {msg}")


def _real(v) -> float:
    """``v`` as a float if it is a real number (Python, numpy, or a one-element numpy array or torch
    tensor), else NaN (which every range check refuses)."""
    if (isinstance(v, np.ndarray) and v.size == 1) or (hasattr(v, "numel") and callable(v.numel) and v.numel() == 1):
        v = v.item()
    return float(v) if isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_)) else math.nan


def _lens_camera(fn: str, K, model, dist):
    """(K (3, 3) float64, model name, packed dist (8,) float64 or None for the pinhole) from K and
    the ``model`` / ``dist`` arguments, or from a camera of ``gvnn_warp.cameras``."""
    if hasattr(K, "model") and hasattr(K, "K") and hasattr(K, "dist") and not isinstance(K, np.ndarray):
        if model is not None or dist is not None:
            _fail(fn, ValueError, "arguments 'model' and 'dist' must not be given with a camera object")
        cam = K
        if cam.K.dim() != 2 or (cam.dist is not None and cam.dist.dim() != 1):
            _fail(fn, ValueError, "argument 'K' must be an unbatched camera (K (3, 3), dist (n,))")
        model = {v: k for k, v in _lens.MODEL_IDS.items()}[int(cam.model)]
        K, dist = cam.K, cam.dist
    K = _as_numpy(fn, "K", K, (2,)).astype(np.float64)
    if model is None:
        model = "pinhole" if dist is None else "radtan"
    if model not in _lens.MODEL_IDS:
        _fail(fn, ValueError, f"argument 'model' must be one of {list(_lens.MODEL_IDS)}, got {model!r}")
    mid = _lens.MODEL_IDS[model]
    if mid == _lens.PINHOLE:
        if dist is not None:
            _fail(fn, ValueError, "argument 'dist' must be None for the pinhole model")
        return K, model, None
    n = _lens.N_COEFFS[mid]
    if isinstance(dist, (list, tuple)):
        dist = np.asarray(dist, dtype=np.float64)
    coeffs = None if dist is None else _as_numpy(fn, "dist", dist, (1,)).astype(np.float64)
    if coeffs is None or coeffs.shape != (n,) or not np.all(np.isfinite(coeffs)):
        got = None if coeffs is None else coeffs.tolist()
        _fail(fn, ValueError, f"argument 'dist' must be {n} finite coefficients for the {model} model, got {got}")
    return K, model, _lens.pack_dist(mid, coeffs)


def _is_torch(x) -> bool:
    return type(x).__module__.split(".")[0] == "torch"


def _as_numpy(fn: str, name: str, x, ndims: tuple[int, ...]) -> np.ndarray:
    """numpy float32/float64 view of a numpy array or CPU torch tensor with one of ``ndims``."""
    if _is_torch(x):
        import torch

        if not isinstance(x, torch.Tensor):
            _fail(fn, TypeError, f"argument '{name}' must be a numpy array or torch tensor, got {type(x).__name__}")
        if x.device.type != "cpu":
            _fail(fn, ValueError, f"argument '{name}' must be on the CPU, got device {x.device}")
        if x.dtype not in (torch.float32, torch.float64):
            _fail(fn, TypeError, f"argument '{name}' must be float32 or float64, got {x.dtype}")
        x = x.detach().numpy()
    elif not isinstance(x, np.ndarray):
        _fail(fn, TypeError, f"argument '{name}' must be a numpy array or torch tensor, got {type(x).__name__}")
    elif x.dtype not in (np.float32, np.float64):
        _fail(fn, TypeError, f"argument '{name}' must be float32 or float64, got {x.dtype}")
    if x.ndim not in ndims:
        want = " or ".join(f"{d}-D" for d in ndims)
        _fail(fn, ValueError, f"argument '{name}' must be {want}, got shape {tuple(x.shape)}")
    return x


@dataclass(eq=False)
class Frame:
    """One RGB-D frame (or a batch of B frames) prepared for alignment by :meth:`DirectAligner.prepare`.

    Attributes:
        images: per level (fine to coarse) a ``wp.array`` (B, C', H_l, W_l) float32 (C' = 1 unless
            the aligner keeps colour).
        depths: per level a ``wp.array`` (B, 1, H_l, W_l) float32 (0 = no depth), or None for a
            frame given without depth (usable only as the live frame of a pair).
        batched: whether the input had a batch dimension.
        torch: whether the input was a torch tensor (results come back as torch tensors).
    """

    images: list
    depths: list | None
    batched: bool
    torch: bool
    _mean_depth: np.ndarray | None = field(default=None, repr=False)

    @property
    def batch(self) -> int:
        return int(self.images[0].shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the finest level."""
        return int(self.images[0].shape[2]), int(self.images[0].shape[3])

    def mean_depth(self) -> np.ndarray:
        """(B,) mean valid depth of the coarsest level (1 where there is none)."""
        if self._mean_depth is None:
            d = self.depths[-1].numpy().reshape(self.batch, -1)
            n = (d > 0).sum(1)
            self._mean_depth = np.where(n > 0, d.sum(1, dtype=np.float64) / np.maximum(n, 1), 1.0)
        return self._mean_depth


def _recycle(pool: list, pyramid: _Pyramid) -> None:
    if len(pool) < _POOL_SIZE:
        pool.append(pyramid)


def _out_view(a: wp.array, lanes: bool) -> wp.array:
    """A flat view of an output buffer: float32 scalars, or vec8 (8 consecutive pixels) for the
    8-lane kernels (an empty one for a missing or empty buffer)."""
    if lanes and a.size > 0:
        return wp.array(ptr=a.ptr, dtype=_launch.vec8f, shape=(a.size // 8,), device="cpu")
    if lanes:
        return wp.empty(0, dtype=_launch.vec8f, device="cpu")
    return a.flatten()


class _Pyramid:
    """Preallocated pyramid buffers of one frame size, with the launches that fill them recorded
    once (a recorded launch replays in a few microseconds); reused through the aligner's pool."""

    def __init__(self, aligner: DirectAligner, B: int, C: int, H: int, W: int, with_depth: bool):
        Co = C if aligner.color else 1
        self.key = (B, C, H, W, with_depth)
        self.shapes = _pyramid.pyramid_shapes(H, W, aligner._levels_for(H, W))
        self.images = [wp.empty((B, Co, h, w), dtype=wp.float32, device="cpu") for h, w in self.shapes]
        self.depths = [wp.empty((B, 1, h, w), dtype=wp.float32, device="cpu") for h, w in self.shapes] if with_depth \
            else None
        empty = wp.empty(0, dtype=wp.float32, device="cpu")
        depths = self.depths or [empty] * len(self.shapes)
        f32 = wp.float32
        self.weights = aligner._channel_weights(C)
        # the 8-lane kernels where the rows are whole vectors (one output channel for the base level)
        lanes0 = self.lanes0 = Co == 1 and W % 8 == 0
        self.level0 = _launch.RecordedLaunch(
            _pyramid.level0_lanes_kernel(C)[f32] if lanes0 else _pyramid.level0_kernel(C, Co)[f32], B * H,
            [empty, self.weights.flatten(), empty, *([_out_view(empty, True)] if lanes0 else []), H, W,
             int(with_depth), aligner.depth_tolerance],
            [_out_view(self.images[0], lanes0), _out_view(depths[0], lanes0)], work=W, grain=_GRAIN,
        )
        self.down = []
        for k in range(1, len(self.shapes)):
            (h, w), (ho, wo) = self.shapes[k - 1], self.shapes[k]
            lanes = wo % 8 == 0
            self.down.append(_launch.RecordedLaunch(
                (_pyramid.downsample_lanes_kernel(Co) if lanes else _pyramid.downsample_kernel(Co))[f32], B * ho,
                [self.images[k - 1].flatten(), depths[k - 1].flatten() if with_depth else empty,
                 h, w, ho, wo, aligner.depth_tolerance, int(with_depth)],
                [_out_view(self.images[k], lanes), _out_view(depths[k], lanes)], work=wo,
                grain=_GRAIN,
            ))

    def fill(self, image: np.ndarray, depth: np.ndarray | None) -> None:
        self.level0.set_arg(0, wp.array(image.reshape(-1), dtype=wp.float32, device="cpu", copy=False))
        if depth is not None:
            d = wp.array(depth.reshape(-1), dtype=wp.float32, device="cpu", copy=False)
            self.level0.set_arg(2, d)
            if self.lanes0:  # the 8-lane kernel also reads the depth as vec8
                self.level0.set_arg(3, _out_view(d, True))
        self.level0()
        for run in self.down:
            run()


class DirectAligner:
    """Coarse-to-fine direct (photometric) RGB-D alignment (``gvnn_warp.odometry``; how it works:
    the module docstring; conventions: ``docs/conventions.md``).

    Methods:
        ``align(ref_image, ref_depth, live_image, live_depth=None, init=None) -> (T, info)``:
            images (C, H, W) / (B, C, H, W), depths (1, H, W) / (B, 1, H, W) (0/NaN: none),
            numpy or torch; ``T`` (4, 4) / (B, 4, 4) float64 maps reference-camera points into
            the live camera (the ``pose`` of ``warp_frame_depth(live, ref_depth, pose, K)``),
            returned as the kind of ``ref_image``; ``init`` an initial ``T`` (identity if None).
        ``prepare(image, depth=None) -> Frame``: a frame's pyramid, built once.
        ``align_frames(ref, live, init=None) -> (T, info)``: :meth:`align` on prepared frames.

    ``info``: ``{"converged": bool (or (B,) bool array), "levels": [per level, coarse to fine:
    {"level", "size": (H_l, W_l), "iterations": trials, "cost": cost per valid pixel,
    "valid_fraction"}]}`` (per-item arrays when batched).

    Args:
        K: (3, 3) intrinsics of the finest level (numpy or torch; float64 internally), or an
            unbatched camera of ``gvnn_warp.cameras`` (``RadTanCamera``, ``FisheyeCamera``,
            ``PinholeCamera``), which sets ``model`` and ``dist``.
        model: the lens model of both frames, "pinhole" (default), "radtan" or "fisheye"
            (docs/conventions.md, "Camera models"); the images are used as they are (distorted):
            the reference pixels' rays are undistorted once per pyramid level and the moved
            points projected through the lens, at every level (the coefficients act on
            normalized coordinates, so they hold for every level's intrinsics).
        dist: the model's coefficients: (k1, k2, p1, p2, k3) for "radtan" (OpenCV's), (k1, k2,
            k3, k4) for "fisheye" (cv2.fisheye's); giving them without ``model`` means "radtan".
        levels: pyramid levels (1 = no pyramid); fewer are used if a level would have a side
            below 4 pixels. None (default): as many as keep the coarsest level's shorter side at
            6 pixels or more (6 levels at 320x240, 7 at 640x480), which gives the widest basin.
        iterations: the most trials (normal-equation passes after the first) per level: an int
            for every level, or a sequence from the finest level (index 0) towards the coarsest,
            whose last entry also holds for the levels beyond it.
        robust: the M-estimator of the residuals: "huber", "cauchy", "geman_mcclure", "tukey"
            (as in ``robust_rho``) or "l2".
        scale: the M-estimator's scale (in intensity units).
        depth_weight: weight of the depth term (the moved point's z against the live depth); > 0
            needs live depths.
        occlusion: the occlusion test's relative depth difference (0: none): when the live frame
            has a depth, a reference pixel is skipped where a live depth under its bilinear sample
            (the diagonal taps) differs from its moved point's z by more than ``occlusion * z`` (occluded in the live
            view, or a sample across a depth edge). Without it, such pixels bias the optimum
            (issue 15: +0.05 cm in y and +0.0075 deg about x per pair on the rendered sequence).
            Applied at the two finest levels: at the coarser ones, far from the optimum, it
            would drop the very pixels that pull the pose in (a much narrower basin); without it
            at the second finest level, the estimate the finest level starts from kept that bias
            (+0.049 cm in y at 640x480), and the finest level's last, unevaluated step (see
            ``take_step``) removed only ~90% of it.
        min_depth: depths at or below it count as missing (metres).
        color: keep every colour channel in the residual (C per pixel) instead of one intensity.
        tolerance: a level stops when a step moves the image by less than this many pixels.
        take_step: steps shorter than this many finest-level pixels are taken unevaluated (see
            the module docstring).
        min_decrease: stop a level when an accepted step lowers the cost per pixel by less than
            this fraction (0: never; it saves trials at coarse levels but narrows the basin).
        lm_lambda: initial Levenberg-Marquardt damping (relative to diag(JtWJ)); ``lm_up`` /
            ``lm_down``: its growth after a rejected / shrink after an accepted step.
        min_valid_fraction: fewest valid pixels (fraction of the level's) to trust a level.
        depth_tolerance: the relative depth spread that counts as one surface when depths are
            downsampled, and between neighbouring pixels of the finest level: a depth that far
            from a neighbour's (a depth edge, where colours mix two surfaces) is not used (see
            :mod:`gvnn_warp.kernels.pyramid`).
    """

    # prepare() may run on one thread while align_frames() runs on another (on other frames): they
    # share no buffers (a frame's pyramid comes from the pool of dead frames' pyramids), so
    # gvnn_warp.tracking pipelines them
    concurrent_prepare = True

    def __init__(
        self,
        K,
        *,
        levels: int | None = None,
        iterations=(4, 6, 10, 20, 30),
        robust: str = "huber",
        scale: float = 0.05,
        depth_weight: float = 0.0,
        occlusion: float = 0.05,
        min_depth: float = MIN_DEPTH,
        color: bool = False,
        tolerance: float = 0.05,
        take_step: float = 0.5,
        min_decrease: float = 0.0,
        lm_lambda: float = 1e-4,
        lm_up: float = 4.0,
        lm_down: float = 0.25,
        min_valid_fraction: float = 0.05,
        depth_tolerance: float = _pyramid.DEPTH_TOLERANCE,
        model: str | None = None,
        dist=None,
    ):
        fn = "DirectAligner"
        K, self.model, self.dist = _lens_camera(fn, K, model, dist)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            _fail(fn, ValueError, f"argument 'K' must be finite (3, 3) intrinsics with fx, fy > 0, got {K.tolist()}")
        self.K = K
        if levels is not None and (not isinstance(levels, (int, np.integer)) or isinstance(levels, bool) or levels < 1):
            _fail(fn, ValueError, f"argument 'levels' must be None or an int >= 1, got {levels!r}")
        self.levels = None if levels is None else int(levels)
        if isinstance(iterations, (int, np.integer)) and not isinstance(iterations, bool):
            iterations = (int(iterations),)
        try:
            if isinstance(iterations, str):
                raise TypeError
            iterations = tuple(int(i) for i in iterations)
        except (TypeError, ValueError):
            _fail(fn, TypeError, f"argument 'iterations' must be an int or a sequence of ints, got {iterations!r}")
        if not iterations or min(iterations) < 0:
            _fail(fn, ValueError, f"argument 'iterations' must be >= 0, got {iterations!r}")
        self.iterations = iterations  # level l uses iterations[min(l, len - 1)]
        if robust not in _ROBUST:
            _fail(fn, ValueError, f"argument 'robust' must be one of {list(_ROBUST)}, got {robust!r}")
        self.robust = robust
        for name, v, lo in (("scale", scale, 0.0), ("min_depth", min_depth, 0.0), ("tolerance", tolerance, 0.0),
                            ("lm_up", lm_up, 1.0)):
            if not lo < _real(v) < math.inf:
                _fail(fn, ValueError, f"argument '{name}' must be a finite number > {lo}, got {v!r}")
        for name, v in (("depth_weight", depth_weight), ("occlusion", occlusion), ("lm_lambda", lm_lambda),
                        ("depth_tolerance", depth_tolerance), ("take_step", take_step),
                        ("min_decrease", min_decrease)):
            if not 0.0 <= _real(v) < math.inf:
                _fail(fn, ValueError, f"argument '{name}' must be a finite number >= 0, got {v!r}")
        if not 0.0 < _real(lm_down) <= 1.0:
            _fail(fn, ValueError, f"argument 'lm_down' must be in (0, 1], got {lm_down!r}")
        if not 0.0 <= _real(min_valid_fraction) <= 1.0:
            _fail(fn, ValueError, f"argument 'min_valid_fraction' must be in [0, 1], got {min_valid_fraction!r}")
        self.scale = _real(scale)
        self.depth_weight = _real(depth_weight)
        self.occlusion = _real(occlusion)
        self.min_depth = _real(min_depth)
        self.color = bool(color)
        self.tolerance = _real(tolerance)
        self.min_decrease = _real(min_decrease)
        self.take_step = _real(take_step)
        self.lm_lambda = _real(lm_lambda)
        self.lm_up = _real(lm_up)
        self.lm_down = _real(lm_down)
        self.min_valid_fraction = _real(min_valid_fraction)
        self.depth_tolerance = _real(depth_tolerance)
        self._weights: dict[int, wp.array] = {}
        self._states: dict[tuple, _State] = {}  # per (B, level shapes)
        self._frame_pool: dict[tuple, list] = {}  # per (B, C, H, W, with depth): free _Pyramid buffers

    # ------------------------------------------------------------------------------ pyramids

    def _levels_for(self, H: int, W: int) -> int:
        n = 1
        if self.levels is None:  # auto: halve while the shorter side stays >= _AUTO_MIN_SIDE
            while min(H >> n, W >> n) >= _AUTO_MIN_SIDE:
                n += 1
            return n
        while n < self.levels and min(H >> n, W >> n) >= _MIN_SIDE:
            n += 1
        return n

    def _channel_weights(self, C: int) -> wp.array:
        w = self._weights.get(C)
        if w is None:
            if self.color:
                m = np.eye(C, dtype=np.float32)
            elif C == 3:
                m = np.array([_LUMA], dtype=np.float32)
            else:
                m = np.full((1, C), 1.0 / C, dtype=np.float32)
            w = self._weights[C] = wp.array(m, dtype=wp.float32, device="cpu")
        return w

    def prepare(self, image, depth=None) -> Frame:
        """Build the pyramid of one frame (or a batch): ``image`` (C, H, W) / (B, C, H, W), ``depth``
        (1, H, W) / (B, 1, H, W) or None (then the frame can only be the live frame of a pair).
        The inputs are copied (later changes to them do not affect the frame)."""
        return self._prepare("prepare", "image", "depth", image, depth)

    def _prepare(self, fn: str, image_name: str, depth_name: str, image, depth, use_depth: bool = True) -> Frame:
        torch_in = _is_torch(image)
        img = _as_numpy(fn, image_name, image, (3, 4))
        batched = img.ndim == 4
        if not batched:
            img = img[None]
        B, C, H, W = img.shape
        if B < 1 or C < 1 or H < 1 or W < 1:
            _fail(fn, ValueError, f"argument '{image_name}' must have no empty dimension, got shape {img.shape}")
        if B * C * H * W >= 2**31:
            _fail(fn, ValueError, f"argument '{image_name}' is too large for int32 indexing: shape {img.shape}")
        hint = ""  # for shapes refused below that look like (H, W, C), as image libraries load images
        if W in (1, 3, 4) and C > 4:
            hint = (f", which looks channel-last {'(B, H, W, C)' if batched else '(H, W, C)'}: images are "
                    f"{'(B, C, H, W)' if batched else '(C, H, W)'} (numpy: transpose, torch: permute)")
        if H < _MIN_SIDE or W < _MIN_SIDE:
            _fail(fn, ValueError, f"argument '{image_name}' must be at least {_MIN_SIDE}x{_MIN_SIDE} pixels, "
                  f"got shape {tuple(np.shape(image))}{hint}")
        if depth is not None:
            d = _as_numpy(fn, depth_name, depth, (4,) if batched else (3,))
            if not batched:
                d = d[None]
            if d.shape != (B, 1, H, W):
                want = (B, 1, H, W) if batched else (1, H, W)
                also = f"; argument '{image_name}' has shape {tuple(np.shape(image))}{hint}" if hint else ""
                _fail(fn, ValueError, f"argument '{depth_name}' must have shape {want}, got {tuple(depth.shape)}{also}")
        if not use_depth:
            depth = None  # checked, but not needed
        key = (B, C, H, W, depth is not None)
        pool = self._frame_pool.setdefault(key, [])
        pyr = pool.pop() if pool else _Pyramid(self, B, C, H, W, depth is not None)
        pyr.fill(np.ascontiguousarray(img, dtype=np.float32),
                 None if depth is None else np.ascontiguousarray(d, dtype=np.float32))
        frame = Frame(images=pyr.images, depths=pyr.depths, batched=batched, torch=torch_in)
        # the buffers go back to the pool when the frame is gone (a tracker drops one per frame)
        weakref.finalize(frame, _recycle, pool, pyr)
        return frame

    # ------------------------------------------------------------------------------ alignment

    def align(self, ref_image, ref_depth, live_image, live_depth=None, init=None):
        """Estimate ``T`` (4, 4) / (B, 4, 4) float64 mapping reference-camera points into the live camera.

        Args:
            ref_image, live_image: (C, H, W) or (B, C, H, W) intensities.
            ref_depth: (1, H, W) or (B, 1, H, W) metres (0/NaN = none).
            live_depth: like ``ref_depth``; needed when ``depth_weight > 0``, used by the occlusion test.
            init: initial ``T`` ((4, 4) or (B, 4, 4); (3, 4) rows [R | t] also accepted), a rigid
                transform (R a rotation within 1e-3), e.g. a constant-velocity prediction;
                identity if None.

        Returns:
            ``(T, info)``: T of the kind of ``ref_image`` (numpy or torch), see the module docstring
            for ``info``.
        """
        fn = "align"
        if ref_depth is None:
            _fail(fn, ValueError, "argument 'ref_depth' must be given (the reference frame needs depth)")
        if live_depth is None and self.depth_weight > 0:
            _fail(fn, ValueError, "argument 'live_depth' must be given when depth_weight > 0")
        ref = self._prepare(fn, "ref_image", "ref_depth", ref_image, ref_depth)
        live = self._prepare(fn, "live_image", "live_depth", live_image, live_depth,
                             self.depth_weight > 0 or self.occlusion > 0)
        if live.batched != ref.batched or live.images[0].shape != ref.images[0].shape:
            got = tuple(np.shape(live_image))
            want = tuple(ref.images[0].shape[:1] if ref.batched else ()) + (np.shape(ref_image)[-3],) + ref.shape
            _fail(fn, ValueError, f"argument 'live_image' must have the shape of 'ref_image' {want}, got {got}")
        return self._align(fn, ref, live, init)

    def align_frames(self, ref: Frame, live: Frame, init=None):
        """:meth:`align` on two prepared frames (``ref`` needs depth; ``live`` needs depth when
        ``depth_weight > 0``); same results."""
        fn = "align_frames"
        for name, f in (("ref", ref), ("live", live)):
            if not isinstance(f, Frame):
                _fail(fn, TypeError, f"argument '{name}' must be a Frame from DirectAligner.prepare, got "
                      f"{type(f).__name__}")
        if ref.depths is None:
            _fail(fn, ValueError, "argument 'ref' must be prepared with a depth")
        if self.depth_weight > 0 and live.depths is None:
            _fail(fn, ValueError, "argument 'live' must be prepared with a depth when depth_weight > 0")
        if live.batched != ref.batched or tuple(live.images[0].shape) != tuple(ref.images[0].shape):
            _fail(fn, ValueError, f"arguments 'ref' and 'live' must have the same shape, got "
                  f"{tuple(ref.images[0].shape)} and {tuple(live.images[0].shape)}")
        n_levels = self._levels_for(*ref.shape)
        grey_mismatch = not self.color and ref.images[0].shape[1] != 1
        if len(ref.images) != n_levels or len(live.images) != n_levels or grey_mismatch:
            _fail(fn, ValueError, "arguments 'ref' and 'live' must be prepared by an aligner with these levels and "
                  "colour settings")
        return self._align(fn, ref, live, init)

    def _init_pose(self, fn: str, init, B: int, batched: bool) -> np.ndarray:
        if init is None:
            return np.broadcast_to(np.eye(4), (B, 4, 4)).copy()
        T = _as_numpy(fn, "init", init, (3,) if batched else (2,)).astype(np.float64)
        if not batched:
            T = T[None]
        if T.shape[0] != B or T.shape[1:] not in ((4, 4), (3, 4)):
            want = f"({B}, 4, 4)" if batched else "(4, 4)"
            _fail(fn, ValueError, f"argument 'init' must have shape {want} (or 3x4 rows), got {tuple(np.shape(init))}")
        if not np.all(np.isfinite(T)):
            _fail(fn, ValueError, "argument 'init' must be finite")
        R = T[:, :3, :3]
        off = np.abs(np.einsum("bji,bjk->bik", R, R) - np.eye(3)).max(axis=(1, 2))
        bad = np.flatnonzero((off > _RIGID_TOLERANCE) | (np.linalg.det(R) < 0))
        if T.shape[1] == 4:
            bad = np.union1d(bad, np.flatnonzero(np.abs(T[:, 3] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) > _RIGID_TOLERANCE))
        if bad.size:
            b = int(bad[0])
            _fail(fn, ValueError, f"argument 'init' must be rigid transforms [R | t] (R a rotation: R^T R = I within "
                                  f"{_RIGID_TOLERANCE:g}, det +1; a 4x4's last row 0 0 0 1), but "
                                  f"{'item ' + str(b) if batched else 'it'} is not: "
                                  f"{np.array2string(T[b], precision=4, separator=', ').replace(chr(10), '')}")
        out = np.broadcast_to(np.eye(4), (B, 4, 4)).copy()
        out[:, :3, :] = T[:, :3, :]
        return out

    def _state(self, B: int, shapes) -> _State:
        key = (B, tuple(shapes))
        st = self._states.get(key)
        if st is None:
            st = self._states[key] = _State(self, B, shapes)
        return st

    def _align(self, fn: str, ref: Frame, live: Frame, init):
        B = ref.batch
        T0 = self._init_pose(fn, init, B, ref.batched)
        shapes = [(int(a.shape[2]), int(a.shape[3])) for a in ref.images]
        st = self._state(B, shapes)
        st.T_np[:] = T0[:, :3, :]
        st.zmean_np[:] = ref.mean_depth()
        level_info = []
        for level in range(len(shapes) - 1, -1, -1):
            ne, lm_first, lm_next = st.runner(ref, live, level)
            st.pose_np[:] = st.T_np
            for cmd in ne:
                cmd()
            lm_first()
            active = st.active_np
            for _ in range(self.iterations[min(level, len(self.iterations) - 1)]):
                if not active.any():
                    break
                for cmd in ne:
                    cmd()
                lm_next()
            h, w = shapes[level]
            frac = st.count_np / float(h * w)
            level_info.append({
                "level": level, "size": (h, w),
                "iterations": st.trials_np.copy() if ref.batched else int(st.trials_np[0]),
                "cost": st.mean_np.copy() if ref.batched else float(st.mean_np[0]),
                "valid_fraction": np.where(st.ok_np > 0, frac, 0.0) if ref.batched else
                float(frac[0] if st.ok_np[0] else 0.0),
            })
        converged = (st.ok_np > 0) & (st.step_np < 10.0 * self.tolerance)
        T = np.zeros((B, 4, 4))
        T[:, :3, :] = st.T_np
        T[:, 3, 3] = 1.0
        info = {"converged": converged if ref.batched else bool(converged[0]), "levels": level_info}
        out = T if ref.batched else T[0]
        if ref.torch:
            import torch

            out = torch.from_numpy(out)
        return out, info


class _State:
    """Per (batch size, level shapes): the Levenberg-Marquardt state of :mod:`.kernels.lm` (with
    numpy views), the intrinsics of every level, and per (level, reference pyramid, live pyramid)
    the normal equations' outputs with the launches that fill them and the LM step launches,
    recorded once: in frame-to-frame tracking pyramids are pooled, so the same few combinations
    recur, and a trial costs a few recorded launches."""

    def __init__(self, aligner: DirectAligner, B: int, shapes):
        self.aligner = aligner
        self.B = B
        Ks = [_pyramid.scale_intrinsics(aligner.K, level) for level in range(len(shapes))]
        self.K = [wp.array(np.broadcast_to(Kl.astype(np.float32), (B, 3, 3)).copy(), dtype=wp.mat33f, device="cpu")
                  for Kl in Ks]
        self.f = [math.sqrt(Kl[0, 0] * Kl[1, 1]) for Kl in Ks]
        # a distorted lens: its coefficients (the same at every level) and each level's pixel rays
        self.dist = None if aligner.dist is None else wp.array(
            np.broadcast_to(aligner.dist.astype(np.float32), (B, 8)).copy(), dtype=_launch.vec8f, device="cpu")
        self.shapes = list(shapes)
        self._rays: dict[int, wp.array] = {}
        self.min_count = [max(_MIN_VALID_PIXELS, aligner.min_valid_fraction * h * w) for h, w in shapes]

        def arr(dtype, n=B):
            a = wp.zeros(n, dtype=dtype, device="cpu")
            return a, a.numpy()

        self.pose, pose_np = arr(_launch.mat34f)
        self.pose_np = pose_np.reshape(B, 3, 4)
        self.T, T_np = arr(_launch.mat34d)
        self.T_np = T_np.reshape(B, 3, 4)
        self.Tn, _ = arr(_launch.mat34d)
        self.H, _ = arr(wp.float64, B * 36)
        self.g, _ = arr(wp.float64, B * 6)
        self.zmean, self.zmean_np = arr(wp.float64)
        self.mean, self.mean_np = arr(wp.float64)
        self.count, self.count_np = arr(wp.float64)
        self.lam, _ = arr(wp.float64)
        self.step, self.step_np = arr(wp.float64)
        self.trials, self.trials_np = arr(wp.int32)
        self.active, self.active_np = arr(wp.int32)
        self.ok, self.ok_np = arr(wp.int32)
        self._runners: dict[tuple, tuple] = {}

    def runner(self, ref: Frame, live: Frame, level: int):
        """(normal-equation launches, first LM step, next LM step) for this pair at ``level``."""
        al = self.aligner
        # the live depth serves the depth term and the occlusion test (the finest _OCCLUSION_LEVELS
        # levels; skipped without live depths)
        occlusion = al.occlusion > 0 and level < _OCCLUSION_LEVELS
        use_depth = live.depths is not None and (al.depth_weight > 0 or occlusion)
        key = (level, id(ref.images[level]), id(ref.depths[level]), id(live.images[level]),
               id(live.depths[level]) if use_depth else None)
        run = self._runners.get(key)
        if run is None:
            if len(self._runners) >= _SYSTEM_CACHE:
                self._runners.pop(next(iter(self._runners)))
            run = self._runners[key] = self._make_runner(ref, live, level, use_depth)
        return run[:3]

    def _make_runner(self, ref: Frame, live: Frame, level: int, use_depth: bool):
        from ..kernels import photometric_normal_equations

        al = self.aligner
        args = (ref.images[level], ref.depths[level], live.images[level], self.pose, self.K[level])
        kw = {"robust": al.robust, "scale": al.scale, "depth_weight": al.depth_weight, "min_depth": al.min_depth,
              "occlusion": al.occlusion if level < _OCCLUSION_LEVELS else 0.0,
              "live_depth": live.depths[level] if use_depth else None}
        if self.dist is not None:  # the level's rays, computed once per aligner state
            if level not in self._rays:
                from ..kernels.sampling.pipeline import pixel_rays

                h, w = self.shapes[level]
                self._rays[level] = pixel_rays(self.K[level], self.dist, h, w, al.model)
            kw.update(dist=self.dist, model=al.model, rays=self._rays[level])
        ne = photometric_normal_equations(*args, **kw)
        cmds = getattr(ne, "_cmds", None)
        rows = getattr(ne, "_rows", None)
        if cmds and len(cmds) == 2 and rows is not None:
            # the row kernel only: the LM step reduces its per-row sums itself (one launch fewer per trial)
            cmds = cmds[:1]
            system = [rows, rows.shape[0] // (self.B * _pk.ROW_STRIDE), _pk.ROW_STRIDE]
            step_kernel = _lm.lm_step_rows
        else:
            if not cmds:  # no recorded launches to replay: the public call with out= each time
                cmds = [functools.partial(photometric_normal_equations, *args, out=ne, **kw)]
            system = [ne.JtWJ.flatten(), ne.JtWr.flatten(), ne.cost, ne.count]
            step_kernel = _lm.lm_step
        lm = []
        for first in (1, 0):
            lm.append(_launch.wp_launch(
                step_kernel, dim=self.B,
                inputs=[*system, self.zmean, first,
                        self.min_count[level], self.f[level], al.tolerance, max(al.tolerance, al.take_step / 2**level),
                        al.lm_lambda, al.lm_up, al.lm_down,
                        _LAMBDA_MAX, al.min_decrease],
                outputs=[self.T, self.Tn, self.pose, self.H, self.g, self.mean, self.count, self.lam, self.step,
                         self.trials, self.active, self.ok],
                device="cpu", record_cmd=True,
            ))
        # the arrays stay referenced with their recorded launches: their ids (the cache key) and
        # addresses cannot be reused by other arrays while the entry exists
        keep = (ref.images[level], ref.depths[level], live.images[level], kw["live_depth"], ne, lm)
        lm_first, lm_next = (_compat.replay_function(c) for c in lm)
        return tuple(cmds), lm_first, lm_next, keep
