"""The image files of TUM-format sequences (numpy and Pillow): 8-bit colour PNGs and 16-bit depth
PNGs (metres * depth_scale, 0 = no depth); a file that cannot be read raises :class:`DatasetError`
naming it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from .errors import DatasetError

__all__ = [
    "DEFAULT_DEPTH_SCALE",
    "check_depth_mode",
    "check_rgb_mode",
    "open_image",
    "read_depth",
    "read_rgb",
    "to_gray",
    "write_depth",
    "write_rgb",
]

#: TUM RGB-D and ICL-NUIM store depth as metres * 5000 in 16-bit PNGs.
DEFAULT_DEPTH_SCALE = 5000.0


def open_image(path: Path, what: str, load: bool = True):
    """The Pillow image at ``path`` (its pixels read unless ``load`` is False: the header only);
    DatasetError naming the file if it is missing or cannot be read."""
    try:
        im = Image.open(path)
        if load:
            im.load()
    except FileNotFoundError:
        raise DatasetError(f"{path}: missing {what} image") from None
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as e:
        raise DatasetError(f"{path}: cannot read {what} image ({type(e).__name__}: {e})") from None
    return im


_RGB_MODES = ("RGB", "RGBA", "RGBX", "L", "LA", "P", "PA")
_DEPTH_MODES = ("I;16", "I;16L", "I;16B", "I;16N", "I")  # "I": some Pillow versions open 16-bit PNGs so


def check_rgb_mode(path: Path, mode: str) -> None:
    if mode not in _RGB_MODES:
        raise DatasetError(f"{path}: colour image must be 8-bit RGB or grey, got Pillow mode {mode}")


def check_depth_mode(path: Path, mode: str) -> None:
    if mode in _DEPTH_MODES:
        return
    if mode in ("L", "P", "1"):
        raise DatasetError(f"{path}: depth image is 8-bit (Pillow mode {mode}); expected a 16-bit single-channel PNG")
    if mode in ("RGB", "RGBA", "RGBX", "LA", "PA", "CMYK", "YCbCr"):
        raise DatasetError(f"{path}: depth image has colour channels (Pillow mode {mode}); "
                           "expected a 16-bit single-channel PNG")
    raise DatasetError(f"{path}: depth image has Pillow mode {mode}; expected a 16-bit single-channel PNG")


def read_rgb(path: str | Path) -> np.ndarray:
    """An 8-bit colour (or grey) image as float32 (3, H, W) in [0, 1]."""
    path = Path(path)
    im = open_image(path, "colour")
    check_rgb_mode(path, im.mode)
    rgb = np.asarray(im.convert("RGB"), dtype=np.float32) / np.float32(255.0)
    return np.ascontiguousarray(rgb.transpose(2, 0, 1))


def read_depth(path: str | Path, depth_scale: float = DEFAULT_DEPTH_SCALE) -> np.ndarray:
    """A 16-bit single-channel depth PNG as float32 (1, H, W) metres (raw / ``depth_scale``; 0 = no
    depth). 8-bit, colour and floating-point images are refused."""
    path = Path(path)
    im = open_image(path, "depth")
    check_depth_mode(path, im.mode)
    raw = np.asarray(im)
    if im.mode == "I" and (raw.min(initial=0) < 0 or raw.max(initial=0) > 65535):
        raise DatasetError(f"{path}: depth image must be 16-bit, got 32-bit values outside 0..65535")
    raw = raw.astype(np.float32)
    return (raw / np.float32(depth_scale))[None]


def to_gray(rgb: np.ndarray) -> np.ndarray:
    """(1, H, W) luma 0.299 R + 0.587 G + 0.114 B (ITU-R BT.601, as OpenCV and Open3D) of (3, H, W)."""
    return (np.float32(0.299) * rgb[0] + np.float32(0.587) * rgb[1] + np.float32(0.114) * rgb[2])[None]


def write_rgb(path: Path, image: np.ndarray) -> None:
    """Write a float (3, H, W) image in [0, 1] as an 8-bit RGB PNG (rounded, clipped)."""
    rgb8 = np.clip(np.rint(image.transpose(1, 2, 0) * 255.0), 0, 255).astype(np.uint8)
    Image.fromarray(np.ascontiguousarray(rgb8)).save(path, compress_level=1)


def write_depth(path: Path, depth: np.ndarray, depth_scale: float) -> None:
    """Write a depth (H, W) in metres as a 16-bit PNG of metres * ``depth_scale`` rounded; depths
    that are not finite, not positive, or beyond 65535 / ``depth_scale`` metres become 0 (no depth)."""
    raw = depth * depth_scale
    raw = np.where(np.isfinite(raw) & (raw > 0) & (raw <= 65535.0), np.rint(np.nan_to_num(raw)), 0.0)
    Image.fromarray(raw.astype(np.uint16)).save(path, compress_level=1)
