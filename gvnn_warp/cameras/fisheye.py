"""The equidistant (Kannala-Brandt) fisheye camera model of ``cv2.fisheye``."""

from __future__ import annotations

from torch import Tensor

from ..kernels.geometry import lens
from .base import Camera

__all__ = ["FisheyeCamera"]


class FisheyeCamera(Camera):
    """The equidistant (Kannala-Brandt) fisheye of ``cv2.fisheye``: ``FisheyeCamera(K, dist)``,
    K (3, 3) or (B, 3, 3) (cv2.fisheye's skew alpha is K[0, 1] / K[0, 0]), dist (4,) or (B, 4) =
    (k1, k2, k3, k4)."""

    model = lens.FISHEYE
    n_coeffs = 4

    def __init__(self, K: Tensor, dist: Tensor):
        super().__init__(K, dist)
