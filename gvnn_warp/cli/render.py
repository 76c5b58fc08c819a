"""``gvnn-warp render``: render a synthetic RGB-D sequence and write it as a TUM RGB-D folder.

Usage::

    gvnn-warp render --out DIR [--motion so3|se3] [--frames N] [--size WxH] [--seed S] [--scene-seed S]

Writes ``DIR/rgb/*.png`` (8-bit colour), ``DIR/depth/*.png`` (16-bit, metres * 5000, 0 = no
depth), ``DIR/rgb.txt``, ``DIR/depth.txt``, ``DIR/groundtruth.txt`` (``T_world_cam`` as
``timestamp tx ty tz qx qy qz qw``) and ``DIR/intrinsics.txt`` (``fx fy cx cy``): exactly the
format ``gvnn-warp track`` and other TUM tools read (see docs/datasets.md). Frames are 1/30 s apart.
Refuses a folder that already holds a sequence unless ``--overwrite``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .args import UsageError, bounded_int, description, image_size, output_dir, seed

__all__ = ["add_parser", "check", "render_sequence", "run"]

REQUIRES = ("tqdm",)  # checked by gvnn_warp.cli before run(); rendering and writing need no torch

MAX_SIDE = 2048  # largest image side: a 2048x2048 RGB-D frame is 64 MiB in float32
MAX_FRAMES = 100_000  # about an hour at 30 fps
FPS = 30.0
T0 = 1_700_000_000.0  # first timestamp (s), in the range of real sensor clocks
CHUNK = 16  # at most this many frames rendered per Warp launch
CHUNK_BYTES = 256 * 2**20  # ... and at most this much float32 colour + depth per launch
TUM_FILES = ("rgb.txt", "depth.txt", "groundtruth.txt", "intrinsics.txt")

MOTIONS = {
    "se3": "smooth hand-held-like 6-DoF motion: 1.5-4 cm and 0.6-1.6 deg per frame",
    "so3": "rotation about a fixed centre only: 2-8 deg per frame",
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=output_dir, required=True, metavar="DIR",
                   help="folder to write the sequence into (made if missing)")
    p.add_argument("--motion", choices=tuple(MOTIONS), default="se3",
                   help="; ".join(f"{k}: {v}" for k, v in MOTIONS.items()))
    p.add_argument("--frames", type=bounded_int(1, MAX_FRAMES), default=200, metavar="N", help="number of frames")
    p.add_argument("--size", type=image_size(16, MAX_SIDE), default="320x240", metavar="WxH", help="image size WxH")
    p.add_argument("--seed", type=seed, default=0, metavar="S", help="seed of the room and the trajectory")
    p.add_argument("--scene-seed", type=seed, default=None, metavar="S",
                   help="seed of the room, if another than --seed (gvnn-warp vo trains in room 0: another trajectory "
                        "in that room is --scene-seed 0 --seed S; default: --seed)")
    p.add_argument("--overwrite", action="store_true", help="replace a TUM sequence already in --out")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "render",
        help="render a synthetic RGB-D sequence into a TUM RGB-D folder (with ground truth)",
        description=description(__doc__),
    )
    add_arguments(p)
    p.set_defaults(func=run)
    return p


def trajectory(motion: str, frames: int, seed: int):
    """``T_world_cam`` (frames, 4, 4) of the ``motion`` (see ``MOTIONS``)."""
    from ..synthetic import rotation_trajectory, smooth_se3_trajectory

    if motion == "se3":
        return smooth_se3_trajectory(frames, seed)
    return rotation_trajectory(frames, seed)


def check(args: argparse.Namespace) -> None:
    """Checks that need what is on disk (raises UsageError before any work): --out must not hold a
    TUM sequence already, unless --overwrite."""
    existing = [name for name in TUM_FILES if (args.out / name).exists()]
    if existing and not args.overwrite:
        raise UsageError(f"--out {args.out} already holds a sequence ({existing[0]}); pass --overwrite or choose "
                         "another folder")


def render_sequence(out: Path, motion: str, frames: int, size: tuple[int, int], seed: int,
                    progress: bool = True, scene_seed: int | None = None) -> float:
    """Render and write the sequence (the room of ``scene_seed``, default ``seed``); returns the
    seconds spent rendering (not writing)."""
    import numpy as np
    from tqdm import tqdm

    from ..datasets.tum import TUMWriter
    from ..synthetic import default_intrinsics, make_room_scene, render_rgbd

    width, height = size
    K = default_intrinsics(width, height)
    poses = trajectory(motion, frames, seed)
    scene = make_room_scene(seed if scene_seed is None else scene_seed)
    stamps = T0 + np.arange(frames) / FPS
    chunk = max(1, min(CHUNK, CHUNK_BYTES // (16 * width * height)))  # 4 float32 channels per pixel
    if out.is_dir():  # --overwrite: drop the old images so no stale frame is left beside the new lists
        for kind in ("rgb", "depth"):
            for f in (out / kind).glob("*.png"):
                f.unlink()
    comment = f"gvnn-warp render --motion {motion} --frames {frames} --size {width}x{height} --seed {seed}"
    if scene_seed is not None and scene_seed != seed:
        comment += f" --scene-seed {scene_seed}"
    render_s = 0.0
    with TUMWriter(out, K, comment=comment) as writer, tqdm(
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


def run(args: argparse.Namespace) -> int:
    check(args)
    args.out.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    render_s = render_sequence(args.out, args.motion, args.frames, args.size, args.seed,
                               progress=not args.no_progress, scene_seed=getattr(args, "scene_seed", None))
    total = time.perf_counter() - t
    width, height = args.size
    print(f"render {args.motion}: {args.frames} frames {width}x{height} in {total:.1f} s "
          f"({1e3 * render_s / args.frames:.1f} ms/frame rendering); wrote {args.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m gvnn_warp.cli.render ...``: the same as ``gvnn-warp render ...``."""
    from . import main as cli_main

    return cli_main(["render", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
