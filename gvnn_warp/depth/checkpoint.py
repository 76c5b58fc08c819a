"""Reading the checkpoints of ``gvnn-warp depth train`` (:func:`.train.train` writes them): what
``depth eval`` and ``track --depth predicted`` load, without the depth training's module (:mod:`.train`).

A checkpoint is a dict saved with ``torch.save`` and read with ``weights_only=True``: its
``format`` (:data:`CHECKPOINT_FORMAT`), the run's ``config`` (:class:`.train.DepthConfig` as a
dict), the kept depth network's weights ``depth_net`` and, to resume, the rest of the run's state.
Settings added after the first checkpoints were written are absent from those; :data:`BEFORE` says
what such a checkpoint did.
"""

from __future__ import annotations

from pathlib import Path

from ..vo.checkpoint import CheckpointError, checkpoint_file, load_file
from .model import DepthNet

__all__ = ["BEFORE", "CHECKPOINT_FORMAT", "load_checkpoint", "load_depth_net"]

CHECKPOINT_FORMAT = "gvnn_warp.depth/1"

# what checkpoints written before a setting existed did
BEFORE = {"norm": "none", "vary_gap": False, "all_targets": False}


def load_checkpoint(path: str | Path) -> dict:
    """A checkpoint of :func:`.train.train` (``torch.load`` with ``weights_only=True``);
    ``CheckpointError``, one line naming the file, for anything else."""
    path = checkpoint_file(path, "checkpoint", "gvnn-warp depth train")
    ck = load_file(path, "checkpoint", "not a checkpoint of gvnn-warp depth train ({}: not a torch file, or one "
                                       "that holds more than tensors and plain values)")
    if not isinstance(ck, dict) or ck.get("format") != CHECKPOINT_FORMAT:
        found = ck.get("format") if isinstance(ck, dict) else None
        if isinstance(found, int) and "network" in ck:  # (gvnn_warp.vo.checkpoint's formats are numbers)
            raise CheckpointError(f"checkpoint {path}: a learned-VO checkpoint (gvnn-warp vo), not a depth network's "
                                  "(gvnn-warp depth train); track takes it with --method vo --checkpoint")
        raise CheckpointError(f"checkpoint {path}: format {found!r}, not a depth checkpoint ({CHECKPOINT_FORMAT!r}, "
                              "written by gvnn-warp depth train)")
    return ck


def load_depth_net(ck: dict) -> DepthNet:
    """The trained depth network of a checkpoint (:func:`load_checkpoint`), in eval mode."""
    c = ck["config"]
    net = DepthNet(tuple(c["widths"]), c["min_depth"], c["max_depth"], c.get("norm", BEFORE["norm"]))
    net.load_state_dict(ck["depth_net"])
    return net.eval()
