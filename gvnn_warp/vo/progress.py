"""A small progress bar on stderr (no dependency): step count, loss, step rate and time left."""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["Progress"]


def _fmt_time(s: float) -> str:
    s = max(0, int(round(s)))
    return f"{s // 60:d}:{s % 60:02d}"


class Progress:
    """``Progress(total, initial=0, desc="")``; ``update(step, loss)`` redraws at most every
    ``min_interval`` seconds (always on the last step) and ``close()`` ends the line. When the stream
    is not a terminal it prints a plain line every ``log_interval`` seconds instead."""

    def __init__(
        self,
        total: int,
        initial: int = 0,
        desc: str = "",
        stream: TextIO | None = None,
        width: int = 24,
        min_interval: float = 0.2,
        log_interval: float = 10.0,
        enabled: bool = True,
    ):
        self.total, self.initial, self.desc, self.width = total, initial, desc, width
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.min_interval = min_interval if self.tty else log_interval
        self.enabled = enabled
        self.t0 = time.perf_counter()
        self.last_draw = -1e9
        self.step = initial

    def line(self, step: int, loss: float | None) -> str:
        elapsed = time.perf_counter() - self.t0
        done = step - self.initial
        rate = done / elapsed if elapsed > 0 and done > 0 else 0.0
        left = (self.total - step) / rate if rate > 0 else float("nan")
        frac = step / self.total if self.total else 1.0
        fill = int(round(frac * self.width))
        bar = "#" * fill + "." * (self.width - fill)
        loss_s = f" loss {loss:.4g}" if loss is not None else ""
        eta = _fmt_time(left) if left == left else "?"
        return (
            f"{self.desc} [{bar}] {step}/{self.total}{loss_s} {rate:.2f} it/s "
            f"elapsed {_fmt_time(elapsed)} left {eta}"
        )

    def update(self, step: int, loss: float | None = None) -> None:
        self.step = step
        if not self.enabled:
            return
        now = time.perf_counter()
        if now - self.last_draw < self.min_interval and step < self.total:
            return
        self.last_draw = now
        text = self.line(step, loss)
        if self.tty:
            self.stream.write("\r" + text + "\x1b[K")
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()
