"""Progress bars that suit where the output goes.

:func:`progress_bar` takes ``tqdm``'s arguments. On a terminal it is a ``tqdm`` bar; when standard
error is a file or a pipe (a log, CI), where a bar's carriage returns pile up into one unreadable
line, it prints the same status as whole lines instead, at most one every ``LOG_INTERVAL`` seconds
and one at the end.
"""

from __future__ import annotations

import sys

from tqdm import tqdm

__all__ = ["LOG_INTERVAL", "LineProgress", "progress_bar"]

LOG_INTERVAL = 10.0  # seconds between two status lines when standard error is not a terminal


class _Lines:
    """A stream that passes whole lines and drops the bare newline and carriage return with which
    ``tqdm`` ends or clears a bar."""

    def __init__(self, stream):
        self.stream = stream

    def write(self, text: str):
        if text not in ("\n", "\r"):
            self.stream.write(text)

    def flush(self):
        self.stream.flush()


class LineProgress(tqdm):
    """A ``tqdm`` that writes each status as a line of its own (no carriage returns)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if not self.disable:
            self.fp = _Lines(self.fp)

    def display(self, msg=None, pos=None):
        text = self.__str__() if msg is None else msg
        if text:
            self.fp.write(text + "\n")
            self.fp.flush()
        return True


def _is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # a closed or unusual stream
        return False


def progress_bar(*args, **kwargs) -> tqdm:
    """A ``tqdm(*args, **kwargs)`` bar on a terminal, else a :class:`LineProgress` (see the module
    docstring)."""
    stream = kwargs.get("file") or sys.stderr
    if _is_terminal(stream):
        return tqdm(*args, **kwargs)
    kwargs["mininterval"] = max(float(kwargs.get("mininterval", 0.1)), LOG_INTERVAL)
    kwargs.pop("dynamic_ncols", None)
    kwargs.setdefault("ncols", 100)
    return LineProgress(*args, **kwargs)
