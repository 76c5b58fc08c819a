"""Argument types shared by the demos' command lines (argparse ``type=`` callables)."""

from __future__ import annotations

import argparse
from collections.abc import Callable


def image_size(min_side: int) -> Callable[[str], tuple[int, int]]:
    """``type=`` for ``--size WxH``: returns (width, height), each at least ``min_side``."""

    def parse(text: str) -> tuple[int, int]:
        try:
            w, h = (int(v) for v in text.lower().split("x"))
        except ValueError:
            raise argparse.ArgumentTypeError(f"size must be WxH, e.g. 160x120, got {text!r}") from None
        if w < min_side or h < min_side:
            raise argparse.ArgumentTypeError(f"size must be at least {min_side}x{min_side}, got {text!r}")
        return w, h

    return parse


def positive_int(text: str) -> int:
    """``type=`` for counts: a positive integer."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return v


def nonnegative_int(text: str) -> int:
    """``type=`` for optional repetitions: an integer >= 0."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return v
