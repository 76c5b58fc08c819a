"""A frame prepared for alignment: its image (and depth) pyramid, in buffers that are reused.

:class:`Frame` is what :meth:`gvnn_warp.odometry.DirectAligner.prepare` returns. Its pyramid lives
in :class:`PyramidBuffers`: the buffers of every level of one frame size, preallocated, with the
Warp launches of :mod:`gvnn_warp.kernels.pyramid` that fill them recorded once; the aligner keeps
the buffers of dropped frames in a pool (:func:`recycle`) and fills them again for a new frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import warp as wp

from ..kernels import pyramid as _pyramid
from ..kernels.core import compat as _compat
from ..kernels.core import launch as _launch

__all__ = ["Frame", "PyramidBuffers", "recycle"]

POOL_SIZE = 4  # pyramids of dropped frames kept per frame size for reuse
_GRAIN = 32768  # pyramid launches split over threads in pieces of at least this many pixels


@dataclass(eq=False)
class Frame:
    """One RGB-D frame (or a batch of B frames) prepared for alignment by :meth:`DirectAligner.prepare`.

    Attributes:
        images: per level (fine to coarse) a ``wp.array`` (B, C', H_l, W_l) float32 (C' = 1 unless
            the aligner keeps colour).
        depths: per level a ``wp.array`` (B, 1, H_l, W_l) float32 (0 = no depth), or None for a
            frame given without depth (usable only as the live frame of a pair).
        batched: whether the input had a batch dimension.
        torch: whether the input was a torch tensor (results come back as torch tensors).
    """

    images: list
    depths: list | None
    batched: bool
    torch: bool
    _mean_depth: np.ndarray | None = field(default=None, repr=False)

    @property
    def batch(self) -> int:
        return int(self.images[0].shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the finest level."""
        return int(self.images[0].shape[2]), int(self.images[0].shape[3])

    def mean_depth(self) -> np.ndarray:
        """(B,) mean valid depth of the coarsest level (1 where there is none)."""
        if self._mean_depth is None:
            d = self.depths[-1].numpy().reshape(self.batch, -1)
            n = (d > 0).sum(1)
            self._mean_depth = np.where(n > 0, d.sum(1, dtype=np.float64) / np.maximum(n, 1), 1.0)
        return self._mean_depth


def recycle(pool: list, pyramid: PyramidBuffers) -> None:
    """Give a dropped frame's buffers back to its pool (up to POOL_SIZE kept per frame size)."""
    if len(pool) < POOL_SIZE:
        pool.append(pyramid)


def _out_view(a: wp.array, lanes: bool) -> wp.array:
    """A flat view of an output buffer: float32 scalars, or vec8 (8 consecutive pixels) for the
    8-lane kernels (an empty one for a missing or empty buffer)."""
    if lanes and a.size > 0:
        return _compat.alias(a, _launch.vec8f, (a.size // 8,))
    if lanes:
        return wp.empty(0, dtype=_launch.vec8f, device="cpu")
    return a.flatten()


class PyramidBuffers:
    """Preallocated pyramid buffers of one frame size, with the launches that fill them recorded
    once (a recorded launch replays in a few microseconds); reused through the aligner's pool.
    ``resample``: a :class:`~gvnn_warp.kernels.sampling.remap.RemapTable` through which each frame
    (B, C, H, W), of the table's source size, is resampled in the base level's pass, which is then of
    the table's output size."""

    def __init__(self, B: int, C: int, H: int, W: int, with_depth: bool, *, levels: int, weights: wp.array,
                 color: bool, depth_tolerance: float, resample=None):
        Co = C if color else 1
        self.key = (B, C, H, W, with_depth)
        if resample is not None:  # (the base level is the table's output)
            H, W = resample.out_height, resample.out_width
        self.shapes = _pyramid.pyramid_shapes(H, W, levels)
        self.images = [wp.empty((B, Co, h, w), dtype=wp.float32, device="cpu") for h, w in self.shapes]
        self.depths = [wp.empty((B, 1, h, w), dtype=wp.float32, device="cpu") for h, w in self.shapes] if with_depth \
            else None
        empty = wp.empty(0, dtype=wp.float32, device="cpu")
        depths = self.depths or [empty] * len(self.shapes)
        f32 = wp.float32
        self.weights = weights
        # the 8-lane kernels where the rows are whole vectors (one output channel for the base level)
        lanes = Co == 1 and W % 8 == 0
        self.lanes0 = lanes and resample is None  # (fill() then also passes the depth as vec8)
        if resample is None:
            kernel = _pyramid.level0_lanes_kernel(C) if lanes else _pyramid.level0_kernel(C, Co)
            extra, source = [_out_view(empty, True)] if lanes else [], []
        else:  # the frame resampled through a RemapTable as the base level is made
            t = resample
            kernel = _pyramid.level0_remap_lanes_kernel(C) if lanes else _pyramid.level0_remap_kernel(C, Co)
            extra, source = [t.base, t.wx, t.wy, t.index], [t.width, t.width * t.height]
        self.level0 = _launch.RecordedLaunch(
            kernel[f32], B * H,
            [empty, self.weights.flatten(), empty, *extra, H, W, *source, int(with_depth), depth_tolerance],
            [_out_view(self.images[0], lanes), _out_view(depths[0], lanes)], work=W, grain=_GRAIN,
        )
        self.down = []
        for k in range(1, len(self.shapes)):
            (h, w), (ho, wo) = self.shapes[k - 1], self.shapes[k]
            lanes = wo % 8 == 0
            self.down.append(_launch.RecordedLaunch(
                (_pyramid.downsample_lanes_kernel(Co) if lanes else _pyramid.downsample_kernel(Co))[f32], B * ho,
                [self.images[k - 1].flatten(), depths[k - 1].flatten() if with_depth else empty,
                 h, w, ho, wo, depth_tolerance, int(with_depth)],
                [_out_view(self.images[k], lanes), _out_view(depths[k], lanes)], work=wo,
                grain=_GRAIN,
            ))

    def fill(self, image: np.ndarray, depth: np.ndarray | None) -> None:
        self.level0.set_arg(0, wp.array(image.reshape(-1), dtype=wp.float32, device="cpu", copy=False))
        if depth is not None:
            d = wp.array(depth.reshape(-1), dtype=wp.float32, device="cpu", copy=False)
            self.level0.set_arg(2, d)
            if self.lanes0:  # the 8-lane kernel also reads the depth as vec8
                self.level0.set_arg(3, _out_view(d, True))
        self.level0()
        for run in self.down:
            run()
