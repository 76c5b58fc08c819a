"""The one argument-checking helper used by every public function.

``ArgCheck("warp_frame_depth")`` binds symbolic dimensions across the arguments of one call, so
``chk.tensor("depth", depth, "B 1 H W")`` after ``chk.tensor("image", image, "B C H W")`` also
checks that the batch sizes and image sizes agree, and every message names the function, the
argument, what was expected and what came.

Shape specs are space-separated tokens: an integer (that size), ``a|b`` (one of these sizes), an
upper-case name (a size bound on first use and checked after), ``*`` (any size), and a leading
``...`` (any number of leading dimensions, including none).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

FLOAT_DTYPES = (torch.float32, torch.float64)


class ArgCheck:
    def __init__(self, fn: str):
        self.fn = f"gvnn_warp.{fn}"
        self.dims: dict[str, tuple[int, str]] = {}
        self.dtype: tuple[torch.dtype, str] | None = None

    def _fail(self, exc, msg: str):
        raise exc(f"{self.fn}: {msg}")

    def tensor(self, name: str, t, spec: str, *, floating: bool = True) -> torch.Tensor:
        """Check ``t`` is a CPU tensor of shape ``spec`` (and, if ``floating``, float32/float64,
        the same dtype as every other floating argument of the call). Returns ``t``."""
        if not isinstance(t, torch.Tensor):
            self._fail(TypeError, f"argument '{name}' must be a torch.Tensor, got {type(t).__name__}")
        if t.device.type != "cpu":
            self._fail(ValueError, f"argument '{name}' must be on the CPU, got device {t.device}")
        if floating:
            if t.dtype not in FLOAT_DTYPES:
                self._fail(TypeError, f"argument '{name}' must be float32 or float64, got {t.dtype}")
            if self.dtype is None:
                self.dtype = (t.dtype, name)
            elif t.dtype != self.dtype[0]:
                self._fail(
                    TypeError,
                    f"argument '{name}' has dtype {t.dtype} but '{self.dtype[1]}' has {self.dtype[0]}; "
                    "all floating arguments must share one dtype",
                )
        self._shape(name, tuple(t.shape), spec)
        return t

    def _shape(self, name: str, shape: tuple[int, ...], spec: str) -> None:
        tokens = spec.split()
        leading = bool(tokens) and tokens[0] == "..."
        if leading:
            tokens = tokens[1:]
        want = f"({', '.join(spec.split())})"
        if len(shape) < len(tokens) or (not leading and len(shape) != len(tokens)):
            self._fail(ValueError, f"argument '{name}' must have shape {want}, got {shape}")
        for tok, size in zip(tokens, shape[len(shape) - len(tokens) :]):
            if tok == "*":
                continue
            if tok[0].isdigit():
                allowed = [int(a) for a in tok.split("|")]
                if size not in allowed:
                    self._fail(ValueError, f"argument '{name}' must have shape {want}, got {shape}")
            elif tok in self.dims:
                bound, src = self.dims[tok]
                if size != bound:
                    self._fail(
                        ValueError,
                        f"argument '{name}' has {tok}={size} (shape {shape}) but '{src}' has {tok}={bound}",
                    )
            else:
                self.dims[tok] = (size, name)

    def option(self, name: str, value, allowed: Sequence):
        """Check ``value`` is one of ``allowed``; returns it."""
        if value not in allowed:
            self._fail(ValueError, f"argument '{name}' must be one of {list(allowed)}, got {value!r}")
        return value

    def positive(self, name: str, value) -> float:
        """Check ``value`` is a finite number > 0; returns it as float."""
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (0 < value < float("inf")):
            self._fail(ValueError, f"argument '{name}' must be a positive finite number, got {value!r}")
        return float(value)

    def dim(self, name: str) -> int:
        return self.dims[name][0]
