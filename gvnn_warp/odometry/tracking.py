"""Frame-to-frame and keyframe visual odometry over a sequence, with any pairwise RGB-D aligner (numpy).

The aligner is anything with ``prepare(image, depth) -> frame`` (build what is reused for every
pair a frame takes part in, e.g. its image pyramid) and ``align_frames(ref_frame, live_frame,
init=None) -> (T_live_ref (4, 4), info)``, or with only ``align(ref_image, ref_depth, live_image,
live_depth=None, init=None) -> (T_live_ref, info)`` (``gvnn_warp.odometry.DirectAligner``;
:func:`frame_aligner` adapts it). ``T_live_ref`` maps reference-camera points into the live
camera; ``info`` may hold ``converged`` (bool) and the valid fraction of the finest level.

Poses are chained as ``T_world_live = T_world_ref @ inv(T_live_ref)``.

Pipelining: an aligner whose ``concurrent_prepare`` attribute is true (``DirectAligner``) may
``prepare`` one frame while it aligns other, already prepared frames. The tracker then prepares
frame i on a helper thread while it aligns frame i - 1 to its reference, so the core that the
alignment's serial parts leave idle builds the next pyramid; each frame's pose is known one
:meth:`Tracker.add` later (:meth:`Tracker.result` aligns the last one). The poses are those of the
sequential order, bit for bit (the same calls on the same frames); only the time changes, and every
call returns only when its work is done, so nothing of it runs during another tracker's turn.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..progress import progress_bar
from .inputs import rigid_pose

__all__ = [
    "INITS",
    "check_init",
    "KeyframePolicy",
    "TrackingStopped",
    "TrackResult",
    "Tracker",
    "frame_aligner",
    "info_converged",
    "info_valid_fraction",
    "track",
]


@dataclass(frozen=True)
class KeyframePolicy:
    """When to replace the reference (keyframe): after a frame is aligned to it, that frame becomes
    the new reference if its motion from the reference exceeds ``max_trans_m`` metres or
    ``max_rot_deg`` degrees, or if fewer than ``min_valid`` of the reference's pixels were usable
    (valid depth, inside the live image), or if the alignment did not converge."""

    max_trans_m: float = 0.05
    max_rot_deg: float = 2.0
    min_valid: float = 0.6


class TrackingStopped(InputError):
    """A frame that could not be read stopped :func:`track`: ``frame`` is its index, ``result`` the
    :class:`TrackResult` of the frames before it, ``__cause__`` the reader's error (whose message
    this one repeats)."""

    def __init__(self, frame: int, result: TrackResult, cause: Exception):
        super().__init__(str(cause))
        self.frame, self.result = frame, result


@dataclass
class TrackResult:
    """The outcome of :func:`track` over N frames.

    Attributes:
        poses: (N, 4, 4) estimated ``T_world_cam``; ``poses[0]`` is the start pose.
        reference: (N,) the frame each frame was aligned to (-1 for frame 0).
        converged: (N,) bool, the aligner's ``converged`` flag (True for frame 0).
        finite: (N,) bool, False where the aligner returned a non-finite pose (the initial guess
            was used instead).
        valid_fraction: (N,) the finest level's valid fraction (NaN when unknown / frame 0).
        seconds: (N,) time per frame in ``prepare`` + ``align_frames`` (file reading excluded;
            ``seconds[0]`` is frame 0's ``prepare``). When pipelined, ``seconds[i]`` for i >= 3 is
            the time of the step that prepared frame i and aligned frame i - 1 (the last entry
            also the last frame's alignment); frame 1 is prepared and aligned alone, and
            ``seconds[2]`` is frame 2's ``prepare``. The sum, hence ``ms_per_pair``, is the whole
            time.
        keyframes: frames used as references, in order.
        infos: the aligner's ``info`` per frame (None for frame 0).
    """

    poses: np.ndarray
    reference: np.ndarray
    converged: np.ndarray
    finite: np.ndarray
    valid_fraction: np.ndarray
    seconds: np.ndarray
    keyframes: list[int] = field(default_factory=list)
    infos: list = field(default_factory=list, repr=False)

    @property
    def pairs(self) -> int:
        return max(self.poses.shape[0] - 1, 0)

    @property
    def ms_per_pair(self) -> float:
        """Mean alignment time per frame pair (ms), all prepares included."""
        return 1e3 * float(self.seconds.sum()) / self.pairs if self.pairs else float("nan")

    @property
    def unconverged_frames(self) -> list[int]:
        """Frames whose alignment did not converge or returned a non-finite pose."""
        return [int(i) for i in np.flatnonzero(~(self.converged & self.finite))]


def _info_value(info, key):
    value = info.get(key) if isinstance(info, dict) else getattr(info, key, None)
    if isinstance(value, (list, tuple)):
        value = value[-1] if value else None
    elif isinstance(value, np.ndarray) and value.ndim:
        value = value.reshape(-1)[-1] if value.size else None
    return value


def info_converged(info) -> bool:
    """The ``converged`` flag of an aligner's info (True when it reports none)."""
    value = _info_value(info, "converged")
    return True if value is None else bool(value)


def info_valid_fraction(info) -> float:
    """The finest level's valid fraction of an aligner's info (NaN when it reports none); the last
    entry of a per-level list is taken as the finest."""
    for key in ("valid_fraction", "valid", "fitness"):
        value = _info_value(info, key)
        if value is not None:
            return float(value)
    levels = info.get("levels") if isinstance(info, dict) else None
    if levels:
        finest = levels[-1] if isinstance(levels, (list, tuple)) else None
        if isinstance(finest, dict) and "valid_fraction" in finest:
            return float(finest["valid_fraction"])
    return float("nan")


class _AlignAdapter:
    """``prepare`` / ``align_frames`` over an aligner that only has ``align``."""

    def __init__(self, aligner):
        self.aligner = aligner

    def prepare(self, image, depth):
        return image, depth

    def align_frames(self, ref, live, init=None):
        return self.aligner.align(ref[0], ref[1], live[0], live[1], init=init)


def frame_aligner(aligner):
    """``aligner`` itself if it has ``prepare`` and ``align_frames``, else an adapter over its ``align``."""
    if hasattr(aligner, "prepare") and hasattr(aligner, "align_frames"):
        return aligner
    if hasattr(aligner, "align"):
        return _AlignAdapter(aligner)
    raise TypeError(f"track: aligner must have prepare/align_frames or align, got {type(aligner).__name__}")


def _inv(T: np.ndarray) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def _motion(T: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation deg) of a rigid motion."""
    cos = np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(T[:3, 3])), math.degrees(math.acos(cos))


_PREPARE_POOL: ThreadPoolExecutor | None = None
_PREPARE_POOL_LOCK = threading.Lock()
INITS = ("identity", "velocity")  # an alignment's initial guess: see track's ``init``


def check_init(fn: str, init) -> None:
    """ValueError naming ``fn`` unless ``init`` is one of :data:`INITS`."""
    if init not in INITS:
        raise ValueError(f"{fn}: argument 'init' must be one of {', '.join(map(repr, INITS))}, got {init!r}")


def _prepare_pool() -> ThreadPoolExecutor:
    """The one helper thread that pipelined trackers prepare frames on (made on first use)."""
    global _PREPARE_POOL
    with _PREPARE_POOL_LOCK:
        if _PREPARE_POOL is None:
            _PREPARE_POOL = ThreadPoolExecutor(1, thread_name_prefix="gvnn_warp-prepare")
        return _PREPARE_POOL


class Tracker:
    """Odometry one frame at a time: :meth:`add` each frame in order, then :meth:`result`.

    Arguments as :func:`track` (which is a loop over this); ``n_frames`` sizes the result arrays.
    Stepping two trackers alternately compares two aligners under the same machine load (each
    :meth:`add` returns only when its work is done, pipelined or not).
    """

    def __init__(self, aligner, n_frames: int, *, start_pose: np.ndarray | None = None,
                 keyframes: KeyframePolicy | None = None, init: str = "identity", warmup: bool = True,
                 pipeline: bool | None = None):
        check_init("track", init)
        if n_frames < 1:
            raise ValueError(f"track: need at least one frame, got {n_frames}")
        self.fa = frame_aligner(aligner)
        if pipeline is None:
            pipeline = bool(getattr(self.fa, "concurrent_prepare", False))
        self.pipeline = pipeline
        self.pending = None  # pipelined: (index, prepared frame) not aligned yet
        self.keyframes, self.init, self.warmup = keyframes, init, warmup
        self.n = 0
        self.poses = np.empty((n_frames, 4, 4))
        self.poses[0] = np.eye(4) if start_pose is None else rigid_pose(
            "gvnn_warp.odometry.tracking.track", "start_pose", start_pose)
        self.reference = np.full(n_frames, -1, dtype=np.int64)
        self.converged = np.ones(n_frames, dtype=bool)
        self.finite = np.ones(n_frames, dtype=bool)
        self.valid = np.full(n_frames, np.nan)
        self.seconds = np.zeros(n_frames)
        self.infos: list = []
        self.kf: list[int] = []

    def add(self, image, depth) -> None:
        """Process the next frame: prepare it and (from the second frame on) align it to the
        reference; pipelined, align the previous frame while this one is prepared."""
        fa, i = self.fa, self.n
        if i >= self.poses.shape[0]:
            raise IndexError(f"track: more than the {self.poses.shape[0]} frames announced")
        if i > 1 and self.pipeline:  # (frame 1 alone: its alignment loads the kernels, not worth overlapping)
            t = time.perf_counter()
            job = _prepare_pool().submit(fa.prepare, image, depth)
            pending, self.pending = self.pending, None
            try:
                if pending is not None:
                    self._align(*pending)
            finally:
                live_frame = job.result()  # also when the alignment failed: no work left running
            self.pending = (i, live_frame)
            self.seconds[i] = time.perf_counter() - t
            self.n += 1
            return
        if i == 0:
            if self.warmup:  # untimed: one-off costs (compiled kernels, buffers) out of the first pairs' times
                eye = np.eye(4)
                frames = [fa.prepare(image, depth), fa.prepare(image, depth)]
                fa.align_frames(frames[0], frames[1], init=eye)  # loads the kernels: alone, before the helper thread
                if self.pipeline:  # the helper thread, and a third frame's buffers as the pipeline has it
                    job = _prepare_pool().submit(fa.prepare, image, depth)
                    fa.align_frames(frames[1], frames[0], init=eye)
                    frames.append(job.result())
                for ref in frames:  # what the aligner keeps per pair of frame buffers, for every pair
                    for live in frames:
                        if live is not ref:
                            fa.align_frames(ref, live, init=eye)
                del frames
            t = time.perf_counter()
            self.ref_frame = fa.prepare(image, depth)
            self.seconds[0] = time.perf_counter() - t
            self.ref_index, self.kf = 0, [0]
            self.T_world_ref = self.poses[0]
            self.T_prev_ref = np.eye(4)  # previous frame relative to the reference
            self.step = np.eye(4)  # previous frame-to-frame motion T_{i-1, i-2}
            self.infos.append(None)
            self.n = 1
            return
        t = time.perf_counter()
        self._align(i, fa.prepare(image, depth))
        self.seconds[i] = time.perf_counter() - t
        self.n += 1

    def _align(self, i: int, live_frame) -> None:
        """Align prepared frame i to the reference; its pose, flags and the next reference."""
        guess = self.T_prev_ref if self.init == "identity" else self.step @ self.T_prev_ref
        T_live_ref, info = self.fa.align_frames(self.ref_frame, live_frame, init=guess)
        T_live_ref = np.asarray(T_live_ref, dtype=np.float64).reshape(4, 4)
        self.infos.append(info)
        self.reference[i] = self.ref_index
        self.converged[i] = info_converged(info)
        self.valid[i] = info_valid_fraction(info)
        if not np.all(np.isfinite(T_live_ref)):
            self.finite[i] = False
            T_live_ref = guess
        self.poses[i] = self.T_world_ref @ _inv(T_live_ref)
        self.step = T_live_ref @ _inv(self.T_prev_ref)
        self.T_prev_ref = T_live_ref
        kf = self.keyframes
        if kf is None:
            new_ref = True
        else:
            trans, rot = _motion(T_live_ref)
            new_ref = (trans > kf.max_trans_m or rot > kf.max_rot_deg or self.valid[i] < kf.min_valid
                       or not (self.converged[i] and self.finite[i]))
        if new_ref:
            self.ref_frame, self.ref_index, self.T_world_ref = live_frame, i, self.poses[i]
            self.T_prev_ref = np.eye(4)
            if kf is not None:
                self.kf.append(i)

    @property
    def ms_per_pair(self) -> float:
        return 1e3 * float(self.seconds[: self.n].sum()) / max(self.n - 1, 1)

    def finish(self) -> None:
        """Pipelined: align the last frame added (its time joins that frame's). Called by :meth:`result`."""
        if self.pending is not None:
            i, live_frame = self.pending
            self.pending = None
            t = time.perf_counter()
            self._align(i, live_frame)
            self.seconds[i] += time.perf_counter() - t

    def result(self) -> TrackResult:
        """The result over the frames added so far."""
        self.finish()
        n = self.n
        kf = list(range(max(n - 1, 1))) if self.keyframes is None else list(self.kf)
        return TrackResult(self.poses[:n].copy(), self.reference[:n].copy(), self.converged[:n].copy(),
                           self.finite[:n].copy(), self.valid[:n].copy(), self.seconds[:n].copy(), kf,
                           list(self.infos))


def track(
    read_frame: Callable[[int], tuple[np.ndarray, np.ndarray]],
    n_frames: int,
    aligner,
    *,
    start_pose: np.ndarray | None = None,
    keyframes: KeyframePolicy | None = None,
    init: str = "identity",
    progress: bool = True,
    desc: str = "track",
    warmup: bool = True,
    pipeline: bool | None = None,
) -> TrackResult:
    """Estimate the camera trajectory of ``n_frames`` frames by aligning each to a reference frame.

    Args:
        read_frame: ``i -> (image (C, H, W), depth (1, H, W) metres)``; not timed.
        n_frames: number of frames.
        aligner: see the module docstring.
        start_pose: ``T_world_cam`` of frame 0 (default identity).
        keyframes: None for frame-to-frame odometry (each frame's reference is the previous one),
            else the policy that decides when the reference is replaced.
        init: the initial guess of each alignment: ``"identity"`` (the live frame is where the
            previous frame was) or ``"velocity"`` (constant velocity: the previous frame-to-frame
            motion repeated).
        progress: show a tqdm progress bar (frames per second, ms per pair).
        warmup: first align frame 0 with itself, untimed, so that one-off costs (loading compiled
            kernels, allocating buffers) are not counted as the first pair's time.
        pipeline: prepare each frame on a helper thread while the previous one is aligned (see the
            module docstring; the same poses). None (default): when the aligner allows it
            (``concurrent_prepare``).

    A frame i >= 1 that ``read_frame`` cannot read (``gvnn_warp.errors.InputError``, e.g. an image
    whose pixels do not decode) raises :class:`TrackingStopped` holding the result of frames 0 to i - 1.
    """
    tracker = Tracker(aligner, n_frames, start_pose=start_pose, keyframes=keyframes, init=init, warmup=warmup,
                      pipeline=pipeline)
    # frame 0 (with the warm-up, which loads or first compiles the kernels) before the bar, so that
    # a compile notice is not printed into it and its rate counts tracked frames only (the Tracker
    # has refused n_frames < 1)
    tracker.add(*read_frame(0))
    with progress_bar(total=n_frames, initial=1, unit="frame", disable=not progress, desc=desc,
                      dynamic_ncols=True) as bar:
        for i in range(1, n_frames):
            try:
                frame = read_frame(i)
            except InputError as e:
                raise TrackingStopped(i, tracker.result(), e) from e
            tracker.add(*frame)
            bar.update(1)
            if progress and (i % 10 == 0 or i == n_frames - 1):
                bar.set_postfix_str(f"{tracker.ms_per_pair:.1f} ms/pair", refresh=False)
    return tracker.result()
