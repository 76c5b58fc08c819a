"""A TUM sequence fused into a :class:`~.volume.TSDFVolume`: after tracking, or while tracking
against the model (what ``gvnn-warp track --fuse`` / ``--model`` run; no torch).

- :func:`fuse_sequence`: every frame integrated at its estimated pose;
- :class:`ModelTracker`: frame-to-model tracking (KinectFusion's loop): each new frame is aligned
  by the direct aligner to the model raycast at the previous frame's pose (its depth, and its
  colour or the grey of it, as the reference frame), then integrated at the pose found. The model
  averages every earlier frame, so the reference is less noisy than the previous frame and errors
  do not chain from frame to frame as they do in frame-to-frame odometry;
- :func:`render_picture`: a PNG of the model raycast from a pose, its colour shaded by the normals.

Both take each frame's depth from the sequence's depth files, or from ``depth``, a callable
``image (3, H, W) RGB -> depth (1, H, W)`` (``gvnn_warp.depth.predict.DepthPredictor``: monocular
depth, whose units are then the map's: voxel size and truncation are in them too).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..datasets.images import to_gray
from ..datasets.tum import TUMSequence
from ..errors import InputError
from ..odometry.tracking import INITS, TrackingStopped, TrackResult, info_converged, info_valid_fraction
from ..progress import progress_bar
from .volume import IntegrateReport, MapFull, TSDFVolume

__all__ = ["FuseReport", "ModelTracker", "camera_of", "fuse_sequence", "render_picture"]


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
    module docstring."""

    def __init__(self, seq: TUMSequence, aligner, volume: TSDFVolume, depth=None, *, color: bool = False,
                 init: str = "identity"):
        if init not in INITS:
            raise ValueError(f"ModelTracker: argument 'init' must be one of {', '.join(map(repr, INITS))}, "
                             f"got {init!r}")
        self.seq, self.aligner, self.volume, self.depth = seq, aligner, volume, depth
        self.color, self.init = bool(color), init
        self.fuse = FuseReport()

    def __call__(self, n: int, start_pose: np.ndarray, progress: bool = True) -> TrackResult:
        seq, vol, camera = self.seq, self.volume, camera_of(self.seq)
        H, W = seq.height, seq.width
        channels = (lambda rgb: rgb) if self.color else to_gray
        poses = np.full((n, 4, 4), np.nan)
        poses[0] = start_pose
        converged, finite = np.ones(n, bool), np.ones(n, bool)
        valid, seconds = np.full(n, np.nan), np.zeros(n)
        infos: list = [None]
        step = np.eye(4)  # the previous frame's motion, T_{i-1, i-2}
        def result(m: int) -> TrackResult:  # the first m frames
            return TrackResult(poses[:m].copy(), np.arange(-1, m - 1), converged[:m].copy(), finite[:m].copy(),
                               valid[:m].copy(), seconds[:m].copy(), list(range(max(m - 1, 1))), infos[:m])

        rgb, depth = _frame(seq, 0, self.depth)
        prev_depth = depth
        s = time.perf_counter()
        try:
            self.fuse.add(0, vol.integrate(depth, rgb, camera, start_pose), time.perf_counter() - s)
        except MapFull as e:
            raise TrackingStopped(1, result(1), InputError(str(e))) from e
        with progress_bar(total=n, initial=1, unit="frame", desc="track (model)", disable=not progress) as bar:
            for i in range(1, n):
                try:  # (a frame that cannot be read, or a map beyond the memory given: the frames before it stand)
                    rgb, depth = _frame(seq, i, self.depth)
                except InputError as e:
                    raise TrackingStopped(i, result(i), e) from e
                s = time.perf_counter()
                # (at the pose frame i - 1 was just integrated at: its depth tells the rays where to start)
                ref_depth, ref_colour, _ = vol.raycast(camera, poses[i - 1], H, W, start_depth=prev_depth,
                                                       normals=False)
                # (the live depth too: the aligner's occlusion test and depth term use it)
                guess = step if self.init == "velocity" else None
                T, info = self.aligner.align(channels(ref_colour), ref_depth[None], channels(rgb), depth, init=guess)
                T = np.asarray(T, dtype=np.float64)
                if not np.all(np.isfinite(T)):
                    finite[i], T = False, (np.eye(4) if guess is None else guess)
                step = T
                poses[i] = poses[i - 1] @ np.linalg.inv(T)
                converged[i], valid[i] = info_converged(info), info_valid_fraction(info)
                t = time.perf_counter()
                try:
                    self.fuse.add(i, vol.integrate(depth, rgb, camera, poses[i]), time.perf_counter() - t)
                except MapFull as e:
                    raise TrackingStopped(i, result(i), InputError(str(e))) from e
                prev_depth = depth
                seconds[i] = time.perf_counter() - s
                infos.append(info)
                bar.update(1)
                if i % 10 == 0 or i == n - 1:
                    bar.set_postfix_str(f"{1000 * seconds[1:i + 1].mean():.0f} ms/frame", refresh=False)
        return result(n)


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
