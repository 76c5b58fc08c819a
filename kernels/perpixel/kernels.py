"""Thin per-pixel kernels over :mod:`.perpixel` (flows, warps, 3D transforms) and :mod:`.robust`.

Each kernel handles one element ``wp.tid() + offset`` (see :mod:`.launch`): for image-sized
kernels a flat (b, y, x) index into a (B, H, W) grid, for the robust penalties a flat index into
any tensor. Channel-first fields are flat ``scalar`` arrays indexed with
:func:`.perpixel.channel`; point maps (B, H, W, 3) are ``vec3`` arrays in (b, y, x) order.

The kernels live in four Warp modules (sampling, flows, points, robust), each compiled on its
first use, and declare how :func:`.launch.launch` may split them over threads (bottom of file).
"""

from typing import Any

import warp as wp

from .. import robust
from ..core.kinds import FloatKernel
from . import transforms as perpixel
from .transforms import channel

# Four Warp modules (each compiled, float32 and float64 together, on the first launch of one of its
# kernels), so that e.g. a user of the M-estimators alone does not compile the image kernels.
_SAMPLING = f"{__name__}.sampling"
_FLOWS = f"{__name__}.flows"
_POINTS = f"{__name__}.points"
_ROBUST = f"{__name__}.robust"


@wp.kernel(module=_SAMPLING)
def _flow_warp(
    offset: int,
    image: wp.array(dtype=Any),
    flow: wp.array(dtype=Any),
    C: int,
    H: int,
    W: int,
    padding: int,
    out: wp.array(dtype=Any),
):
    i = wp.tid() + offset  # flat (b, y, x)
    hw = H * W
    b, j, px, py = perpixel.pixel_index(i, H, W)
    fx = channel(flow, b, 0, 2, hw, j)
    fy = channel(flow, b, 1, 2, hw, j)
    perpixel.sample_pixel(image, out, b, C, H, W, j, type(fx)(px) + fx, type(fx)(py) + fy, padding)


@wp.kernel(module=_SAMPLING)
def _disparity_warp(
    offset: int,
    image: wp.array(dtype=Any),
    disparity: wp.array(dtype=Any),
    C: int,
    H: int,
    W: int,
    padding: int,
    out: wp.array(dtype=Any),
):
    i = wp.tid() + offset  # flat (b, y, x); disparity is (B, 1, H, W), i.e. indexed by i
    b, j, px, py = perpixel.pixel_index(i, H, W)
    d = disparity[i]
    perpixel.sample_pixel(image, out, b, C, H, W, j, type(d)(px) - d, type(d)(py), padding)


@wp.kernel(module=_FLOWS)
def _affine_flow(offset: int, params: wp.array(dtype=Any), H: int, W: int, flow: wp.array(dtype=Any)):
    i = wp.tid() + offset
    hw = H * W
    b, j, px, py = perpixel.pixel_index(i, H, W)
    a0 = channel(params, b, 0, 6, hw, j)
    x = type(a0)(px)
    y = type(a0)(py)
    xp, yp = perpixel.affine_point(
        x,
        y,
        a0,
        channel(params, b, 1, 6, hw, j),
        channel(params, b, 2, 6, hw, j),
        channel(params, b, 3, 6, hw, j),
        channel(params, b, 4, 6, hw, j),
        channel(params, b, 5, 6, hw, j),
    )
    flow[(b * 2) * hw + j] = xp - x
    flow[(b * 2 + 1) * hw + j] = yp - y


@wp.kernel(module=_FLOWS)
def _se2_flow(offset: int, params: wp.array(dtype=Any), H: int, W: int, flow: wp.array(dtype=Any)):
    i = wp.tid() + offset
    hw = H * W
    b, j, px, py = perpixel.pixel_index(i, H, W)
    theta = channel(params, b, 0, 3, hw, j)
    x = type(theta)(px)
    y = type(theta)(py)
    xp, yp = perpixel.se2_point(x, y, theta, channel(params, b, 1, 3, hw, j), channel(params, b, 2, 3, hw, j))
    flow[(b * 2) * hw + j] = xp - x
    flow[(b * 2 + 1) * hw + j] = yp - y


@wp.kernel(module=_FLOWS)
def _homography_flow(offset: int, params: wp.array(dtype=Any), H: int, W: int, flow: wp.array(dtype=Any)):
    i = wp.tid() + offset
    hw = H * W
    b, j, px, py = perpixel.pixel_index(i, H, W)
    h0 = channel(params, b, 0, 9, hw, j)
    x = type(h0)(px)
    y = type(h0)(py)
    xp, yp = perpixel.homography_point(
        x,
        y,
        h0,
        channel(params, b, 1, 9, hw, j),
        channel(params, b, 2, 9, hw, j),
        channel(params, b, 3, 9, hw, j),
        channel(params, b, 4, 9, hw, j),
        channel(params, b, 5, 9, hw, j),
        channel(params, b, 6, 9, hw, j),
        channel(params, b, 7, 9, hw, j),
        channel(params, b, 8, 9, hw, j),
    )
    flow[(b * 2) * hw + j] = xp - x
    flow[(b * 2 + 1) * hw + j] = yp - y


@wp.kernel(module=_FLOWS)
def _plane_disparity(offset: int, params: wp.array(dtype=Any), H: int, W: int, disparity: wp.array(dtype=Any)):
    i = wp.tid() + offset
    hw = H * W
    b, j, px, py = perpixel.pixel_index(i, H, W)
    a = channel(params, b, 0, 3, hw, j)
    disparity[i] = perpixel.plane_disparity(
        type(a)(px), type(a)(py), a, channel(params, b, 1, 3, hw, j), channel(params, b, 2, 3, hw, j)
    )


@wp.kernel(module=_SAMPLING)
def _affine_flow_warp(
    offset: int,
    image: wp.array(dtype=Any),
    params: wp.array(dtype=Any),
    C: int,
    H: int,
    W: int,
    padding: int,
    out: wp.array(dtype=Any),
):
    i = wp.tid() + offset  # fused affine_flow + flow_warp: no flow intermediate
    hw = H * W
    b, j, px, py = perpixel.pixel_index(i, H, W)
    a0 = channel(params, b, 0, 6, hw, j)
    xp, yp = perpixel.affine_point(
        type(a0)(px),
        type(a0)(py),
        a0,
        channel(params, b, 1, 6, hw, j),
        channel(params, b, 2, 6, hw, j),
        channel(params, b, 3, 6, hw, j),
        channel(params, b, 4, 6, hw, j),
        channel(params, b, 5, 6, hw, j),
    )
    perpixel.sample_pixel(image, out, b, C, H, W, j, xp, yp, padding)


@wp.kernel(module=_POINTS)
def _pointwise_se3(
    offset: int, points: wp.array(dtype=Any), params: wp.array(dtype=Any), hw: int, out: wp.array(dtype=Any)
):
    i = wp.tid() + offset  # flat (b, y, x)
    b = i // hw
    j = i - b * hw
    omega = wp.vector(channel(params, b, 0, 6, hw, j), channel(params, b, 1, 6, hw, j), channel(params, b, 2, 6, hw, j))
    t = wp.vector(channel(params, b, 3, 6, hw, j), channel(params, b, 4, 6, hw, j), channel(params, b, 5, 6, hw, j))
    p, ok = perpixel.finite_or_zero(points[i])
    out[i] = wp.where(ok, perpixel.se3_point(p, omega, t), points[i])


@wp.kernel(module=_POINTS)
def _pointwise_sim3(
    offset: int, points: wp.array(dtype=Any), params: wp.array(dtype=Any), hw: int, out: wp.array(dtype=Any)
):
    i = wp.tid() + offset
    b = i // hw
    j = i - b * hw
    omega = wp.vector(channel(params, b, 0, 7, hw, j), channel(params, b, 1, 7, hw, j), channel(params, b, 2, 7, hw, j))
    t = wp.vector(channel(params, b, 3, 7, hw, j), channel(params, b, 4, 7, hw, j), channel(params, b, 5, 7, hw, j))
    p, ok = perpixel.finite_or_zero(points[i])
    out[i] = wp.where(ok, perpixel.sim3_point(p, omega, t, channel(params, b, 6, 7, hw, j)), points[i])


@wp.kernel(module=_POINTS)
def _pointwise_transform10(
    offset: int, points: wp.array(dtype=Any), params: wp.array(dtype=Any), hw: int, out: wp.array(dtype=Any)
):
    i = wp.tid() + offset
    b = i // hw
    j = i - b * hw
    omega = wp.vector(
        channel(params, b, 0, 10, hw, j), channel(params, b, 1, 10, hw, j), channel(params, b, 2, 10, hw, j)
    )
    t = wp.vector(channel(params, b, 3, 10, hw, j), channel(params, b, 4, 10, hw, j), channel(params, b, 5, 10, hw, j))
    anchor = wp.vector(
        channel(params, b, 7, 10, hw, j), channel(params, b, 8, 10, hw, j), channel(params, b, 9, 10, hw, j)
    )
    p, ok = perpixel.finite_or_zero(points[i])
    out[i] = wp.where(ok, perpixel.transform10_point(p, omega, t, channel(params, b, 6, 10, hw, j), anchor), points[i])


@wp.kernel(module=_FLOWS)
def _affine_grid(
    offset: int, theta: wp.array(dtype=Any), H: int, W: int, align_corners: int, grid: wp.array(dtype=Any)
):
    i = wp.tid() + offset  # flat (b, y, x); theta holds the two rows of batch item b at 2b, 2b + 1
    b, j, px, py = perpixel.pixel_index(i, H, W)
    r0 = theta[2 * b]
    r1 = theta[2 * b + 1]
    gx = perpixel.grid_coordinate(type(r0[0])(px), W, align_corners)
    gy = perpixel.grid_coordinate(type(r0[0])(py), H, align_corners)
    grid[i] = wp.vector(r0[0] * gx + r0[1] * gy + r0[2], r1[0] * gx + r1[1] * gy + r1[2])


@wp.kernel(module=_ROBUST)
def _robust_rho(offset: int, x: wp.array(dtype=Any), kind: int, scale: wp.float64, out: wp.array(dtype=Any)):
    i = wp.tid() + offset
    xi = x[i]
    out[i] = robust.rho(xi, kind, type(xi)(scale))


@wp.kernel(module=_ROBUST)
def _robust_psi(offset: int, x: wp.array(dtype=Any), kind: int, scale: wp.float64, out: wp.array(dtype=Any)):
    i = wp.tid() + offset
    xi = x[i]
    out[i] = robust.psi(xi, kind, type(xi)(scale))


@wp.kernel(module=_ROBUST)
def _smoothness(
    offset: int,
    field: wp.array(dtype=Any),
    H: int,
    W: int,
    kind: int,
    scale: wp.float64,
    weight_x: wp.float64,
    weight_y: wp.float64,
    out: wp.array(dtype=Any),
):
    i = wp.tid() + offset  # flat (b, k, y, x) of a (B, K, H, W) field
    j = i % (H * W)
    py = j // W
    px = j - py * W
    f = field[i]
    c = type(f)(scale)
    r = type(f)(0.0)
    if px + 1 < W:
        r = r + robust.rho(field[i + 1] - f, kind, c) * type(f)(weight_x)
    if py + 1 < H:
        r = r + robust.rho(field[i + W] - f, kind, c) * type(f)(weight_y)
    out[i] = r


# Threaded launches (see :meth:`.launch.FloatKernel.set_parallel`). Adjoint scopes: a per-pixel
# parameter field is written back only at the element's own pixel ("element"); an image gradient
# (bilinear scatter), a smoothness field (neighbour differences, within one (b, k) plane) and
# affine_grid's theta are written only within the element's batch item / plane ("segment").
_GRAIN_PIXELS = 4096  # fewest pixels worth a separate chunk


def _batch_item(a):
    return a["H"] * a["W"]


_SAMPLING_PARALLEL = dict(segment=_batch_item, grain=_GRAIN_PIXELS)

flow_warp = FloatKernel(_flow_warp, image="scalar", flow="scalar", out="scalar").set_parallel(
    scopes={"image": "segment", "flow": "element"}, **_SAMPLING_PARALLEL
)
disparity_warp = FloatKernel(_disparity_warp, image="scalar", disparity="scalar", out="scalar").set_parallel(
    scopes={"image": "segment", "disparity": "element"}, **_SAMPLING_PARALLEL
)
affine_flow_warp = FloatKernel(_affine_flow_warp, image="scalar", params="scalar", out="scalar").set_parallel(
    scopes={"image": "segment", "params": "element"}, **_SAMPLING_PARALLEL
)
affine_flow = FloatKernel(_affine_flow, params="scalar", flow="scalar").set_parallel(scopes={"params": "element"})
se2_flow = FloatKernel(_se2_flow, params="scalar", flow="scalar").set_parallel(scopes={"params": "element"})
homography_flow = FloatKernel(_homography_flow, params="scalar", flow="scalar").set_parallel(
    scopes={"params": "element"}
)
plane_disparity = FloatKernel(_plane_disparity, params="scalar", disparity="scalar").set_parallel(
    scopes={"params": "element"}
)
pointwise_se3 = FloatKernel(_pointwise_se3, points="vec3", params="scalar", out="vec3").set_parallel(
    scopes={"points": "element", "params": "element"}
)
pointwise_sim3 = FloatKernel(_pointwise_sim3, points="vec3", params="scalar", out="vec3").set_parallel(
    scopes={"points": "element", "params": "element"}
)
pointwise_transform10 = FloatKernel(_pointwise_transform10, points="vec3", params="scalar", out="vec3").set_parallel(
    scopes={"points": "element", "params": "element"}
)
affine_grid = FloatKernel(_affine_grid, theta="vec3", grid="vec2").set_parallel(
    segment=_batch_item, scopes={"theta": "segment"}
)
robust_rho = FloatKernel(_robust_rho, x="scalar", out="scalar").set_parallel(scopes={"x": "element"})
robust_psi = FloatKernel(_robust_psi, x="scalar", out="scalar").set_parallel(scopes={"x": "element"})
smoothness = FloatKernel(_smoothness, field="scalar", out="scalar").set_parallel(
    segment=_batch_item, scopes={"field": "segment"}
)
