"""Our tracker against Open3D's on a real TUM RGB-D folder, at growing motions (issue 32, target 5).

    python -m benchmarks.tum_strides --data DIR [--strides 1,2,3,4,5,6] [--intrinsics fr1]

For each stride s the frames 0, s, 2s, ... of the folder are tracked frame to frame from the identity
by ``gvnn-warp track``'s aligner (through the folder's lens: ``lens="resample"`` and ``"exact"``)
and by Open3D 0.20's ``rgbd_odometry_multi_scale`` in its ``Hybrid`` (photometric + geometric, its
best on TUM) and ``Intensity`` modes, on the same frames (Open3D through the pinhole of the same K:
it has no lens model). Printed: the ATE (SE(3) Umeyama, by evo; ground truth of nearest stamp) of
each, and ms per pair.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from PIL import Image

from gvnn_warp.datasets.tum import read_tum
from gvnn_warp.odometry.evaluation import evaluate_trajectory, nearest_groundtruth
from gvnn_warp.odometry.sequence import make_aligner
from gvnn_warp.odometry.tracking import frame_aligner


def _track(aligner, frames) -> tuple[np.ndarray, float]:
    fa = frame_aligner(aligner)
    prepared = [fa.prepare(*f) for f in frames]
    poses = [np.eye(4)]
    t = []
    for i in range(1, len(frames)):
        s = time.perf_counter()
        T, _ = fa.align_frames(prepared[i - 1], prepared[i], init=np.eye(4))
        t.append(time.perf_counter() - s)
        poses.append(poses[-1] @ np.linalg.inv(np.asarray(T, dtype=np.float64)))
    return np.stack(poses), 1000 * float(np.mean(t))


def main(argv=None) -> None:
    from benchmarks.odometry import Open3DAligner

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--strides", default="1,2,3,4,5,6")
    p.add_argument("--intrinsics", default=None)
    args = p.parse_args(argv)
    seq = read_tum(args.data, intrinsics=args.intrinsics)
    gt, valid = nearest_groundtruth(seq.timestamps, seq.gt_timestamps, seq.gt_raw_poses, 0.02)
    print(f"{seq.root.name}: {len(seq)} frames, {seq.width}x{seq.height}, intrinsics {seq.intrinsics_source}")
    methods = {"ours (lens resampled)": make_aligner(seq.K, dist=seq.dist, size=(seq.width, seq.height)),
               "ours (lens exact)": make_aligner(seq.K, dist=seq.dist, lens="exact"),
               "Open3D Hybrid": Open3DAligner(seq.K, seq.depth_scale, "Hybrid"),
               "Open3D Intensity": Open3DAligner(seq.K, seq.depth_scale, "Intensity")}
    grey = [(seq.image(i, gray=True), seq.depth(i)) for i in range(len(seq))]
    raw = [(np.ascontiguousarray(np.asarray(Image.open(seq.rgb_files[i]).convert("RGB"))),
            np.ascontiguousarray(np.asarray(Image.open(seq.depth_files[i])).astype(np.uint16)))
           for i in range(len(seq))]
    for s in (int(v) for v in args.strides.split(",")):
        idx = [i for i in range(0, len(seq), s) if valid[i]]
        if len(idx) < 3:
            continue
        line = f"  every {s} frame{'s' if s > 1 else ''} ({len(idx)} frames):"
        for name, aligner in methods.items():
            frames = [(raw if name.startswith("Open3D") else grey)[i] for i in idx]
            poses, ms = _track(aligner, frames)
            start = gt[idx[0]]
            m = evaluate_trajectory(seq.timestamps[idx], start @ poses, gt[idx])
            line += f"  {name} {100 * m.ate_rmse_m:.2f} cm ({ms:.0f} ms)"
        print(line)


if __name__ == "__main__":
    main()
