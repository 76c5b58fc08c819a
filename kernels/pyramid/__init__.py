"""Image and depth pyramids for coarse-to-fine alignment (no torch).

Level ``l + 1`` halves level ``l``: output pixel ``(x', y')`` covers the 2x2 input pixels ``(2x' + i,
2y' + j)``, i, j in {0, 1}, so with the pixel-centre convention of ``docs/conventions.md`` a position
maps as ``x' = (x + 0.5) / 2 - 0.5`` and the intrinsics as ``fx' = fx / 2``, ``cx' = (cx + 0.5) / 2 -
0.5`` (:func:`scale_intrinsics`). Odd sizes drop the last row / column: ``H' = H // 2``.

- Intensities: the mean of the 2x2 block (per channel).
- Depths: 0, NaN, +-inf and negative values mean "no depth" and are written as 0. The output is the
  mean of the valid taps that lie on the nearest surface of the block, i.e. within a relative
  ``tolerance`` of the smallest valid depth (``d <= d_min (1 + tolerance)``); farther taps (the
  other side of a depth edge) are left out, so no depth is invented between a foreground and a
  background surface. A block with no valid tap gives 0.

:func:`prepare_level0` converts an input frame to the pyramid's base level: channels mixed by a
weight matrix (e.g. RGB to one intensity), depths cleaned as above; a non-finite intensity is read
as 0 and its pixel's depth becomes missing, so it is never used as a reference pixel. A depth that
differs from a valid 4-neighbour's by more than the relative ``tolerance`` (``|d - e| > tolerance
min(d, e)``: the two lie on different surfaces) is written as 0 too, on both sides of such a depth
edge: there a pixel's colour mixes both surfaces (anti-aliasing, blur, the sensor's footprint) while
its depth is one of them, so it moves inconsistently between views. Used as reference pixels, the
mixed pixels at the top edges of objects standing in front of a background biased the photometric
optimum (issue 15: +0.004 cm in y per pair at 640x480 with the occlusion test, removed by this);
used as live depths, they fail the occlusion test of samples next to an edge. The coarser levels
inherit the gaps through the downsampling.

Shapes: images (B, C, H, W), depths (B, 1, H, W), float32 or float64 (one type per call).

The kernels (:mod:`.kernels`, one pixel at a time; :mod:`.lanes_kernels`, 8 at a time for one
output channel and widths a multiple of 8) are made on first use for their channel counts; the
host functions (:mod:`.pipeline`) launch the scalar ones.
"""

from .kernels import downsample_kernel, level0_kernel, level0_remap_kernel
from .lanes_kernels import downsample_lanes_kernel, level0_lanes_kernel, level0_remap_lanes_kernel
from .pipeline import DEPTH_TOLERANCE, downsample, prepare_level0, pyramid_shapes, scale_intrinsics

__all__ = [
    "DEPTH_TOLERANCE",
    "downsample",
    "downsample_kernel",
    "downsample_lanes_kernel",
    "level0_kernel",
    "level0_remap_kernel",
    "level0_remap_lanes_kernel",
    "level0_lanes_kernel",
    "prepare_level0",
    "pyramid_shapes",
    "scale_intrinsics",
]
