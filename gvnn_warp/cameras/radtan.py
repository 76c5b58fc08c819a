"""OpenCV's radial-tangential camera model."""

from __future__ import annotations

from torch import Tensor

from ..kernels.geometry import lens
from .base import Camera

__all__ = ["RadTanCamera"]


class RadTanCamera(Camera):
    """OpenCV's radial-tangential model: ``RadTanCamera(K, dist)``, K (3, 3) or (B, 3, 3), dist
    (5,) or (B, 5) = (k1, k2, p1, p2, k3) as ``cv2.projectPoints`` takes them."""

    model = lens.RADTAN
    n_coeffs = 5

    def __init__(self, K: Tensor, dist: Tensor):
        super().__init__(K, dist)
