"""gvnn_warp.fusion: the TSDF against surfaces known in closed form (planes, a sphere), through a
pinhole and a lens, its mesh, its invariances (world translation across block boundaries, thread
count), bad input and the PLY files."""

import re
import subprocess
import sys
import warnings

import numpy as np
import pytest
import torch
from gvnn_warp.kernels.core.threads import get_num_threads, set_num_threads

from gvnn_warp.fusion import TSDFVolume, write_ply
from gvnn_warp.fusion.ply import read_ply

W, H = 160, 120
K = np.array([[125.0, 0, 79.5], [0, 125.0, 59.5], [0, 0, 1]])  # (a pixel is 1.2 cm at 1.5 m: finer than a voxel)
VOXEL = 0.02


def _pose(R=None, t=(0, 0, 0)):
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    T[:3, 3] = t
    return T


def _rot(axis, deg):
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.radians(deg) * np.asarray(axis, float)).as_matrix()


def _rays(K_, dist=None):
    """(H, W, 3) rays (xn, yn, 1) of every pixel; through radial-tangential ``dist`` by fixed-point
    undistortion (an independent numpy inverse)."""
    x, y = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    xd, yd = (x - K_[0, 2]) / K_[0, 0], (y - K_[1, 2]) / K_[1, 1]
    xn, yn = xd.copy(), yd.copy()
    if dist is not None:
        k1, k2, p1, p2, k3 = dist
        for _ in range(200):
            r2 = xn * xn + yn * yn
            radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
            dx = 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
            dy = p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
            xn, yn = (xd - dx) / radial, (yd - dy) / radial
    return np.stack([xn, yn, np.ones_like(xn)], -1)


def _sphere_depth(T_world_cam, centre, radius, rays):
    """Depth (z) of the first hit of each ray with a sphere, 0 where it misses."""
    R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
    d = rays @ R.T  # world directions (not unit: z = 1 in the camera)
    oc = t - centre
    a = (d * d).sum(-1)
    b = 2 * (d * oc).sum(-1)
    c = oc @ oc - radius**2
    disc = b * b - 4 * a * c
    z = np.where(disc > 0, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), 0.0)
    return np.where(z > 0, z, 0.0).astype(np.float32)


def _plane_depth(n, c, rays):
    """Depth of the plane n . p = c (camera frame) along each ray."""
    return (c / (rays @ n)).astype(np.float32)


@pytest.fixture(scope="module")
def sphere():
    """A sphere of radius 0.5 m at 1.5 m, fused from 9 poses around it."""
    centre, radius = np.array([0.1, -0.05, 1.5]), 0.5
    rays = _rays(K)
    vol = TSDFVolume(VOXEL, 4 * VOXEL, max_depth=4.0)
    poses = []
    for yaw in (-20, -10, 0, 10, 20):
        for pitch in ((-8, 8) if yaw in (-10, 10) else (0,)):
            R = _rot([0, 1, 0], yaw) @ _rot([1, 0, 0], pitch)
            t = centre - R @ np.array([0, 0, 1.5])  # looking at the centre from 1.5 m
            T = _pose(R, t)
            poses.append(T)
            colour = np.broadcast_to(np.array([0.2, 0.5, 0.8])[:, None, None], (3, H, W)).astype(np.float32)
            vol.integrate(_sphere_depth(T, centre, radius, rays), colour, K, T)
    return vol, centre, radius, poses, rays


def test_raycast_and_mesh_of_a_sphere_match_the_sphere(sphere):
    vol, centre, radius, poses, rays = sphere
    T = poses[2]
    depth, colour, normals = vol.raycast(K, T, H, W)
    true = _sphere_depth(T, centre, radius, rays)
    both = (depth > 0) & (true > 0)
    assert both.sum() > 0.9 * (true > 0).sum()  # (the silhouette's pixels may miss)
    assert np.median(np.abs(depth[both] - true[both])) < 0.15 * VOXEL
    assert np.percentile(np.abs(depth[both] - true[both]), 90) < 0.5 * VOXEL
    np.testing.assert_allclose(colour[:, both].mean(1), [0.2, 0.5, 0.8], atol=1e-4)  # (float32 running means)
    # normals: the sphere's, in the camera frame, facing the camera
    p_cam = depth[..., None] * rays
    c_cam = T[:3, :3].T @ (centre - T[:3, 3])
    expected = (p_cam - c_cam) / radius
    ok = both & (np.abs(normals).sum(0) > 0)
    cos = (normals.transpose(1, 2, 0)[ok] * expected[ok]).sum(-1)
    assert ok.sum() > 0.8 * both.sum() and np.median(cos) > 0.995
    # the mesh: on the sphere, faces outward (counter-clockwise seen from outside)
    v, f, c = vol.extract_mesh()
    dist = np.abs(np.linalg.norm(v - centre, axis=1) - radius)
    assert len(f) > 500 and np.median(dist) < 0.1 * VOXEL and dist.max() < 0.75 * VOXEL
    a, b, cc = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    face_n = np.cross(b - a, cc - a)
    outward = ((a + b + cc) / 3 - centre)
    assert ((face_n * outward).sum(1) > 0).mean() > 0.99
    np.testing.assert_allclose(c.mean(0), [0.2, 0.5, 0.8], atol=1e-4)
    assert f.min() >= 0 and f.max() < len(v)
    assert np.unique(f).size == len(v)  # every vertex is in a face
    # shared vertices: an interior edge belongs to two faces
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, count = np.unique(edges, axis=0, return_counts=True)
    assert (count == 2).mean() > 0.9 and count.max() <= 2
    pts, cols = vol.extract_points()  # the crossings: the vertices and those at the mesh's borders
    assert len(pts) >= len(v) and np.isin(v.view("V12"), pts.view("V12")).all()
    assert np.median(np.abs(np.linalg.norm(pts - centre, axis=1) - radius)) < 0.1 * VOXEL


def test_raycast_from_a_start_depth(sphere):
    # frame-to-model tracking passes the depth of the frame just integrated at the pose: the rays start
    # twice the truncation before it; the same surface is found as accurately (the march samples other
    # points, so a depth may differ, most near the silhouette, where the band lies along the rays); no
    # start where the value is not a depth; a start past the surface passes it over (documented)
    vol, centre, radius, poses, rays = sphere
    T = poses[2]
    true = _sphere_depth(T, centre, radius, rays)
    d0, c0, n0 = vol.raycast(K, T, H, W)
    d1, c1, n1 = vol.raycast(K, T, H, W, start_depth=true[None])
    assert ((d1 > 0) != (d0 > 0)).sum() <= 0.002 * (d0 > 0).sum()
    both = (d0 > 0) & (d1 > 0)
    assert np.median(np.abs(d1 - d0)[both]) < 1e-4
    for q in (50, 90):
        err0, err1 = (np.percentile(np.abs(d[both & (true > 0)] - true[both & (true > 0)]), q) for d in (d0, d1))
        assert err1 < 1.1 * err0 + 1e-4
    np.testing.assert_allclose(c1[:, both].mean(1), c0[:, both].mean(1), atol=1e-4)
    col = np.arange(W)[None] % 4
    invalid = np.where(col == 0, 0.0, np.where(col == 1, np.nan, np.where(col == 2, -1.0, np.inf)))
    d2, _, _ = vol.raycast(K, T, H, W, start_depth=np.broadcast_to(invalid, (H, W)).astype(np.float32))
    np.testing.assert_array_equal(d2, d0)
    # a start just behind the surface (the first value it reads negative): the ray marches again from
    # the tile's range
    inside = np.where(true > 0, true + 2.5 * vol.truncation, 0).astype(np.float32)
    d3, _, _ = vol.raycast(K, T, H, W, start_depth=inside)
    ok = (d3 > 0) & (true > 0)
    assert ok.sum() > 0.99 * ((d0 > 0) & (true > 0)).sum() and np.median(np.abs(d3 - d0)[ok & (d0 > 0)]) < 1e-4
    # a start in the free space behind it: the sphere is passed over (nothing behind it in this scene)
    behind = np.where(true > 0, true + 2 * radius + 3 * vol.truncation, 0).astype(np.float32)
    d4, _, _ = vol.raycast(K, T, H, W, start_depth=behind)
    assert (d4[true > 0] == 0).mean() > 0.99
    with pytest.raises(ValueError, match=r"TSDFVolume.raycast: argument 'start_depth' must be \(120, 160\)"):
        vol.raycast(K, T, H, W, start_depth=true[:, :-1])
    # without normals (frame-to-model tracking does not use them): the same depth and colour
    d5, c5, n5 = vol.raycast(K, T, H, W, start_depth=true[None], normals=False)
    assert n5 is None
    np.testing.assert_array_equal(d5, d1)
    np.testing.assert_array_equal(c5, c1)
    with pytest.raises(TypeError, match=r"TSDFVolume.raycast: argument 'normals' must be True or False"):
        vol.raycast(K, T, H, W, normals="no")
    assert vol.raycast(K, T, H, W, normals=np.bool_(False))[2] is None


def _kernels_run(monkeypatch):
    """The names of the kernels TSDFVolume launches over threads from now on (a list that fills)."""
    import gvnn_warp.fusion.volume as volume_module

    names, launch = [], volume_module.launch_chunks

    def spy(kernel, *args, **kwargs):
        names.append(kernel.key)
        return launch(kernel, *args, **kwargs)

    monkeypatch.setattr(volume_module, "launch_chunks", spy)
    return names


def test_the_8_lane_raycast_equals_the_ray_by_ray_one(sphere, monkeypatch):
    # the raycast marches a tile's row of 8 rays as lanes; the ray-by-ray kernel must give the same
    # depth, colour and normals bit for bit: rows wider than the image (a width that is not a multiple
    # of 8, with hits in the last, partial tiles), rays that miss, starts from a depth (invalid values,
    # starts behind the surface: the march begins again), a pose from far away and one whose nearest
    # rays start inside the band, a lens camera
    vol, centre, radius, poses, rays = sphere
    kernels = _kernels_run(monkeypatch)
    true = _sphere_depth(poses[2], centre, radius, rays)
    start = np.where(np.arange(W)[None] % 3 == 0, true + 2.5 * vol.truncation, true).astype(np.float32)
    start[::5, ::2] = np.nan
    far = _pose(_rot([0, 1, 0], 30), centre - _rot([0, 1, 0], 30) @ np.array([0, 0, 2.8]))
    near = _pose(np.eye(3), centre - np.array([0.0, 0.0, radius + vol.min_depth + 0.5 * vol.truncation]))
    calls = [(K, poses[2], H, W, None), (K, poses[2], H, W, start), (K, far, 117, 151, None),
             (K, near, H, W, None), (K, near, 117, 151, None),
             ((K, (-0.2, 0.05, 0.001, -0.001, 0.0)), poses[4], H, W, None)]
    try:
        for camera, T, h, w, s in calls:
            out = []
            for lanes in (True, False):
                vol._lanes = lanes
                del kernels[:]
                out.append(vol.raycast(camera, T, h, w, start_depth=s))
                assert ("raycast_rows" if lanes else "raycast") in kernels
            assert (out[0][0] > 0).mean() > 0.05
            if w % 8:  # (hits in the last, partial tile column and row of the near pose)
                assert (out[0][0][:, 144:] > 0).any() == (out[0][0][112:] > 0).any() == (T is near)
            for a, b in zip(*out):
                np.testing.assert_array_equal(a.view(np.uint32), b.view(np.uint32))
    finally:
        vol._lanes = True


def test_trilinear_value_and_gradient_match_finite_differences(sphere):
    # hashing.trilinear_grad (the raycast's Newton step): its value is hashing.trilinear's and its
    # gradient the trilinear interpolant's, checked by central differences inside the band, across
    # voxel and block boundaries
    import warp as wp
    from gvnn_warp.kernels.fusion import hashing

    @wp.kernel
    def probe(table: wp.array(dtype=wp.vec4i), mask: int, tw: wp.array(dtype=wp.vec2), pts: wp.array(dtype=wp.vec3),
              inv_voxel: float, value: wp.array(dtype=float), grad: wp.array(dtype=wp.vec3),
              plain: wp.array(dtype=float), ok: wp.array(dtype=int)):
        i = wp.tid()
        v, g, o = hashing.trilinear_grad(table, mask, tw, pts[i], inv_voxel)
        v2, o2 = hashing.trilinear(table, mask, tw, pts[i], inv_voxel)
        value[i] = v
        grad[i] = g
        plain[i] = v2
        ok[i] = wp.where(o and o2, 1, 0)

    vol, centre, radius, poses, rays = sphere
    rng = np.random.default_rng(5)
    d = rng.normal(size=(400, 3)) * [0.5, 0.5, 1.0]
    d[:, 2] = -np.abs(d[:, 2])  # (the side the cameras saw)
    base = centre + (radius + rng.uniform(-0.6, 0.6, (400, 1)) * vol.truncation) * d / np.linalg.norm(d, axis=1,
                                                                                                          keepdims=True)
    h = 1e-4
    offsets = np.concatenate([[[0.0, 0, 0]], h * np.eye(3), -h * np.eye(3)])
    pts = (base[:, None] + offsets[None]).reshape(-1, 3).astype(np.float32)
    n = len(pts)
    out = [wp.empty(n, dtype=float, device="cpu"), wp.empty(n, dtype=wp.vec3, device="cpu"),
           wp.empty(n, dtype=float, device="cpu"), wp.empty(n, dtype=int, device="cpu")]
    wp.launch(probe, dim=n, inputs=[vol.table, vol.mask, vol.tw, wp.array(pts, dtype=wp.vec3, device="cpu"),
                                    1.0 / vol.voxel_size, *out], device="cpu")
    value, grad, plain, ok = (a.numpy() for a in out)
    np.testing.assert_array_equal(value, plain)
    value, grad, ok = value.reshape(-1, 7), grad.reshape(-1, 7, 3)[:, 0], ok.reshape(-1, 7).all(1)
    fd = (value[:, 1:4] - value[:, 4:7]) / (2 * h)
    # (a difference across a voxel face sees a kink of the interpolant, ~3% of the points: the rest agree)
    agree = ok & (np.abs(fd - grad) <= 0.02 * np.abs(grad) + 0.05).all(1)
    assert ok.sum() > 200 and agree[ok].mean() > 0.9
    assert np.median(np.linalg.norm(grad[ok], axis=1)) > 0.5 / vol.truncation  # (a TSDF: ~1 / truncation)


def test_trilinear_across_blocks_matches_a_plain_lookup(sphere):
    # hashing.trilinear_grad looks up each distinct block of the 8 voxels once: against a plain
    # numpy lookup of every voxel through the block coordinates, at points whose 8 voxels reach
    # into the next block on none, one, two and all three axes, in the band and beyond it
    # (unobserved or unallocated voxels: not ok, value 0)
    import warp as wp
    from gvnn_warp.kernels.fusion import hashing

    @wp.kernel
    def probe(table: wp.array(dtype=wp.vec4i), mask: int, tw: wp.array(dtype=wp.vec2), pts: wp.array(dtype=wp.vec3),
              inv_voxel: float, value: wp.array(dtype=float), grad: wp.array(dtype=wp.vec3), ok: wp.array(dtype=int)):
        i = wp.tid()
        v, g, o = hashing.trilinear_grad(table, mask, tw, pts[i], inv_voxel)
        value[i] = v
        grad[i] = g
        ok[i] = wp.where(o, 1, 0)

    vol, centre, radius, _, _ = sphere
    n_blocks = vol.n_blocks
    coords, tw = vol.coords.numpy()[:n_blocks], vol.tw.numpy()
    index = {tuple(c): i for i, c in enumerate(coords)}

    def voxel(v):  # (tsdf, weight) of integer voxel v; weight 0 where its block is not allocated
        b = tuple(np.floor_divide(v, 8))
        if b not in index:
            return 0.0, 0.0
        lx, ly, lz = np.asarray(v) - 8 * np.asarray(b)
        return tuple(tw[index[b] * 512 + lx + 8 * (ly + 8 * lz)])

    rng = np.random.default_rng(7)
    d = rng.normal(size=(300, 3)) * [0.5, 0.5, 1.0]
    d[:, 2] = -np.abs(d[:, 2])
    near = centre + (radius + rng.uniform(-1.5, 1.5, (300, 1)) * vol.truncation) * d / np.linalg.norm(
        d, axis=1, keepdims=True)
    cells = np.floor(near / VOXEL).astype(np.int64)
    reach = np.array([[(k >> a) & 1 for a in range(3)] for k in range(8)])[rng.integers(0, 8, 300)]
    cells = np.where(reach == 1, 8 * np.floor_divide(cells, 8) + 7, cells)  # (the 8 voxels reach over those axes)
    frac = rng.uniform(0.02, 0.98, (300, 3))
    pts = ((cells + frac) * VOXEL).astype(np.float32)
    out = [wp.empty(len(pts), dtype=float, device="cpu"), wp.empty(len(pts), dtype=wp.vec3, device="cpu"),
           wp.empty(len(pts), dtype=int, device="cpu")]
    wp.launch(probe, dim=len(pts), inputs=[vol.table, vol.mask, vol.tw, wp.array(pts, dtype=wp.vec3, device="cpu"),
                                           1.0 / vol.voxel_size, *out], device="cpu")
    value, grad, ok = (a.numpy() for a in out)
    g = pts.astype(np.float64) / VOXEL
    i0, t = np.floor(g).astype(np.int64), g - np.floor(g)
    for n in range(len(pts)):
        ref, ref_grad, ref_ok = 0.0, np.zeros(3), True
        for c in range(8):
            dc = np.array([c & 1, (c >> 1) & 1, (c >> 2) & 1])
            f, w = voxel(i0[n] + dc)
            if w <= 0:
                ref_ok = False
                continue
            wts = np.where(dc == 1, t[n], 1 - t[n])
            ref += wts.prod() * f
            ref_grad += f * np.array([(2 * dc[a] - 1) * np.prod(np.delete(wts, a)) for a in range(3)]) / VOXEL
        assert bool(ok[n]) == ref_ok, n
        if ref_ok:
            np.testing.assert_allclose(value[n], ref, atol=1e-5)
            np.testing.assert_allclose(grad[n], ref_grad, atol=1e-3 / VOXEL)
    assert ok.sum() > 100 and (~ok.astype(bool)).sum() > 10
    assert all(ok[(reach.sum(1) == r)].sum() > 5 for r in range(4))  # (every kind of reach, observed)

    # hashing.trilinear_colour at the same points, on random colours (a quarter of the voxels with no
    # colour): the trilinear weights of the voxels that hold one, renormalised; black where none does
    @wp.kernel
    def probe_colour(table: wp.array(dtype=wp.vec4i), mask: int, colour: wp.array(dtype=wp.vec4),
                     pts: wp.array(dtype=wp.vec3), inv_voxel: float, rgb: wp.array(dtype=wp.vec3)):
        i = wp.tid()
        rgb[i] = hashing.trilinear_colour(table, mask, colour, pts[i], inv_voxel)

    n_vox = n_blocks * 512
    colours = np.zeros((vol.colour.shape[0], 4), np.float32)
    colours[:n_vox, :3] = rng.uniform(0, 1, (n_vox, 3))
    colours[:n_vox, 3] = np.where(rng.uniform(0, 1, n_vox) < 0.25, 0.0, rng.uniform(0.5, 3.0, n_vox))
    rgb = wp.empty(len(pts), dtype=wp.vec3, device="cpu")
    wp.launch(probe_colour, dim=len(pts), inputs=[vol.table, vol.mask, wp.array(colours, dtype=wp.vec4, device="cpu"),
                                                  wp.array(pts, dtype=wp.vec3, device="cpu"), 1.0 / vol.voxel_size,
                                                  rgb], device="cpu")
    rgb = rgb.numpy()
    partial = black = 0
    for n in range(len(pts)):
        ref, total, held = np.zeros(3), 0.0, 0
        for c in range(8):
            dc = np.array([c & 1, (c >> 1) & 1, (c >> 2) & 1])
            v = i0[n] + dc
            b = tuple(np.floor_divide(v, 8))
            if b not in index:
                continue
            lx, ly, lz = v - 8 * np.asarray(b)
            cc = colours[index[b] * 512 + lx + 8 * (ly + 8 * lz)]
            if cc[3] > 0:
                r = np.where(dc == 1, t[n], 1 - t[n]).prod()
                ref, total, held = ref + r * cc[:3], total + r, held + 1
        np.testing.assert_allclose(rgb[n], ref / total if total > 0 else 0.0, atol=2e-5)
        partial += 0 < held < 8
        black += held == 0
    assert partial > 50 and black > 5


def test_world_translation_across_block_boundaries_changes_nothing(sphere):
    # the same frames with the world moved by an offset that crosses many blocks, into negative
    # coordinates (floor division of negative voxel indices): the same depth and the same mesh, moved
    vol, centre, radius, poses, rays = sphere
    shift = np.array([-3.37, -5.01, -2.2])  # (not a multiple of the block size)
    moved = TSDFVolume(VOXEL, 4 * VOXEL, max_depth=4.0)
    for T in poses:
        T2 = T.copy()
        T2[:3, 3] += shift
        moved.integrate(_sphere_depth(T, centre, radius, rays), None, K, T2)
    T2 = poses[2].copy()
    T2[:3, 3] += shift
    d1, _, _ = vol.raycast(K, poses[2], H, W)
    d2, _, _ = moved.raycast(K, T2, H, W)
    both = (d1 > 0) & (d2 > 0)
    assert both.sum() > 0.95 * (d1 > 0).sum()
    assert np.median(np.abs(d1[both] - d2[both])) < 0.1 * VOXEL  # (the voxel grid moved with the world, not exactly)
    v2, _, _ = moved.extract_mesh()
    assert np.median(np.abs(np.linalg.norm(v2 - (centre + shift), axis=1) - radius)) < 0.1 * VOXEL


def test_results_do_not_depend_on_the_thread_count(sphere, monkeypatch):
    import gvnn_warp.fusion.volume as volume_module

    _, centre, radius, poses, rays = sphere
    # (the raycast's depth range in a part per thread even for this small map: 1, 2, 3 parts below)
    monkeypatch.setattr(volume_module, "_BLOCKS_PER_PART", 1)
    out = []
    before = get_num_threads()
    try:
        for n in (1, 2, 3):
            set_num_threads(n)
            vol = TSDFVolume(VOXEL, 4 * VOXEL, max_depth=4.0)
            for T in poses[:4]:
                vol.integrate(_sphere_depth(T, centre, radius, rays), None, K, T)
            out.append((vol.tw.numpy()[: vol.n_blocks * 512].copy(), *vol.raycast(K, poses[1], H, W),
                        *vol.extract_mesh()))
    finally:
        set_num_threads(before)
    for other in out[1:]:
        for a, b in zip(out[0], other):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("with_colour, lens", [(True, False), (False, False), (True, True)])
def test_the_8_lane_integration_equals_the_voxel_by_voxel_one(with_colour, lens, monkeypatch):
    # frames are integrated by the 8-lane kernel; the voxel-by-voxel one must give the
    # same TSDF, weights and colours bit for bit, in the hard cases too: noisy depth, depth edges
    # (sphere against a wall), NaN, inf, negative, zero and out-of-range pixels, a surface nearer than
    # min_depth's band (voxels behind the near plane), voxels projecting outside the image, weights > 1;
    # through a pinhole and a radial-tangential lens
    rng = np.random.default_rng(7)
    camera = (K, (-0.5, 0.0, 0.001, -0.002, 0.0)) if lens else K  # (its domain ends inside the image)
    centre, radius = np.array([0.1, -0.05, 1.0]), 0.35
    rays = _rays(K)
    vols = [TSDFVolume(VOXEL, 4 * VOXEL, max_depth=4.0, min_depth=0.15) for _ in range(2)]
    vols[1]._lanes = False
    kernels = _kernels_run(monkeypatch)
    for k, yaw in enumerate((-12, 0, 9, 0)):
        R = _rot([0, 1, 0], yaw) @ _rot([1, 0, 0], 3 * k - 4)
        T = _pose(R, centre - R @ np.array([0, 0, 1.0]) + rng.normal(0, 0.01, 3))
        sphere = _sphere_depth(T, centre, radius, rays)
        wall = _plane_depth(np.array([0.1, 0.05, 1.0]), 2.2, rays)
        depth = np.where(sphere > 0, sphere, wall) + rng.normal(0, 0.004, (H, W)).astype(np.float32)
        depth[:3, :] = 0.17  # a band crossing the near plane
        depth[5:8, ::7] = np.nan
        depth[9, ::5] = np.inf
        depth[10, ::3] = -0.5
        depth[11, ::2] = 0.0
        depth[12, ::4] = 9.0
        colour = rng.random((3, H, W), dtype=np.float32) if with_colour else None
        for vol in vols:
            del kernels[:]
            vol.integrate(depth, colour, camera, T)
            assert ("integrate_rows" if vol._lanes else "integrate") in kernels
    a, b = vols
    n = a.n_blocks * 512
    assert a.n_blocks == b.n_blocks > 0 and (a.tw.numpy()[:n, 1] > 1).any()
    np.testing.assert_array_equal(a.tw.numpy()[:n].view(np.uint32), b.tw.numpy()[:n].view(np.uint32))
    np.testing.assert_array_equal(a.colour.numpy()[:n].view(np.uint32), b.colour.numpy()[:n].view(np.uint32))
    assert (a.colour.numpy()[:n, 3] > 0).any() == with_colour


def test_a_lens_camera_integrates_and_raycasts_through_its_distortion():
    # a tilted plane seen through a radial-tangential lens: the depth of each lens pixel in closed
    # form (its ray from an independent numpy undistortion); fused and raycast through the same lens
    dist = (-0.25, 0.08, 0.001, -0.002, 0.0)
    rays = _rays(K, dist)
    n, c = np.array([0.25, -0.1, 1.0]), 1.2
    depth = _plane_depth(n, c, rays)
    vol = TSDFVolume(VOXEL, 4 * VOXEL, max_depth=4.0)
    for _ in range(2):
        vol.integrate(depth, None, (K, dist), np.eye(4))
    got, _, normals = vol.raycast((K, dist), np.eye(4), H, W)
    ok = got > 0
    assert ok.mean() > 0.9
    assert np.median(np.abs(got[ok] - depth[ok])) < 0.1 * VOXEL
    unit = n / np.linalg.norm(n)
    good = np.abs(normals).sum(0) > 0
    assert np.median(normals.transpose(1, 2, 0)[good] @ -unit) > 0.999
    # the surface in space is the plane itself: seen through a pinhole with the same K it has the
    # pinhole's closed-form depth, which is not the lens image's (so the lens was used)
    pinhole_true = _plane_depth(n, c, _rays(K))
    d_pin, _, _ = vol.raycast(K, np.eye(4), H, W)
    both = (d_pin > 0) & ok
    assert both.mean() > 0.8 and np.median(np.abs(d_pin[both] - pinhole_true[both])) < 0.1 * VOXEL
    assert np.percentile(np.abs(depth - pinhole_true)[both], 90) > VOXEL


def test_a_lens_camera_takes_its_coefficients_as_a_tuple_an_array_or_a_tensor():
    torch = pytest.importorskip("torch")
    dist = (-0.25, 0.08, 0.001, -0.002, 0.0)
    depth = _plane_depth(np.array([0.25, -0.1, 1.0]), 1.2, _rays(K, dist))
    out = []
    for coeffs in (dist, np.array(dist), torch.tensor(dist, dtype=torch.float64)):
        vol = TSDFVolume(VOXEL, 4 * VOXEL, max_depth=4.0)
        vol.integrate(depth, None, (K, coeffs), np.eye(4))
        out.append(vol.raycast((K, coeffs), np.eye(4), H, W)[0])
    assert (out[0] > 0).mean() > 0.9
    for d in out[1:]:
        np.testing.assert_array_equal(d, out[0])


def test_invalid_depth_is_skipped_and_a_frame_without_any_changes_nothing():
    rays = _rays(K)
    depth = _plane_depth(np.array([0, 0, 1.0]), 1.0, rays)
    depth[:10] = np.nan
    depth[10:20] = -1.0
    depth[20:24] = 0.0
    original = depth.copy()
    vol = TSDFVolume(VOXEL)
    report = vol.integrate(depth, None, K, np.eye(4))
    np.testing.assert_array_equal(depth, original)  # inputs are never modified
    assert report.valid_pixels == (H - 24) * W and report.new_blocks == report.total_blocks > 0
    got, _, _ = vol.raycast(K, np.eye(4), H, W)
    assert np.all(np.isfinite(got)) and np.median(np.abs(got[30:] - 1.0)) < 0.05 * VOXEL
    assert (got[:8] == 0).all()  # rows never seen: no surface
    none = vol.integrate(np.full((H, W), np.nan, np.float32), None, K, np.eye(4))
    assert none.valid_pixels == 0 and none.blocks == 0 and none.total_blocks == report.total_blocks


def test_memory_limit_and_growth():
    rays = _rays(K)
    depth = _plane_depth(np.array([0, 0, 1.0]), 2.0, rays)
    small = TSDFVolume(0.005, max_memory_mb=0.5)  # 42 blocks at most
    with pytest.raises(ValueError, match=r"TSDFVolume.integrate: the map needs more than 42 blocks .* use larger "
                                         r"voxels or allow more memory"):
        small.integrate(depth, None, K, np.eye(4))
    grown = TSDFVolume(0.005, max_memory_mb=512)  # past its first allocation and first table
    for x in np.linspace(-4, 4, 9):
        grown.integrate(depth, None, K, _pose(t=(x, 0, 0)))
    assert grown.n_blocks > 1024 and grown.memory_bytes == grown.n_blocks * 512 * 24
    d, _, _ = grown.raycast(K, _pose(t=(4.0, 0, 0)), H, W)
    assert np.median(np.abs(d[d > 0] - 2.0)) < 0.002
    # voxels are indexed with 32-bit integers: no memory allowance takes a map past that
    from gvnn_warp.fusion.volume import MAX_BLOCKS

    assert TSDFVolume(0.01, max_memory_mb=1e6).max_blocks == MAX_BLOCKS and MAX_BLOCKS * 512 < 2**31


@pytest.mark.parametrize("call, error, message", [
    (lambda v: v.integrate(np.ones((H, W, 3), np.float32), None, K, np.eye(4)), ValueError,
     r"TSDFVolume.integrate: argument 'depth' must be \(H, W\) or \(1, H, W\)"),
    (lambda v: v.integrate(np.ones((H, W), np.float32), np.ones((H, W, 3), np.float32), K, np.eye(4)), ValueError,
     r"argument 'colour' must be \(3, 120, 160\) like the depth, got \(120, 160, 3\), which looks channel-last"),
    (lambda v: v.integrate(np.ones((H, W), np.int32), None, K, np.eye(4)), TypeError,
     r"TSDFVolume.integrate: argument 'depth' must be float32 or float64"),
    # integer pixels as read from PNGs: what to do with them
    (lambda v: v.integrate(np.ones((H, W), np.uint16), None, K, np.eye(4)), TypeError,
     r"'depth' must be float32 or float64, got uint16 \(depth in metres: divide a depth PNG's values by its "
     r"depth scale"),
    (lambda v: v.integrate(np.ones((H, W), np.float32), np.ones((3, H, W), np.uint8), K, np.eye(4)), TypeError,
     r"'colour' must be float32 or float64, got uint8 \(images in \[0, 1\]: divide 8-bit ones by 255\)"),
    (lambda v: v.integrate(np.ones((H, W), np.float32), None, K, np.ones((4, 4))), ValueError,
     r"argument 'T_world_cam' must be a rigid transform"),
    (lambda v: v.integrate(np.ones((H, W), np.float32), None, np.eye(2), np.eye(4)), ValueError,
     r"argument 'camera' must have a finite \(3, 3\) K"),
    (lambda v: v.integrate(np.ones((H, W), np.float32), None, (K, (0.1, 0.2)), np.eye(4)), ValueError,
     r"TSDFVolume.integrate: argument 'camera' as \(K, dist\) needs dist = 5 finite radial-tangential"),
    # the argument named 'camera', as the method calls it (not the aligner's 'K')
    (lambda v: v.integrate(np.ones((H, W), np.float32), None, (100.0, 100.0, 80.0, 60.0), np.eye(4)), TypeError,
     r"TSDFVolume.integrate: argument 'camera' must be a \(3, 3\) K \(numpy or torch\), a \(K, dist\) pair or a "
     r"camera of gvnn_warp.cameras, got a tuple of 4"),
    (lambda v: v.integrate(np.ones((H, W), np.float32), None, K.tolist(), np.eye(4)), TypeError,
     r"argument 'camera' must be a \(3, 3\) K .*got a list of 3"),
    (lambda v: v.integrate(np.ones((H, W), np.float32), None, "K", np.eye(4)), TypeError,
     r"TSDFVolume.integrate: argument 'camera' must be a numpy array or torch tensor"),
    (lambda v: TSDFVolume(0.01, pixel_stride=0), ValueError, r"argument 'pixel_stride' must be an integer >= 1"),
    (lambda v: TSDFVolume(0.01, max_memory_mb=float("inf")), ValueError,
     r"TSDFVolume.__init__: argument 'max_memory_mb' must be a finite number of MiB"),
    (lambda v: v.raycast(K, np.eye(4), 0, W), ValueError, r"TSDFVolume.raycast: arguments 'height' and 'width'"),
    (lambda v: TSDFVolume(0.0), ValueError, r"TSDFVolume.__init__: argument 'voxel_size' must be a positive"),
    (lambda v: TSDFVolume(0.01, 0.001), ValueError, r"argument 'truncation' must be at least the voxel size"),
    (lambda v: TSDFVolume(0.01, min_depth=2.0, max_depth=1.0), ValueError, r"0 < min_depth < max_depth"),
])
def test_bad_input_is_named(call, error, message):
    with pytest.raises(error, match=message):
        call(TSDFVolume(VOXEL))


def test_integer_intrinsics_are_taken_as_floats():
    Ki = np.array([[100, 0, 80], [0, 100, 60], [0, 0, 1]])  # (whole pixels, written as integers)
    depth = np.full((H, W), 1.0, np.float32)
    a, b = TSDFVolume(VOXEL), TSDFVolume(VOXEL)
    assert a.integrate(depth, None, Ki, np.eye(4)) == b.integrate(depth, None, Ki.astype(np.float64), np.eye(4))
    np.testing.assert_array_equal(a.raycast(Ki, np.eye(4), H, W)[0], b.raycast(Ki.astype(float), np.eye(4), H, W)[0])
    np.testing.assert_array_equal(a.raycast(torch.tensor(Ki), np.eye(4), H, W)[0], b.raycast(Ki, np.eye(4), H, W)[0])


def test_colours_not_finite_or_8_bit_are_warned_about_and_the_model_stays_finite():
    depth = np.full((H, W), 1.0, np.float32)
    colour = np.random.default_rng(0).random((3, H, W)).astype(np.float32)
    holes = colour.copy()
    holes[:, 5:15, 10:30] = np.nan
    holes[0, 0, 0] = np.inf
    vol = TSDFVolume(VOXEL)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        vol.integrate(depth, holes, K, np.eye(4))
        vol.integrate(depth, holes, K, np.eye(4))
        vol.integrate(depth, 255 * colour, K, np.eye(4))
        vol.integrate(depth, 255 * colour, K, np.eye(4))
    messages = [str(w.message).split(": ", 1)[1] for w in caught]
    assert len(messages) == 2 and messages[0].startswith("argument 'colour' has NaN or infinite values")
    assert messages[1].startswith("argument 'colour' has values up to 254")
    d, c, _ = vol.raycast(K, np.eye(4), H, W)
    assert (d > 0).mean() > 0.5 and np.isfinite(c).all()
    v, f, vc = vol.extract_mesh()
    assert len(f) > 0 and np.isfinite(vc).all()
    # non-finite colour values are black (0), as a colour of zeros would be
    a, b = TSDFVolume(VOXEL), TSDFVolume(VOXEL)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a.integrate(depth, holes, K, np.eye(4))
    b.integrate(depth, np.where(np.isfinite(holes), holes, 0.0).astype(np.float32), K, np.eye(4))
    np.testing.assert_array_equal(a.raycast(K, np.eye(4), H, W)[1], b.raycast(K, np.eye(4), H, W)[1])


def test_empty_volume_has_empty_results():
    vol = TSDFVolume(VOXEL)
    with pytest.warns(UserWarning, match=r"TSDFVolume.extract_mesh: the volume is empty \(no frame has been "
                                         r"integrated\): the mesh is empty"):
        v, f, c = vol.extract_mesh()
    assert v.shape == (0, 3) and f.shape == (0, 3) and c.shape == (0, 3)
    # (a depth in millimetres integrates nothing: the same, the depth named)
    assert vol.integrate(np.full((H, W), 1500.0, np.float32), None, K, np.eye(4)).valid_pixels == 0
    with pytest.warns(UserWarning, match=r"the volume is empty \(none of the 1 frames integrated has depth within "
                                         r"\[0.1, 8\] .*millimetres"):
        assert vol.extract_mesh()[1].shape == (0, 3)
    d, col, n = vol.raycast(K, np.eye(4), H, W)
    assert not d.any() and not col.any() and not n.any()


def test_ply_round_trip_and_header(tmp_path):
    rng = np.random.default_rng(0)
    v = rng.normal(size=(7, 3)).astype(np.float32)
    f = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6]], np.int32)
    c = rng.uniform(size=(7, 3)).astype(np.float32)
    write_ply(tmp_path / "m.ply", v, f, c, comment="test mesh")
    head = (tmp_path / "m.ply").read_bytes()[:300].decode("ascii", "replace")
    assert head.startswith("ply\nformat binary_little_endian 1.0\ncomment test mesh\nelement vertex 7\n")
    assert "property list uchar int vertex_indices\nend_header\n" in head
    v2, f2, c2 = read_ply(tmp_path / "m.ply")
    np.testing.assert_array_equal(v2, v)
    np.testing.assert_array_equal(f2, f)
    np.testing.assert_allclose(c2, np.round(c * 255) / 255, atol=1e-7)
    write_ply(tmp_path / "p.ply", v)  # a point cloud
    v3, f3, c3 = read_ply(tmp_path / "p.ply")
    assert f3 is None and c3 is None and np.array_equal(v3, v)
    with pytest.raises(ValueError, match="face indices"):
        write_ply(tmp_path / "bad.ply", v, f + 5)


def test_fuse_sequence_skips_frames_without_a_pose_or_depth(tmp_path):
    from gvnn_warp.cli import main
    from gvnn_warp.datasets.tum import read_tum
    from gvnn_warp.fusion.sequence import fuse_sequence

    assert main(["render", "--out", str(tmp_path / "seq"), "--frames", "3", "--size", "32x24", "--no-progress"]) == 0
    seq = read_tum(tmp_path / "seq")
    poses = seq.gt_poses.copy()
    poses[1] = np.nan
    vol = TSDFVolume(0.05, max_depth=10.0)
    report = fuse_sequence(vol, seq, poses, progress=False)
    assert report.skipped == [1] and report.integrated == 2 and vol.n_blocks > 0


def test_model_tracking_with_a_depth_source_scales_with_its_units(tmp_path):
    # a depth source (the CLI's --depth predicted passes the depth network) replaces the depth files
    # in both the integration and the alignment: the same frames with every depth halved, tracked in
    # a map of halved voxels, give the same rotations and halved translations (the depth files'
    # depth in one of the two would break that)
    from gvnn_warp.cli import main
    from gvnn_warp.datasets.tum import read_tum
    from gvnn_warp.fusion.sequence import ModelTracker, fuse_sequence
    from gvnn_warp.odometry import DirectAligner

    assert main(["render", "--out", str(tmp_path / "seq"), "--frames", "6", "--size", "96x72", "--seed", "4",
                 "--no-progress"]) == 0
    seq = read_tum(tmp_path / "seq")
    frames = [seq.image(i) for i in range(len(seq))]
    calls = []

    def halved(rgb):  # (the frame found by its colour: a source sees only the image)
        i = next(k for k, f in enumerate(frames) if np.array_equal(f, rgb))
        calls.append(i)
        return 0.5 * seq.depth(i)

    runs = {}
    for name, scale, depth in (("files", 1.0, None), ("halved", 0.5, halved)):
        vol = TSDFVolume(0.02 * scale, max_depth=10.0)
        tracker = ModelTracker(seq, DirectAligner(seq.K), vol, depth=depth)
        runs[name] = tracker(len(seq), np.eye(4), progress=False).poses
    assert calls == list(range(len(seq)))  # (each frame's depth asked for once)
    files, halved_run = runs["files"], runs["halved"]
    assert np.abs(files[-1][:3, 3]).max() > 0.02  # (the camera moved)
    np.testing.assert_allclose(halved_run[:, :3, :3], files[:, :3, :3], atol=1e-4)
    np.testing.assert_allclose(halved_run[:, :3, 3], 0.5 * files[:, :3, 3], atol=1e-4)
    # fuse_sequence takes the source too: halved depth, halved poses' translations, halved voxels give
    # the same TSDF (halving is exact in binary)
    halved_poses = files.copy()
    halved_poses[:, :3, 3] *= 0.5
    vols = [TSDFVolume(0.02 * s, max_depth=10.0) for s in (1.0, 0.5)]
    fuse_sequence(vols[0], seq, files, progress=False)
    fuse_sequence(vols[1], seq, halved_poses, depth=halved, progress=False)
    n = vols[0].n_blocks * 512
    assert vols[1].n_blocks == vols[0].n_blocks > 0
    assert np.array_equal(vols[1].tw.numpy()[:n], vols[0].tw.numpy()[:n])


def test_model_tracking_takes_colour_and_a_constant_velocity_start(tmp_path):
    # ModelTracker's color and init as the frame-to-frame tracker's: the aligner sees RGB reference
    # and live images (the model's raycast colour and the frame's) and, with init="velocity", starts
    # each alignment from the motion it found for the frame before; the poses stay on the truth
    from gvnn_warp.cli import main
    from gvnn_warp.datasets.tum import read_tum
    from gvnn_warp.fusion.sequence import ModelTracker
    from gvnn_warp.odometry import DirectAligner

    assert main(["render", "--out", str(tmp_path / "seq"), "--frames", "6", "--size", "160x120", "--seed", "4",
                 "--no-progress"]) == 0
    seq = read_tum(tmp_path / "seq")

    class Spy:
        def __init__(self, aligner):
            self.aligner, self.calls = aligner, []

        def align(self, ref_image, ref_depth, live_image, live_depth=None, init=None):
            T, info = self.aligner.align(ref_image, ref_depth, live_image, live_depth, init=init)
            self.calls.append((ref_image.shape, live_image.shape, None if init is None else np.array(init),
                               np.array(T)))
            return T, info

    runs = {}
    for color, init in ((False, "identity"), (True, "velocity")):
        spy = Spy(DirectAligner(seq.K, color=color))
        tracker = ModelTracker(seq, spy, TSDFVolume(0.01, max_depth=10.0), color=color, init=init)
        runs[color] = tracker(len(seq), seq.gt_poses[0], progress=False).poses
        channels = 3 if color else 1
        assert all(r[0] == l[0] == channels for r, l, _, _ in spy.calls)
        inits = [c[2] for c in spy.calls]
        if init == "identity":
            assert all(g is None for g in inits)
        else:
            np.testing.assert_array_equal(inits[0], np.eye(4))
            for before, after in zip(spy.calls, spy.calls[1:]):
                np.testing.assert_array_equal(after[2], before[3])  # (the previous frame's motion)
    for poses in runs.values():
        err = np.linalg.norm(poses[:, :3, 3] - seq.gt_poses[: len(seq), :3, 3], axis=1)
        assert err.max() < 0.02, err  # (the camera moves 1.5 cm a frame, 7.5 cm in all)
    with pytest.raises(ValueError, match="ModelTracker: argument 'init'"):
        ModelTracker(seq, DirectAligner(seq.K), TSDFVolume(0.02), init="constant")


def test_frame_to_model_one_frame_at_a_time(tmp_path):
    # FrameToModel, the loop's body for frames the caller holds: stepped by hand over a rendered
    # sequence it follows the true poses, times every frame after the first, integrates every frame;
    # more frames than announced, a bad init or no frames are refused
    from gvnn_warp.cli import main
    from gvnn_warp.datasets.tum import read_tum
    from gvnn_warp.fusion import BYTES_PER_BLOCK, MapFull
    from gvnn_warp.fusion.sequence import FrameToModel, ModelTracker
    from gvnn_warp.odometry import DirectAligner
    from gvnn_warp.odometry.tracking import TrackingStopped

    assert main(["render", "--out", str(tmp_path / "seq"), "--frames", "5", "--size", "160x120", "--seed", "6",
                 "--no-progress"]) == 0
    seq = read_tum(tmp_path / "seq")
    vol = TSDFVolume(0.01, max_depth=10.0)
    model = FrameToModel(DirectAligner(seq.K), vol, seq.K, seq.height, seq.width, len(seq),
                         start_pose=seq.gt_poses[0])
    for i in range(len(seq)):
        model.add(seq.image(i), seq.depth(i))
        assert model.n == i + 1 and vol.n_blocks > 0
    r = model.result()
    err = np.linalg.norm(r.poses[:, :3, 3] - seq.gt_poses[: len(seq), :3, 3], axis=1)
    assert np.abs(seq.gt_poses[len(seq) - 1, :3, 3] - seq.gt_poses[0, :3, 3]).max() > 0.03  # (it moved)
    assert err.max() < 0.01, err
    # ModelTracker is a loop over it: the same poses bit for bit, an info per frame
    tracked = ModelTracker(seq, DirectAligner(seq.K), TSDFVolume(0.01, max_depth=10.0))(len(seq), seq.gt_poses[0],
                                                                                          progress=False)
    assert np.array_equal(tracked.poses, r.poses) and len(r.infos) == len(r.poses) == len(tracked.infos)
    assert r.infos[0] is None and all(info is not None for info in r.infos[1:])
    # times: frame 0 none; later frames the raycast and the alignment beside the integration
    assert r.seconds[0] == 0 == model.integrate_seconds[0]
    assert (r.seconds[1:] > model.integrate_seconds[1:]).all() and (model.integrate_seconds[1:] > 0).all()
    assert model.ms_per_frame == pytest.approx(1e3 * r.seconds[1:].mean())
    assert model.fuse.integrated == len(seq) and r.converged.all() and r.finite.all()
    np.testing.assert_array_equal(model.result(1).poses, seq.gt_poses[:1])
    with pytest.raises(IndexError, match="more than the 5 frames"):
        model.add(seq.image(0), seq.depth(0))
    fresh = FrameToModel(DirectAligner(seq.K), TSDFVolume(0.01, max_depth=10.0), seq.K, seq.height, seq.width, 2,
                         start_pose=seq.gt_poses[0])
    with pytest.raises(ValueError, match=r"FrameToModel.add: argument 'rgb' must be \(3, 120, 160\).*channel-last"):
        fresh.add(seq.image(0).transpose(1, 2, 0), seq.depth(0))
    with pytest.raises(ValueError, match=r"FrameToModel.add: argument 'depth' must be \(1, 120, 160\)"):
        fresh.add(seq.image(0), seq.depth(0)[:, :60])
    assert fresh.n == 0  # (nothing integrated by a refused frame)
    with pytest.warns(UserWarning, match=r"FrameToModel.add: argument 'rgb' has values up to .*divide 8-bit"):
        FrameToModel(DirectAligner(seq.K), TSDFVolume(0.01, max_depth=10.0), seq.K, seq.height, seq.width, 1).add(
            255 * seq.image(0), seq.depth(0))
    with pytest.warns(UserWarning, match=r"FrameToModel.add: frame 0 has no depth within .* millimetres"):
        mm = FrameToModel(DirectAligner(seq.K), TSDFVolume(0.01, max_depth=10.0), seq.K, seq.height, seq.width, 1)
        mm.add(seq.image(0), 1000 * seq.depth(0))
    assert mm.fuse.skipped == [0]
    # each warning once, and one does not silence the other (8-bit colours first, then millimetres)
    both = FrameToModel(DirectAligner(seq.K), TSDFVolume(0.01, max_depth=10.0), seq.K, seq.height, seq.width, 4)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        both.add(255 * seq.image(0), seq.depth(0))
        both.add(255 * seq.image(1), seq.depth(1))
        both.add(seq.image(2), 1000 * seq.depth(2))
        both.add(seq.image(3), 1000 * seq.depth(3))
    # (the aligner's own warning about the same intensities is not given on top: it would name an
    # argument the caller never passed)
    assert [("8-bit" in str(w.message), "millimetres" in str(w.message)) for w in caught] == [(True, False),
                                                                                           (False, True)]
    quiet = FrameToModel(DirectAligner(seq.K), TSDFVolume(0.01, max_depth=10.0), seq.K, seq.height, seq.width, 2,
                         warn=False)
    with warnings.catch_warnings(record=True) as caught:  # (warn=False: none, the aligner's included)
        warnings.simplefilter("always")
        quiet.add(255 * seq.image(0), seq.depth(0))
        quiet.add(255 * seq.image(1), seq.depth(1))
    assert caught == []
    fresh.add(seq.image(0), seq.depth(0)[0])  # (H, W) depth, as TSDFVolume.integrate takes it
    fresh.add(seq.image(1), seq.depth(1)[0])
    np.testing.assert_allclose(fresh.result().poses[1], r.poses[1], atol=1e-6)
    with pytest.raises(ValueError, match=r"result: argument 'n' must be in \[1, 5\]"):
        model.result(6)
    # a map that outgrows the memory at frame 3: nothing of frame 3 kept (frames 0-2 stand), in
    # FrameToModel and through ModelTracker (TrackingStopped at frame 3, three poses and infos)
    blocks = []
    probe = TSDFVolume(0.01, max_depth=10.0)
    for i in range(4):
        blocks.append(probe.integrate(seq.depth(i), seq.image(i), seq.K, r.poses[i]).total_blocks)
    assert blocks[3] > blocks[2]
    tight = (blocks[2] + 0.5) * BYTES_PER_BLOCK / 2**20
    small = FrameToModel(DirectAligner(seq.K), TSDFVolume(0.01, max_depth=10.0, max_memory_mb=tight), seq.K,
                         seq.height, seq.width, 5, start_pose=seq.gt_poses[0])
    for i in range(3):
        small.add(seq.image(i), seq.depth(i))
    step = small._step.copy()
    with pytest.raises(MapFull):
        small.add(seq.image(3), seq.depth(3))
    assert small.n == 3 and len(small.infos) == 3 and np.isnan(small.poses[3]).all()
    assert np.array_equal(small._step, step) and np.array_equal(small.result().poses, r.poses[:3])
    with pytest.raises(TrackingStopped) as stopped:
        ModelTracker(seq, DirectAligner(seq.K), TSDFVolume(0.01, max_depth=10.0, max_memory_mb=tight))(
            len(seq), seq.gt_poses[0], progress=False)
    part = stopped.value.result
    assert stopped.value.frame == 3 and len(part.poses) == len(part.infos) == len(part.seconds) == 3
    assert np.array_equal(part.poses, r.poses[:3]) and "max_memory_mb" in str(stopped.value)
    # refused arguments
    with pytest.raises(ValueError, match="FrameToModel: argument 'init'"):
        FrameToModel(DirectAligner(seq.K), vol, seq.K, seq.height, seq.width, 3, init="constant")
    with pytest.raises(ValueError, match="FrameToModel: argument 'start_pose' must be a finite"):
        FrameToModel(DirectAligner(seq.K), vol, seq.K, seq.height, seq.width, 3, start_pose=np.eye(4)[:3])
    with pytest.raises(ValueError, match="FrameToModel: argument 'start_pose' must be a rigid"):
        FrameToModel(DirectAligner(seq.K), vol, seq.K, seq.height, seq.width, 3, start_pose=2 * np.eye(4))
    big_K = np.array([[480.0, 0, 319.5], [0, 480.0, 239.5], [0, 0, 1]])  # (a K for 640x480 frames)
    with pytest.raises(ValueError, match=r"argument 'camera' has its principal point \(319.5, 239.5\) outside the "
                                         r"160x120 frames"):
        FrameToModel(DirectAligner(big_K), vol, big_K, seq.height, seq.width, 3)
    with pytest.raises(ValueError, match="argument 'aligner' has K .* argument 'camera'"):
        FrameToModel(DirectAligner(seq.K * [[1.1], [1.1], [1]]), vol, seq.K, seq.height, seq.width, 3)
    fr1 = np.array([0.2624, -0.9531, -0.0054, 0.0026, 1.1633])
    with pytest.raises(ValueError, match="argument 'aligner' is a pinhole DirectAligner and argument 'camera' has a "
                                         "lens distortion"):
        FrameToModel(DirectAligner(seq.K), vol, (seq.K, fr1), seq.height, seq.width, 3)
    FrameToModel(DirectAligner(seq.K, dist=fr1), vol, (seq.K, fr1), seq.height, seq.width, 3)  # (the same camera)
    FrameToModel(DirectAligner(seq.K), vol, (seq.K, np.zeros(5)), seq.height, seq.width, 3)  # (no distortion)
    with pytest.raises(ValueError, match="FrameToModel: argument 'n_frames'"):
        FrameToModel(DirectAligner(seq.K), vol, seq.K, seq.height, seq.width, 0)
    with pytest.raises(ValueError, match="FrameToModel: arguments 'height' and 'width'"):
        FrameToModel(DirectAligner(seq.K), vol, seq.K, seq.width, 120.0, 3)


def test_model_tracking_benchmark_runs(tmp_path, monkeypatch, capsys):
    # benchmarks/model_tracking.py (as `python -m benchmarks.model_tracking` from the repository's
    # root): its two sides do what track --fuse and track --model do (every frame integrated once at
    # the frame-to-frame poses: the volume of fuse_sequence at them, bit for bit; the model side
    # ModelTracker's poses), then end to end on a tiny rendered sequence, times and ATEs printed
    from pathlib import Path

    from gvnn_warp.cli import main
    from gvnn_warp.datasets.tum import read_tum
    from gvnn_warp.fusion.sequence import ModelTracker, fuse_sequence
    from gvnn_warp.odometry.sequence import make_aligner

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2]))
    from benchmarks import model_tracking

    assert main(["render", "--out", str(tmp_path / "seq"), "--frames", "6", "--size", "96x64", "--seed", "5",
                 "--no-progress"]) == 0
    seq = read_tum(tmp_path / "seq")
    r, f2f, model, f2f_volume = model_tracking.run(seq, 6)
    assert r["f2f_integrated"] == 6 and f2f.pending is None and model.n == 6
    again = TSDFVolume(0.01, max_memory_mb=4096)
    fuse_sequence(again, seq, f2f.result().poses, progress=False)
    n_vox = again.n_blocks * 512
    assert f2f_volume.n_blocks == again.n_blocks > 0
    assert np.array_equal(f2f_volume.tw.numpy()[:n_vox], again.tw.numpy()[:n_vox])
    start = model.result().poses[0]  # (the ground truth of nearest stamp, as track: 1 ulp from the interpolated)
    tracked = ModelTracker(seq, make_aligner(seq.K), TSDFVolume(0.01, max_memory_mb=4096))(6, start, progress=False)
    assert np.array_equal(model.result().poses, tracked.poses)
    assert r["model_integrate_ms"] == pytest.approx(1e3 * model.integrate_seconds[1:].mean())

    model_tracking.main(["--frames", "5", "--size", "96x64", "--seed", "4"])
    out = capsys.readouterr().out
    ratio = re.search(r"ms per frame \(mean\) +frame to frame \+ fusion +([0-9.]+) +model +([0-9.]+) +ratio ([0-9.]+)",
                      out)
    f2f, model, r = (float(g) for g in ratio.groups())
    assert f2f > 0 and model > 0 and abs(r - model / f2f) < 0.01 + 0.01 * r
    ate = re.search(r"ATE +frame to frame ([0-9.]+) cm +model ([0-9.]+) cm", out)
    assert all(0 <= float(g) < 1.0 for g in ate.groups())  # (5 frames of 1.5 cm steps: well under 1 cm)


def test_raycast_colour_is_interpolated_between_voxels(monkeypatch):
    # a slightly tilted plane ~1 m away (off the voxel layers) whose colour ramps along x and y by
    # 0.02 a voxel: the raycast's colour at each hit is the ramp's value there to a fraction of a
    # voxel's step, by either kernel (trilinear between the voxels; the nearest voxel's colour, as
    # before, is off by ~0.4 of a step (median))
    rays = _rays(K)
    n, c = np.array([0.05, -0.03, 1.0]), 1.013
    depth = _plane_depth(n, c, rays)

    def ramp(points):  # (the colour at world points: the camera is at the origin)
        return np.clip(0.5 + 0.02 * (points[..., 0] + 0.6 * points[..., 1]) / VOXEL, 0.0, 1.0)

    red = ramp(rays * depth[..., None]).astype(np.float32)
    image = np.stack([red, 1.0 - red, np.full_like(red, 0.5)])
    vol = TSDFVolume(VOXEL, 4 * VOXEL, max_depth=4.0)
    for _ in range(3):
        vol.integrate(depth, image, K, np.eye(4))
    for lanes in (True, False):
        monkeypatch.setattr(vol, "_lanes", lanes)
        out_depth, colour, _ = vol.raycast(K, np.eye(4), H, W)
        truth = ramp(rays * out_depth[..., None])
        hit = (out_depth > 0) & (truth > 0.05) & (truth < 0.95)
        hit[:, :4] = hit[:, -4:] = hit[:4] = hit[-4:] = False  # (the plane's edge)
        err = np.abs(colour[0] - truth)[hit]
        assert hit.sum() > 0.4 * H * W
        assert np.median(err) < 0.1 * 0.02 and np.percentile(err, 95) < 0.3 * 0.02, (lanes, np.median(err))
        np.testing.assert_allclose(colour[1][hit], 1.0 - colour[0][hit], atol=1e-5)
        np.testing.assert_allclose(colour[2][hit], 0.5, atol=1e-5)


def test_the_sequence_names_load_on_first_use():
    # gvnn_warp.fusion serves FrameToModel, ModelTracker and fuse_sequence without loading their
    # module (and the aligner's) on import, and never loads torch
    code = (
        "import sys\n"
        "import gvnn_warp.fusion as F\n"
        "assert 'gvnn_warp.fusion.sequence' not in sys.modules, 'sequence loaded on import'\n"
        "from gvnn_warp.fusion import FrameToModel, ModelTracker, fuse_sequence\n"
        "from gvnn_warp.fusion import sequence\n"
        "assert (FrameToModel, ModelTracker, fuse_sequence) == (sequence.FrameToModel, sequence.ModelTracker,"
        " sequence.fuse_sequence)\n"
        "assert set(sequence.__all__) <= set(F.__all__) and 'TSDFVolume' in F.__all__\n"
        "assert 'FrameToModel' in dir(F)\n"
        "assert 'torch' not in sys.modules, 'torch imported'\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
