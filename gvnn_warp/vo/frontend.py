"""The trained VO network as an odometry front end: alone, or as the initial guess of the direct aligner.

:class:`NetworkAligner` has the ``prepare(image, depth)`` / ``align_frames(ref, live, init=None)``
interface of :mod:`gvnn_warp.odometry.tracking`, so ``gvnn_warp.odometry.tracking.track`` runs it over a sequence
(``gvnn-warp track --method vo|vo+direct``). Frames of another size than the network's are resized
to it (:func:`resize_frame`: colour by antialiased bilinear filtering, depth by the nearest pixel
centre, so no depth is invented across edges) and the intrinsics scaled with the pixel-centre
convention of ``docs/conventions.md`` (``x' = (x + 0.5) s - 0.5``). With a
``gvnn_warp.odometry.DirectAligner`` (``vo+direct``) the network's estimate is the aligner's ``init``
and the aligner runs on the full-size frames; the pose the network returns is metric, so it does
not depend on the image size.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ..functional.lie import se3_to_matrix
from .pose import full_xi

__all__ = ["NetworkAligner", "VOFrame", "resize_frame", "scale_intrinsics"]


def scale_intrinsics(K, size_from: tuple[int, int], size_to: tuple[int, int]) -> np.ndarray:
    """``K`` (3, 3) of an image of ``size_from`` = (W, H) for the same image resampled to ``size_to``
    (pixel centres at integer coordinates: ``x' = (x + 0.5) * s - 0.5``)."""
    K = np.asarray(K, dtype=np.float64)
    sx, sy = size_to[0] / size_from[0], size_to[1] / size_from[1]
    out = K.copy()
    out[0, 0], out[0, 1], out[0, 2] = K[0, 0] * sx, K[0, 1] * sx, (K[0, 2] + 0.5) * sx - 0.5
    out[1, 1], out[1, 2] = K[1, 1] * sy, (K[1, 2] + 0.5) * sy - 0.5
    return out


def _tensor(x) -> torch.Tensor:
    return x if isinstance(x, torch.Tensor) else torch.from_numpy(np.ascontiguousarray(x))


def resize_frame(image, depth, size: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """An RGB-D frame at ``size`` = (W, H): ``image`` (3, H0, W0) / (B, 3, H0, W0) and ``depth``
    (1, H0, W0) / (B, 1, H0, W0) (numpy or torch; metres, 0 / NaN / negative = none) -> float32 torch
    (B, 3, H, W) in the input's intensity units and (B, 1, H, W) with 0 where there is no depth.
    Colour: bilinear with antialiasing; depth: the nearest source pixel centre (no mixing)."""
    img, dep = _tensor(image).float(), _tensor(depth).float()
    if img.dim() == 3:
        img, dep = img[None], dep[None]
    dep = torch.where(torch.isfinite(dep) & (dep > 0), dep, torch.zeros_like(dep))
    W, H = size
    if img.shape[-2:] != (H, W):
        img = F.interpolate(img, size=(H, W), mode="bilinear", align_corners=False, antialias=True)
        dep = F.interpolate(dep, size=(H, W), mode="nearest-exact")
    return img.contiguous(), dep.contiguous()


@dataclass(eq=False)
class VOFrame:
    """A frame prepared by :meth:`NetworkAligner.prepare`: the network's input and, for ``vo+direct``,
    the direct aligner's frame."""

    image: torch.Tensor  # (1, 3, H, W) at the network's size
    depth: torch.Tensor  # (1, 1, H, W)
    direct: object = None  # gvnn_warp.odometry.Frame at the original size


class NetworkAligner:
    """Relative poses ``T_live_ref`` of RGB-D frame pairs from a trained :class:`~gvnn_warp.vo.CascadeVO`,
    refined by a direct aligner if one is given.

    Args:
        network: the trained network (:func:`gvnn_warp.vo.checkpoint.load_network`), in eval mode.
        K: (3, 3) intrinsics of the frames as they are given (their full size).
        image_size: (W, H) of the frames as they are given.
        refine: extra applications of the network's last stage (the checkpoint's ``refine``).
        symmetries: the pair's symmetries the estimate is averaged over (the checkpoint's
            ``symmetries``; ``CascadeVO.predict``).
        direct: None (the network alone) or a ``gvnn_warp.odometry.DirectAligner`` built for ``K``,
            which refines the network's estimate on the full-size frames (``align_frames(..., init=)``).

    ``prepare(image, depth)``: image (3, H, W) RGB in [0, 1], depth (1, H, W) metres.
    ``align_frames(ref, live, init=None)``: ``(T (4, 4) float64, info)``; ``init`` (the tracker's
    guess) is not used: the network's estimate replaces it. ``info`` is the direct aligner's (with
    ``"network_pose"`` added), or ``{"converged": True, "network_pose": T}`` for the network alone.
    """

    def __init__(self, network, K, image_size: tuple[int, int], refine: int = 0, direct=None,
                 symmetries: tuple[str, ...] = ()):
        self.net = network
        self.size = tuple(network.size)
        self.image_size = tuple(int(v) for v in image_size)
        self.K_net = torch.from_numpy(scale_intrinsics(K, self.image_size, self.size)).float()
        self.refine = int(refine)
        self.symmetries = tuple(symmetries)
        self.direct = direct

    def prepare(self, image, depth) -> VOFrame:
        img = np.asarray(image) if not isinstance(image, torch.Tensor) else image
        if img.shape[-3] != 3:
            raise ValueError(f"NetworkAligner.prepare: the network needs RGB images (3, H, W), got shape "
                             f"{tuple(img.shape)}")
        if tuple(img.shape[-2:]) != (self.image_size[1], self.image_size[0]):
            raise ValueError(f"NetworkAligner.prepare: frames must be {self.image_size[0]}x{self.image_size[1]} "
                             f"(the size K was given for), got {img.shape[-1]}x{img.shape[-2]}")
        small, small_depth = resize_frame(img, depth, self.size)
        frame = VOFrame(small, small_depth)
        if self.direct is not None:
            frame.direct = self.direct.prepare(image, depth)
        return frame

    def predict(self, ref: VOFrame, live: VOFrame) -> np.ndarray:
        """The network's ``T_live_ref`` (4, 4) float64."""
        with torch.no_grad():
            xi = self.net.predict(ref.image, live.image, ref.depth, live.depth, self.K_net, refine=self.refine,
                                  symmetries=self.symmetries)
            T34 = se3_to_matrix(full_xi(xi).double())[0]
        T = np.eye(4)
        T[:3, :] = T34.numpy()
        return T

    def align_frames(self, ref: VOFrame, live: VOFrame, init=None):
        T_net = self.predict(ref, live)
        if self.direct is None:
            return T_net, {"converged": True, "network_pose": T_net}
        T, info = self.direct.align_frames(ref.direct, live.direct, init=T_net)
        info = dict(info)
        info["network_pose"] = T_net
        return T, info
