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


def _int_at_least(text: str, minimum: int, expected: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
    if v < minimum:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
    return v


def positive_int(text: str) -> int:
    """``type=`` for counts: a positive integer."""
    return _int_at_least(text, 1, "a positive integer")


def nonnegative_int(text: str) -> int:
    """``type=`` for optional repetitions: an integer >= 0."""
    return _int_at_least(text, 0, "an integer >= 0")


def positive_float(text: str) -> float:
    """``type=`` for rates and scales: a finite number > 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not 0 < v < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v
