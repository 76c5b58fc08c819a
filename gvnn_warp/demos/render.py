"""``gvnn-warp render``: render a synthetic RGB-D sequence and write it as a TUM RGB-D folder.

Usage::

    gvnn-warp render --out DIR [--motion so3|se3] [--frames N] [--size WxH] [--seed S]

Writes ``DIR/rgb/*.png`` (8-bit colour), ``DIR/depth/*.png`` (16-bit, metres * 5000, 0 = no
depth), ``DIR/rgb.txt``, ``DIR/depth.txt``, ``DIR/groundtruth.txt`` (``T_world_cam`` as
``timestamp tx ty tz qx qy qz qw``) and ``DIR/intrinsics.txt`` (``fx fy cx cy``): exactly the
format ``gvnn-warp track`` and other TUM tools read (see docs/datasets.md). Frames are 1/30 s apart.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ._args import image_size, nonnegative_int, positive_int

__all__ = ["add_parser", "run"]

_SIZE = image_size(16)
FPS = 30.0
T0 = 1_700_000_000.0  # first timestamp (s), in the range of real sensor clocks
CHUNK = 16  # frames rendered per Warp launch
TUM_FILES = ("rgb.txt", "depth.txt", "groundtruth.txt", "intrinsics.txt")

MOTIONS = {
    "se3": "smooth hand-held-like 6-DoF motion: 1.5-4 cm and 0.6-1.6 deg per frame",
    "so3": "rotation about a fixed centre only: 2-8 deg per frame",
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder to write the sequence into (created)")
    p.add_argument("--motion", choices=tuple(MOTIONS), default="se3",
                   help="; ".join(f"{k}: {v}" for k, v in MOTIONS.items()) + " (default se3)")
    p.add_argument("--frames", type=positive_int, default=200, metavar="N", help="number of frames (default 200)")
    p.add_argument("--size", type=_SIZE, default=(320, 240), metavar="WxH", help="image size WxH (default 320x240)")
    p.add_argument("--seed", type=nonnegative_int, default=0, metavar="S",
                   help="seed of the room and the trajectory (default 0)")
    p.add_argument("--overwrite", action="store_true", help="replace a TUM sequence already in --out")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "render",
        help="render a synthetic RGB-D sequence into a TUM RGB-D folder (with ground truth)",
        description=__doc__.split("\n\n")[0],
    )
    add_arguments(p)
    p.set_defaults(func=run)
    return p


def _error(message: str) -> SystemExit:
    return SystemExit(f"gvnn-warp render: error: {message}")


def trajectory(motion: str, frames: int, seed: int):
    """``T_world_cam`` (frames, 4, 4) of the ``motion`` (see ``MOTIONS``)."""
    from ..synthetic import rotation_trajectory, smooth_se3_trajectory

    if motion == "se3":
        return smooth_se3_trajectory(frames, seed)
    return rotation_trajectory(frames, seed)


def check_out(out: Path, overwrite: bool) -> None:
    """Refuse an --out that is a file, or that already holds a TUM sequence (unless ``overwrite``)."""
    if out.exists() and not out.is_dir():
        raise _error(f"--out {out} exists and is not a directory")
    existing = [name for name in TUM_FILES if (out / name).exists()]
    if existing and not overwrite:
        raise _error(f"--out {out} already holds a sequence ({existing[0]}); pass --overwrite or choose another folder")


def render_sequence(out: Path, motion: str, frames: int, size: tuple[int, int], seed: int,
                    progress: bool = True) -> float:
    """Render and write the sequence; returns the seconds spent rendering (not writing)."""
    import numpy as np
    from tqdm import tqdm

    from ..datasets.tum import TUMWriter
    from ..synthetic import default_intrinsics, make_room_scene, render_rgbd

    width, height = size
    K = default_intrinsics(width, height)
    poses = trajectory(motion, frames, seed)
    scene = make_room_scene(seed)
    stamps = T0 + np.arange(frames) / FPS
    if out.is_dir():  # --overwrite: drop the old images so no stale frame is left beside the new lists
        for kind in ("rgb", "depth"):
            for f in (out / kind).glob("*.png"):
                f.unlink()
    comment = f"gvnn-warp render --motion {motion} --frames {frames} --size {width}x{height} --seed {seed}"
    render_s = 0.0
    with TUMWriter(out, K, comment=comment) as writer, tqdm(
        total=frames, unit="frame", disable=not progress, desc="render"
    ) as bar:
        for start in range(0, frames, CHUNK):
            stop = min(start + CHUNK, frames)
            t = time.perf_counter()
            image, depth = render_rgbd(scene, poses[start:stop], K, width, height)
            render_s += time.perf_counter() - t
            for k in range(stop - start):
                writer.add(stamps[start + k], image[k], depth[k], poses[start + k])
                bar.update(1)
    return render_s


def run(args: argparse.Namespace) -> int:
    check_out(args.out, args.overwrite)
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise _error(f"cannot create --out {args.out}: {e.strerror or e}") from None
    t = time.perf_counter()
    try:
        render_s = render_sequence(args.out, args.motion, args.frames, args.size, args.seed,
                                   progress=not args.no_progress)
    except KeyboardInterrupt:
        print("gvnn-warp render: interrupted; the folder is incomplete", file=sys.stderr)
        return 130
    total = time.perf_counter() - t
    width, height = args.size
    print(f"render {args.motion}: {args.frames} frames {width}x{height} in {total:.1f} s "
          f"({1e3 * render_s / args.frames:.1f} ms/frame rendering); wrote {args.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="gvnn-warp render", description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
