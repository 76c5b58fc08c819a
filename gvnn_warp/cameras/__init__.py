"""Camera models for the torch front: pinhole, radial-tangential (OpenCV) and fisheye
(cv2.fisheye), differentiable in all their parameters, and the functions that move pixels and
images between a distorted camera and its ideal pinhole (:mod:`.models`). Every op that takes
``K`` also takes a camera object in its place.
"""

from . import models
from .models import *  # noqa: F403

__all__ = list(models.__all__)
