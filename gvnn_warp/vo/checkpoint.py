"""The checkpoint of ``gvnn-warp vo`` (format 4, documented in ``docs/vo_checkpoint.md``) and the
trained network it holds.

A checkpoint holds only tensors, dicts, lists, tuples, str, int, float, bool and None, so it loads
with ``torch.load(path, weights_only=True)`` (no pickled code). Its ``"format"`` number changes
whenever what is stored changes; a file of another format is refused with a one-line
:class:`CheckpointError` (format 1 had no ``"format"`` key and held pickled numpy arrays; format 2
had no ``"network"`` entry, so the network could not be rebuilt without the training code's
defaults).

Checkpoints are written atomically (:func:`atomic_save`) and hold the global random generators'
state (:func:`rng_state`), so that a resumed run continues exactly.
"""

from __future__ import annotations

import os
import random
from pathlib import Path

import numpy as np
import torch

from ..errors import InputError
from .model import CascadeVO

__all__ = [
    "CHECKPOINT",
    "CHECKPOINT_FORMAT",
    "CheckpointError",
    "atomic_save",
    "atomic_write_text",
    "build_network",
    "checkpoint_file",
    "load_file",
    "load_network",
    "network_spec",
    "read_checkpoint",
    "rng_state",
    "set_rng_state",
]

CHECKPOINT = "checkpoint.pt"  # its file name in a run's output directory
CHECKPOINT_FORMAT = 4

# the CascadeVO constructor arguments stored under "network" -> "kwargs"
_NETWORK_KEYS = ("motion", "scales", "size", "widths", "depth_input", "n_head_layers", "omega_scale", "t_scale",
                 "depth_normalised_t")


class CheckpointError(InputError):
    """A file that is not a checkpoint this gvnn_warp can use; the message is one line naming the file."""


def network_spec(cfg, K: torch.Tensor) -> dict:
    """The ``"network"`` entry of a checkpoint of a run with config ``cfg`` whose training frames have
    intrinsics ``K`` (3, 3) at the network's size."""
    kwargs = {
        "motion": cfg.motion, "scales": tuple(int(s) for s in cfg.stage_scales), "size": tuple(cfg.size),
        "widths": tuple(cfg.widths), "depth_input": bool(cfg.depth_input), "n_head_layers": int(cfg.n_head_layers),
        "omega_scale": float(cfg.omega_scale), "t_scale": float(cfg.t_scale),
        "depth_normalised_t": bool(cfg.depth_normalised_t),
    }
    return {"class": "CascadeVO", "kwargs": kwargs, "refine": int(cfg.refine),
            "symmetries": [str(n) for n in cfg.symmetries], "intrinsics": K.detach().to(torch.float64).clone()}


def build_network(spec: dict) -> CascadeVO:
    """An untrained :class:`CascadeVO` of the shape ``spec`` (a checkpoint's ``"network"`` entry) describes."""
    kw = dict(spec["kwargs"])
    return CascadeVO(kw.pop("motion"), scales=tuple(kw.pop("scales")), size=tuple(kw.pop("size")),
                     widths=tuple(kw.pop("widths")), **kw)


def checkpoint_file(path: str | Path, what: str, writer: str) -> Path:
    """``path`` as a Path if it is a file; :class:`CheckpointError` naming it otherwise (a run's folder:
    the file in it, if there is one; ``writer``: the command that writes OUT/checkpoint.pt)."""
    path = Path(path)
    if path.is_dir():
        inside = path / CHECKPOINT
        hint = f": give the file in it, {inside}" if inside.is_file() else f" ({writer} writes OUT/{CHECKPOINT})"
        raise CheckpointError(f"{what} {path}: a folder, not a file{hint}")
    if not path.is_file():
        raise CheckpointError(f"{what} {path}: no such file" if not path.exists() else f"{what} {path}: not a file")
    return path


def load_file(path: Path, what: str, not_loadable: str):
    """``torch.load(path, weights_only=True)``; :class:`CheckpointError` naming the file if it cannot be
    read, or, with ``not_loadable`` (its ``{}``: the error's type), if it is no torch file of tensors
    and plain values."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except OSError as e:  # (unreadable: not a question of its contents)
        raise CheckpointError(f"{what} {path}: cannot be read ({e.strerror or type(e).__name__})") from None
    except Exception as e:  # pickle.UnpicklingError for pickled objects other than tensors and containers,
        # RuntimeError / EOFError for a file that is not a torch save at all
        raise CheckpointError(f"{what} {path}: " + not_loadable.format(type(e).__name__)) from None


def read_checkpoint(path: str | Path, what: str = "checkpoint") -> dict:
    """Load a checkpoint with ``weights_only=True`` and check its format; :class:`CheckpointError` otherwise."""
    path = checkpoint_file(path, what, "gvnn-warp vo")
    ck = load_file(path, what, "not a gvnn-warp vo checkpoint this version can load safely ({}; written by an older "
                               "version, or not a checkpoint)")
    if not isinstance(ck, dict) or ck.get("format") != CHECKPOINT_FORMAT:
        found = ck.get("format", 1) if isinstance(ck, dict) else "?"
        if isinstance(found, str) and found.startswith("gvnn_warp.depth/"):  # (depth.train's formats)
            raise CheckpointError(f"{what} {path}: a depth network's checkpoint (gvnn-warp depth train), not a "
                                  "learned-VO one (gvnn-warp vo); track takes it with --depth predicted "
                                  "--checkpoint")
        raise CheckpointError(f"{what} {path}: checkpoint format {found}, this gvnn_warp reads format "
                              f"{CHECKPOINT_FORMAT} (written by another version: train it again with gvnn-warp vo)")
    missing = [k for k in ("config", "model", "network", "step") if k not in ck]
    if missing:
        raise CheckpointError(f"{what} {path}: format {CHECKPOINT_FORMAT} checkpoint without {', '.join(missing)}")
    return ck


def load_network(path: str | Path) -> tuple[CascadeVO, dict]:
    """The trained network of a checkpoint (in eval mode) and the checkpoint's ``"network"`` entry."""
    ck = read_checkpoint(path)
    spec = ck["network"]
    try:
        net = build_network(spec)
        net.load_state_dict(ck["model"])
    except (KeyError, TypeError, ValueError, RuntimeError) as e:
        raise CheckpointError(f"checkpoint {path}: its network cannot be rebuilt ({type(e).__name__}: "
                              f"{str(e).splitlines()[0] if str(e) else ''})") from None
    net.eval()
    return net, spec


def atomic_save(obj, path: Path) -> None:
    """``torch.save`` to a temporary file in ``path``'s folder, then renamed over ``path``: a run
    stopped while saving leaves the previous checkpoint whole."""
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def atomic_write_text(text: str, path: Path) -> None:
    """Write ``text`` to ``path`` through a temporary file renamed over it (as :func:`atomic_save`)."""
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)


def rng_state() -> dict:
    """The global generators' states as tensors and plain Python values (see CHECKPOINT_FORMAT)."""
    name, keys, pos, has_gauss, cached = np.random.get_state()
    numpy_state = {"name": name, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
                   "has_gauss": int(has_gauss), "cached_gaussian": float(cached)}
    return {"torch": torch.get_rng_state(), "numpy": numpy_state, "python": random.getstate()}


def set_rng_state(state: dict) -> None:
    """Restore the global generators from :func:`rng_state`'s dict."""
    torch.set_rng_state(state["torch"])
    n = state["numpy"]
    np.random.set_state((n["name"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"],
                         n["cached_gaussian"]))
    version, internal, gauss = state["python"]
