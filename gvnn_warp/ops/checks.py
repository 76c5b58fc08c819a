"""The one argument-checking helper used by every public function (and :func:`flat`, which
gives a checked argument the shape the ops take).

``ArgCheck("warp_frame_depth")`` binds symbolic dimensions across the arguments of one call, so
``chk.tensor("depth", depth, "B 1 H W")`` after ``chk.tensor("image", image, "B C H W")`` also
checks that the batch sizes and image sizes agree, and every message names the function, the
argument, what was expected and what came.

Shape specs are space-separated tokens: an integer (that size), ``a|b`` (one of these sizes), an
upper-case name (a size bound on first use and checked after), ``*`` (any size), and a leading
``...`` (any number of dimensions, including none, at that place). ``spec1 or spec2`` accepts
either (alternatives of different ranks).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence

import numpy as np
import torch

FLOAT_DTYPES = (torch.float32, torch.float64)


class ArgCheck:
    def __init__(self, fn: str):
        self.fn = f"gvnn_warp.{fn}"
        self.dims: dict[str, tuple[int, str]] = {}
        self.dtype: tuple[torch.dtype, str] | None = None
        self.hint = ""  # added to shape errors: an image argument that looks channel-last

    def fail(self, exc, msg: str):
        raise exc(f"{self.fn}: {msg}{self.hint if exc is ValueError else ''}")

    def tensor(self, name: str, t, spec: str, *, floating: bool = True, image: bool = False) -> torch.Tensor:
        """Check ``t`` is a CPU tensor of shape ``spec`` (and, if ``floating``, float32/float64,
        the same dtype as every other floating argument of the call). Returns ``t``. ``image``: ``t``
        is an image whose channels come before its rows (``... C H W``); if it looks channel-last
        (last size 1, 3 or 4 and more than 4 "channels"), every later shape error of the call says so."""
        if not isinstance(t, torch.Tensor):
            self.fail(TypeError, f"argument '{name}' must be a torch.Tensor, got {type(t).__name__}")
        if t.device.type != "cpu":
            self.fail(ValueError, f"argument '{name}' must be on the CPU, got device {t.device}")
        if floating:
            if t.dtype not in FLOAT_DTYPES:
                self.fail(TypeError, f"argument '{name}' must be float32 or float64, got {t.dtype}")
            if self.dtype is None:
                self.dtype = (t.dtype, name)
            elif t.dtype != self.dtype[0]:
                self.fail(
                    TypeError,
                    f"argument '{name}' has dtype {t.dtype} but '{self.dtype[1]}' has {self.dtype[0]}; "
                    "all floating arguments must share one dtype",
                )
        if t.numel() >= 2**31:
            self.fail(ValueError, f"argument '{name}' has {t.numel()} elements; kernels index with int32 (< 2**31)")
        if image and t.dim() >= 3 and t.shape[-1] in (1, 3, 4) and t.shape[-3] > 4 and not self.hint:
            lead, n = ["B"] * (t.dim() - 3), t.dim()
            perm = ", ".join(map(str, [*range(n - 3), n - 1, n - 3, n - 2]))
            self.hint = (f" (argument '{name}' has shape {tuple(t.shape)}, which looks channel-last "
                         f"({', '.join([*lead, 'H', 'W', 'C'])}): images are ({', '.join([*lead, 'C', 'H', 'W'])}); "
                         f"use .permute({perm}))")
        alternatives = spec.split(" or ")
        if len(alternatives) > 1:  # pick the alternative of matching rank, for a specific message
            same_rank = [a for a in alternatives if len(a.split()) == t.dim()]
            if not same_rank:
                wants = " or ".join(f"({', '.join(a.split())})" for a in alternatives)
                self.fail(ValueError, f"argument '{name}' must have shape {wants}, got {tuple(t.shape)}")
            spec = same_rank[0]
        self.shape(name, tuple(t.shape), spec)
        return t

    def shape(self, name: str, shape: tuple[int, ...], spec: str) -> None:
        tokens = spec.split()
        want = f"({', '.join(tokens)})"
        if "..." in tokens:  # fixed tokens before and after any number of free dimensions
            k = tokens.index("...")
            head, tail = tokens[:k], tokens[k + 1 :]
            ok = len(shape) >= len(head) + len(tail)
            pairs = list(zip(head, shape)) + list(zip(tail, shape[len(shape) - len(tail) :] if tail else ()))
        else:
            ok = len(shape) == len(tokens)
            pairs = list(zip(tokens, shape))
        if not ok:
            self.fail(ValueError, f"argument '{name}' must have shape {want}, got {shape}")
        for tok, size in pairs:
            if tok == "*":
                continue
            if tok[0].isdigit():
                if size not in [int(a) for a in tok.split("|")]:
                    self.fail(ValueError, f"argument '{name}' must have shape {want}, got {shape}")
            elif tok in self.dims:
                bound, src = self.dims[tok]
                if size != bound:
                    self.fail(
                        ValueError,
                        f"argument '{name}' has {tok}={size} (shape {shape}) but '{src}' has {tok}={bound}",
                    )
            else:
                self.dims[tok] = (size, name)

    def pose(self, name: str, T, spec: str) -> torch.Tensor:
        """Check a pose of shape ``spec`` (e.g. ``"B 3|4 4"``: (B, 3, 4) or (B, 4, 4)); returns its
        top 3x4 block (a 4x4's last row is ignored)."""
        self.tensor(name, T, spec)
        return T[..., :3, :]

    def option(self, name: str, value, allowed: Sequence):
        """Check ``value`` is one of ``allowed``; returns it."""
        if value not in allowed:
            self.fail(ValueError, f"argument '{name}' must be one of {list(allowed)}, got {value!r}")
        return value

    def positive(self, name: str, value, dtype: torch.dtype | None = None) -> float:
        """Check ``value`` is a real number (Python or NumPy scalar, not bool) that is finite and
        > 0; returns it as float. With ``dtype``, also that its square is a normal number of that
        dtype (``value`` in [sqrt(tiny), sqrt(max)]: ~[1.1e-19, 1.8e19] for float32), so a scale c
        and c^2 survive the conversion to the kernel's precision."""
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            self.fail(TypeError, f"argument '{name}' must be a real number, got {type(value).__name__}")
        if not (0 < value < float("inf")):
            self.fail(ValueError, f"argument '{name}' must be a positive finite number, got {value!r}")
        value = float(value)
        if dtype is not None:
            info = torch.finfo(dtype)
            lo, hi = math.sqrt(info.tiny), math.sqrt(info.max)
            if not lo <= value <= hi:
                self.fail(ValueError, f"argument '{name}' must lie in [{lo:.3g}, {hi:.3g}] for {dtype}, got {value!r}")
        return value

    def dim(self, name: str) -> int:
        return self.dims[name][0]


def flat(t: torch.Tensor, inner: int) -> torch.Tensor:
    """(..., *inner dims) -> contiguous (n, *inner dims): a checked argument as the ops take it."""
    return t.reshape(-1, *t.shape[t.dim() - inner :]).contiguous()
