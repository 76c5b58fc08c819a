"""Camera intrinsics and camera trajectories for the synthetic RGB-D data (numpy only).

Conventions are the project's: camera frame x right, y down, z forward (metres); ``K`` maps camera
coordinates to pixels whose centres are at integer coordinates; a pose ``T_a_b`` (float64, 4x4)
maps points from frame ``b`` into frame ``a``; trajectories are stacks of ``T_world_cam``.

The world frame of the room has the same orientation as an upright camera looking into the room:
x right, y down (the floor is at ``y = ROOM_MAX[1]``), z towards the far wall. A camera with
identity rotation therefore looks along +z, level with the floor.

The room is built by :func:`.scene.make_room_scene`, which keeps its boxes at least
``BOX_CLEARANCE`` away from ``CAMERA_REGION_MIN``/``CAMERA_REGION_MAX``; every trajectory here
keeps the camera centre inside that region, so all rendered depths stay above ~0.4 m.
"""

from __future__ import annotations

import numpy as np

from .scene import CAMERA_REGION_MAX, CAMERA_REGION_MIN

__all__ = [
    "default_intrinsics",
    "euler_to_rotation",
    "pose_error",
    "relative_pose",
    "rotation_angle_deg",
    "rotation_trajectory",
    "smooth_se3_trajectory",
]


def default_intrinsics(width: int, height: int) -> np.ndarray:
    """Pinhole intrinsics ``K`` (3, 3) float64 with fx = fy = 0.75 * width (horizontal FOV ~67 deg,
    like ICL-NUIM) and the principal point at the image centre ((width - 1) / 2, (height - 1) / 2)."""
    f = 0.75 * width
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def euler_to_rotation(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """``R_world_cam`` (..., 3, 3) from angles in radians: ``R = Ry(yaw) @ Rx(pitch) @ Rz(roll)``.

    Yaw turns about the world's vertical (y) axis (positive: towards +x), pitch about the camera's
    x axis (positive: looking down, towards the floor at +y), roll about its optical axis.
    """
    yaw, pitch, roll = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (yaw, pitch, roll)))
    one, zero = np.ones_like(yaw), np.zeros_like(yaw)
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    ry = np.stack([cy, zero, sy, zero, one, zero, -sy, zero, cy], -1).reshape(yaw.shape + (3, 3))
    rx = np.stack([one, zero, zero, zero, cp, sp, zero, -sp, cp], -1).reshape(yaw.shape + (3, 3))
    rz = np.stack([cr, -sr, zero, sr, cr, zero, zero, zero, one], -1).reshape(yaw.shape + (3, 3))
    return ry @ rx @ rz


def _poses(rotations: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Stack (n, 3, 3) rotations and (n, 3) camera centres into (n, 4, 4) ``T_world_cam``."""
    T = np.zeros((rotations.shape[0], 4, 4))
    T[:, :3, :3] = rotations
    T[:, :3, 3] = centres
    T[:, 3, 3] = 1.0
    return T


def relative_pose(T_world_a: np.ndarray, T_world_b: np.ndarray) -> np.ndarray:
    """``T_a_b = inv(T_world_a) @ T_world_b`` for rigid poses (..., 4, 4), broadcast; float64."""
    T_world_a = np.asarray(T_world_a, dtype=np.float64)
    T_world_b = np.asarray(T_world_b, dtype=np.float64)
    R_t = np.swapaxes(T_world_a[..., :3, :3], -1, -2)
    T_a_world = np.zeros(T_world_a.shape)
    T_a_world[..., :3, :3] = R_t
    T_a_world[..., :3, 3] = -(R_t @ T_world_a[..., :3, 3:4])[..., 0]
    T_a_world[..., 3, 3] = 1.0
    return T_a_world @ T_world_b


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """Geodesic angle (degrees) of rotation matrices (..., 3, 3).

    As ``atan2(sin, cos)`` with ``2 sin = |vee(R - R^T)|`` and ``2 cos = trace(R) - 1``: accurate
    also near 0 (where ``arccos`` of the trace loses half the digits)."""
    R = np.asarray(R, dtype=np.float64)
    cos = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    return np.degrees(np.arctan2(np.linalg.norm(v, axis=-1) / 2.0, cos))


def pose_error(T_est: np.ndarray, T_gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rotation error in degrees, the geodesic angle of ``R_est^T R_gt``; translation error in
    metres, ``|t_est - t_gt|``) between poses (..., 3, 4) or (..., 4, 4), in float64."""
    T_est = np.asarray(T_est, dtype=np.float64)
    T_gt = np.asarray(T_gt, dtype=np.float64)
    R = np.swapaxes(T_est[..., :3, :3], -1, -2) @ T_gt[..., :3, :3]
    return rotation_angle_deg(R), np.linalg.norm(T_est[..., :3, 3] - T_gt[..., :3, 3], axis=-1)


def _ar1(rng: np.random.Generator, n: int, dim: int, corr: float) -> np.ndarray:
    """Stationary unit-variance AR(1) sequence (n, dim) with lag-1 correlation ``corr``."""
    x = np.empty((n, dim))
    x[0] = rng.standard_normal(dim)
    innovation = np.sqrt(1.0 - corr**2)
    for k in range(1, n):
        x[k] = corr * x[k - 1] + innovation * rng.standard_normal(dim)
    return x


def rotation_trajectory(
    n_frames: int,
    seed: int,
    centre: np.ndarray | None = None,
    step_deg: tuple[float, float] = (2.0, 8.0),
    max_pitch_deg: float = 30.0,
    max_roll_deg: float = 15.0,
) -> np.ndarray:
    """Pure-rotation, hand-held-like camera trajectory ``T_world_cam`` (n_frames, 4, 4) float64.

    The camera centre is fixed (``centre``, default: drawn from the seed inside the camera region).
    The angular velocity is a smooth random walk whose magnitude stays within ``step_deg``
    (degrees per frame; typical consecutive-frame rotations are 2-8 deg). Yaw wanders freely, pitch
    and roll are pulled back towards level so the camera never faces the floor or the ceiling
    (|pitch| stays within about ``max_pitch_deg``, |roll| within about ``max_roll_deg``).
    Deterministic given ``seed``.
    """
    rng = np.random.default_rng([seed, 1])
    if centre is None:
        centre = rng.uniform(CAMERA_REGION_MIN, CAMERA_REGION_MAX)
    lo, hi = np.radians(step_deg)
    # Smooth speed in [lo, hi] and a smoothly turning direction of (yaw, pitch, roll) rates.
    speed = lo + (hi - lo) / (1.0 + np.exp(-1.5 * _ar1(rng, n_frames, 1, 0.9)[:, 0]))
    direction = _ar1(rng, n_frames, 3, 0.85) * np.array([1.0, 0.6, 0.3])
    limits = np.radians([max_pitch_deg, max_roll_deg])
    angles = np.empty((n_frames, 3))
    angles[0] = [rng.uniform(-np.pi, np.pi), *(rng.uniform(-0.5, 0.5, 2) * limits)]
    for k in range(1, n_frames):
        rate = direction[k].copy()
        rate[1:] -= 2.0 * (angles[k - 1, 1:] / limits) ** 3  # soft restoring pull towards level
        angles[k] = angles[k - 1] + speed[k] * rate / np.linalg.norm(rate)
    return _poses(euler_to_rotation(*angles.T), np.broadcast_to(centre, (n_frames, 3)))


def _wobbly_loop(rng: np.random.Generator, radii: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """Random smooth closed curve sampled densely, (4096, 2 + len(extra)), free of cusps.

    The first two coordinates run once around a convex, slightly wobbly loop inside the ellipse of
    semi-axes ``radii`` (radius modulated by 1 + harmonics 2 and 3 of amplitude <= 0.1, small
    enough to keep the loop convex). Each further coordinate is a random sum of harmonics 1..3
    spanning [-extra, extra]. The start point and the direction of travel are random.
    """
    theta = np.linspace(0.0, 2.0 * np.pi, 4096, endpoint=False)[:, None]
    k = np.array([2.0, 3.0])
    wobble = (rng.uniform(0.0, [0.06, 0.04]) * np.cos(k * theta + rng.uniform(0.0, 2.0 * np.pi, 2))).sum(-1)
    loop = (1.0 + wobble[:, None]) / 1.1 * radii * np.concatenate([np.cos(theta), np.sin(theta)], -1)
    harmonics = np.zeros((theta.shape[0], extra.shape[0]))
    for k in range(1, 4):
        a, b = rng.standard_normal((2, extra.shape[0])) / k
        harmonics += a * np.cos(k * theta) + b * np.sin(k * theta)
    lo, hi = harmonics.min(0), harmonics.max(0)
    curve = np.concatenate([loop, (2.0 * (harmonics - lo) / (hi - lo) - 1.0) * extra], -1)
    curve = np.roll(curve, rng.integers(curve.shape[0]), axis=0)
    return curve[::-1] if rng.uniform() < 0.5 else curve


def _walk_curve(curve: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Points along a closed dense ``curve`` (m, d), starting at ``curve[0]`` and advancing by the arc
    lengths ``steps`` (n - 1,), looping around as often as needed; returns (n, d)."""
    closed = np.concatenate([curve, curve[:1]])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    s = np.concatenate([[0.0], np.cumsum(steps)]) % arc[-1]
    return np.stack([np.interp(s, arc, closed[:, j]) for j in range(curve.shape[1])], -1)


def _smooth_steps(rng: np.random.Generator, n: int, lo: float, hi: float) -> np.ndarray:
    """(n,) per-frame step lengths varying smoothly between ``lo`` and ``hi``."""
    k = np.arange(n)
    period = rng.uniform(60.0, 160.0)
    phase = 0.5 + 0.5 * np.sin(2.0 * np.pi * k / period + rng.uniform(0.0, 2.0 * np.pi))
    return lo + (hi - lo) * phase


def smooth_se3_trajectory(
    n_frames: int,
    seed: int,
    step_m: tuple[float, float] = (0.015, 0.04),
    step_deg: tuple[float, float] = (0.6, 1.6),
) -> np.ndarray:
    """Slow, smooth 6-DoF camera trajectory ``T_world_cam`` (n_frames, 4, 4) float64.

    The camera centre circles the camera region (``CAMERA_REGION_MIN/MAX``) along a random smooth
    convex loop in x-z, its height varying smoothly, moving ``step_m[0]``-``step_m[1]`` metres per
    frame (the speed varies smoothly). The gaze circles a forward-looking direction the same way:
    yaw (about the vertical) within a random 15-25 deg of a seed-dependent heading within 15 deg
    of +z, pitch within 6-10 deg, roll within 4 deg, turning ``step_deg[0]``-``step_deg[1]``
    degrees per frame. Deterministic given ``seed``.
    """
    rng = np.random.default_rng([seed, 2])
    half = (CAMERA_REGION_MAX - CAMERA_REGION_MIN) / 2.0
    path = _wobbly_loop(rng, half[[0, 2]] * rng.uniform(0.6, 1.0, 2), half[[1]])  # (x, z, y)
    centres = (CAMERA_REGION_MAX + CAMERA_REGION_MIN) / 2.0 + _walk_curve(
        path, _smooth_steps(rng, n_frames - 1, *step_m)
    )[:, [0, 2, 1]]
    gaze = _wobbly_loop(rng, np.radians([rng.uniform(15.0, 25.0), rng.uniform(6.0, 10.0)]), np.radians([4.0]))
    angles = _walk_curve(gaze, _smooth_steps(rng, n_frames - 1, *np.radians(step_deg)))
    angles[:, 0] += np.radians(rng.uniform(-15.0, 15.0))
    return _poses(euler_to_rotation(*angles.T), centres)
