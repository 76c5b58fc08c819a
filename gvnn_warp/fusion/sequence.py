"""A TUM sequence fused into a :class:`~.volume.TSDFVolume`: after tracking, or while tracking
against the model (what ``gvnn-warp track --fuse`` / ``--model`` run; no torch).

- :func:`fuse_sequence`: every frame integrated at its estimated pose;
- :class:`ModelTracker`: frame-to-model tracking (KinectFusion's loop): each new frame is aligned
  by the direct aligner to the model raycast at the previous frame's pose (its depth, and its
  colour or the grey of it, as the reference frame), then integrated at the pose found. The model
  averages every earlier frame, so the reference is less noisy than the previous frame and errors
  do not chain from frame to frame as they do in frame-to-frame odometry. :class:`FrameToModel`
  is the same one frame at a time, for frames the caller holds;
- :func:`render_picture`: a PNG of the model raycast from a pose, its colour shaded by the normals.

:func:`fuse_sequence` and :class:`ModelTracker` take each frame's depth from the sequence's depth
files, or from ``depth``, a callable ``image (3, H, W) RGB -> depth (1, H, W)``
(``gvnn_warp.depth.predict.DepthPredictor``: monocular depth, whose units are then the map's:
voxel size and truncation are in them too).
"""

from __future__ import annotations

import contextlib
import time
import warnings
from pathlib import Path

import numpy as np

from ..datasets.images import to_gray
from ..datasets.tum import TUMSequence
from ..errors import InputError
from ..odometry.inputs import INTENSITY_LIMIT, as_numpy, fail, is_torch, rigid_pose
from ..odometry.tracking import TrackingStopped, TrackResult, check_init, info_converged, info_valid_fraction
from ..progress import progress_bar
from .volume import IntegrateReport, MapFull, TSDFVolume

__all__ = ["FrameToModel", "FuseReport", "ModelTracker", "camera_of", "fuse_sequence", "render_picture"]


def camera_of(seq: TUMSequence):
    """The camera of a sequence as :class:`TSDFVolume` takes it: K, or (K, radial-tangential dist)."""
    return seq.K if seq.dist is None else (seq.K, seq.dist)


class FuseReport:
    """Fusion statistics: frames integrated, frames skipped (no valid depth), seconds spent integrating."""

    def __init__(self):
        self.integrated, self.skipped, self.seconds = 0, [], 0.0

    def add(self, frame: int, report: IntegrateReport, seconds: float) -> None:
        self.seconds += seconds
        if report.valid_pixels == 0:
            self.skipped.append(frame)
        else:
            self.integrated += 1

    @property
    def ms_per_frame(self) -> float:
        n = self.integrated + len(self.skipped)
        return 1000.0 * self.seconds / max(n, 1)


def _frame(seq: TUMSequence, i: int, depth=None) -> tuple[np.ndarray, np.ndarray]:
    """(colour (3, H, W), depth (1, H, W)) of frame ``i``: the depth file's, or ``depth(colour)``."""
    rgb = seq.image(i)
    return rgb, (seq.depth(i) if depth is None else depth(rgb))


def fuse_sequence(volume: TSDFVolume, seq: TUMSequence, poses: np.ndarray, *, depth=None,
                  progress: bool = True) -> FuseReport:
    """Integrate frames 0 .. len(poses) - 1 of ``seq`` at ``poses`` (N, 4, 4) ``T_world_cam``;
    frames whose pose is not finite are skipped (reported), as are frames with no valid depth.
    ``depth``: see the module docstring."""
    report = FuseReport()
    camera = camera_of(seq)
    for i in progress_bar(range(len(poses)), desc="fuse", unit="frame", disable=not progress):
        if not np.all(np.isfinite(poses[i])):
            report.skipped.append(i)
            continue
        colour, frame_depth = _frame(seq, i, depth)
        s = time.perf_counter()
        r = volume.integrate(frame_depth, colour, camera, poses[i])
        report.add(i, r, time.perf_counter() - s)
    return report


class FrameToModel:
    """Frame-to-model tracking one frame at a time (see the module docstring), for frames the caller
    holds: :meth:`add` each frame in order (colour (3, H, W) in [0, 1], depth (1, H, W) metres), then
    :meth:`result` (a :class:`TrackResult`). The first frame is integrated at ``start_pose`` (a rigid
    (4, 4) ``T_world_cam``; identity if None); each later one is aligned to the model raycast at the
    previous frame's pose, starting from the depth integrated there, then integrated at the pose
    found. ``aligner``: a ``DirectAligner`` (or anything with its ``align``) for the same camera and
    images, grey or, with ``color``, RGB; ``init`` as :class:`ModelTracker`'s; ``camera``: as
    :meth:`TSDFVolume.integrate` takes it, for ``height`` x ``width`` frames (a pinhole K whose
    principal point lies outside them is refused, as is a plain ``DirectAligner`` with another K);
    ``volume``: the model, normally empty; ``n_frames`` sizes the result.

    ``seconds`` per frame count the raycast, the alignment and the integration (frame 0: 0);
    ``integrate_seconds`` the integration alone; ``fuse`` holds the integrations' statistics. A frame
    with no depth in the volume's range changes nothing in the map (``fuse.skipped``; a warning
    with ``warn``, once). A map that outgrows the volume's memory raises ``MapFull`` from
    :meth:`add`, nothing of that frame kept. Stepping it alternately with a frame-to-frame
    :class:`~gvnn_warp.odometry.tracking.Tracker` compares the two under the same machine load
    (``benchmarks.model_tracking``)."""

    def __init__(self, aligner, volume: TSDFVolume, camera, height: int, width: int, n_frames: int, *,
                 start_pose: np.ndarray | None = None, color: bool = False, init: str = "identity",
                 warn: bool = True):
        fn = "gvnn_warp.fusion.sequence.FrameToModel"
        check_init(fn, init)
        if not (isinstance(n_frames, (int, np.integer)) and n_frames >= 1):
            fail(fn, ValueError, f"argument 'n_frames' must be an integer >= 1, got {n_frames!r}")
        if not all(isinstance(v, (int, np.integer)) and v >= 2 for v in (height, width)):
            fail(fn, ValueError, f"arguments 'height' and 'width' must be integers >= 2 (the frames' size), got "
                                 f"{height!r}, {width!r}")
        pose = np.eye(4) if start_pose is None else rigid_pose(fn, "start_pose", start_pose)
        _check_camera(fn, aligner, camera, height, width)
        self.aligner, self.volume, self.camera, self.height, self.width = aligner, volume, camera, height, width
        self.color, self.init, self.warn = bool(color), init, bool(warn)
        self.n = 0
        self.poses = np.full((n_frames, 4, 4), np.nan)
        self.poses[0] = pose
        self.converged, self.finite = np.ones(n_frames, bool), np.ones(n_frames, bool)
        self.valid, self.seconds = np.full(n_frames, np.nan), np.zeros(n_frames)
        self.integrate_seconds = np.zeros(n_frames)
        self.infos: list = [None]
        self.fuse = FuseReport()
        self._step = np.eye(4)  # the previous frame's motion, T_{i-1, i-2}
        self._prev_depth = None  # the depth integrated last: where the raycast's rays start
        self._warned: set[str] = set()  # the warnings given (each once)

    def add(self, rgb: np.ndarray, depth: np.ndarray) -> None:
        """Process the next frame (see the class docstring): ``rgb`` (3, H, W) in [0, 1], ``depth``
        (1, H, W) or (H, W) metres (0, NaN, negative: none), numpy arrays or CPU tensors."""
        fn, H, W = "gvnn_warp.fusion.sequence.FrameToModel.add", self.height, self.width
        i = self.n
        if i >= self.poses.shape[0]:
            raise IndexError(f"{fn}: more than the {self.poses.shape[0]} frames announced (n_frames)")
        rgb = as_numpy(fn, "rgb", rgb, (3,))
        if rgb.shape != (3, H, W):
            hint = ", which looks channel-last (H, W, 3): transpose it" if rgb.shape == (H, W, 3) else ""
            fail(fn, ValueError, f"argument 'rgb' must be (3, {H}, {W}) (the height and width given), got "
                                 f"{rgb.shape}{hint}")
        depth = as_numpy(fn, "depth", depth, (2, 3))
        if depth.shape not in ((H, W), (1, H, W)):
            fail(fn, ValueError, f"argument 'depth' must be (1, {H}, {W}) or ({H}, {W}), got {depth.shape}")
        depth = depth.reshape(1, H, W)
        if self.warn and "8-bit" not in self._warned:
            top = float(np.nanmax(rgb[:, ::7, ::7], initial=0.0))
            if top > INTENSITY_LIMIT:
                self._warned.add("8-bit")
                warnings.warn(f"{fn}: argument 'rgb' has values up to {top:g}; colours are expected in [0, 1] "
                              "(divide 8-bit images by 255), and accuracy suffers otherwise", UserWarning,
                              stacklevel=2)
        s = time.perf_counter()
        pose, step, info = self.poses[0], self._step, None
        converged, finite, valid = True, True, np.nan
        if i > 0:
            # (at the pose frame i - 1 was just integrated at: its depth tells the rays where to start)
            ref_depth, ref_colour, _ = self.volume.raycast(self.camera, self.poses[i - 1], H, W,
                                                           start_depth=self._prev_depth, normals=False)
            channels = (lambda c: c) if self.color else to_gray
            # (the live depth too: the aligner's occlusion test and depth term use it)
            guess = self._step if self.init == "velocity" else None
            with self._quiet():
                T, info = self.aligner.align(channels(ref_colour), ref_depth[None], channels(rgb), depth, init=guess)
            T = np.asarray(T, dtype=np.float64)
            if not np.all(np.isfinite(T)):
                finite, T = False, (np.eye(4) if guess is None else guess)
            step, pose = T, self.poses[i - 1] @ np.linalg.inv(T)
            converged, valid = info_converged(info), info_valid_fraction(info)
        t = time.perf_counter()
        with self._quiet():
            report = self.volume.integrate(depth, rgb, self.camera, pose)  # (MapFull: nothing of frame i kept)
        done = time.perf_counter()
        self.fuse.add(i, report, done - t)
        if report.valid_pixels == 0 and self.warn and "no depth" not in self._warned:
            self._warned.add("no depth")
            warnings.warn(f"{fn}: frame {i} has no depth within the volume's range [{self.volume.min_depth:g}, "
                          f"{self.volume.max_depth:g}] m: nothing integrated (depths in millimetres, or negated?)",
                          UserWarning, stacklevel=2)
        self.poses[i], self._step, self._prev_depth = pose, step, depth
        self.converged[i], self.finite[i], self.valid[i] = converged, finite, valid
        if i > 0:
            self.infos.append(info)
            self.seconds[i], self.integrate_seconds[i] = done - s, done - t
        self.n += 1

    @contextlib.contextmanager
    def _quiet(self):
        """Around the aligner's and the volume's calls: once :meth:`add` has warned about 8-bit
        colours (naming the user's argument), or with warnings off, their own warnings about the
        same values (naming arguments the caller never passed) are not given too."""
        if "8-bit" not in self._warned and self.warn:
            yield
            return
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*DirectAligner\.\w+: argument '\w+' has intensities")
            warnings.filterwarnings("ignore", message=r".*TSDFVolume\.integrate: argument 'colour' has values up to")
            yield

    @property
    def ms_per_frame(self) -> float:
        """Mean time per frame after the first (raycast, alignment, integration), ms."""
        return 1e3 * float(self.seconds[1:self.n].sum()) / max(self.n - 1, 1)

    def result(self, n: int | None = None) -> TrackResult:
        """The result over the frames added so far (or the first ``n`` of them; 1 gives the start
        pose alone, also before any frame)."""
        if n is None:
            n = self.n
        elif not (isinstance(n, (int, np.integer)) and 1 <= n <= max(self.n, 1)):
            raise ValueError(f"gvnn_warp.fusion.sequence.FrameToModel.result: argument 'n' must be in [1, "
                             f"{max(self.n, 1)}] (the frames added), got {n!r}")
        return TrackResult(self.poses[:n].copy(), np.arange(-1, n - 1), self.converged[:n].copy(),
                           self.finite[:n].copy(), self.valid[:n].copy(), self.seconds[:n].copy(),
                           list(range(max(n - 1, 1))), list(self.infos[:n]))


def _check_camera(fn: str, aligner, camera, height: int, width: int) -> None:
    """Refuse a pinhole K (of ``camera``, plain or with distortion) whose principal point lies outside
    ``height`` x ``width`` frames (a K for another image size), and a plain ``DirectAligner`` (no
    lens model, no resampling) whose K differs from it: the model would be raycast with one camera
    and aligned with another."""
    K = camera[0] if isinstance(camera, tuple) and len(camera) == 2 else camera
    if not (isinstance(K, np.ndarray) or is_torch(K)):
        return  # (a camera object of gvnn_warp.cameras: the volume checks it)
    K = np.asarray(K.detach().cpu() if is_torch(K) else K, dtype=np.float64)
    if K.shape != (3, 3):
        return  # (the volume's error names it)
    if not (0 <= K[0, 2] <= width - 1 and 0 <= K[1, 2] <= height - 1):
        fail(fn, ValueError, f"argument 'camera' has its principal point ({K[0, 2]:g}, {K[1, 2]:g}) outside the "
                             f"{width}x{height} frames: intrinsics for another image size?")
    A = getattr(aligner, "K", None)
    plain = getattr(aligner, "model", None) in (None, "pinhole") and getattr(aligner, "resample", None) is None
    if plain and isinstance(A, np.ndarray) and A.shape == (3, 3) and not isinstance(camera, tuple) \
            and not np.allclose(A, K, rtol=1e-6, atol=1e-6):
        fail(fn, ValueError, f"argument 'aligner' has K {A.tolist()}, argument 'camera' {K.tolist()}: the model "
                             "is raycast with the camera and aligned with the aligner's, so they must be the same")
    if plain and A is not None and getattr(aligner, "dist", None) is None and isinstance(camera, tuple):
        dist = camera[1]
        dist = np.asarray(dist.detach().cpu() if is_torch(dist) else dist, dtype=np.float64)
        if np.any(dist != 0):
            fail(fn, ValueError, "argument 'aligner' is a pinhole DirectAligner and argument 'camera' has a lens "
                                 "distortion: make the aligner for the same camera (DirectAligner(K, dist=...), or "
                                 "with resample=)")


class ModelTracker:
    """Frame-to-model tracking (see the module docstring): ``tracker(n, start_pose, progress)`` ->
    :class:`TrackResult` over the first ``n`` frames of ``seq``, with ``volume`` holding the model
    at the end and ``fuse`` its integration statistics. ``aligner``: a ``DirectAligner`` for the
    sequence's camera, grey images, or colour ones with ``color`` (an aligner made with
    ``color=True``); ``init``: each alignment's initial guess, ``"identity"`` (the frame is where
    the previous one was) or ``"velocity"`` (the previous frame's motion again), as
    :func:`gvnn_warp.odometry.tracking.track`'s; ``seconds`` per frame count the raycast, the
    alignment and the integration. A frame that cannot be read, or a map that outgrows the volume's
    memory, raises ``TrackingStopped`` with the result of the frames before it. ``depth``: see the
    module docstring. A loop of :class:`FrameToModel` over the sequence's frames."""

    def __init__(self, seq: TUMSequence, aligner, volume: TSDFVolume, depth=None, *, color: bool = False,
                 init: str = "identity"):
        check_init("gvnn_warp.fusion.sequence.ModelTracker", init)
        self.seq, self.aligner, self.volume, self.depth = seq, aligner, volume, depth
        self.color, self.init = bool(color), init
        self.fuse = FuseReport()

    def __call__(self, n: int, start_pose: np.ndarray, progress: bool = True) -> TrackResult:
        seq = self.seq
        model = FrameToModel(self.aligner, self.volume, camera_of(seq), seq.height, seq.width, n,
                             start_pose=start_pose, color=self.color, init=self.init, warn=False)
        self.fuse = model.fuse
        rgb, depth = _frame(seq, 0, self.depth)  # (frame 0 unreadable: its error, nothing tracked)
        try:
            model.add(rgb, depth)
        except MapFull as e:
            raise TrackingStopped(1, model.result(1), InputError(str(e))) from e
        with progress_bar(total=n, initial=1, unit="frame", desc="track (model)", disable=not progress) as bar:
            for i in range(1, n):
                try:  # (a frame that cannot be read, or a map beyond the memory given: the frames before it stand)
                    rgb, depth = _frame(seq, i, self.depth)
                    model.add(rgb, depth)
                except InputError as e:
                    raise TrackingStopped(i, model.result(), e) from e
                except MapFull as e:
                    raise TrackingStopped(i, model.result(), InputError(str(e))) from e
                bar.update(1)
                if i % 10 == 0 or i == n - 1:
                    bar.set_postfix_str(f"{model.ms_per_frame:.0f} ms/frame", refresh=False)
        return model.result()


def render_picture(volume: TSDFVolume, camera, T_world_cam: np.ndarray, height: int, width: int,
                   path: str | Path, title: str | None = None) -> float:
    """A PNG of the model seen from ``T_world_cam``: its colour shaded by the normals (a light at the
    camera), black where there is no surface. Returns the fraction of pixels with a surface."""
    from PIL import Image, ImageDraw

    depth, colour, normals = volume.raycast(camera, T_world_cam, height, width)
    light = np.abs(normals[2])  # (the normal's z in the camera: facing the camera is bright)
    shade = np.where(light > 0, 0.35 + 0.65 * light, 1.0)
    img = np.clip(colour * shade[None], 0.0, 1.0)
    img[:, depth <= 0] = 0.0
    out = Image.fromarray(np.round(255 * img.transpose(1, 2, 0)).astype(np.uint8))
    if title:
        ImageDraw.Draw(out).text((4, 4), title, fill=(255, 255, 255))
    out.save(path)
    return float((depth > 0).mean())
