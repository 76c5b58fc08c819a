"""The gvnn-warp command line: render RGB-D sequences, track the camera through them or through real
TUM RGB-D folders and fuse them into a map, learn depth from video without labels, and demos of the
layers (align, flow, learned VO).

Every command checks its arguments before it starts (a bad one gets a one-line error after the
usage line and exit status 2), checks that the packages it needs are installed, and exits with one
line and status 130 on Ctrl-C.

Each command is a module of this package that only parses arguments and calls the library
(``gvnn_warp.synthetic.sequence``, ``gvnn_warp.odometry.sequence``, ``gvnn_warp.demos``,
``gvnn_warp.vo``): ``add_parser(subparsers)``, its own ``run(args)``, and optionally ``REQUIRES``, the
importable packages it needs, checked before it starts. How a command runs (the checks, errors,
Ctrl-C) is :mod:`.runner`'s, shared with the commands run on their own.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from .args import HelpFormatter, plain_text
from .runner import (
    EXIT_GRACE_SECONDS,
    INSTALL_HINTS,
    INTERRUPTED_STATUS,
    add_command,
    announce_compiles,
    missing_packages,
    parse_and_run,
    run_command,
    tidy_parser,
)

__all__ = [
    "DEMOS",
    "EXIT_GRACE_SECONDS",
    "INSTALL_HINTS",
    "INTERRUPTED_STATUS",
    "announce_compiles",
    "build_parser",
    "main",
    "missing_packages",
    "run_command",
    "tidy_parser",
]

# the table of commands: the modules gvnn_warp.cli.<name>, imported by build_parser (by name, not at
# import time: ``python -m gvnn_warp.cli.vo`` must find its module not yet imported, and vo sets
# OMP_WAIT_POLICY before anything imports torch)
DEMOS = ("align", "flow", "vo", "render", "track", "depth")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gvnn-warp", description=__doc__.split("\n\n")[0], formatter_class=HelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in DEMOS:
        module = importlib.import_module(f"{__name__}.{name}")
        add_command(sub, module.add_parser, getattr(module, "REQUIRES", ()))
    for action in sub._choices_actions:  # the one-line summaries in `gvnn-warp --help`
        action.help = plain_text(action.help)
    return parser


def main(argv: list[str] | None = None) -> int:
    """``gvnn-warp ...``: parse ``argv`` (default ``sys.argv[1:]``) and run the command it names;
    returns the exit status. Run as a program (``argv`` None), it also calls :func:`.runner.freeze_at_exit`."""
    try:
        parser = build_parser()
    except KeyboardInterrupt:
        print("gvnn-warp: interrupted", file=sys.stderr)
        return INTERRUPTED_STATUS
    return parse_and_run(parser, argv)
