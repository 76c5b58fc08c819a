"""The bilinear sampler (``@wp.func``, no launches here): one position per call with its custom
adjoint (:mod:`.scalar`), and 8 positions per call as length-8 vectors, forward only, the same
values bitwise (:mod:`.lanes`). Kernels name its functions through this module
(``sampler.sample_channels``, ``sampler.gather_lanes``...); the conventions (flat (B, C, H, W)
images, pixel positions, padding modes as ``grid_sample``'s) are in :mod:`.scalar`.
"""

from .lanes import (
    LANES,
    MAX_LANES_PLANE,
    blend_lanes,
    clamp_lanes,
    dense,
    floor_lanes,
    gather_lanes,
    inside_flag,
    normalized_to_pixel_lanes,
    planes_view,
    sample_lanes,
    sample_position_lanes,
    taps_lanes,
)
from .scalar import (
    INSIDE_TOLERANCE,
    PADDING_BORDER,
    PADDING_MODES,
    PADDING_ZEROS,
    UNROLLED_CHANNELS,
    bilinear,
    bilinear_taps,
    normalized_to_pixel,
    sample_channels,
    sample_channels_grad,
    sample_channels_values,
    sample_position,
    tap,
)

__all__ = [
    "INSIDE_TOLERANCE",
    "LANES",
    "MAX_LANES_PLANE",
    "PADDING_BORDER",
    "PADDING_MODES",
    "PADDING_ZEROS",
    "UNROLLED_CHANNELS",
    "bilinear",
    "bilinear_taps",
    "blend_lanes",
    "clamp_lanes",
    "dense",
    "floor_lanes",
    "gather_lanes",
    "inside_flag",
    "normalized_to_pixel",
    "normalized_to_pixel_lanes",
    "planes_view",
    "sample_channels",
    "sample_channels_grad",
    "sample_channels_values",
    "sample_lanes",
    "sample_position",
    "sample_position_lanes",
    "tap",
    "taps_lanes",
]
