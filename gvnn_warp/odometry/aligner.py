"""Direct RGB-D odometry: a coarse-to-fine Levenberg-Marquardt aligner on the fused photometric
normal equations (:func:`gvnn_warp.kernels.photometric_normal_equations`).

:class:`DirectAligner` estimates the rigid motion ``T`` (4x4, float64) that maps points of the
reference camera into the live camera - the ``pose`` of ``warp_frame_depth(live_image, ref_depth,
pose, K)`` - by minimising the robust photometric error ``sum rho(live(project(T X)) - ref(u))``
over the reference pixels ``u`` with valid depth (``X`` their back-projected points). Conventions
(pixel centres, intrinsics, poses, valid depths): ``docs/conventions.md``.

Shapes: images ``(C, H, W)`` or ``(B, C, H, W)`` float intensities (e.g. in [0, 1]); depths
``(1, H, W)`` (or ``(H, W)``) / ``(B, 1, H, W)`` metres, where 0, NaN, inf and negative values mean
"no depth"; numpy arrays or torch tensors (CPU), float32 or float64 (computed in float32). Results
come back as the kind of the reference image (numpy or torch), poses always float64.

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
   Warp kernel (:mod:`gvnn_warp.kernels.photometric.lm`), so a trial is a few recorded launches.
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

import math
import warnings
import weakref

import numpy as np
import warp as wp

from ..kernels import pyramid as _pyramid
from ..kernels.geometry.camera import MIN_DEPTH
from ..kernels.sampling.remap import RemapTable
from .frame import Frame, PyramidBuffers, recycle
from .inputs import INTENSITY_LIMIT, MIN_SIDE, as_numpy, fail, initial_pose, is_torch, lens_camera, real_number
from .solver import LMState

__all__ = ["DirectAligner", "Frame"]

_LUMA = (0.299, 0.587, 0.114)
_ROBUST = ("huber", "cauchy", "geman_mcclure", "tukey", "l2")
_AUTO_MIN_SIDE = 6  # levels=None: the coarsest level's shorter side is 6-11 pixels
OCCLUSION_LEVELS = 2  # the occlusion test runs at the finest this many levels (see DirectAligner's 'occlusion')


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
        resample: None, or a ``gvnn_warp.kernels.sampling.remap.RemapTable`` (one position per
            pixel of its output size): the frames given to ``prepare`` are another camera's images
            of the table's source size, resampled through it into the pinhole camera ``K`` (images
            of the table's output size) in the same pass that makes the pyramid's base level
            (:class:`~.undistort.UndistortingAligner`'s lens frames).
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
            (the diagonal taps) differs from its moved point's z by more than ``occlusion * z``
            (occluded in the live view, or a sample across a depth edge). Without it, such pixels
            bias the optimum (measured: +0.05 cm in y and +0.0075 deg about x per pair on a
            rendered sequence, benchmarks/RESULTS.md).
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
    # gvnn_warp.odometry.tracking pipelines them
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
        resample=None,
    ):
        fn = "DirectAligner"
        K, self.model, self.dist = lens_camera(fn, K, model, dist)
        if resample is not None:
            if not isinstance(resample, RemapTable):
                fail(fn, TypeError, f"argument 'resample' must be None or a RemapTable, got {type(resample).__name__}")
            if resample.out_width is None:
                fail(fn, ValueError, f"argument 'resample' must have an output size (RemapTable's out_size): "
                                     f"{resample.n} positions for a {resample.width}x{resample.height} source")
            if min(resample.out_width, resample.out_height) < MIN_SIDE:
                fail(fn, ValueError, f"argument 'resample' must make images of at least {MIN_SIDE}x{MIN_SIDE} "
                                     f"pixels, got {resample.out_width}x{resample.out_height}")
            if self.model != "pinhole":
                fail(fn, ValueError, f"argument 'resample' resamples into a pinhole camera; model is {self.model!r}")
        self.resample = resample
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            fail(fn, ValueError, f"argument 'K' must be finite (3, 3) intrinsics with fx, fy > 0, got {K.tolist()}")
        self.K = K
        if levels is not None and (not isinstance(levels, (int, np.integer)) or isinstance(levels, bool) or levels < 1):
            fail(fn, ValueError, f"argument 'levels' must be None or an int >= 1, got {levels!r}")
        self.levels = None if levels is None else int(levels)
        if isinstance(iterations, (int, np.integer)) and not isinstance(iterations, bool):
            iterations = (int(iterations),)
        try:
            if isinstance(iterations, str):
                raise TypeError
            iterations = tuple(int(i) for i in iterations)
        except (TypeError, ValueError):
            fail(fn, TypeError, f"argument 'iterations' must be an int or a sequence of ints, got {iterations!r}")
        if not iterations or min(iterations) < 0:
            fail(fn, ValueError, f"argument 'iterations' must be >= 0, got {iterations!r}")
        self.iterations = iterations  # level l uses iterations[min(l, len - 1)]
        if robust not in _ROBUST:
            fail(fn, ValueError, f"argument 'robust' must be one of {list(_ROBUST)}, got {robust!r}")
        self.robust = robust
        for name, v, lo in (("scale", scale, 0.0), ("min_depth", min_depth, 0.0), ("tolerance", tolerance, 0.0),
                            ("lm_up", lm_up, 1.0)):
            if not lo < real_number(v) < math.inf:
                fail(fn, ValueError, f"argument '{name}' must be a finite number > {lo}, got {v!r}")
        for name, v in (("depth_weight", depth_weight), ("occlusion", occlusion), ("lm_lambda", lm_lambda),
                        ("depth_tolerance", depth_tolerance), ("take_step", take_step),
                        ("min_decrease", min_decrease)):
            if not 0.0 <= real_number(v) < math.inf:
                fail(fn, ValueError, f"argument '{name}' must be a finite number >= 0, got {v!r}")
        if not 0.0 < real_number(lm_down) <= 1.0:
            fail(fn, ValueError, f"argument 'lm_down' must be in (0, 1], got {lm_down!r}")
        if not 0.0 <= real_number(min_valid_fraction) <= 1.0:
            fail(fn, ValueError, f"argument 'min_valid_fraction' must be in [0, 1], got {min_valid_fraction!r}")
        self.scale = real_number(scale)
        self.depth_weight = real_number(depth_weight)
        self.occlusion = real_number(occlusion)
        self.min_depth = real_number(min_depth)
        self.color = bool(color)
        self.tolerance = real_number(tolerance)
        self.min_decrease = real_number(min_decrease)
        self.take_step = real_number(take_step)
        self.lm_lambda = real_number(lm_lambda)
        self.lm_up = real_number(lm_up)
        self.lm_down = real_number(lm_down)
        self.min_valid_fraction = real_number(min_valid_fraction)
        self.depth_tolerance = real_number(depth_tolerance)
        self._range_warned = False  # intensities beyond [0, 1] are reported once per aligner
        self._weights: dict[int, wp.array] = {}
        self._states: dict[tuple, LMState] = {}  # per (B, level shapes)
        self._frame_pool: dict[tuple, list] = {}  # per (B, C, H, W, with depth): free PyramidBuffers

    # ------------------------------------------------------------------------------ pyramids

    def _levels_for(self, H: int, W: int) -> int:
        n = 1
        if self.levels is None:  # auto: halve while the shorter side stays >= _AUTO_MIN_SIDE
            while min(H >> n, W >> n) >= _AUTO_MIN_SIDE:
                n += 1
            return n
        while n < self.levels and min(H >> n, W >> n) >= MIN_SIDE:
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
        return self._prepare("DirectAligner.prepare", "image", "depth", image, depth)

    def _prepare(self, fn: str, image_name: str, depth_name: str, image, depth, use_depth: bool = True) -> Frame:
        torch_in = is_torch(image)
        img = as_numpy(fn, image_name, image, (3, 4))
        batched = img.ndim == 4
        if not batched:
            img = img[None]
        B, C, H, W = img.shape
        if B < 1 or C < 1 or H < 1 or W < 1:
            fail(fn, ValueError, f"argument '{image_name}' must have no empty dimension, got shape {img.shape}")
        if B * C * H * W >= 2**31:
            fail(fn, ValueError, f"argument '{image_name}' is too large for int32 indexing: shape {img.shape}")
        hint = ""  # for shapes refused below that look like (H, W, C), as image libraries load images
        if W in (1, 3, 4) and C > 4:
            hint = (f", which looks channel-last {'(B, H, W, C)' if batched else '(H, W, C)'}: images are "
                    f"{'(B, C, H, W)' if batched else '(C, H, W)'} (numpy: transpose, torch: permute)")
        if H < MIN_SIDE or W < MIN_SIDE:
            fail(fn, ValueError, f"argument '{image_name}' must be at least {MIN_SIDE}x{MIN_SIDE} pixels, "
                  f"got shape {tuple(np.shape(image))}{hint}")
        if self.resample is not None and (H, W) != (self.resample.height, self.resample.width):
            fail(fn, ValueError, f"argument '{image_name}' must be {self.resample.width}x{self.resample.height} "
                                 f"pixels (the resampling table's source), got shape {tuple(np.shape(image))}")
        if depth is not None:
            d = as_numpy(fn, depth_name, depth, (4,) if batched else (2, 3))
            if not batched:  # ((H, W) taken as (1, H, W), as TSDFVolume.integrate takes a depth)
                d = d.reshape(1, *d.shape) if d.ndim == 3 else d[None, None]
            if d.shape != (B, 1, H, W):
                want = f"{(B, 1, H, W)}" if batched else f"{(1, H, W)} or {(H, W)}"
                also = f"; argument '{image_name}' has shape {tuple(np.shape(image))}{hint}" if hint else ""
                fail(fn, ValueError, f"argument '{depth_name}' must have shape {want}, got {tuple(depth.shape)}{also}")
        if not use_depth:
            depth = None  # checked, but not needed
        if not self._range_warned:  # 8-bit intensities run, but worse (the thresholds assume [0, 1])
            sample = img[..., ::7, ::7]  # (1/49 of the pixels: cheap beside the pyramid)
            top = float(np.nanmax(sample)) if np.isfinite(sample).any() else 0.0
            if top > INTENSITY_LIMIT:
                self._range_warned = True
                warnings.warn(f"gvnn_warp.odometry.{fn}: argument '{image_name}' has intensities up to {top:g}; "
                              "they are expected in [0, 1] (divide 8-bit images by 255), and accuracy suffers "
                              "otherwise",
                              UserWarning, stacklevel=3)
        key = (B, C, H, W, depth is not None)
        pool = self._frame_pool.setdefault(key, [])
        Ho, Wo = (H, W) if self.resample is None else (self.resample.out_height, self.resample.out_width)
        pyr = pool.pop() if pool else PyramidBuffers(B, C, H, W, depth is not None, levels=self._levels_for(Ho, Wo),
                                                     weights=self._channel_weights(C), color=self.color,
                                                     depth_tolerance=self.depth_tolerance, resample=self.resample)
        pyr.fill(np.ascontiguousarray(img, dtype=np.float32),
                 None if depth is None else np.ascontiguousarray(d, dtype=np.float32))
        frame = Frame(images=pyr.images, depths=pyr.depths, batched=batched, torch=torch_in)
        # the buffers go back to the pool when the frame is gone (a tracker drops one per frame)
        weakref.finalize(frame, recycle, pool, pyr)
        return frame

    # ------------------------------------------------------------------------------ alignment

    def align(self, ref_image, ref_depth, live_image, live_depth=None, init=None):
        """Estimate ``T`` (4, 4) / (B, 4, 4) float64 mapping reference-camera points into the live camera.

        Args:
            ref_image, live_image: (C, H, W) or (B, C, H, W) intensities.
            ref_depth: (1, H, W) (or (H, W)) or (B, 1, H, W) metres (0/NaN = none).
            live_depth: like ``ref_depth``; needed when ``depth_weight > 0``, used by the occlusion test.
            init: initial ``T`` ((4, 4) or (B, 4, 4); (3, 4) rows [R | t] also accepted), a rigid
                transform (R a rotation within 1e-3), e.g. a constant-velocity prediction;
                identity if None.

        Returns:
            ``(T, info)``: T of the kind of ``ref_image`` (numpy or torch), see the module docstring
            for ``info``.
        """
        fn = "DirectAligner.align"
        if ref_depth is None:
            fail(fn, ValueError, "argument 'ref_depth' must be given (the reference frame needs depth)")
        if live_depth is None and self.depth_weight > 0:
            fail(fn, ValueError, "argument 'live_depth' must be given when depth_weight > 0")
        ref = self._prepare(fn, "ref_image", "ref_depth", ref_image, ref_depth)
        live = self._prepare(fn, "live_image", "live_depth", live_image, live_depth,
                             self.depth_weight > 0 or self.occlusion > 0)
        if live.batched != ref.batched or live.images[0].shape != ref.images[0].shape:
            got = tuple(np.shape(live_image))
            want = tuple(ref.images[0].shape[:1] if ref.batched else ()) + (np.shape(ref_image)[-3],) + ref.shape
            fail(fn, ValueError, f"argument 'live_image' must have the shape of 'ref_image' {want}, got {got}")
        return self._align(fn, ref, live, init)

    def align_frames(self, ref: Frame, live: Frame, init=None):
        """:meth:`align` on two prepared frames (``ref`` needs depth; ``live`` needs depth when
        ``depth_weight > 0``); same results."""
        fn = "DirectAligner.align_frames"
        for name, f in (("ref", ref), ("live", live)):
            if not isinstance(f, Frame):
                fail(fn, TypeError, f"argument '{name}' must be a Frame from DirectAligner.prepare, got "
                      f"{type(f).__name__}")
        if ref.depths is None:
            fail(fn, ValueError, "argument 'ref' must be prepared with a depth")
        if self.depth_weight > 0 and live.depths is None:
            fail(fn, ValueError, "argument 'live' must be prepared with a depth when depth_weight > 0")
        if live.batched != ref.batched or tuple(live.images[0].shape) != tuple(ref.images[0].shape):
            fail(fn, ValueError, f"arguments 'ref' and 'live' must have the same shape, got "
                  f"{tuple(ref.images[0].shape)} and {tuple(live.images[0].shape)}")
        n_levels = self._levels_for(*ref.shape)
        grey_mismatch = not self.color and ref.images[0].shape[1] != 1
        if len(ref.images) != n_levels or len(live.images) != n_levels or grey_mismatch:
            fail(fn, ValueError, "arguments 'ref' and 'live' must be prepared by an aligner with these levels and "
                  "colour settings")
        return self._align(fn, ref, live, init)

    def _state(self, B: int, shapes) -> LMState:
        key = (B, tuple(shapes))
        st = self._states.get(key)
        if st is None:
            st = self._states[key] = LMState(self, B, shapes, OCCLUSION_LEVELS)
        return st

    def _align(self, fn: str, ref: Frame, live: Frame, init):
        B = ref.batch
        T0 = initial_pose(fn, init, B, ref.batched)
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
            import torch  # (only for torch input: the odometry never needs torch otherwise)

            out = torch.from_numpy(out)
        return out, info
