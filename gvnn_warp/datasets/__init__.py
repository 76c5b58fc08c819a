"""Readers and writers of RGB-D sequence formats (numpy and Pillow only; never imports torch or Warp).

- :mod:`gvnn_warp.datasets.tum`: TUM RGB-D / ICL-NUIM folders (``rgb.txt``, ``depth.txt``,
  ``groundtruth.txt``) and TUM trajectory files; its parts: :mod:`.trajectory` (trajectory files,
  quaternions, timestamp association and interpolation), :mod:`.intrinsics` (presets,
  ``intrinsics.txt``), :mod:`.images` (colour and depth PNGs), :mod:`.errors` (:class:`DatasetError`).
"""

from .tum import (
    DEFAULT_DEPTH_SCALE,
    DISTORTION_PRESETS,
    INTRINSICS_PRESETS,
    DatasetError,
    TUMSequence,
    TUMWriter,
    associate,
    intrinsics_preset,
    matrix_to_quaternion_xyzw,
    quaternion_xyzw_to_matrix,
    read_depth,
    read_rgb,
    read_trajectory,
    read_tum,
    write_trajectory,
)

__all__ = [
    "DEFAULT_DEPTH_SCALE",
    "DISTORTION_PRESETS",
    "INTRINSICS_PRESETS",
    "DatasetError",
    "TUMSequence",
    "TUMWriter",
    "associate",
    "intrinsics_preset",
    "matrix_to_quaternion_xyzw",
    "quaternion_xyzw_to_matrix",
    "read_depth",
    "read_rgb",
    "read_trajectory",
    "read_tum",
    "write_trajectory",
]
