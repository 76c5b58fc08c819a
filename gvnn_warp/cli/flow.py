"""``gvnn-warp flow``: fit a per-pixel affine optic flow between two synthetic frames.

Usage::

    gvnn-warp flow --out DIR [--steps N] [--size WxH] [--seed S]

Frame 1 is a procedural multi-scale colour texture (fractal value noise over five octaves,
evaluated analytically); frame 2 is the same texture evaluated at ``p + f(p)`` for a known smooth
non-rigid flow ``f`` (a sum of Gaussian-weighted affine motions), so that
``flow_warp(frame1, f) ~= frame2``. A per-pixel affine flow field (``params (1, 6, H, W)``,
initialised to the identity) is fitted with Adam on a robust photometric error
(``robust_rho(affine_flow_warp(frame1, params) - frame2, "cauchy")``) plus a Huber
``smoothness_loss`` on the parameters, coarse to fine (both frames blurred, less and less). The
end-point error (EPE) against the true flow is printed along the way and compared with the EPE of
the zero flow; ``DIR/flow.png`` shows the frames, both flows (colour: hue = direction, saturation
= magnitude), the warped frame and the residuals.
"""

from __future__ import annotations

import argparse
import sys

from .args import bounded_int, description, image_size, output_dir, seed
from .runner import command_main

_SIZE = image_size(32)

__all__ = ["add_parser", "run"]

REQUIRES = ("torch", "matplotlib")  # checked by gvnn_warp.cli before run()

DEFAULT_SIZE = "160x120"
DEFAULT_STEPS = 300
MAX_STEPS = 100_000
bounded_steps = bounded_int(1, MAX_STEPS)


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "flow",
        help="fit a per-pixel affine optic flow between two synthetic frames (M-estimator + smoothness)",
        description=description(__doc__),
    )
    p.add_argument("--out", type=output_dir, required=True, metavar="DIR",
                   help="directory for flow.png (made if missing)")
    p.add_argument("--steps", type=bounded_steps, default=DEFAULT_STEPS, metavar="N", help="Adam steps")
    p.add_argument("--size", type=_SIZE, default=DEFAULT_SIZE, metavar="WxH", help="image size WxH")
    p.add_argument("--seed", type=seed, default=0, metavar="S", help="seed of the texture and the true flow")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    # the demo imports torch and matplotlib: only now, once gvnn_warp.cli has checked that they are
    # installed (--help and the commands that need no torch never load it)
    from ..demos.flow import flow_demo

    flow_demo(args.out, args.size, args.steps, args.seed)
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m gvnn_warp.cli.flow ...``: the same as ``gvnn-warp flow ...``."""
    return command_main(add_parser, REQUIRES, argv)


if __name__ == "__main__":
    sys.exit(main())
