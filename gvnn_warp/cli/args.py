"""What the demos' command lines share: argument types (argparse ``type=`` callables) that refuse
bad values with a one-line message, the error for bad combinations found after parsing, and the
help formatter.

Every ``type=`` here raises ``argparse.ArgumentTypeError``, which argparse prints after the usage
line (``gvnn-warp align: error: argument --size: ...``) before exiting with status 2. Checks that
need several arguments raise :class:`UsageError` from the command's ``run`` before any work starts;
``gvnn_warp.cli`` prints those the same way.
"""

from __future__ import annotations

import argparse
import math
import os
import re
from collections.abc import Callable
from pathlib import Path

__all__ = [
    "CHECKPOINT",
    "MAX_SEED",
    "MAX_SIDE",
    "HelpFormatter",
    "UsageError",
    "bounded_int",
    "description",
    "finite_float",
    "image_size",
    "nonnegative_int",
    "output_dir",
    "plain_text",
    "positive_float",
    "positive_int",
    "refuse_earlier_run",
    "refuse_sequence_folder",
    "seed",
]

MAX_SIDE = 4096  # default largest image side: a 4096x4096 float32 RGB-D frame is already 256 MiB
MAX_SEED = 2**32 - 1  # numpy's and torch's seeds both take this range


class UsageError(ValueError):
    """Arguments that are each valid but cannot work together (or with what is on disk); raised
    by a command's ``run`` before it starts work. ``gvnn_warp.cli`` prints the message after the
    usage line and exits with status 2, as argparse does for a bad single argument."""


def image_size(min_side: int, max_side: int = MAX_SIDE, example: str = "160x120") -> Callable[[str], tuple[int, int]]:
    """``type=`` for ``--size WxH``: returns (width, height), each side in [min_side, max_side];
    ``example``: a size the command takes, for the message."""

    def parse(text: str) -> tuple[int, int]:
        try:
            w, h = (int(v) for v in text.lower().split("x"))
        except ValueError:
            raise argparse.ArgumentTypeError(f"size must be WxH, e.g. {example}, got {text!r}") from None
        if not (min_side <= w <= max_side and min_side <= h <= max_side):
            raise argparse.ArgumentTypeError(
                f"each side must be between {min_side} and {max_side} pixels, got {text!r}"
            )
        return w, h

    return parse


def bounded_int(minimum: int, maximum: int | None = None) -> Callable[[str], int]:
    """``type=`` for counts: an integer in [minimum, maximum] (no upper bound if ``maximum`` is None)."""
    if maximum is None:
        expected = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"
    else:
        expected = f"an integer from {minimum} to {maximum}"

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if v < minimum or (maximum is not None and v > maximum):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return v

    return parse


positive_int = bounded_int(1)
positive_int.__doc__ = "``type=`` for counts: a positive integer."
nonnegative_int = bounded_int(0)
nonnegative_int.__doc__ = "``type=`` for optional repetitions: an integer >= 0."
seed = bounded_int(0, MAX_SEED)
seed.__doc__ = "``type=`` for ``--seed``: an integer from 0 to 2**32 - 1."


def bounded_int_list(minimum: int, maximum: int | None = None) -> Callable[[str], tuple[int, ...]]:
    """``type=`` for a comma-separated list of integers in [minimum, maximum] (e.g. ``1,2,5``)."""
    one = bounded_int(minimum, maximum)

    def parse(text: str) -> tuple[int, ...]:
        parts = [t.strip() for t in text.split(",")]
        if not parts or any(not t for t in parts):
            raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}")
        return tuple(one(t) for t in parts)

    return parse


def finite_float(minimum: float = -math.inf, maximum: float = math.inf, unit: str = "",
                 above_minimum: bool = False, below_maximum: bool = False) -> Callable[[str], float]:
    """``type=`` for a finite number in [minimum, maximum] (``above_minimum``: > minimum;
    ``below_maximum``: < maximum; NaN and inf are refused)."""
    u = f" {unit}" if unit else ""
    if above_minimum or below_maximum:
        expected = (f"a number {'>' if above_minimum else '>='} {minimum:g} and {'<' if below_maximum else '<='} "
                    f"{maximum:g}{u}")
    elif math.isinf(minimum) and math.isinf(maximum):
        expected = "a finite number"
    elif math.isinf(maximum):
        expected = f"a finite number >= {minimum:g}{u}"
    elif math.isinf(minimum):
        expected = f"a finite number <= {maximum:g}{u}"
    else:
        expected = f"a number from {minimum:g} to {maximum:g}{u}"

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not (math.isfinite(v) and minimum <= v <= maximum) or (above_minimum and v == minimum) or (
                below_maximum and v == maximum):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return v

    return parse


def positive_float(text: str) -> float:
    """``type=`` for rates and scales: a finite number > 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not 0 < v < math.inf:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return v


def output_dir(text: str) -> Path:
    """``type=`` for ``--out DIR``: a directory that exists or can be made (it is made by the
    command, once all arguments are checked). Refuses an existing file, a path below a file, and a
    directory that cannot be written."""
    path = Path(text)
    if text == "":
        raise argparse.ArgumentTypeError("expected a directory, got ''")
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} exists and is not a directory")
    parent = path
    while not parent.exists():  # the nearest existing ancestor must be a writable directory
        parent = parent.parent
    if not parent.is_dir():
        raise argparse.ArgumentTypeError(f"cannot make directory {text!r}: {str(parent)!r} is a file")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"cannot write to {str(parent)!r}")
    return path


# a training run's checkpoint in its --out folder: gvnn_warp.vo.checkpoint.CHECKPOINT, spelled out here
# because importing that module loads torch before the arguments are checked (a test keeps them equal)
CHECKPOINT = "checkpoint.pt"


def refuse_sequence_folder(out: Path) -> None:
    """A results ``--out`` that holds a sequence (its ``rgb.txt``): refused, one line, before any work
    (the results would be written among the sequence's files)."""
    if (out / "rgb.txt").exists():
        raise UsageError(f"--out {out} holds a sequence (rgb.txt); choose another folder")


def refuse_earlier_run(out: Path, resume: bool, overwrite: bool) -> None:
    """A training command's ``--out``: refuse a folder that holds an earlier run's checkpoint unless
    ``--resume`` continues it or ``--overwrite`` starts again (one line, before any work)."""
    if (out / CHECKPOINT).exists() and not (resume or overwrite):
        raise UsageError(f"--out {out} already holds a training run ({out / CHECKPOINT}); pass --resume to "
                         "continue it, --overwrite to start again, or choose another folder")


_MARKUP = [
    (re.compile(r":(?:mod|func|class|meth|attr|data):`~?([^`]+)`"), r"\1"),  # :mod:`x` -> x
    (re.compile(r"``([^`]+)``"), r"\1"),  # ``x`` -> x
    (re.compile(r"`([^`]+)`"), r"\1"),
    (re.compile(r"\*\*([^*]+)\*\*"), r"\1"),
]


def plain_text(text: str | None) -> str | None:
    """Docstring markup (reST literals and roles, markdown bold) removed, for help texts."""
    if text is None:
        return None
    for pattern, repl in _MARKUP:
        text = pattern.sub(repl, text)
    return text


def description(doc: str) -> str:
    """A module docstring as a help description: its paragraphs without the ``Usage::`` block
    (argparse prints the usage itself), markup removed."""
    kept, skip = [], False
    for para in doc.strip().split("\n\n"):
        if para.strip() == "Usage::":
            skip = True
            continue
        if skip and para.startswith("    "):
            continue
        skip = False
        kept.append(para)
    return plain_text("\n\n".join(kept))


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Help texts without markup, with every option's default shown: " (default: X)" is added to an
    option's help unless the help mentions its default already or there is none (None, False)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = plain_text(action.help or "")
        default = action.default
        if (
            action.option_strings
            and not (default is None or default is False or default is argparse.SUPPRESS)
            and "default" not in text
            and "%(default)" not in text
        ):
            text += " (default: %(default)s)"
        return text

    def _format_text(self, text: str) -> str:
        return super()._format_text(plain_text(text))
