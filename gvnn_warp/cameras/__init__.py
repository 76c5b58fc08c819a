"""Camera models for the torch front: pinhole, radial-tangential (OpenCV) and fisheye
(cv2.fisheye), differentiable in all their parameters, one model per module (:mod:`.pinhole`,
:mod:`.radtan`, :mod:`.fisheye`, over :mod:`.base`), and the functions that move pixels and images
between a distorted camera and its ideal pinhole (:mod:`.undistort`). Every op that takes ``K``
also takes a camera object in its place (:func:`.base.camera_args`; the fused ops:
:class:`.fused.FusedCamera`).

A camera object holds references to the tensors it is given (``K`` and ``dist``), so gradients
reach them. The models, their domain (where a point counts as valid) and the unprojection's
tolerance are in ``docs/conventions.md`` ("Camera models"); the pure-Warp functions are in
``gvnn_warp.kernels.geometry.lens``.
"""

from .._exports import lazy_exports

# the public names are those of the modules (their __all__), each loaded on first use
__getattr__, __dir__ = lazy_exports(__name__, ('base', 'pinhole', 'radtan', 'fisheye', 'undistort', 'fused'))
