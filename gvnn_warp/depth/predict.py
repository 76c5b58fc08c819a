"""Depth predicted by a trained depth network, frame by frame, for tracking from colour alone.

:class:`DepthPredictor` turns a colour frame (3, H, W) into a depth image (1, H, W) that the direct
aligner takes in place of a sensor's (``gvnn-warp track --depth predicted``): the frame is resized to
the network's size (antialiased bilinear), the full-resolution head's depth is resized back
(bilinear) and multiplied by one scale for the whole sequence, fixed at the first frame so that its
median depth is ``first_median`` metres. Monocular depth has no scale of its own: a trajectory tracked
with it is compared with the truth after a similarity (scale) alignment (``evo_ape -as``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ..odometry.inputs import as_numpy, colour_values, fail
from ..vo.frontend import resize_frame
from .checkpoint import load_checkpoint, load_depth_net

__all__ = ["DepthPredictor"]


class DepthPredictor:
    """``predictor(image)``: image (3, H, W) float32/float64 numpy or torch in [0, 1] -> depth (1, H, W)
    float32 numpy (see the module docstring). Values beyond [0, 1] (8-bit intensities) are warned
    about once; NaN and infinite pixels are taken as 0 (black), also warned about once.
    ``checkpoint``: the ``checkpoint.pt`` of ``gvnn-warp depth train`` (``CheckpointError`` for
    anything else); ``first_median``: metres, the median depth of the first frame predicted (> 0)."""

    def __init__(self, checkpoint: str | Path, first_median: float = 1.0):
        if not first_median > 0:
            raise ValueError(f"DepthPredictor: first_median must be > 0 metres, got {first_median!r}")
        ck = load_checkpoint(checkpoint)
        self.checkpoint = Path(checkpoint)
        self.net = load_depth_net(ck)
        self.size = tuple(ck["config"]["size"])  # (W, H) the network was trained at
        self.first_median = float(first_median)
        self.scale: float | None = None  # fixed by the first frame
        self._warned: set[str] = set()  # (each warning once)

    def __call__(self, image) -> np.ndarray:
        fn = "gvnn_warp.depth.DepthPredictor"
        img = as_numpy(fn, "image", image, (3,))  # (integer images refused, with what to do)
        if img.shape[0] != 3:
            hint = ", which looks channel-last (H, W, 3): transpose it" if img.shape[-1] == 3 else ""
            fail(fn, ValueError, f"argument 'image' must be (3, H, W) RGB, got {img.shape}{hint}")
        img = colour_values(fn, "image", img, self._warned, ", and the depth differs otherwise")
        image = torch.from_numpy(np.ascontiguousarray(img, dtype=np.float32))
        H, W = image.shape[-2:]
        small, _ = resize_frame(image, torch.zeros(1, H, W), self.size)
        with torch.no_grad():
            depth = self.net.depth(small)
        depth = F.interpolate(depth, size=(H, W), mode="bilinear", align_corners=False)[0]
        if self.scale is None:
            self.scale = self.first_median / float(depth.median())
        return (depth * self.scale).numpy()
