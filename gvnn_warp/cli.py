"""The ``gvnn-warp`` command line: demos of the layers on data made at run time."""

from __future__ import annotations

import argparse
import importlib
import sys

# subcommand modules in gvnn_warp.demos; each has add_parser(subparsers) and its own run(args)
DEMOS = ("align", "flow", "vo", "render", "track")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="gvnn-warp", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in DEMOS:
        importlib.import_module(f"gvnn_warp.demos.{name}").add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
