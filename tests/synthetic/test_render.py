"""Tests of the synthetic RGB-D renderer (gvnn_warp.synthetic.render) and the camera trajectories
(gvnn_warp.synthetic.trajectories). numpy + Warp only."""

from __future__ import annotations

import numpy as np
import pytest

from gvnn_warp.synthetic import (
    BOX_CLEARANCE,
    CAMERA_REGION_MAX,
    CAMERA_REGION_MIN,
    ROOM_MAX,
    ROOM_MIN,
    default_intrinsics,
    euler_to_rotation,
    make_room_scene,
    relative_pose,
    render_rgbd,
    rotation_angle_deg,
    rotation_trajectory,
    smooth_se3_trajectory,
    surface_distance,
)

W, H = 320, 240


@pytest.fixture(scope="module")
def scene():
    return make_room_scene(seed=3)


@pytest.fixture(scope="module")
def poses():
    """A few varied cameras: two from each trajectory kind."""
    return np.concatenate([rotation_trajectory(60, seed=5)[::40], smooth_se3_trajectory(60, seed=6)[::40]])


def unproject(depth: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:
    """World points (H, W, 3) of every pixel centre: T_world_cam * (depth * K^-1 [u, v, 1])."""
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T
    X = rays * depth[..., None].astype(np.float64)
    return X @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]


def ray_cast_reference(scene, origin: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """float64 numpy nearest-hit ray parameter t for rays origin + t * d (d: (M, 3))."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / directions
        t = np.min(np.maximum((scene.room_min - origin) * inv, (scene.room_max - origin) * inv), axis=1)
        for lo, hi in zip(scene.box_min, scene.box_max, strict=True):
            t0, t1 = (lo - origin) * inv, (hi - origin) * inv
            t_in, t_out = np.max(np.minimum(t0, t1), axis=1), np.min(np.maximum(t0, t1), axis=1)
            t = np.where((t_in <= t_out) & (t_in > 0) & (t_in < t), t_in, t)
    return t


def bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Sample image (C, H, W) at float pixel coordinates (inside [0, W-1] x [0, H-1]); (C, M)."""
    _, h, w = image.shape
    u0 = np.clip(np.floor(u).astype(int), 0, w - 2)
    v0 = np.clip(np.floor(v).astype(int), 0, h - 2)
    a, b = u - u0, v - v0
    return (
        image[:, v0, u0] * (1 - a) * (1 - b)
        + image[:, v0, u0 + 1] * a * (1 - b)
        + image[:, v0 + 1, u0] * (1 - a) * b
        + image[:, v0 + 1, u0 + 1] * a * b
    )


# ------------------------------------------------------------------------------------------------
# Scene


def test_scene_layout_is_deterministic_and_respects_clearances():
    for seed in range(8):
        scene = make_room_scene(seed)
        again = make_room_scene(seed)
        np.testing.assert_array_equal(scene.box_min, again.box_min)
        np.testing.assert_array_equal(scene.surface_colours, again.surface_colours)
        assert scene.n_boxes == 6
        assert np.all(scene.box_min >= ROOM_MIN) and np.all(scene.box_max <= ROOM_MAX)
        assert np.all(scene.box_max - scene.box_min >= 0.3 - 1e-9)
        # No box within BOX_CLEARANCE of the camera region (L_inf distance between boxes).
        gap = np.maximum(scene.box_min - CAMERA_REGION_MAX, CAMERA_REGION_MIN - scene.box_max).max(axis=1)
        assert np.all(gap >= BOX_CLEARANCE - 1e-9)
        # Boxes both near (< 2.5 m) and far (> 3 m) from the middle of the camera region.
        centre = (CAMERA_REGION_MIN + CAMERA_REGION_MAX) / 2
        outside = np.maximum(scene.box_min - centre, 0) + np.maximum(centre - scene.box_max, 0)
        dist = np.linalg.norm(outside, axis=1)
        assert dist.min() < 2.5 and dist.max() > 3.0
        assert len(np.unique(scene.surface_seed)) == scene.surface_seed.size  # every surface differs
    assert not np.array_equal(make_room_scene(0).box_min, make_room_scene(1).box_min)


# ------------------------------------------------------------------------------------------------
# Depth


def test_depth_lies_on_scene_surfaces(scene, poses):
    K = default_intrinsics(W, H)
    _, depth = render_rgbd(scene, poses, K, W, H)
    assert depth.shape == (len(poses), 1, H, W) and depth.dtype == np.float32
    for T, d in zip(poses, depth[:, 0], strict=True):
        assert np.all(np.isfinite(d)) and d.min() > 0.3
        dist = surface_distance(scene, unproject(d, K, T))
        assert np.mean(dist < 1e-3) > 0.999, np.percentile(dist, [50, 99, 100])


def test_depth_is_nearest_hit(scene, poses):
    """Pixel-centre depths equal an independent float64 nearest-hit ray cast (z of the hit)."""
    K = default_intrinsics(W, H)
    _, depth = render_rgbd(scene, poses, K, W, H, supersample=1)
    v, u = np.mgrid[0:H:3, 0:W:3].reshape(2, -1)
    rays_cam = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T  # z = 1: t is the depth
    for T, d in zip(poses, depth[:, 0], strict=True):
        t = ray_cast_reference(scene, T[:3, 3], rays_cam @ T[:3, :3].T)
        close = np.abs(d[v, u] - t) < 1e-4 * t
        assert np.mean(close) > 0.999


def test_depth_in_empty_room_from_the_centre():
    """With no boxes and an identity camera at the origin, the principal point sees the far wall at
    z = ROOM_MAX[2], and a pixel above it the ceiling at depth |y_ceiling| * fy / (cy - v)."""
    empty = make_room_scene(0, n_boxes=0)
    w, h = 33, 25  # odd sizes: the principal point is a pixel centre
    K = default_intrinsics(w, h)
    _, depth = render_rgbd(empty, np.eye(4), K, w, h)
    cx, cy, fy = int(K[0, 2]), int(K[1, 2]), K[1, 1]
    assert depth[0, 0, cy, cx] == pytest.approx(ROOM_MAX[2], rel=1e-6)
    assert depth[0, 0, 0, cx] == pytest.approx(-ROOM_MIN[1] * fy / cy, rel=1e-5)


# ------------------------------------------------------------------------------------------------
# Colour


def test_image_is_textured_everywhere(scene, poses):
    image, _ = render_rgbd(scene, poses, default_intrinsics(W, H), W, H)
    assert image.shape == (len(poses), 3, H, W) and image.dtype == np.float32
    assert image.min() >= 0.0 and image.max() <= 1.0
    for img in image:
        assert np.all(img.std(axis=(1, 2)) > 0.05)  # every channel varies
        grey = img.mean(0)
        # Local contrast: the std within every 16x16 block, and the gradient magnitude per pixel.
        block_std = grey.reshape(H // 16, 16, W // 16, 16).std(axis=(1, 3))
        assert np.mean(block_std > 0.01) > 0.97, np.percentile(block_std, [1, 5, 50])
        grad = np.hypot(np.diff(grey, axis=1)[:-1], np.diff(grey, axis=0)[:, :-1])
        assert np.mean(grad > 2e-3) > 0.8, np.percentile(grad, [10, 20, 50])


def _box_filtered_fine_render(scene, T, K, w, h):
    """Render at 4x the resolution and average 4x4 blocks: a reference resolving the fine texture
    bands and the edges."""
    K_fine = K.copy()
    K_fine[:2, :2] *= 4
    K_fine[:2, 2] = 4 * K[:2, 2] + 1.5  # fine pixel (4u + 1.5, 4v + 1.5) = coarse pixel (u, v)
    fine, _ = render_rgbd(scene, T, K_fine, 4 * w, 4 * h)
    return fine.reshape(len(T), 3, h, 4, w, 4).mean(axis=(3, 5))


def _near_surface_change(depth: np.ndarray, radius: int = 2) -> np.ndarray:
    """(N, H, W) mask of pixels within ``radius`` of a depth edge or crease: where 1 / depth (affine
    in (u, v) on a plane) has a non-zero second difference."""
    inv = 1.0 / depth[:, 0].astype(np.float64)
    kink = np.zeros(inv.shape, dtype=bool)
    kink[:, :, 1:-1] |= np.abs(inv[:, :, 2:] - 2 * inv[:, :, 1:-1] + inv[:, :, :-2]) > 1e-4 * inv[:, :, 1:-1]
    kink[:, 1:-1] |= np.abs(inv[:, 2:] - 2 * inv[:, 1:-1] + inv[:, :-2]) > 1e-4 * inv[:, 1:-1]
    padded = np.pad(kink, ((0, 0), (radius, radius), (radius, radius)))
    h, w = inv.shape[1:]
    return np.any(
        [padded[:, dv : dv + h, du : du + w] for dv in range(2 * radius + 1) for du in range(2 * radius + 1)],
        axis=0,
    )


def test_supersampling_refines_edges_only():
    """Inside faces (textures pre-filtered to the pixel footprint) supersampling changes nothing; at
    depth edges and creases it brings pixels closer to a 4x-resolution box-filtered render."""
    scene = make_room_scene(1)
    T = smooth_se3_trajectory(20, seed=2)[[0, 19]]
    w, h = 160, 120
    K = default_intrinsics(w, h)
    single, depth = render_rgbd(scene, T, K, w, h, supersample=1)
    multi, depth_multi = render_rgbd(scene, T, K, w, h, supersample=4)
    np.testing.assert_array_equal(depth, depth_multi)  # depth is always the pixel-centre ray's
    changed = np.any(single != multi, axis=1)
    assert 0 < changed.mean() < 0.15
    assert not np.any(changed & ~_near_surface_change(depth))

    reference = _box_filtered_fine_render(scene, T, K, w, h)
    error_single = np.abs(single - reference).mean(axis=1)[changed].mean()
    error_multi = np.abs(multi - reference).mean(axis=1)[changed].mean()
    assert error_multi < 0.7 * error_single


def test_subpixel_rotation_is_not_aliased():
    """Turning the camera by about half a pixel moves the image by a homography (exact for any depth);
    the second render sampled there reproduces the first only if the texture is band-limited to
    the pixel grid. Low resolution, where most texture bands are finer than a pixel: without the
    pre-filter the error is ~2.5x larger."""
    w, h = 80, 60
    K = default_intrinsics(w, h)
    R = euler_to_rotation(0.5 / K[0, 0], 0.3 / K[0, 0], 0.0)  # R_1_2
    v, u = np.mgrid[0:h, 0:w].reshape(2, -1).astype(np.float64)
    uv = np.stack([u, v, np.ones_like(u)], -1) @ (K @ R.T @ np.linalg.inv(K)).T  # K R_2_1 K^-1 [u, v, 1]
    u2, v2 = uv[:, 0] / uv[:, 2], uv[:, 1] / uv[:, 2]
    inside = (u2 >= 0) & (u2 <= w - 1) & (v2 >= 0) & (v2 <= h - 1)
    for seed in range(3):
        scene = make_room_scene(seed)
        for T1 in rotation_trajectory(21, seed)[::10]:
            T2 = T1.copy()
            T2[:3, :3] = T1[:3, :3] @ R
            image, _ = render_rgbd(scene, np.stack([T1, T2]), K, w, h)
            error = np.abs(image[0].reshape(3, -1)[:, inside] - bilinear(image[1], u2[inside], v2[inside]))
            assert error.mean() < 0.011


def test_render_is_close_to_a_high_resolution_render(scene, poses):
    """Pre-filtered textures and edge supersampling approximate a 4x4 box filter (pixel integration)."""
    K = default_intrinsics(W, H)
    coarse, _ = render_rgbd(scene, poses[:2], K, W, H)
    error = np.abs(coarse - _box_filtered_fine_render(scene, poses[:2], K, W, H))
    assert error.mean() < 0.02 and np.percentile(error, 99) < 0.1


def test_batch_and_threads_give_identical_results(scene, poses):
    K = default_intrinsics(96, 72)
    batch = render_rgbd(scene, poses, K, 96, 72, n_threads=2)
    single_thread = render_rgbd(scene, poses, K, 96, 72, n_threads=1)
    for a, b in zip(batch, single_thread, strict=True):
        np.testing.assert_array_equal(a, b)
    for i, T in enumerate(poses):
        one = render_rgbd(scene, T, K, 96, 72, n_threads=3)
        np.testing.assert_array_equal(one[0][0], batch[0][i])
        np.testing.assert_array_equal(one[1][0], batch[1][i])


def test_moved_camera_agrees_with_reprojection(scene):
    """Render two views 3 cm and 1 deg apart; points of view 1 projected into view 2 see the same
    colour there (bilinear sampling), where visible in both views."""
    K = default_intrinsics(W, H)
    T1 = smooth_se3_trajectory(1, seed=11)[0]
    T_1_2 = np.eye(4)
    T_1_2[:3, :3] = euler_to_rotation(np.radians(0.6), np.radians(-0.5), np.radians(0.5))
    T_1_2[:3, 3] = [0.02, -0.01, 0.02]
    T2 = T1 @ T_1_2
    image, depth = render_rgbd(scene, np.stack([T1, T2]), K, W, H)

    X1 = unproject(depth[0, 0], K, np.eye(4)).reshape(-1, 3)
    T_2_1 = relative_pose(T2, T1)
    X2 = X1 @ T_2_1[:3, :3].T + T_2_1[:3, 3]
    uv = X2 @ K.T
    u, v = uv[:, 0] / uv[:, 2], uv[:, 1] / uv[:, 2]
    inside = (u >= 0) & (u <= W - 1) & (v >= 0) & (v <= H - 1)
    # Visible in view 2 (and not at a depth edge there): on a plane 1 / depth is affine in (u, v), so
    # bilinear interpolation of view 2's 1 / depth must give the point's 1 / z, with no jump between
    # the four neighbours.
    u0 = np.clip(np.floor(u).astype(int), 0, W - 2)
    v0 = np.clip(np.floor(v).astype(int), 0, H - 2)
    d2 = depth[1, 0]
    corners = np.stack([d2[v0, u0], d2[v0, u0 + 1], d2[v0 + 1, u0], d2[v0 + 1, u0 + 1]])
    inverse_depth = bilinear(1.0 / depth[1], u, v)[0]
    visible = inside & (np.abs(inverse_depth * X2[:, 2] - 1) < 1e-3) & (corners.max(0) < 1.1 * corners.min(0))
    assert visible.mean() > 0.85

    colour1 = image[0].reshape(3, -1)[:, visible]
    colour2 = bilinear(image[1], u[visible], v[visible])
    error = np.abs(colour1 - colour2).mean()
    unwarped = np.abs(image[0] - image[1]).mean()
    assert error < 0.01
    assert unwarped > 3 * error  # the motion is large enough for the comparison to mean something


# ------------------------------------------------------------------------------------------------
# Intrinsics, poses and trajectories


def test_default_intrinsics():
    K = default_intrinsics(W, H)
    hfov = np.degrees(2 * np.arctan(W / 2 / K[0, 0]))
    assert 65 <= hfov <= 70 and K[0, 0] == K[1, 1]
    np.testing.assert_allclose(K[:2, 2], [(W - 1) / 2, (H - 1) / 2])


def test_relative_pose_maps_b_into_a():
    rng = np.random.default_rng(0)
    T = rotation_trajectory(5, seed=0)
    T[:, :3, 3] = rng.normal(size=(5, 3))
    T_a_b = relative_pose(T[:, None], T[None, :])  # (5, 5, 4, 4) by broadcasting
    X_b = np.append(rng.normal(size=3), 1.0)
    for a in range(5):
        for b in range(5):
            np.testing.assert_allclose(T_a_b[a, b] @ X_b, np.linalg.solve(T[a], T[b] @ X_b), atol=1e-12)
    identity = np.broadcast_to(np.eye(4), (5, 4, 4))
    np.testing.assert_allclose(T_a_b[np.arange(5), np.arange(5)], identity, atol=1e-12)


def _steps(T):
    rel = relative_pose(T[:-1], T[1:])
    return rotation_angle_deg(rel[:, :3, :3]), np.linalg.norm(rel[:, :3, 3], axis=1)


@pytest.mark.parametrize("trajectory", [rotation_trajectory, smooth_se3_trajectory])
def test_trajectories_are_deterministic_rigid_and_seed_dependent(trajectory):
    T = trajectory(50, seed=4)
    assert T.shape == (50, 4, 4) and T.dtype == np.float64
    np.testing.assert_array_equal(T, trajectory(50, seed=4))
    assert not np.allclose(T, trajectory(50, seed=5))
    R = T[:, :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_array_equal(T[:, 3], np.broadcast_to([0, 0, 0, 1.0], (50, 4)))


def test_rotation_trajectory_motion():
    for seed in range(4):
        T = rotation_trajectory(200, seed)
        angle, shift = _steps(T)
        assert np.all(shift < 1e-12)  # a fixed camera centre...
        assert np.all(T[:, :3, 3] >= CAMERA_REGION_MIN) and np.all(T[:, :3, 3] <= CAMERA_REGION_MAX)
        assert 2.0 < np.median(angle) < 8.0  # ...turning by several degrees per frame
        assert np.mean((angle >= 1.5) & (angle <= 9.0)) > 0.95
        forward = T[:, :3, 2]  # optical axis in the world; the world's y points down
        assert np.all(np.abs(forward[:, 1]) < np.sin(np.radians(40)))  # never at floor or ceiling
        right = T[:, :3, 0]
        assert np.all(np.abs(right[:, 1]) < np.sin(np.radians(25)))  # modest roll


def test_se3_trajectory_motion():
    for seed in range(4):
        T = smooth_se3_trajectory(200, seed)
        angle, shift = _steps(T)
        assert np.all((shift > 0.01) & (shift < 0.05))
        assert 0.5 < np.median(angle) < 2.0 and angle.max() < 2.5
        assert np.all(T[:, :3, 3] >= CAMERA_REGION_MIN) and np.all(T[:, :3, 3] <= CAMERA_REGION_MAX)
        assert np.all(T[:, 2, 2] > np.cos(np.radians(45)))  # looking mostly along +z
        # Smooth: step lengths change little from frame to frame, and the heading turns gradually.
        assert np.abs(np.diff(shift)).max() < 0.002 and np.abs(np.diff(angle)).max() < 0.2
        heading = np.diff(T[:, :3, 3], axis=0)
        heading /= np.linalg.norm(heading, axis=1, keepdims=True)
        assert np.all(np.sum(heading[1:] * heading[:-1], axis=1) > np.cos(np.radians(20)))


@pytest.mark.parametrize("scene_seed", [0, 1])
def test_trajectories_keep_clear_of_the_scene(scene_seed):
    scene = make_room_scene(scene_seed)
    K = default_intrinsics(80, 60)
    T = np.concatenate([rotation_trajectory(100, scene_seed), smooth_se3_trajectory(100, scene_seed)])[::5]
    _, depth = render_rgbd(scene, T, K, 80, 60, supersample=1)
    assert depth.min() >= 0.3
