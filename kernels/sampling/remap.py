"""Resampling an image through a fixed map of source positions (e.g. undistortion into the ideal
pinhole image of a lens camera): the map is turned once into source indices and weights
(:class:`RemapTable`), then each image costs one thin kernel launch per plane."""

import numpy as np
import warp as wp

from ..core.launch import launch_chunks

wp.set_module_options({"enable_backward": False})  # (no gradients here: half the compile time)

__all__ = ["RemapTable", "remap", "remap_bilinear", "remap_frame", "remap_nearest", "remap_rgbd"]


@wp.kernel
def remap_bilinear(offset: int, src: wp.array(dtype=wp.float32), base: wp.array(dtype=wp.int32),
                   wx: wp.array(dtype=wp.float32), wy: wp.array(dtype=wp.float32), W: int,
                   out: wp.array(dtype=wp.float32)):
    """out[k]: bilinear between source pixels base[k], +1, +W, +W+1 with weights (wx[k], wy[k]); 0
    where base[k] < 0 (no source)."""
    k = offset + wp.tid()
    b = base[k]
    value = 0.0
    if b >= 0:
        fx = wx[k]
        fy = wy[k]
        top = (1.0 - fx) * src[b] + fx * src[b + 1]
        bottom = (1.0 - fx) * src[b + W] + fx * src[b + W + 1]
        value = (1.0 - fy) * top + fy * bottom
    out[k] = value


@wp.kernel
def remap_nearest(offset: int, src: wp.array(dtype=wp.float32), index: wp.array(dtype=wp.int32),
                  out: wp.array(dtype=wp.float32)):
    """out[k] = src[index[k]], 0 where index[k] < 0 or the value is not finite."""
    k = offset + wp.tid()
    i = index[k]
    value = 0.0
    if i >= 0:
        v = src[i]
        if wp.isfinite(v):
            value = v
    out[k] = value


@wp.kernel
def remap_frame(offset: int, image: wp.array(dtype=wp.float32), depth: wp.array(dtype=wp.float32), C: int,
                base: wp.array(dtype=wp.int32), wx: wp.array(dtype=wp.float32), wy: wp.array(dtype=wp.float32),
                index: wp.array(dtype=wp.int32), W: int, out_image: wp.array(dtype=wp.float32),
                out_depth: wp.array(dtype=wp.float32)):
    """An RGB-D frame in one pass: each of the C image planes as :func:`remap_bilinear`, the depth as
    :func:`remap_nearest` (planes of ``image`` W * H apart; of the output, N apart)."""
    k = offset + wp.tid()
    n = index.shape[0]
    plane = image.shape[0] // C
    b = base[k]
    fx = wx[k]
    fy = wy[k]
    for c in range(C):
        value = float(0.0)
        if b >= 0:
            o = c * plane + b
            top = (1.0 - fx) * image[o] + fx * image[o + 1]
            bottom = (1.0 - fx) * image[o + W] + fx * image[o + W + 1]
            value = (1.0 - fy) * top + fy * bottom
        out_image[c * n + k] = value
    i = index[k]
    d = float(0.0)
    if i >= 0:
        v = depth[i]
        if wp.isfinite(v):
            d = v
    out_depth[k] = d


class RemapTable:
    """A map of source positions ``positions`` (N, 2) (u, v), pixel centres at integer coordinates,
    into a (H, W) = (``height``, ``width``) source, as the indices and weights the kernels read:
    bilinear where the position is inside [0, W - 1] x [0, H - 1], nearest where it is within half a
    pixel of the image. ``out_size`` (W', H'): the output image the N positions make, row by row
    (N = W' H', else ValueError); default: the source's size when N = W H, else none
    (``out_width`` and ``out_height`` None: the caller gives the output's shape)."""

    def __init__(self, positions: np.ndarray, width: int, height: int, out_size: tuple[int, int] | None = None):
        p = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
        u, v = p[:, 0], p[:, 1]
        self.width, self.height, self.n = int(width), int(height), p.shape[0]
        if out_size is not None and int(out_size[0]) * int(out_size[1]) != self.n:
            raise ValueError(f"RemapTable: {self.n} positions for an output of {out_size[0]}x{out_size[1]}")
        if out_size is None and self.n == self.width * self.height:
            out_size = (self.width, self.height)
        self.out_width, self.out_height = (None, None) if out_size is None else (int(out_size[0]), int(out_size[1]))
        inside = (u >= 0) & (v >= 0) & (u <= width - 1) & (v <= height - 1)
        x0 = np.clip(np.floor(u), 0, width - 2).astype(np.int64)
        y0 = np.clip(np.floor(v), 0, height - 2).astype(np.int64)
        base = np.where(inside, y0 * width + x0, -1).astype(np.int32)
        frac = np.stack([u - x0, v - y0]).astype(np.float32)  # (2, N): wx, then wy
        iu, iv = np.floor(u + 0.5).astype(np.int64), np.floor(v + 0.5).astype(np.int64)
        near = (u >= -0.5) & (v >= -0.5) & (iu >= 0) & (iv >= 0) & (iu < width) & (iv < height)
        index = np.where(near, iv * width + iu, -1).astype(np.int32)
        self.base = wp.array(base, dtype=wp.int32, device="cpu")
        self.wx = wp.array(frac[0], dtype=wp.float32, device="cpu")  # (planes: 8 pixels' read as one vector)
        self.wy = wp.array(frac[1], dtype=wp.float32, device="cpu")
        self.index = wp.array(index, dtype=wp.int32, device="cpu")


def _output_shape(fn: str, table: RemapTable, out_shape: tuple[int, int] | None) -> tuple[int, int]:
    """(H', W'): ``out_shape``, by default the table's output size; ValueError if the table's
    positions do not make it."""
    if out_shape is None:
        if table.out_width is None:
            raise ValueError(f"{fn}: the table has no output size (RemapTable's out_size): give out_shape")
        out_shape = (table.out_height, table.out_width)
    if table.n != out_shape[0] * out_shape[1]:
        raise ValueError(f"{fn}: {table.n} positions for an output of {out_shape}")
    return out_shape


def remap(src: np.ndarray, table: RemapTable, out_shape: tuple[int, int] | None = None,
          nearest: bool = False) -> np.ndarray:
    """``src`` (C, H, W) float32 resampled through ``table``: (C, H', W') float32 with
    ``out_shape`` = (H', W') (default: the table's output size); bilinear, or the nearest pixel's
    value (non-finite values read as 0)."""
    C, H, W = src.shape
    if (H, W) != (table.height, table.width):
        raise ValueError(f"remap: the source is {W}x{H}, the table's {table.width}x{table.height}")
    out_shape = _output_shape("remap", table, out_shape)
    n = out_shape[0] * out_shape[1]
    flat = np.ascontiguousarray(src, dtype=np.float32).reshape(C, -1)
    out = np.empty((C, n), np.float32)
    for c in range(C):
        s = wp.array(flat[c], dtype=wp.float32, device="cpu", copy=False)
        o = wp.array(out[c], dtype=wp.float32, device="cpu", copy=False)
        kernel, args = ((remap_nearest, [s, table.index, o]) if nearest else
                        (remap_bilinear, [s, table.base, table.wx, table.wy, W, o]))
        launch_chunks(kernel, n, args)
    return out.reshape(C, *out_shape)


def remap_rgbd(image: np.ndarray, depth: np.ndarray, table: RemapTable, out_shape: tuple[int, int] | None = None):
    """An RGB-D frame, ``image`` (C, H, W) bilinear and ``depth`` (1, H, W) nearest, resampled
    through ``table`` in one launch: ((C, H', W'), (1, H', W')) float32, ``out_shape`` = (H', W')
    (default: the table's output size)."""
    C, H, W = image.shape
    if (H, W) != (table.height, table.width) or depth.shape != (1, H, W):
        raise ValueError(f"remap_rgbd: image {image.shape} and depth {depth.shape} must be (C, {table.height}, "
                         f"{table.width}) and (1, {table.height}, {table.width})")
    out_shape = _output_shape("remap_rgbd", table, out_shape)
    n = out_shape[0] * out_shape[1]
    img = wp.array(np.ascontiguousarray(image, dtype=np.float32).reshape(-1), dtype=wp.float32, device="cpu",
                   copy=False)
    dep = wp.array(np.ascontiguousarray(depth, dtype=np.float32).reshape(-1), dtype=wp.float32, device="cpu",
                   copy=False)
    out_img = np.empty(C * n, np.float32)
    out_dep = np.empty(n, np.float32)
    launch_chunks(remap_frame, n, [img, dep, C, table.base, table.wx, table.wy, table.index, W,
                                   wp.array(out_img, dtype=wp.float32, device="cpu", copy=False),
                                   wp.array(out_dep, dtype=wp.float32, device="cpu", copy=False)])
    return out_img.reshape(C, *out_shape), out_dep.reshape(1, *out_shape)
