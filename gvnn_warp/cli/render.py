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

from ..synthetic.sequence import MOTIONS, TUM_FILES, render_sequence
from .args import UsageError, bounded_int, description, image_size, output_dir, seed
from .runner import command_main

__all__ = ["add_parser", "check", "run"]

REQUIRES = ("tqdm",)  # checked by gvnn_warp.cli before run(); rendering and writing need no torch

MAX_SIDE = 2048  # largest image side: a 2048x2048 RGB-D frame is 64 MiB in float32
MAX_FRAMES = 100_000  # about an hour at 30 fps


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


def check(args: argparse.Namespace) -> None:
    """Checks that need what is on disk (raises UsageError before any work): --out must not hold a
    TUM sequence already, unless --overwrite."""
    existing = [name for name in TUM_FILES if (args.out / name).exists()]
    if existing and not args.overwrite:
        raise UsageError(f"--out {args.out} already holds a sequence ({existing[0]}); pass --overwrite or choose "
                         "another folder")


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
    return command_main(add_parser, REQUIRES, argv)


if __name__ == "__main__":
    sys.exit(main())
