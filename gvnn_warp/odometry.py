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
   rejected (``lambda`` grows by ``lm_up``). Every trial is one fused pass over the level.
3. A level stops after ``iterations[l]`` trials, or when a step moves the image by less than
   ``tolerance`` pixels of that level: ``f_l (|omega| + |t| / z)`` with ``f_l`` the level's focal
   length and ``z`` the mean valid reference depth, or when ``lambda`` exceeds ``1e8`` (no step
   lowers the cost).

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

Import needs no torch; torch is imported only when a tensor comes in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from .kernels import launch as _launch
from .kernels import pyramid as _pyramid
from .kernels.camera import MIN_DEPTH

__all__ = ["DirectAligner", "Frame"]

_LUMA = (0.299, 0.587, 0.114)
_ROBUST = ("huber", "cauchy", "geman_mcclure", "tukey", "l2")
_MIN_SIDE = 4  # smallest side (pixels) of a pyramid level
_MIN_VALID_PIXELS = 24  # below this a level's system is not trusted, whatever the fraction
_LAMBDA_MAX = 1e8


def _fail(fn: str, exc: type[Exception], msg: str):
    raise exc(f"gvnn_warp.odometry.{fn}: {msg}")


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


def _so3_exp(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(B, 3) rotation vectors -> (R (B, 3, 3), V (B, 3, 3)) of the SE(3) exponential."""
    th2 = (w * w).sum(-1)
    th = np.sqrt(th2)
    small = th2 < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(ths)) / (ths * ths))
    c = np.where(small, 1.0 / 6.0 - th2 / 120.0, (ths - np.sin(ths)) / (ths * ths * ths))
    z = np.zeros_like(th)
    Wx = np.stack([z, -w[:, 2], w[:, 1], w[:, 2], z, -w[:, 0], -w[:, 1], w[:, 0], z], -1).reshape(-1, 3, 3)
    W2 = Wx @ Wx
    eye = np.eye(3)
    R = eye + a[:, None, None] * Wx + b[:, None, None] * W2
    V = eye + b[:, None, None] * Wx + c[:, None, None] * W2
    return R, V


def _se3_exp(delta: np.ndarray) -> np.ndarray:
    """(B, 6) twists [omega, t] -> (B, 4, 4) exp."""
    R, V = _so3_exp(delta[:, :3])
    T = np.zeros((delta.shape[0], 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = (V @ delta[:, 3:, None])[..., 0]
    T[:, 3, 3] = 1.0
    return T


class DirectAligner:
    """Coarse-to-fine direct (photometric) RGB-D alignment, see the module docstring.

    Args:
        K: (3, 3) intrinsics of the finest level (numpy or torch; float64 internally).
        levels: pyramid levels (1 = no pyramid); fewer are used if a level would have a side
            below 4 pixels.
        iterations: trials (normal-equation passes) per level: an int for every level, or a
            sequence from the finest level (index 0) to the coarsest.
        robust: the M-estimator of the residuals: "huber", "cauchy", "geman_mcclure", "tukey"
            (as in ``robust_rho``) or "l2".
        scale: the M-estimator's scale (in intensity units).
        depth_weight: weight of the depth term (the moved point's z against the live depth); > 0
            needs live depths.
        min_depth: depths at or below it count as missing (metres).
        color: keep every colour channel in the residual (C per pixel) instead of one intensity.
        tolerance: a level stops when a step moves the image by less than this many pixels.
        lm_lambda: initial Levenberg-Marquardt damping (relative to diag(JtWJ)); ``lm_up`` /
            ``lm_down``: its growth after a rejected / shrink after an accepted step.
        min_valid_fraction: fewest valid pixels (fraction of the level's) to trust a level.
        depth_tolerance: the relative depth spread that counts as one surface when depths are
            downsampled (see :mod:`gvnn_warp.kernels.pyramid`).
    """

    def __init__(
        self,
        K,
        *,
        levels: int = 4,
        iterations=(4, 6, 10, 20),
        robust: str = "huber",
        scale: float = 0.05,
        depth_weight: float = 0.0,
        min_depth: float = MIN_DEPTH,
        color: bool = False,
        tolerance: float = 0.01,
        lm_lambda: float = 1e-4,
        lm_up: float = 4.0,
        lm_down: float = 0.25,
        min_valid_fraction: float = 0.05,
        depth_tolerance: float = _pyramid.DEPTH_TOLERANCE,
    ):
        fn = "DirectAligner"
        K = _as_numpy(fn, "K", K, (2,)).astype(np.float64)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            _fail(fn, ValueError, f"argument 'K' must be finite (3, 3) intrinsics with fx, fy > 0, got {K.tolist()}")
        self.K = K
        if not isinstance(levels, (int, np.integer)) or isinstance(levels, bool) or levels < 1:
            _fail(fn, ValueError, f"argument 'levels' must be an int >= 1, got {levels!r}")
        self.levels = int(levels)
        if isinstance(iterations, (int, np.integer)) and not isinstance(iterations, bool):
            iterations = (int(iterations),) * self.levels
        try:
            iterations = tuple(int(i) for i in iterations)
        except (TypeError, ValueError):
            _fail(fn, TypeError, f"argument 'iterations' must be an int or a sequence of ints, got {iterations!r}")
        if not iterations or min(iterations) < 0:
            _fail(fn, ValueError, f"argument 'iterations' must be >= 0, got {iterations!r}")
        # shorter sequences repeat their last (coarsest) entry
        self.iterations = tuple(iterations[min(k, len(iterations) - 1)] for k in range(self.levels))
        if robust not in _ROBUST:
            _fail(fn, ValueError, f"argument 'robust' must be one of {list(_ROBUST)}, got {robust!r}")
        self.robust = robust
        for name, v, lo in (("scale", scale, 0.0), ("min_depth", min_depth, 0.0), ("tolerance", tolerance, 0.0),
                            ("lm_up", lm_up, 1.0)):
            if not (isinstance(v, (int, float)) and lo < v < math.inf):
                _fail(fn, ValueError, f"argument '{name}' must be a finite number > {lo}, got {v!r}")
        for name, v in (("depth_weight", depth_weight), ("lm_lambda", lm_lambda),
                        ("depth_tolerance", depth_tolerance)):
            if not (isinstance(v, (int, float)) and 0.0 <= v < math.inf):
                _fail(fn, ValueError, f"argument '{name}' must be a finite number >= 0, got {v!r}")
        if not (isinstance(lm_down, (int, float)) and 0.0 < lm_down <= 1.0):
            _fail(fn, ValueError, f"argument 'lm_down' must be in (0, 1], got {lm_down!r}")
        if not (isinstance(min_valid_fraction, (int, float)) and 0.0 <= min_valid_fraction <= 1.0):
            _fail(fn, ValueError, f"argument 'min_valid_fraction' must be in [0, 1], got {min_valid_fraction!r}")
        self.scale = float(scale)
        self.depth_weight = float(depth_weight)
        self.min_depth = float(min_depth)
        self.color = bool(color)
        self.tolerance = float(tolerance)
        self.lm_lambda = float(lm_lambda)
        self.lm_up = float(lm_up)
        self.lm_down = float(lm_down)
        self.min_valid_fraction = float(min_valid_fraction)
        self.depth_tolerance = float(depth_tolerance)
        self._weights: dict[int, wp.array] = {}
        self._buffers: dict[tuple, dict] = {}  # per (B, H, W, C'): K per level, pose, outputs

    # ------------------------------------------------------------------------------ pyramids

    def _levels_for(self, H: int, W: int) -> int:
        n = 1
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

    def _prepare(self, fn: str, image_name: str, depth_name: str, image, depth) -> Frame:
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
        if H < _MIN_SIDE or W < _MIN_SIDE:
            _fail(fn, ValueError, f"argument '{image_name}' must be at least {_MIN_SIDE}x{_MIN_SIDE} pixels, "
                  f"got shape {img.shape}")
        if depth is not None:
            d = _as_numpy(fn, depth_name, depth, (4,) if batched else (3,))
            if not batched:
                d = d[None]
            if d.shape != (B, 1, H, W):
                want = (B, 1, H, W) if batched else (1, H, W)
                _fail(fn, ValueError, f"argument '{depth_name}' must have shape {want}, got {tuple(depth.shape)}")
        n_levels = self._levels_for(H, W)
        shapes = _pyramid.pyramid_shapes(H, W, n_levels)
        Co = C if self.color else 1
        images = [wp.empty((B, Co, h, w), dtype=wp.float32, device="cpu") for h, w in shapes]
        depths = None if depth is None else [wp.empty((B, 1, h, w), dtype=wp.float32, device="cpu") for h, w in shapes]
        src = wp.array(np.ascontiguousarray(img, dtype=np.float32), dtype=wp.float32, device="cpu")
        empty = images[0].flatten()[:0]
        dsrc = empty if depth is None else wp.array(np.ascontiguousarray(d, dtype=np.float32), dtype=wp.float32,
                                                     device="cpu")
        _launch.launch(
            _pyramid.level0_kernel[wp.float32], B * H * W,
            [src.flatten(), self._channel_weights(C).flatten(), dsrc.flatten(), C, Co, H * W, int(depth is not None)],
            [images[0].flatten(), empty if depths is None else depths[0].flatten()],
        )
        for k in range(1, n_levels):
            (h, w), (ho, wo) = shapes[k - 1], shapes[k]
            _launch.launch(
                _pyramid.downsample_kernel[wp.float32], B * ho * wo,
                [images[k - 1].flatten(), empty if depths is None else depths[k - 1].flatten(), Co, h, w, ho, wo,
                 self.depth_tolerance, int(depths is not None)],
                [images[k].flatten(), empty if depths is None else depths[k].flatten()],
            )
        return Frame(images=images, depths=depths, batched=batched, torch=torch_in)

    # ------------------------------------------------------------------------------ alignment

    def align(self, ref_image, ref_depth, live_image, live_depth=None, init=None):
        """Estimate ``T`` (4, 4) / (B, 4, 4) float64 mapping reference-camera points into the live camera.

        Args:
            ref_image, live_image: (C, H, W) or (B, C, H, W) intensities.
            ref_depth: (1, H, W) or (B, 1, H, W) metres (0/NaN = none).
            live_depth: like ``ref_depth``; needed only when ``depth_weight > 0``.
            init: initial ``T`` ((4, 4) or (B, 4, 4); (3, 4) rows [R | t] also accepted), e.g. a
                constant-velocity prediction; identity if None.

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
        live = self._prepare(fn, "live_image", "live_depth", live_image,
                             live_depth if self.depth_weight > 0 else None)
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
        if live.batched != ref.batched or tuple(live.images[0].shape) != tuple(ref.images[0].shape) or len(
            live.images
        ) != len(ref.images):
            _fail(fn, ValueError, f"arguments 'ref' and 'live' must have the same shape, got "
                  f"{tuple(ref.images[0].shape)} and {tuple(live.images[0].shape)}")
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
        out = np.broadcast_to(np.eye(4), (B, 4, 4)).copy()
        out[:, :3, :] = T[:, :3, :]
        return out

    def _level_buffers(self, B: int, shapes) -> dict:
        key = (B, tuple(shapes))
        buf = self._buffers.get(key)
        if buf is None:
            Ks = []
            for level in range(len(shapes)):
                Kl = _pyramid.scale_intrinsics(self.K, level).astype(np.float32)
                Ks.append(wp.array(np.broadcast_to(Kl, (B, 3, 3)).copy(), dtype=wp.mat33f, device="cpu"))
            pose = wp.zeros(B, dtype=_launch.mat34f, device="cpu")
            buf = {"K": Ks, "pose": pose, "pose_np": pose.numpy().reshape(B, 3, 4),
                   "f": [float(np.sqrt(abs(_pyramid.scale_intrinsics(self.K, k)[0, 0] *
                                           _pyramid.scale_intrinsics(self.K, k)[1, 1]))) for k in range(len(shapes))]}
            buf["system"] = self._make_system(B, shapes)
            self._buffers[key] = buf
        return buf

    def _make_system(self, B: int, shapes):
        """Returns ``system(ref, live, level, pose, K) -> (JtWJ (B, 6, 6), JtWr (B, 6), cost (B,),
        count (B,))`` as float64 numpy, evaluated by the fused Warp normal equations."""
        from .kernels import photometric_normal_equations

        def system(ref: Frame, live: Frame, level: int, pose: wp.array, K: wp.array):
            JtWJ, JtWr, cost, count = photometric_normal_equations(
                ref.images[level], ref.depths[level], live.images[level], pose, K,
                robust=self.robust, scale=self.scale,
                live_depth=live.depths[level] if self.depth_weight > 0 else None,
                depth_weight=self.depth_weight, min_depth=self.min_depth,
            )
            return (JtWJ.numpy().astype(np.float64).reshape(B, 6, 6), JtWr.numpy().astype(np.float64).reshape(B, 6),
                    cost.numpy().astype(np.float64).reshape(B), count.numpy().astype(np.float64).reshape(B))

        return system

    def _align(self, fn: str, ref: Frame, live: Frame, init):
        B = ref.batch
        T = self._init_pose(fn, init, B, ref.batched)
        T0 = T.copy()
        shapes = [(int(a.shape[2]), int(a.shape[3])) for a in ref.images]
        n_levels = len(shapes)
        buf = self._level_buffers(B, shapes)
        system = buf["system"]
        pose_np = buf["pose_np"]
        pose = buf["pose"]
        zmean = ref.mean_depth()
        eye6 = np.eye(6)
        level_info = []
        last_step = np.full(B, np.inf)
        stopped = np.zeros(B, dtype=bool)
        valid_ok = np.zeros(B, dtype=bool)
        for level in range(n_levels - 1, -1, -1):
            h, w = shapes[level]
            n_pix = float(h * w)
            min_count = max(_MIN_VALID_PIXELS, self.min_valid_fraction * n_pix)
            K = buf["K"][level]
            f = buf["f"][level]
            pose_np[:] = T[:, :3, :]
            H, g, cost, count = system(ref, live, level, pose, K)
            mean = cost / np.maximum(count, 1.0)
            ok = count >= min_count
            active = ok.copy()
            lam = np.full(B, self.lm_lambda)
            trials = np.zeros(B, dtype=np.int64)
            last_step = np.full(B, np.inf)
            stopped = np.zeros(B, dtype=bool)
            for _ in range(self.iterations[level]):
                if not active.any():
                    break
                diag = np.diagonal(H, axis1=1, axis2=2)
                A = H + (lam[:, None] * diag)[:, :, None] * eye6 + 1e-12 * (diag.sum(1) + 1.0)[:, None, None] * eye6
                try:
                    delta = -np.linalg.solve(A, g[..., None])[..., 0]
                except np.linalg.LinAlgError:
                    delta = np.zeros((B, 6))
                good = np.all(np.isfinite(delta), axis=1)
                delta = np.where((active & good)[:, None], delta, 0.0)
                step = f * (np.sqrt((delta[:, :3] ** 2).sum(1)) + np.sqrt((delta[:, 3:] ** 2).sum(1)) / zmean)
                Tn = _se3_exp(delta) @ T
                pose_np[:] = Tn[:, :3, :]
                Hn, gn, costn, countn = system(ref, live, level, pose, K)
                meann = costn / np.maximum(countn, 1.0)
                accept = active & good & (countn >= min_count) & (meann < mean)
                if accept.any():
                    T[accept] = Tn[accept]
                    H[accept] = Hn[accept]
                    g[accept] = gn[accept]
                    mean[accept] = meann[accept]
                    count[accept] = countn[accept]
                lam = np.where(accept, lam * self.lm_down, np.where(active, lam * self.lm_up, lam))
                trials += active
                last_step = np.where(active, step, last_step)
                done = active & ((step < self.tolerance) | (lam > _LAMBDA_MAX) | ~good)
                stopped |= done
                active &= ~done
            valid_ok = ok
            level_info.append({"level": level, "size": (h, w), "iterations": trials if ref.batched else int(trials[0]),
                               "cost": mean if ref.batched else float(mean[0]),
                               "valid_fraction": count / n_pix if ref.batched else float(count[0] / n_pix)})
        converged = valid_ok & (last_step < 10.0 * self.tolerance)
        # items that never had enough valid pixels keep their initial pose
        T = np.where(np.isfinite(T).all(axis=(1, 2))[:, None, None], T, T0)
        info = {"converged": converged if ref.batched else bool(converged[0]), "levels": level_info}
        out = T if ref.batched else T[0]
        if ref.torch:
            import torch

            out = torch.from_numpy(out)
        return out, info
