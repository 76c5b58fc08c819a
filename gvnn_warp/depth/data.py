"""Video for the self-supervised depth networks: the colour frames of TUM-format folders
(``gvnn_warp.datasets.tum.read_tum``: rendered by ``gvnn-warp render`` or recorded by a Kinect),
resized to the network's size, as triplets (t - g, t, t + g) of one folder, with their camera. The
depth files are read for evaluation and figures only (``with_depth``); training never sees them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..cameras import RadTanCamera
from ..datasets.errors import DatasetError
from ..datasets.tum import read_tum
from ..progress import progress_bar
from ..vo.frontend import resize_frame, scale_intrinsics

__all__ = ["Video", "read_video"]


@dataclass
class Video:
    """Frames of one or more folders (see the module docstring).

    Attributes:
        images: (N, 3, H, W) float32 in [0, 1].
        depths: (N, 1, H, W) float32 metres (0 = none), or None when not read.
        targets: (T,) int64 indices into ``images`` of the triplets' middles t: the frames whose
            neighbours t - gap and t + gap are in the same folder, or with ``vary_gap`` (see
            :func:`read_video`) every frame with a neighbour on each side.
        reach: (T,) int64, each target's largest usable gap: ``gap``, or with ``vary_gap`` at most
            its distance to the nearer end of its folder.
        gap: frames between a triplet's target and its sources (the largest, with ``vary_gap``).
        folder: (N,) int64, the folder of each frame; ``roots``: the folders.
        K: (3, 3) float32 intrinsics at the network's size; ``dist``: (5,) float32 radial-tangential
            coefficients (k1, k2, p1, p2, k3) of the images, or None (a pinhole).
    """

    images: Tensor
    depths: Tensor | None
    targets: Tensor
    gap: int
    folder: Tensor
    roots: list[Path]
    K: Tensor
    dist: Tensor | None
    reach: Tensor | None = None  # (None: ``gap`` for every target)

    def camera(self):
        """The camera for ``gvnn_warp.reprojection_loss``: K, or a ``RadTanCamera`` with distortion."""
        return self.K if self.dist is None else RadTanCamera(self.K, self.dist)

    def triplets(self, idx: Tensor, gaps: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """target (B, 3, H, W) and sources (B, 2, 3, H, W) (frames t - g, t + g) of triplets ``idx``;
        g is each triplet's own in ``gaps`` (B,) (integers in [1, gap], each at most its target's
        ``reach``), or without it the largest its target allows (``gap``, or its ``reach``)."""
        t = self.targets[idx]
        reach = torch.full_like(t, self.gap) if self.reach is None else self.reach[idx]
        g = reach
        if gaps is not None:
            if gaps.shape != t.shape or bool(((gaps < 1) | (gaps > reach)).any()):
                near_end = "" if bool((reach == self.gap).all()) else \
                    f" and at most {reach.tolist()} (each target's reach)"
                raise ValueError(f"Video.triplets: argument 'gaps' must be {tuple(t.shape)} integers in "
                                 f"[1, {self.gap}]{near_end}, got {gaps.tolist()}")
            g = gaps
        return self.images[t], torch.stack([self.images[t - g], self.images[t + g]], 1)

    def true_depth(self, frame: int) -> Tensor | None:
        """The true depth (1, 1, H, W) of frame ``frame`` of the first folder, if the folder has a
        depth image for that frame (the video's own when read ``with_depth``; else the depth image
        associated with that colour image), for figures; None otherwise."""
        if self.depths is not None:  # (read with depth: the frames are the colour images with depth)
            dep = self.depths[frame][None]
            return dep if (dep > 0).any() else None
        try:
            colour = read_tum(self.roots[0], colour_only=True)
            seq = read_tum(self.roots[0])  # (its frames: the colour images with a depth image)
            with_depth = np.flatnonzero(seq.timestamps == colour.timestamps[frame])
            if with_depth.size == 0:
                return None
            size = (self.images.shape[-1], self.images.shape[-2])
            _, dep = resize_frame(colour.image(frame), seq.depth(int(with_depth[0])), size)
        except (OSError, ValueError):  # (no depth list, or a depth image that cannot be read: none shown)
            return None
        return dep if (dep > 0).any() else None

    def draw_gaps(self, idx: Tensor, drawn: Tensor) -> Tensor:
        """Each triplet's gap from ``drawn`` (B,) integers in [1, gap] (uniform draws): at most its
        target's ``reach`` (a target near a folder's end takes the largest gap it has)."""
        return drawn if self.reach is None else torch.minimum(drawn, self.reach[idx])


def read_video(roots, size: tuple[int, int], *, gap: int = 1, vary_gap: bool = False, with_depth: bool = False,
               max_frames: int | None = None, progress: bool = False) -> Video:
    """Read the first ``max_frames`` frames of every folder of ``roots`` at ``size`` = (W, H)
    (colour: antialiased bilinear, depth: nearest; the intrinsics scaled to match), as triplets
    (t - gap, t, t + gap); with ``vary_gap``, triplets of any gap up to ``gap``, every frame with a
    neighbour on each side a target (those nearer than ``gap`` to a folder's end with gaps up to
    that distance: measured, the depth of unseen rooms generalised better than with only the
    frames ``gap`` from both ends). The folders must share one camera once resized; DatasetError
    otherwise, or for a folder of fewer than 2 gap + 1 frames (3 with ``vary_gap``)."""
    if not (isinstance(gap, (int, np.integer)) and gap >= 1):
        raise ValueError(f"read_video: argument 'gap' must be an integer >= 1, got {gap!r}")
    images, depths, targets, folder, reach = [], [], [], [], []
    K = dist = None
    n = 0
    seqs = [read_tum(r, colour_only=not with_depth) for r in roots]  # (no depth needed: colour video)
    bar = progress_bar(total=sum(len(s) if max_frames is None else min(len(s), max_frames) for s in seqs),
               desc="reading frames", unit="frame", disable=not progress, mininterval=0.5)
    for k, seq in enumerate(seqs):
        count = len(seq) if max_frames is None else min(len(seq), max_frames)
        least = 1 if vary_gap else gap  # (the smallest gap of a triplet)
        if count < 2 * least + 1:
            raise DatasetError(f"{seq.root / 'rgb.txt'}: {count} frames; triplets {least} frame"
                               f"{'s' if least > 1 else ''} apart need at least {2 * least + 1}")
        K_seq = scale_intrinsics(seq.K, (seq.width, seq.height), size)
        d_seq = None if seq.dist is None else np.asarray(seq.dist, dtype=np.float64)
        if K is None:
            K, dist, first = K_seq, d_seq, seq.root
        elif not np.allclose(K_seq, K, rtol=1e-4, atol=1e-3) or (d_seq is None) != (dist is None) or (
            d_seq is not None and not np.allclose(d_seq, dist)
        ):
            raise DatasetError(f"{seq.root}: its camera (intrinsics, distortion) at {size[0]}x{size[1]} differs from "
                               f"{first}'s (train on one camera)")
        for i in range(count):
            dep = seq.depth(i) if with_depth else np.zeros((1, seq.height, seq.width), np.float32)
            img, dep = resize_frame(seq.image(i), dep, size)
            images.append(img)
            depths.append(dep)
            bar.update()
        middle = np.arange(least, count - least)
        targets.append(n + middle)
        reach.append(np.minimum(np.minimum(middle, count - 1 - middle), gap))
        folder.append(np.full(count, k))
        n += count
    bar.close()
    return Video(
        images=torch.cat(images), depths=torch.cat(depths) if with_depth else None,
        targets=torch.from_numpy(np.concatenate(targets)).long(), gap=gap,
        reach=torch.from_numpy(np.concatenate(reach)).long(),
        folder=torch.from_numpy(np.concatenate(folder)),
        roots=[s.root for s in seqs], K=torch.from_numpy(K).float(),
        dist=None if dist is None else torch.from_numpy(dist).float(),
    )
