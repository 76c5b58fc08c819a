"""Synthetic RGB-D renderer: a textured box room with boxes in it, ray cast by a Warp kernel (CPU).

Pure Warp + numpy (never imports torch). The scene comes from :mod:`.scene`. Conventions are the
project's (see :mod:`.trajectories`): OpenCV camera frame, pixel centres at integer (u, v), ``T_world_cam``
poses, depth = z of the hit point in the camera frame (not the ray length).

Geometry is exact (slab-method intersections, nearest hit wins). Colour is a procedural texture of
the hit point's 2-D surface coordinates (metres): value-noise fBm from 1 m down to ~3 cm
wavelength, a low-frequency colour blend and smooth stripes or checks, different for every
surface, times a fixed view-independent shading per face orientation, so brightness constancy
holds between views. To keep renders free of aliasing, every texture band is faded out where its
wavelength drops below ~1-2 pixel footprints on the surface (an analytic pre-filter; the footprint
is exact for the planar faces), and pixels at depth edges average ``supersample`` x ``supersample``
rays.
"""

from __future__ import annotations

import threading

import numpy as np
import warp as wp

from ..kernels.core.launch import load_module, wp_launch
from .scene import RoomScene

wp.set_module_options({"enable_backward": False})

__all__ = ["render_rgbd"]

_N_OCTAVES = wp.constant(6)  # fBm octaves: wavelengths 1 m, 50 cm, ..., 3.1 cm
_FACE_SHADE = wp.constant(wp.vec3(0.80, 0.95, 0.70))  # view-independent shade per normal axis x, y, z


# ------------------------------------------------------------------------------------------------
# Warp kernels and helpers. Two passes over the N * H * W pixels (flat 1-D launches with an offset,
# so that a range can be split between threads): ``_cast_kernel`` casts the pixel-centre rays
# (depth, surface id); ``_shade_kernel`` textures the centre hit where the 3x3 pixel neighbourhood
# sees one surface, and averages supersample x supersample fully cast and shaded rays elsewhere.


@wp.struct
class _Hit:
    t: float  # ray parameter; with the camera-frame ray direction's z = 1 this is the depth
    surface: int  # 6 * k + 2 * axis + side (see RoomScene)


@wp.func
def _safe_inverse(d: wp.vec3) -> wp.vec3:
    """Component-wise 1 / d with zero components replaced by a tiny positive value."""
    e = 1.0e-20
    return wp.vec3(
        1.0 / wp.where(wp.abs(d[0]) > e, d[0], e),
        1.0 / wp.where(wp.abs(d[1]) > e, d[1], e),
        1.0 / wp.where(wp.abs(d[2]) > e, d[2], e),
    )


@wp.func
def _cast_ray(
    origin: wp.vec3,
    direction: wp.vec3,
    room: wp.array(dtype=wp.vec3),
    box_min: wp.array(dtype=wp.vec3),
    box_max: wp.array(dtype=wp.vec3),
) -> _Hit:
    """Nearest hit of the ray ``origin + t * direction`` (t > 0): the room's walls, seen from inside,
    then every box by the slab method."""
    inv = _safe_inverse(direction)
    t_exit = wp.max(wp.cw_mul(room[0] - origin, inv), wp.cw_mul(room[1] - origin, inv))
    axis = int(wp.argmin(t_exit))
    hit = _Hit()
    hit.t = t_exit[axis]
    hit.surface = 2 * axis + wp.where(direction[axis] > 0.0, 1, 0)
    for b in range(box_min.shape[0]):
        t0 = wp.cw_mul(box_min[b] - origin, inv)
        t1 = wp.cw_mul(box_max[b] - origin, inv)
        t_near = wp.min(t0, t1)
        t_in = wp.max(t_near)
        if t_in > 0.0 and t_in < hit.t and t_in <= wp.min(wp.max(t0, t1)):
            axis = int(wp.argmax(t_near))
            hit.t = t_in
            hit.surface = 6 * (b + 1) + 2 * axis + wp.where(direction[axis] > 0.0, 0, 1)
    return hit


@wp.func
def _hash01(ix: int, iy: int, seed: int) -> float:
    """Integer lattice hash to [0, 1)."""
    h = wp.uint32(ix) * wp.uint32(0x27D4EB2D) + wp.uint32(iy) * wp.uint32(0x165667B1) + wp.uint32(seed)
    h = (h ^ (h >> wp.uint32(15))) * wp.uint32(0x2C1B3C6D)
    h = (h ^ (h >> wp.uint32(12))) * wp.uint32(0x297A2D39)
    h = h ^ (h >> wp.uint32(15))
    return float(h & wp.uint32(0xFFFFFF)) * (1.0 / 16777216.0)


@wp.func
def _value_noise(p: wp.vec2, seed: int) -> float:
    """Smooth (C1) value noise with one lattice cell per unit; zero mean, in [-0.5, 0.5]."""
    fx = wp.floor(p[0])
    fy = wp.floor(p[1])
    ix = int(fx)
    iy = int(fy)
    tx = p[0] - fx
    ty = p[1] - fy
    sx = tx * tx * (3.0 - 2.0 * tx)
    sy = ty * ty * (3.0 - 2.0 * ty)
    bottom = wp.lerp(_hash01(ix, iy, seed), _hash01(ix + 1, iy, seed), sx)
    top = wp.lerp(_hash01(ix, iy + 1, seed), _hash01(ix + 1, iy + 1, seed), sx)
    return wp.lerp(bottom, top, sy) - 0.5


@wp.func
def _band_weight(wavelength: float, footprint: float) -> float:
    """Pre-filter weight of a texture band: 1 at wavelengths above 2 pixel footprints (the Nyquist
    limit of one sample per pixel), 0 below 1, smooth between."""
    return wp.smoothstep(1.0, 2.0, wavelength / footprint)


@wp.func
def _fbm(q: wp.vec2, seed: int, footprint: float) -> float:
    """Band-limited fBm: _N_OCTAVES octaves of value noise from 1 m wavelength down, halving
    the wavelength and multiplying the amplitude by 0.8 each time (lattice rotated per octave).
    Zero mean; standard deviation ~0.14 with all bands present."""
    rot = wp.mat22(1.6, -1.2, 1.2, 1.6)  # 2x scale and a 37 deg rotation
    total = wp.float32(0.0)
    amplitude = wp.float32(0.4)
    wavelength = wp.float32(1.0)
    p = q
    for o in range(_N_OCTAVES):
        w = _band_weight(wavelength, footprint)
        if w <= 0.0:
            break
        total += amplitude * w * _value_noise(p, seed + 7919 * o)
        amplitude *= 0.8
        wavelength *= 0.5
        p = rot * p
    return total


@wp.func
def _surface_colour(
    q: wp.vec2,
    surface: int,
    footprint: float,
    seed: wp.array(dtype=wp.int32),
    colours: wp.array(dtype=wp.vec3, ndim=2),
    pattern: wp.array(dtype=wp.vec4),
) -> wp.vec3:
    """Texture colour (RGB in [0, 1]) at surface coordinates ``q`` (m) of ``surface``, pre-filtered
    for a pixel footprint of ``footprint`` metres. ``pattern`` rows: (cos / period, sin / period,
    kind, weight) of the stripes or checks."""
    s = seed[surface]
    q = q + wp.vec2(float(s % 101), float(s % 97))  # decorrelate the noise lattices of the surfaces
    detail = _fbm(q, s, footprint)
    blend = 0.5 + 2.0 * _band_weight(1.5, footprint) * _value_noise(q * 0.67, s + 1)
    base = wp.lerp(colours[surface, 0], colours[surface, 1], wp.clamp(blend, 0.0, 1.0)) * (1.0 + 1.8 * detail)

    par = pattern[surface]
    frequency = wp.length(wp.vec2(par[0], par[1]))  # cycles per metre
    wave = wp.sin(2.0 * wp.pi * (par[0] * q[0] + par[1] * q[1]))
    if par[2] > 0.5:  # checks: the product of two perpendicular sinusoids
        wave = wave * wp.sin(2.0 * wp.pi * (par[0] * q[1] - par[1] * q[0]))
        frequency = frequency * 1.4142
    mix = par[3] * (0.5 + 0.5 * _band_weight(1.0 / frequency, footprint) * wave)
    rgb = wp.lerp(base, colours[surface, 2], mix)
    return wp.vec3(wp.clamp(rgb[0], 0.0, 1.0), wp.clamp(rgb[1], 0.0, 1.0), wp.clamp(rgb[2], 0.0, 1.0))


@wp.func
def _shade_point(
    p: wp.vec3,
    t: float,
    d: wp.vec3,
    surface: int,
    step_u: wp.vec3,
    step_v: wp.vec3,
    seed: wp.array(dtype=wp.int32),
    colours: wp.array(dtype=wp.vec3, ndim=2),
    pattern: wp.array(dtype=wp.vec4),
) -> wp.vec3:
    """Shaded colour of the hit ``p = origin + t * d`` on ``surface``. The pixel footprint is the
    larger of the derivatives of the hit point along the face with respect to u and v (``step_u/v``:
    world ray change per pixel)."""
    axis = (surface % 6) / 2
    dn = wp.where(d[axis] >= 0.0, 1.0, -1.0) * wp.max(wp.abs(d[axis]), 1.0e-6)
    footprint_u = wp.length(t * (step_u - d * (step_u[axis] / dn)))
    footprint_v = wp.length(t * (step_v - d * (step_v[axis] / dn)))
    footprint = wp.max(wp.max(footprint_u, footprint_v), 1.0e-6)
    q = wp.vec2(p[(axis + 1) % 3], p[(axis + 2) % 3])
    return _FACE_SHADE[axis] * _surface_colour(q, surface, footprint, seed, colours, pattern)


@wp.func
def _camera_rays(T: wp.mat44, K_inv: wp.mat33, u: float, v: float) -> wp.mat33:
    """Rows: the world direction of the ray through pixel (u, v) (camera-frame z = 1) and its
    changes per pixel in u and in v."""
    R = wp.mat33(T[0, 0], T[0, 1], T[0, 2], T[1, 0], T[1, 1], T[1, 2], T[2, 0], T[2, 1], T[2, 2])
    return wp.matrix_from_rows(
        R * (K_inv * wp.vec3(u, v, 1.0)),
        R * wp.vec3(K_inv[0, 0], K_inv[1, 0], 0.0),
        R * wp.vec3(K_inv[0, 1], K_inv[1, 1], 0.0),
    )


@wp.kernel
def _cast_kernel(
    offset: int,
    width: int,
    height: int,
    T_world_cam: wp.array(dtype=wp.mat44),
    K_inv: wp.mat33,
    room: wp.array(dtype=wp.vec3),
    box_min: wp.array(dtype=wp.vec3),
    box_max: wp.array(dtype=wp.vec3),
    depth: wp.array(dtype=wp.float32, ndim=4),
    surface: wp.array(dtype=wp.int32, ndim=3),
):
    i = wp.tid() + offset
    u = i % width
    v = (i / width) % height
    n = i / (width * height)
    T = T_world_cam[n]
    rays = _camera_rays(T, K_inv, float(u), float(v))
    hit = _cast_ray(wp.vec3(T[0, 3], T[1, 3], T[2, 3]), rays[0], room, box_min, box_max)
    depth[n, 0, v, u] = hit.t
    surface[n, v, u] = hit.surface


@wp.kernel
def _shade_kernel(
    offset: int,
    width: int,
    height: int,
    supersample: int,
    T_world_cam: wp.array(dtype=wp.mat44),
    K_inv: wp.mat33,
    room: wp.array(dtype=wp.vec3),
    box_min: wp.array(dtype=wp.vec3),
    box_max: wp.array(dtype=wp.vec3),
    surface_seed: wp.array(dtype=wp.int32),
    surface_colours: wp.array(dtype=wp.vec3, ndim=2),
    surface_pattern: wp.array(dtype=wp.vec4),
    depth: wp.array(dtype=wp.float32, ndim=4),
    surface: wp.array(dtype=wp.int32, ndim=3),
    image: wp.array(dtype=wp.float32, ndim=4),
):
    i = wp.tid() + offset
    u = i % width
    v = (i / width) % height
    n = i / (width * height)
    T = T_world_cam[n]
    origin = wp.vec3(T[0, 3], T[1, 3], T[2, 3])
    rays = _camera_rays(T, K_inv, float(u), float(v))
    s = surface[n, v, u]

    # Does the 3x3 neighbourhood (clamped at the border) see one surface only?
    uniform = wp.int32(1)
    for dv in range(-1, 2):
        for du in range(-1, 2):
            vv = wp.clamp(v + dv, 0, height - 1)
            uu = wp.clamp(u + du, 0, width - 1)
            if surface[n, vv, uu] != s:
                uniform = 0

    rgb = wp.vec3(0.0)
    if uniform == 1 or supersample == 1:
        t = depth[n, 0, v, u]
        p = origin + t * rays[0]
        rgb = _shade_point(p, t, rays[0], s, rays[1], rays[2], surface_seed, surface_colours, surface_pattern)
    else:
        for sy in range(supersample):
            for sx in range(supersample):
                su = (float(sx) + 0.5) / float(supersample) - 0.5
                sv = (float(sy) + 0.5) / float(supersample) - 0.5
                d = rays[0] + su * rays[1] + sv * rays[2]
                hit = _cast_ray(origin, d, room, box_min, box_max)
                rgb += _shade_point(
                    origin + hit.t * d, hit.t, d, hit.surface, rays[1], rays[2],
                    surface_seed, surface_colours, surface_pattern,
                )
        rgb = rgb / float(supersample * supersample)
    image[n, 0, v, u] = rgb[0]
    image[n, 1, v, u] = rgb[1]
    image[n, 2, v, u] = rgb[2]


def _launch_split(kernel, total: int, inputs: list, n_threads: int) -> None:
    """Launch a 1-D ``kernel(offset, *inputs)`` over ``range(total)`` split into ``n_threads`` contiguous
    chunks, one per Python thread (the calling thread takes the first). Chunks must write disjoint
    outputs; the result does not depend on ``n_threads``."""
    bounds = np.linspace(0, total, max(1, n_threads) + 1).astype(np.int64)

    def launch(start: int, stop: int) -> None:
        if stop > start:
            wp_launch(kernel, dim=stop - start, inputs=[start, *inputs], device="cpu")

    chunks = zip(bounds[1:-1], bounds[2:], strict=True)
    threads = [threading.Thread(target=launch, args=(int(a), int(b))) for a, b in chunks]
    for thread in threads:
        thread.start()
    launch(int(bounds[0]), int(bounds[1]))
    for thread in threads:
        thread.join()


def render_rgbd(
    scene: RoomScene,
    T_world_cam: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    supersample: int = 2,
    n_threads: int = 2,
) -> tuple[np.ndarray, np.ndarray]:
    """Render colour and depth images of ``scene`` from the cameras ``T_world_cam`` (on the CPU).

    Anti-aliasing: textures are pre-filtered to the pixel footprint, so a pixel whose 3x3
    neighbourhood of centre rays sees a single surface is shaded once at its centre; every other
    pixel (at depth edges and creases) averages ``supersample`` x ``supersample`` rays spread evenly
    over it.

    Args:
        scene: the room scene.
        T_world_cam: camera poses, (N, 4, 4) or a single (4, 4); computed in float32.
        K: (3, 3) intrinsics shared by all cameras.
        width, height: image size in pixels.
        supersample: rays per pixel side at depth edges (1 disables supersampling).
        n_threads: the pixel range is split into this many chunks launched from as many Python
            threads (Warp releases the GIL during CPU launches); results do not depend on it.

    Returns:
        ``image`` (N, 3, H, W) float32 RGB in [0, 1] and ``depth`` (N, 1, H, W) float32, the z
        (metres) of the surface seen through each pixel centre. The N axis is always present, also
        for a single (4, 4) pose.
    """
    poses = np.asarray(T_world_cam, dtype=np.float32)
    if poses.shape[-2:] != (4, 4) or poses.ndim not in (2, 3):
        raise ValueError(f"T_world_cam must have shape (N, 4, 4) or (4, 4), got {poses.shape}")
    poses = poses.reshape(-1, 4, 4)
    n_frames = poses.shape[0]
    total = n_frames * height * width
    if total >= 2**31:
        raise ValueError("N * H * W must fit in int32")
    if supersample < 1:
        raise ValueError("supersample must be >= 1")
    image = np.empty((n_frames, 3, height, width), dtype=np.float32)
    depth = np.empty((n_frames, 1, height, width), dtype=np.float32)
    surface = np.empty((n_frames, height, width), dtype=np.int32)

    kind, period, angle, weight = scene.surface_pattern.T.astype(np.float64)
    pattern = np.stack([np.cos(angle) / period, np.sin(angle) / period, kind, weight], -1)
    camera = [
        wp.array(poses, dtype=wp.mat44, device="cpu"),
        wp.mat33(*np.linalg.inv(np.asarray(K, dtype=np.float64)).ravel()),
        wp.array(np.stack([scene.room_min, scene.room_max]), dtype=wp.vec3, device="cpu"),
        wp.array(scene.box_min.reshape(-1, 3), dtype=wp.vec3, device="cpu"),
        wp.array(scene.box_max.reshape(-1, 3), dtype=wp.vec3, device="cpu"),
    ]
    textures = [
        wp.array(scene.surface_seed, dtype=wp.int32, device="cpu"),
        wp.array(scene.surface_colours, dtype=wp.vec3, device="cpu"),
        wp.array(pattern, dtype=wp.vec4, device="cpu"),
    ]
    depth_wp = wp.array(depth, dtype=wp.float32, device="cpu", copy=False)
    surface_wp = wp.array(surface, dtype=wp.int32, device="cpu", copy=False)
    image_wp = wp.array(image, dtype=wp.float32, device="cpu", copy=False)

    load_module(_cast_kernel.module)  # compile before the threads start
    _launch_split(_cast_kernel, total, [width, height, *camera, depth_wp, surface_wp], n_threads)
    _launch_split(
        _shade_kernel,
        total,
        [width, height, int(supersample), *camera, *textures, depth_wp, surface_wp, image_wp],
        n_threads,
    )
    return image, depth
