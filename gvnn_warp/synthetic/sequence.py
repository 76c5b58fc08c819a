"""A rendered RGB-D sequence written as a TUM RGB-D folder (what ``gvnn-warp render`` writes).

:func:`render_sequence` renders frames of the synthetic room (:mod:`.scene`, :mod:`.render`) along a
camera trajectory (:func:`trajectory`: one of :data:`MOTIONS`) and writes them with
``gvnn_warp.datasets.tum.TUMWriter``: ``rgb/*.png`` (8-bit colour), ``depth/*.png`` (16-bit, metres *
5000, 0 = no depth), ``rgb.txt``, ``depth.txt``, ``groundtruth.txt`` (``T_world_cam`` as ``timestamp
tx ty tz qx qy qz qw``) and ``intrinsics.txt`` (``fx fy cx cy``; :func:`.default_intrinsics`). Frames
are ``1 / FPS`` s apart, from ``T0``. Never imports torch (numpy and Warp).

Example::

    from pathlib import Path
    from gvnn_warp.datasets.tum import read_tum
    from gvnn_warp.synthetic.sequence import render_sequence

    render_sequence(Path("seq"), "se3", frames=10, size=(64, 48), seed=0, progress=False)
    seq = read_tum("seq")
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..datasets.tum import TUMWriter
from ..progress import progress_bar
from .render import render_rgbd
from .scene import make_room_scene
from .trajectories import default_intrinsics, rotation_trajectory, smooth_se3_trajectory

__all__ = ["FPS", "MOTIONS", "T0", "TUM_FILES", "render_sequence", "trajectory"]

FPS = 30.0  # frames per second of the timestamps
T0 = 1_700_000_000.0  # first timestamp (s), in the range of real sensor clocks
CHUNK = 16  # at most this many frames rendered per Warp launch
CHUNK_BYTES = 256 * 2**20  # ... and at most this much float32 colour + depth per launch
TUM_FILES = ("rgb.txt", "depth.txt", "groundtruth.txt", "intrinsics.txt")  # the lists a sequence folder holds

# the camera motions, by name: what each looks like
MOTIONS = {
    "se3": "smooth hand-held-like 6-DoF motion: 1.5-4 cm and 0.6-1.6 deg per frame",
    "so3": "rotation about a fixed centre only: 2-8 deg per frame",
}


def trajectory(motion: str, frames: int, seed: int) -> np.ndarray:
    """``T_world_cam`` (frames, 4, 4), float64, metres, of the ``motion`` (a key of :data:`MOTIONS`:
    ``"se3"``, :func:`.smooth_se3_trajectory`; ``"so3"``, :func:`.rotation_trajectory`)."""
    if motion not in MOTIONS:
        raise ValueError(f"motion must be one of {', '.join(MOTIONS)}, got {motion!r}")
    if motion == "se3":
        return smooth_se3_trajectory(frames, seed)
    return rotation_trajectory(frames, seed)


def render_sequence(out: Path, motion: str, frames: int, size: tuple[int, int], seed: int,
                    progress: bool = True, scene_seed: int | None = None) -> float:
    """Render ``frames`` frames of ``size`` (width, height) pixels along the ``motion`` trajectory of
    ``seed`` in the room of ``scene_seed`` (default ``seed``), and write them into the folder ``out``
    (made if missing) as a TUM sequence (see the module docstring). An ``out`` that already holds one
    loses its old images first, so no stale frame is left beside the new lists. ``progress``: a tqdm
    bar on stderr. Returns the seconds spent rendering (not writing)."""
    width, height = size
    K = default_intrinsics(width, height)
    poses = trajectory(motion, frames, seed)
    scene = make_room_scene(seed if scene_seed is None else scene_seed)
    stamps = T0 + np.arange(frames) / FPS
    chunk = max(1, min(CHUNK, CHUNK_BYTES // (16 * width * height)))  # 4 float32 channels per pixel
    out = Path(out)
    if out.is_dir():  # an earlier sequence: drop its images so no stale frame is left beside the new lists
        for kind in ("rgb", "depth"):
            for f in (out / kind).glob("*.png"):
                f.unlink()
    comment = f"gvnn-warp render --motion {motion} --frames {frames} --size {width}x{height} --seed {seed}"
    if scene_seed is not None and scene_seed != seed:
        comment += f" --scene-seed {scene_seed}"
    render_s = 0.0
    with TUMWriter(out, K, comment=comment) as writer, progress_bar(
        total=frames, unit="frame", disable=not progress, desc="render"
    ) as bar:
        for start in range(0, frames, chunk):
            stop = min(start + chunk, frames)
            t = time.perf_counter()
            image, depth = render_rgbd(scene, poses[start:stop], K, width, height)
            render_s += time.perf_counter() - t
            for k in range(stop - start):
                writer.add(stamps[start + k], image[k], depth[k], poses[start + k])
                bar.update(1)
    return render_s
