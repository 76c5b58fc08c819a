"""DirectAligner on a rendered se3 sequence: ms per frame pair and accuracy (issue 15 targets).

    python -m benchmarks.odometry_aligner [--frames 200] [--seed 0] [--repeats 3] [--no-open3d]

(run from the repository root). A 200-frame sequence (1.5-4 cm, 0.6-1.6 deg per frame) is
rendered at 320x240 (and a shorter one at 640x480 for timing). Timing is the tracker's work per
pair: ``prepare`` the new frame (its pyramid) and ``align_frames`` with the previous one, on the
process's threads (gvnn_warp follows ``GVNN_WARP_NUM_THREADS``, else the core count), median
over ``--repeats`` passes; when Open3D is installed its tensor ``rgbd_odometry_multi_scale``
(Intensity, default criteria) runs on the same pairs, interleaved pass by pass, for a ratio
(the machine is shared and noisy: compare ratios, not absolute times).

Accuracy (320x240): per 1-frame pair the error of the estimated relative pose (RMSE of the
rotation angle and translation norm: RPE), pairs off by more than 0.25 deg or 1 cm ("failed"),
and the fraction of pairs within those bounds taking every 5th and every 10th frame (every
offset), all from the identity initialisation.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from gvnn_warp.odometry import DirectAligner  # noqa: E402
from gvnn_warp.synthetic import default_intrinsics, make_room_scene, relative_pose, render_rgbd, smooth_se3_trajectory  # noqa: E402  # noqa: E402

MAX_DEG, MAX_M = 0.25, 0.01


def render_sequence(frames: int, width: int, height: int, seed: int):
    """(images (N, 3, H, W) float32, depths (N, 1, H, W) float32, K (3, 3), T_world_cam (N, 4, 4))."""
    poses = smooth_se3_trajectory(frames, seed)
    K = default_intrinsics(width, height)
    images, depths = render_rgbd(make_room_scene(seed), poses, K, width, height)
    return images, depths, K, poses


def pose_errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (deg) and translation (m) errors of (N, 4, 4) estimates."""
    E = np.linalg.inv(T_true) @ T_est
    cos = np.clip((np.trace(E[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1)
    return np.degrees(np.arccos(cos)), np.linalg.norm(E[:, :3, 3], axis=1)


def track_pairs(aligner: DirectAligner, images, depths, step: int) -> tuple[np.ndarray, list]:
    """T_live_ref for pairs (i, i + step), every offset, frame-to-frame style (each frame prepared once
    per offset chain); returns (N - step, 4, 4) estimates in pair order i and the infos."""
    n = images.shape[0]
    out = np.zeros((n - step, 4, 4))
    infos = [None] * (n - step)
    for offset in range(min(step, n - step)):
        prev = aligner.prepare(images[offset], depths[offset])
        for i in range(offset, n - step, step):
            cur = aligner.prepare(images[i + step], depths[i + step])
            out[i], infos[i] = aligner.align_frames(prev, cur)
            prev = cur
    return out, infos


def true_pairs(poses: np.ndarray, step: int) -> np.ndarray:
    return relative_pose(poses[step:], poses[:-step])  # T_{i+step <- i}


def accuracy(aligner: DirectAligner, images, depths, poses) -> dict:
    res = {}
    for step in (1, 5, 10):
        T, infos = track_pairs(aligner, images, depths, step)
        deg, m = pose_errors(T, true_pairs(poses, step))
        ok = (deg <= MAX_DEG) & (m <= MAX_M)
        res[step] = {
            "pairs": len(deg),
            "within": float(ok.mean()),
            "failed": int((~ok).sum()),
            "rpe_rot_deg": float(np.sqrt((deg**2).mean())),
            "rpe_trans_cm": float(100 * np.sqrt((m**2).mean())),
            "not_converged": int(sum(not i["converged"] for i in infos)),
        }
    return res


def _open3d_tracker(K, width, height):
    try:
        import open3d as o3d
    except ImportError:
        return None
    o3 = o3d.t.geometry
    intr = o3d.core.Tensor(K, o3d.core.Dtype.Float64)
    odo = o3d.t.pipelines.odometry

    def make(image, depth):
        color = np.ascontiguousarray(image.transpose(1, 2, 0))
        return o3.RGBDImage(o3.Image(color), o3.Image(np.ascontiguousarray(depth[0])))

    def align(src, dst):
        r = odo.rgbd_odometry_multi_scale(src, dst, intr, depth_scale=1.0, depth_max=20.0,
                                          method=odo.Method.Intensity)
        return r.transformation.numpy()

    return make, align


def time_tracking(aligner, images, depths, repeats: int, o3d_tracker=None) -> dict:
    """Median ms per pair of frame-to-frame tracking over the sequence (ours, and Open3D's)."""
    n = images.shape[0]
    ours, theirs = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        prev = aligner.prepare(images[0], depths[0])
        for i in range(1, n):
            cur = aligner.prepare(images[i], depths[i])
            aligner.align_frames(prev, cur)
            prev = cur
        ours.append((time.perf_counter() - t0) * 1e3 / (n - 1))
        if o3d_tracker is not None:
            make, align = o3d_tracker
            t0 = time.perf_counter()
            prev = make(images[0], depths[0])
            for i in range(1, n):
                cur = make(images[i], depths[i])
                align(prev, cur)
                prev = cur
            theirs.append((time.perf_counter() - t0) * 1e3 / (n - 1))
    res = {"ours_ms": statistics.median(ours), "ours_runs": ours}
    if theirs:
        res["open3d_ms"] = statistics.median(theirs)
        res["ratio"] = res["ours_ms"] / res["open3d_ms"]
    return res


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--no-open3d", action="store_true")
    p.add_argument("--no-accuracy", action="store_true")
    args = p.parse_args(argv)
    from gvnn_warp.kernels.launch import get_num_threads

    print(f"threads: {get_num_threads()}")
    for width, height, frames in ((320, 240, args.frames), (640, 480, max(20, args.frames // 5))):
        t0 = time.perf_counter()
        images, depths, K, poses = render_sequence(frames, width, height, args.seed)
        print(f"\n{width}x{height}: {frames} frames rendered in {time.perf_counter() - t0:.1f} s")
        aligner = DirectAligner(K)
        o3d_tracker = None if args.no_open3d else _open3d_tracker(K, width, height)
        t = time_tracking(aligner, images, depths, args.repeats, o3d_tracker)
        line = f"  tracking: {t['ours_ms']:.2f} ms per pair (runs {', '.join(f'{x:.2f}' for x in t['ours_runs'])})"
        if "open3d_ms" in t:
            line += f"; Open3D tensor multi-scale {t['open3d_ms']:.2f} ms -> ratio {t['ratio']:.2f}"
        print(line)
        if width == 320 and not args.no_accuracy:
            for step, r in accuracy(aligner, images, depths, poses).items():
                print(f"  every {step:>2} frames: {r['pairs']} pairs, {100 * r['within']:.1f}% within {MAX_DEG} deg "
                      f"and {100 * MAX_M:.0f} cm ({r['failed']} failed, {r['not_converged']} not converged), "
                      f"RPE {r['rpe_trans_cm']:.3f} cm / {r['rpe_rot_deg']:.4f} deg")


if __name__ == "__main__":
    main()
