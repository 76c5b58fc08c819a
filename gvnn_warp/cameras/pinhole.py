"""The ideal pinhole camera."""

from __future__ import annotations

from torch import Tensor

from ..kernels.geometry import lens
from .base import Camera

__all__ = ["PinholeCamera"]


class PinholeCamera(Camera):
    """The ideal pinhole: ``PinholeCamera(K)``, K (3, 3) or (B, 3, 3). Every op gives exactly
    (bitwise) what it gives for the tensor ``K`` itself."""

    model = lens.PINHOLE
    n_coeffs = 0

    def __init__(self, K: Tensor):
        super().__init__(K, None)
