"""TSDF fusion against Open3D 0.20's ``VoxelBlockGrid`` on the CPU, side by side in one process.

    python -m benchmarks.fusion [--frames 30] [--size 640x480] [--voxel 0.01] [--seed 3] [--no-open3d]
    python -m benchmarks.fusion --accuracy [--frames 300] [--size 320x240] [--voxel 0.01] [--seed 11]

A se3 sequence of a rendered room (``gvnn_warp.synthetic``) is fused by both with the same voxel
size, truncation (4 voxels), blocks of 8^3 voxels, depth range and true poses. Per frame, interleaved:

- integrate: ours :meth:`TSDFVolume.integrate` (finding the frame's blocks included) against
  Open3D's ``compute_unique_block_coordinates`` + ``integrate`` (the pair its tutorial runs);
- raycast: ours :meth:`TSDFVolume.raycast` (depth, colour, normals) against Open3D's ``ray_cast``
  of depth, colour and normal from the same pose, after each integration;
- raycast from the frame: the same, ours given the depth just integrated at that pose
  (``start_depth``, as frame-to-model tracking does); Open3D's ``ray_cast`` is given the blocks that
  frame touched (its tutorial's call, above, in both rows), which bound its rays the same way.

It prints the medians and their ratio (ours / Open3D; the machines are shared, so the ratio is what
to compare), and the raycast depth's median error against the rendered depth for both.
Open3D is a benchmark extra (``pip install -e .[bench]``; its wheel needs the system's libusb-1.0).

``--accuracy``: the mesh of a rendered se3 sequence fused at its true poses against the room's true
surfaces (``gvnn_warp.synthetic.surface_distance``): accuracy, the distances of the mesh's vertices
to the surface (median, 90th percentile, in voxels); completeness, the fraction of the visible true
surface (every 4th pixel of every 10th frame, back-projected with its true depth) within one voxel
of a mesh vertex.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from gvnn_warp.cli.args import image_size, positive_int
from gvnn_warp.datasets.tum import read_tum
from gvnn_warp.fusion import TSDFVolume
from gvnn_warp.synthetic.sequence import render_sequence

DEPTH_MAX = 10.0  # metres: the rendered rooms are up to 8 m deep


class Open3DVolume:
    """Open3D's VoxelBlockGrid with the same settings, the calls of its TSDF tutorial."""

    def __init__(self, voxel: float, trunc_voxels: float, K: np.ndarray, blocks: int):
        import open3d as o3d

        self.o3d = o3d
        self.vbg = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3d.core.float32, o3d.core.float32, o3d.core.float32),
            attr_channels=((1), (1), (3)), voxel_size=voxel, block_resolution=8, block_count=blocks)
        self.trunc = trunc_voxels
        self.K = o3d.core.Tensor(np.asarray(K, dtype=np.float64))
        self.blocks = None

    def integrate(self, depth_u16: np.ndarray, rgb_u8: np.ndarray, T_world_cam: np.ndarray, depth_scale: float):
        o3d = self.o3d
        depth = o3d.t.geometry.Image(o3d.core.Tensor(depth_u16))
        colour = o3d.t.geometry.Image(o3d.core.Tensor(rgb_u8))  # (uint16 depth with uint8 colour, as it wants)
        extrinsic = o3d.core.Tensor(np.linalg.inv(T_world_cam))
        self.blocks = self.vbg.compute_unique_block_coordinates(depth, self.K, extrinsic, depth_scale, DEPTH_MAX,
                                                                trunc_voxel_multiplier=self.trunc)
        self.vbg.integrate(self.blocks, depth, colour, self.K, extrinsic, depth_scale, DEPTH_MAX,
                           trunc_voxel_multiplier=self.trunc)

    def raycast(self, T_world_cam: np.ndarray, height: int, width: int, depth_scale: float):
        o3d = self.o3d
        out = self.vbg.ray_cast(self.blocks, self.K, o3d.core.Tensor(np.linalg.inv(T_world_cam)), width, height,
                                render_attributes=["depth", "color", "normal"], depth_scale=depth_scale,
                                depth_min=0.1, depth_max=DEPTH_MAX, weight_threshold=0.5,
                                trunc_voxel_multiplier=self.trunc)
        return out["depth"].numpy()[..., 0] / depth_scale


def _median_ms(xs) -> float:
    return 1000.0 * float(np.median(xs))


def run(frames: int, size: tuple[int, int], voxel: float, seed: int, open3d: bool) -> dict:
    from PIL import Image

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "seq"
        render_sequence(root, "se3", frames, size, seed, progress=False)
        seq = read_tum(root)
        ours = TSDFVolume(voxel, 4 * voxel, max_depth=DEPTH_MAX)
        theirs = Open3DVolume(voxel, 4.0, seq.K, 60000) if open3d else None
        # warm-up: kernels compiled or loaded, Open3D's first call
        ours.integrate(seq.depth(0), seq.image(0), seq.K, seq.gt_poses[0])
        ours.raycast(seq.K, seq.gt_poses[0], seq.height, seq.width)
        t = {"ours_integrate": [], "ours_raycast": [], "ours_raycast_from_frame": [], "o3d_integrate": [],
             "o3d_raycast": []}
        err = {"ours": [], "ours_from_frame": [], "o3d": []}
        if theirs is not None:
            raw = [(np.asarray(Image.open(seq.depth_files[i])), np.asarray(Image.open(seq.rgb_files[i]).convert("RGB")))
                   for i in range(frames)]
            theirs.integrate(raw[0][0], raw[0][1], seq.gt_poses[0], seq.depth_scale)
        for i in range(1, frames):
            depth, colour, T = seq.depth(i), seq.image(i), seq.gt_poses[i]
            s = time.perf_counter()
            ours.integrate(depth, colour, seq.K, T)
            t["ours_integrate"].append(time.perf_counter() - s)
            # (the two raycasts in turns: the second of a pair finds the voxels the first read in the caches)
            for which in (("full", "from_frame") if i % 2 else ("from_frame", "full")):
                s = time.perf_counter()
                if which == "full":
                    d_ours, _, _ = ours.raycast(seq.K, T, seq.height, seq.width)
                    t["ours_raycast"].append(time.perf_counter() - s)
                else:
                    d_from, _, _ = ours.raycast(seq.K, T, seq.height, seq.width, start_depth=depth)
                    t["ours_raycast_from_frame"].append(time.perf_counter() - s)
            true = depth[0]
            for key, d in (("ours", d_ours), ("ours_from_frame", d_from)):
                ok = (true > 0) & (d > 0)
                err[key].append(float(np.median(np.abs(d[ok] - true[ok]))))
            if theirs is not None:
                s = time.perf_counter()
                theirs.integrate(raw[i][0], raw[i][1], T, seq.depth_scale)
                t["o3d_integrate"].append(time.perf_counter() - s)
                s = time.perf_counter()
                d_o3d = theirs.raycast(T, seq.height, seq.width, seq.depth_scale)
                t["o3d_raycast"].append(time.perf_counter() - s)
                ok = (true > 0) & (d_o3d > 0)
                err["o3d"].append(float(np.median(np.abs(d_o3d[ok] - true[ok]))))
    res = {k: _median_ms(v) for k, v in t.items() if v}
    res.update({f"{k}_depth_error_mm": 1000 * float(np.median(v)) for k, v in err.items() if v})
    res["blocks"] = ours.n_blocks
    return res


def accuracy(frames: int, size: tuple[int, int], voxel: float, seed: int) -> dict:
    """Mesh accuracy and completeness (see the module docstring)."""
    from scipy.spatial import cKDTree

    from gvnn_warp.synthetic import make_room_scene, surface_distance

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "seq"
        render_sequence(root, "se3", frames, size, seed, progress=False)
        seq = read_tum(root)
        vol = TSDFVolume(voxel, 4 * voxel, max_depth=DEPTH_MAX)
        s = time.perf_counter()
        for i in range(frames):
            vol.integrate(seq.depth(i), seq.image(i), seq.K, seq.gt_poses[i])
        fuse_s = time.perf_counter() - s
        s = time.perf_counter()
        v, f, _ = vol.extract_mesh()
        mesh_s = time.perf_counter() - s
        dist = surface_distance(make_room_scene(seed), v) / voxel
        x, y = np.meshgrid(np.arange(0, seq.width, 4), np.arange(0, seq.height, 4))
        rays = np.stack([(x - seq.K[0, 2]) / seq.K[0, 0], (y - seq.K[1, 2]) / seq.K[1, 1], np.ones(x.shape)], -1)
        surface = []
        for i in range(0, frames, 10):
            d = seq.depth(i)[0][::4, ::4]
            ok = (d > 0.1) & (d < DEPTH_MAX)
            p = d[ok][:, None] * rays[ok]
            T = seq.gt_poses[i]
            surface.append(p @ T[:3, :3].T + T[:3, 3])
        surface = np.concatenate(surface)
        near, _ = cKDTree(v).query(surface, distance_upper_bound=10 * voxel)
    return {"vertices": len(v), "faces": len(f), "median_voxels": float(np.median(dist)),
            "p90_voxels": float(np.percentile(dist, 90)), "completeness": float((near <= voxel).mean()),
            "surface_points": len(surface), "fuse_s": fuse_s, "mesh_s": mesh_s, "blocks": vol.n_blocks}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=positive_int, default=None, help="(default 30; 300 with --accuracy)")
    p.add_argument("--size", type=image_size(16), default=None, help="WxH (default 640x480; 320x240 with --accuracy)")
    p.add_argument("--voxel", type=float, default=0.01)
    p.add_argument("--seed", type=int, default=None, help="(default 3; 11 with --accuracy)")
    p.add_argument("--no-open3d", action="store_true")
    p.add_argument("--accuracy", action="store_true", help="mesh accuracy and completeness instead of timings")
    args = p.parse_args(argv)
    defaults = (300, (320, 240), 11) if args.accuracy else (30, (640, 480), 3)
    args.frames, args.size, args.seed = (given if given is not None else d for given, d in
                                         zip((args.frames, args.size, args.seed), defaults))
    if args.accuracy:
        r = accuracy(args.frames, args.size, args.voxel, args.seed)
        print(f"mesh of {args.frames} frames, {args.size[0]}x{args.size[1]}, voxel {args.voxel:g} m, seed {args.seed}: "
              f"{r['vertices']} vertices, {r['faces']} faces, {r['blocks']} blocks; fused in {r['fuse_s']:.1f} s, "
              f"meshed in {r['mesh_s']:.1f} s")
        print(f"  accuracy: median {r['median_voxels']:.3f} voxel, 90th percentile {r['p90_voxels']:.3f} voxel "
              "from the true surface")
        print(f"  completeness: {100 * r['completeness']:.1f}% of {r['surface_points']} visible true surface points "
              "within one voxel of the mesh")
        return
    open3d = not args.no_open3d
    if open3d:
        try:
            import open3d  # noqa: F401
        except ImportError as e:
            print(f"(Open3D not available: {e}; ours only)")
            open3d = False
    r = run(args.frames, args.size, args.voxel, args.seed, open3d)
    print(f"fusion, {args.size[0]}x{args.size[1]}, voxel {args.voxel:g} m, {args.frames} frames, {r['blocks']} blocks")
    for what, theirs in (("integrate", "integrate"), ("raycast", "raycast"), ("raycast_from_frame", "raycast")):
        line = f"  {what.replace('_', ' '):<18} ours {r[f'ours_{what}']:7.1f} ms"
        if f"o3d_{theirs}" in r:
            line += f"   Open3D {r[f'o3d_{theirs}']:7.1f} ms   ratio {r[f'ours_{what}'] / r[f'o3d_{theirs}']:.2f}"
        print(line)
    print(f"  raycast depth median error: ours {r['ours_depth_error_mm']:.2f} mm (from the frame "
          f"{r['ours_from_frame_depth_error_mm']:.2f} mm)"
          + (f", Open3D {r['o3d_depth_error_mm']:.2f} mm" if "o3d_depth_error_mm" in r else ""))


if __name__ == "__main__":
    main()
