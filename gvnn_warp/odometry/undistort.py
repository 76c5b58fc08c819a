"""A lens camera tracked with the pinhole's kernels: each frame resampled once into an ideal pinhole image.

:class:`UndistortingAligner` wraps a pinhole :class:`~.aligner.DirectAligner`: ``prepare`` resamples
each frame once - colour bilinearly, depth from the nearest pixel (no depth is invented across an
edge) - at the positions where the pixels of an ideal pinhole camera fall in the lens image
(``u = K distort(K_ideal^-1 [x, y, 1])``, computed once per camera, a
:class:`~gvnn_warp.kernels.sampling.remap.RemapTable`), in the same pass that makes the pyramid's
base level (``DirectAligner(K_ideal, resample=table)``), and the aligner then runs on pinhole
images, whose fused kernels use the pinhole's row-linear fast path. :meth:`UndistortingAligner.undistort`
gives the resampled frame itself. The ideal camera (:func:`ideal_camera`) keeps the lens's focal
lengths and is the largest crop whose every pixel falls inside the lens image and the model's
domain (OpenCV's ``getOptimalNewCameraMatrix`` with alpha 0 keeps only such pixels too, but
magnifies them to the full size): an ideal image with no empty border, whose edge the aligner would otherwise take
for the scene's, and with no more pixels than the lens gives there (a magnified 640x480 ideal image
of the same region cost 4-9% more time per pair: more pixels, and larger motions in pixels). The
poses are those of the same physical camera (the resampling changes the pixels, not the camera
centre or orientation). What it changes: the images are interpolated once more (the exact path,
``DirectAligner(K, model="radtan", dist=...)``, moves rays through the lens instead), and the lens
pixels outside the ideal image (a border where the lens bends the image's edges in; ~12% of a
Freiburg 1 frame's: 600x454 of 640x480) are not used.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..kernels.core.kinds import vec8d
from ..kernels.core.launch import launch
from ..kernels.geometry import kernels as geometry_kernels
from ..kernels.geometry import lens as _lens
from ..kernels.sampling.remap import RemapTable, remap, remap_rgbd
from .inputs import MIN_SIDE, as_numpy, fail

__all__ = ["UndistortingAligner", "ideal_camera", "lens_positions"]


def lens_positions(K: np.ndarray, dist, width: int, height: int, K_ideal: np.ndarray | None = None) -> np.ndarray:
    """(H * W, 2) float32 positions (u, v) in the lens image (intrinsics ``K``, radial-tangential
    ``dist`` = k1, k2, p1, p2, k3) of the pixels of the ideal pinhole camera ``K_ideal`` (default
    ``K``); (-1, -1) beyond the model's domain. Each ideal pixel is re-expressed in ``K`` (the same
    ray) and distorted by the lens model's own kernel (``lens.distort_pixel``)."""
    K = np.asarray(K, dtype=np.float64)
    Ki = K if K_ideal is None else np.asarray(K_ideal, dtype=np.float64)
    x, y = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    rays = np.stack([(x - Ki[0, 2]) / Ki[0, 0], (y - Ki[1, 2]) / Ki[1, 1]], -1).reshape(-1, 2)
    n = rays.shape[0]
    pixels = wp.array(rays * np.diag(K)[:2] + K[:2, 2], dtype=wp.vec2d, device="cpu")
    model = _lens.MODEL_IDS["radtan"]
    out = wp.empty(n, dtype=wp.vec2d, device="cpu")
    valid = wp.empty(n, dtype=bool, device="cpu")
    launch(geometry_kernels.distort_pixels_lens()[wp.float64], n,
           [pixels, wp.array(K[None], dtype=wp.mat33d, device="cpu"),
            wp.array(_lens.pack_dist(model, dist)[None], dtype=vec8d, device="cpu"), n, model], [out, valid])
    positions = out.numpy()
    positions[~valid.numpy()] = -1.0
    return positions.astype(np.float32)


def ideal_camera(K: np.ndarray, dist, width: int, height: int) -> tuple[np.ndarray, tuple[int, int]]:
    """The ideal pinhole camera of a lens frame of ``width`` x ``height`` (see the module docstring):
    (``K_ideal`` (3, 3), (W', H')), the focal lengths ``K``'s, the largest crop (its sides shrunk by
    the smallest factor in [1, 3), steps of 0.5%; W' a multiple of 8, the 8-lane kernels' rows, from
    64 pixels on) whose pixels all fall inside the lens image, each crop tried where the lens image
    leaves it even margins (the lens need not be centred: its principal point moves by the crop's
    margin, then by half the difference of the margins, up to three times). For a lens so strong
    that none fits, the last tried (the pixels outside have no data)."""
    K = np.asarray(K, dtype=np.float64)
    last = None
    for scale in np.arange(1.0, 3.0, 0.005):
        w = min(width, 8 * int(width / scale / 8) if width >= 64 else int(width / scale))
        h = min(height, int(height / scale))
        if min(w, h) < MIN_SIDE:
            break
        Ki = K.copy()  # a crop at the same focal lengths: the principal point moves by the margin
        Ki[0, 2], Ki[1, 2] = K[0, 2] - (width - w) / 2, K[1, 2] - (height - h) / 2
        for _ in range(3):  # even the margins: move the crop by half their difference (ray ~ pixel near
            # the edges; a few steps settle it)
            pos = lens_positions(K, dist, w, h, Ki)
            if (pos == -1).all(axis=1).any():  # beyond the model's domain
                break
            slack = np.array([pos[:, 0].min(), width - 1 - pos[:, 0].max(), pos[:, 1].min(),
                              height - 1 - pos[:, 1].max()])
            if slack[0] + slack[1] < 0 or slack[2] + slack[3] < 0:  # too large whatever its place
                break
            if slack.min() >= 0:
                return Ki, (w, h)
            Ki[0, 2] -= (slack[1] - slack[0]) / 2
            Ki[1, 2] -= (slack[3] - slack[2]) / 2
        last = (Ki, (w, h))
    return last if last is not None else (K.copy(), (width, height))


class UndistortingAligner:
    """The direct aligner of a radial-tangential camera through one resampling per frame (see the
    module docstring). ``K`` (3, 3) and ``dist`` (k1, k2, p1, p2, k3) of the lens images of ``size``
    (W, H); ``**kwargs``: the :class:`~.aligner.DirectAligner`'s other settings. Same interface:
    ``prepare``, ``align_frames``, ``align``."""

    concurrent_prepare = True

    def __init__(self, K, dist, size: tuple[int, int], **kwargs):
        from .aligner import DirectAligner

        self.width, self.height = int(size[0]), int(size[1])
        dist = np.asarray(dist, dtype=np.float64).reshape(-1)
        if dist.shape != (5,) or not np.all(np.isfinite(dist)):
            fail("UndistortingAligner", ValueError, f"argument 'dist' must be 5 finite coefficients (k1, k2, p1, "
                                                    f"p2, k3), got {dist.tolist()}")
        K = np.asarray(K, dtype=np.float64)
        self.K, self.dist = K, dist
        self.K_ideal, self.ideal_size = ideal_camera(K, dist, self.width, self.height)
        w, h = self.ideal_size
        self.table = RemapTable(lens_positions(K, dist, w, h, self.K_ideal), self.width, self.height, out_size=(w, h))
        self.aligner = DirectAligner(self.K_ideal, resample=self.table, **kwargs)

    def undistort(self, image, depth=None):
        """(image, depth) of a lens frame ((C, H, W), (1, H, W)) as the ideal pinhole camera's
        ``K_ideal``: ((C, H', W'), (1, H', W')), (W', H') = ``ideal_size``."""
        img = as_numpy("UndistortingAligner.undistort", "image", image, (3,))
        if img.shape[1:] != (self.height, self.width):
            fail("UndistortingAligner.undistort", ValueError, f"argument 'image' must be (C, {self.height}, "
                                                              f"{self.width}), got {img.shape}")
        if depth is None:
            return remap(img, self.table), None
        d = as_numpy("UndistortingAligner.undistort", "depth", depth, (3,))
        if d.shape != (1, self.height, self.width):
            fail("UndistortingAligner.undistort", ValueError, f"argument 'depth' must be (1, {self.height}, "
                                                              f"{self.width}), got {d.shape}")
        return remap_rgbd(img, d, self.table)

    def prepare(self, image, depth=None):
        """The pyramid of a lens frame (or a batch), resampled into the ideal camera as its base level
        is made."""
        for name, a in (("image", image), ("depth", depth)):
            if a is not None and tuple(np.shape(a)[-2:]) != (self.height, self.width):
                fail("UndistortingAligner.prepare", ValueError, f"argument '{name}' must be {self.width}x"
                                                                f"{self.height} pixels, got shape {tuple(np.shape(a))}")
        return self.aligner.prepare(image, depth)

    def align_frames(self, ref, live, init=None):
        return self.aligner.align_frames(ref, live, init)

    def align(self, ref_image, ref_depth, live_image, live_depth=None, init=None):
        return self.aligner.align_frames(self.prepare(ref_image, ref_depth), self.prepare(live_image, live_depth),
                                         init)
