"""``gvnn-warp align``: recover the relative pose of two rendered views by gradient descent.

Two views of the synthetic room (``gvnn_warp.synthetic``) are rendered a known motion apart;
starting from the identity, a 6-vector [omega, t] is fitted by Adam on the photometric error of
``warp_frame_depth(live, ref_depth, se3_to_matrix(xi), K)`` against the reference image,
coarse to fine over an image pyramid. Writes ``align.png`` (reference, live, warped before and
after, residuals) into ``--out``.
"""

from __future__ import annotations

import argparse
import sys

from ..demos.views import MIN_LEVEL_SIZE, max_levels
from .args import UsageError, description, finite_float, image_size, output_dir, positive_int, seed
from .runner import command_main

__all__ = ["add_parser", "check", "run"]

REQUIRES = ("torch", "matplotlib", "tqdm")  # checked by gvnn_warp.cli before run()

MAX_STEPS = 100_000


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "align",
        help="align two rendered RGB-D views by photometric gradient descent",
        description=description(__doc__),
    )
    p.add_argument("--out", type=output_dir, required=True, metavar="DIR",
                   help="directory for align.png (made if missing)")
    p.add_argument("--size", type=image_size(16), default="160x120", metavar="WxH", help="image size WxH")
    p.add_argument("--steps", type=positive_int, default=60, metavar="N", help="Adam steps per pyramid level")
    p.add_argument("--levels", type=positive_int, default=3, metavar="N",
                   help=f"pyramid levels (the coarsest keeps >= {MIN_LEVEL_SIZE} pixels a side)")
    p.add_argument("--rotation-deg", type=finite_float(-180, 180, "degrees"), default=4.0, metavar="DEG",
                   help="true rotation between the views, degrees")
    p.add_argument("--translation-cm", type=finite_float(-50, 50, "cm"), default=8.0, metavar="CM",
                   help="true translation between the views, cm")
    p.add_argument("--seed", type=seed, default=0, metavar="S", help="seed of the scene and the motion")
    p.set_defaults(func=run)
    return p


def check(args: argparse.Namespace) -> None:
    """Argument checks that need several arguments (raises UsageError before any work)."""
    width, height = args.size
    most = max_levels(width, height)
    if args.levels > most:
        raise UsageError(f"--levels {args.levels} is too many for {width}x{height} (the coarsest level must "
                         f"keep >= {MIN_LEVEL_SIZE} pixels a side); use at most {most}")
    if args.steps * args.levels > MAX_STEPS:
        raise UsageError(f"--steps {args.steps} x --levels {args.levels} is more than {MAX_STEPS} steps")


def run(args: argparse.Namespace) -> int:
    check(args)
    # the demo imports torch and matplotlib: only now, once gvnn_warp.cli has checked that they are
    # installed (--help and the commands that need no torch never load it)
    from ..demos.align import align_demo

    align_demo(args.out, args.size, steps=args.steps, levels=args.levels, rotation_deg=args.rotation_deg,
               translation_cm=args.translation_cm, seed=args.seed)
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m gvnn_warp.cli.align ...``: the same as ``gvnn-warp align ...``."""
    return command_main(add_parser, REQUIRES, argv)


if __name__ == "__main__":
    sys.exit(main())
