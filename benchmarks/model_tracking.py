"""Frame-to-model tracking against frame-to-frame tracking with fusion, side by side in one process.

    python -m benchmarks.model_tracking [--frames 300] [--size 320x240] [--seed 11] [--data DIR]

Issue 32's target 4: ``gvnn-warp track --model`` at most 1.5x the time per frame of frame-to-frame
tracking with fusion, at most 0.6x its ATE. A rendered se3 sequence (``gvnn_warp.synthetic``; or a
TUM folder with ``--data``) is tracked both ways, a frame of each in turns (which goes first
alternating), so both run under the same machine load; running the two commands one after the
other, the integration's time alone moved by 20% between runs on these shared hosts.

- frame to frame with fusion (``track --fuse``): :class:`gvnn_warp.odometry.tracking.Tracker`
  (the direct aligner on grey images, pipelined as ``track`` runs it), each frame then integrated
  at its estimated pose;
- frame to model (``track --model``): :class:`gvnn_warp.fusion.sequence.FrameToModel`: the model
  raycast at the previous pose, the alignment to it, the integration.

Both start at the first frame's ground-truth pose (nearest stamp, as ``track``; the identity without
one) with the same aligner settings, voxel size, truncation and memory (``track``'s defaults). The
frames are read (and made grey) first, untimed; the first frame is not timed either (its
integration; the model's first raycast, which loads its kernels, is). Prints the mean milliseconds
per frame of each, their ratio, the medians, the model's integration time per frame (the rest is
its raycast and alignment), and, with ground truth, each trajectory's ATE (evo, SE(3)-aligned, as
``track``).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from gvnn_warp.cli.args import bounded_int, image_size
from gvnn_warp.cli.track import FUSE_MEMORY_MB, FUSE_VOXEL
from gvnn_warp.datasets.images import to_gray
from gvnn_warp.datasets.tum import read_tum
from gvnn_warp.fusion import TSDFVolume
from gvnn_warp.fusion.sequence import FrameToModel, camera_of
from gvnn_warp.odometry.evaluation import evaluate_trajectory, nearest_groundtruth
from gvnn_warp.odometry.sequence import make_aligner
from gvnn_warp.odometry.tracking import Tracker
from gvnn_warp.synthetic.sequence import render_sequence


def run(seq, frames: int) -> dict:
    """Both trackers over the first ``frames`` frames of ``seq``, in turns: the figures, and the two
    trackers and the frame-to-frame side's volume (for the tests)."""
    n = min(frames, len(seq))
    camera = camera_of(seq)
    gt_poses = gt_valid = None
    if seq.gt_poses is not None:  # (as track: the ground truth of nearest stamp, and its first pose as the start)
        gt_poses, gt_valid = nearest_groundtruth(seq.timestamps[:n], seq.gt_timestamps, seq.gt_raw_poses,
                                                 seq.max_difference)
    has_gt = gt_poses is not None and int(gt_valid.sum()) >= 2
    start = gt_poses[0] if has_gt and gt_valid[0] else np.eye(4)

    def aligner():
        return make_aligner(seq.K, dist=seq.dist, size=(seq.width, seq.height))

    def volume():
        return TSDFVolume(FUSE_VOXEL, max_memory_mb=FUSE_MEMORY_MB)

    f2f, f2f_volume = Tracker(aligner(), n, start_pose=start), volume()
    model = FrameToModel(aligner(), volume(), camera, seq.height, seq.width, n, start_pose=start)
    frames_read = [(seq.image(i), seq.depth(i)) for i in range(n)]
    grey = [to_gray(rgb) for rgb, _ in frames_read]  # (track reads the frames grey: not timed)
    integrated = 0  # frame to frame: the frames integrated so far (those whose pose is known)
    t_f2f, t_model = np.zeros(n), np.zeros(n)

    def f2f_step(i: int) -> float:
        nonlocal integrated
        s = time.perf_counter()
        f2f.add(grey[i], frames_read[i][1])
        if i == n - 1:
            f2f.finish()  # (pipelined: the last frame's alignment)
        known = f2f.n if f2f.pending is None else f2f.pending[0]  # (frames whose pose is known)
        while integrated < known:
            c, d = frames_read[integrated]
            f2f_volume.integrate(d, c, camera, f2f.poses[integrated])
            integrated += 1
        return time.perf_counter() - s

    def model_step(i: int) -> float:
        s = time.perf_counter()
        model.add(*frames_read[i])
        return time.perf_counter() - s

    f2f_step(0)
    model_step(0)
    for i in range(1, n):
        steps = ((f2f_step, t_f2f), (model_step, t_model))
        for step, times in (steps if i % 2 else steps[::-1]):
            times[i] = step(i)
    out = {"frames": n, "f2f_ms": 1e3 * t_f2f[1:].mean(), "model_ms": 1e3 * t_model[1:].mean(),
           "f2f_median_ms": 1e3 * float(np.median(t_f2f[1:])), "model_median_ms": 1e3 * float(np.median(t_model[1:])),
           "model_integrate_ms": 1e3 * float(model.integrate_seconds[1:n].mean()),
           "blocks_model": model.volume.n_blocks, "f2f_integrated": integrated}
    if has_gt:
        for name, poses in (("f2f", f2f.result().poses), ("model", model.result().poses)):
            m = evaluate_trajectory(seq.timestamps[:n], poses, gt_poses, gt_valid)
            out[f"{name}_ate_cm"] = 100 * m.ate_rmse_m
    return out, f2f, model, f2f_volume


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=bounded_int(2), default=300)
    p.add_argument("--size", type=image_size(16), default=(320, 240), help="WxH of the rendered frames")
    p.add_argument("--seed", type=int, default=11, help="the rendered sequence's seed (the README's: 11)")
    p.add_argument("--data", default=None, help="a TUM-format folder instead of a rendered sequence")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.data) if args.data else Path(tmp) / "seq"
        if not args.data:
            render_sequence(root, "se3", args.frames, args.size, args.seed, progress=False)
        seq = read_tum(root)
        r = run(seq, args.frames)[0]
    what = args.data or f"rendered se3, seed {args.seed}"
    print(f"frame-to-model against frame-to-frame tracking with fusion: {r['frames']} frames "
          f"{seq.width}x{seq.height} ({what}), in turns")
    print(f"  ms per frame (mean)    frame to frame + fusion {r['f2f_ms']:6.1f}   model {r['model_ms']:6.1f}   "
          f"ratio {r['model_ms'] / r['f2f_ms']:.2f}")
    print(f"  ms per frame (median)  frame to frame + fusion {r['f2f_median_ms']:6.1f}   model "
          f"{r['model_median_ms']:6.1f}   ratio {r['model_median_ms'] / r['f2f_median_ms']:.2f}")
    print(f"  model: integration {r['model_integrate_ms']:.1f} ms per frame, raycast and alignment the rest; "
          f"{r['blocks_model']} blocks")
    if "f2f_ate_cm" in r:
        print(f"  ATE  frame to frame {r['f2f_ate_cm']:.3f} cm   model {r['model_ate_cm']:.3f} cm   ratio "
              f"{r['model_ate_cm'] / r['f2f_ate_cm']:.2f}")


if __name__ == "__main__":
    main()
