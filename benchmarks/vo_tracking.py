"""The learned VO network as an odometry front end: identity, direct, vo and vo+direct on held-out sequences.

    python -m benchmarks.vo_tracking [--se3 CKPT] [--so3 CKPT] [--frames 200] [--size 320x240]
                                     [--seed 900] [--gaps 1,5,10] [--json PATH] [--no-progress]

(run from the repository root, after training the networks with ``gvnn-warp vo --motion se3 --out
out/vo_se3`` and ``--motion so3 --out out/vo_so3``, the defaults of ``--se3`` / ``--so3``; a motion
whose checkpoint is missing is skipped). For each checkpoint a held-out sequence is rendered by
``gvnn_warp.synthetic.sequence`` (``gvnn-warp render``'s library) into a temporary TUM folder - in
the room the network was trained in (its ``scene_seed``), along a trajectory of another seed
(``--seed``, not among the training or evaluation seeds) of the same family: se3 (1.5-4 cm, 0.6-1.6
deg per frame) or so3 (rapid rotation, 2-8 deg per frame) - at ``--size`` (the network's input is
smaller: frames are resized and K scaled, as ``gvnn-warp track --method vo`` does) and read back
through ``gvnn_warp.datasets.tum``.
Then, for the methods

- identity: every relative pose is the identity (the camera assumed still);
- direct: ``gvnn_warp.odometry.DirectAligner`` from the identity (``gvnn-warp track``'s settings);
- vo: the network alone (``gvnn_warp.vo.frontend.NetworkAligner``);
- vo+direct: the direct aligner starting from the network's estimate,

1. tracking, frame to frame over the whole sequence: ATE (SE(3) Umeyama, or the first pose where
   that is degenerate: so3; the camera positions' RMSE by ``evo``), the orientation drift (RMSE of
   the angle between estimated and true orientation per frame, both trajectories starting at the
   true first pose, not aligned), RPE over 1-frame steps by ``evo``, and frames per second (one
   ``prepare`` + ``align_frames`` per frame, file reading excluded; the trackers run in lockstep,
   frame by frame, so that all see the same machine load);
2. pairs: every pair (i, i + g) for g in ``--gaps``, each aligned on its own (direct from the
   identity): the percentage that *fail*, with a rotation error above 2 deg or a translation error
   above 5 cm, and the median errors.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import torch  # noqa: E402  (after OMP_WAIT_POLICY is set)
from tqdm import tqdm  # noqa: E402

from benchmarks.odometry import machine  # noqa: E402
from gvnn_warp.cli.args import bounded_int_list, image_size, positive_int  # noqa: E402  (argument types)
from gvnn_warp.datasets.tum import read_tum  # noqa: E402
from gvnn_warp.odometry.evaluation import evaluate_trajectory, pose_error  # noqa: E402
from gvnn_warp.odometry.sequence import make_aligner  # noqa: E402
from gvnn_warp.odometry.tracking import Tracker  # noqa: E402
from gvnn_warp.synthetic import relative_pose  # noqa: E402
from gvnn_warp.synthetic.sequence import render_sequence  # noqa: E402
from gvnn_warp.vo.checkpoint import load_network, read_checkpoint  # noqa: E402
from gvnn_warp.vo.frontend import NetworkAligner  # noqa: E402

FAIL_ROT_DEG = 2.0
FAIL_TRANS_M = 0.05
METHODS = ("identity", "direct", "vo", "vo+direct")


class Identity:
    """Every relative pose is the identity."""

    def prepare(self, image, depth):
        return None

    def align_frames(self, ref, live, init=None):
        return np.eye(4), {"converged": True}


def make_methods(seq, network, spec) -> dict:
    size = (seq.width, seq.height)
    refine = spec.get("refine", 0)
    symmetries = tuple(spec.get("symmetries", ()))
    return {
        "identity": Identity(),
        "direct": make_aligner(seq.K),
        "vo": NetworkAligner(network, seq.K, size, refine=refine, symmetries=symmetries),
        "vo+direct": NetworkAligner(network, seq.K, size, refine=refine, direct=make_aligner(seq.K),
                                    symmetries=symmetries),
    }


def run_tracking(frames, methods: dict, gt, stamps, progress: bool) -> dict:
    """Frame-to-frame tracking by every method in lockstep; ATE, RPE and frames per second."""
    n = len(frames)
    trackers = {name: Tracker(a, n, start_pose=gt[0]) for name, a in methods.items()}
    names = list(trackers)
    for i in tqdm(range(n), desc="tracking", unit="frame", disable=not progress):
        order = names if i % 2 == 0 else names[::-1]
        for name in order:
            trackers[name].add(*frames[i])
    out = {}
    for name, tr in trackers.items():
        res = tr.result()
        m = evaluate_trajectory(stamps, res.poses, gt)
        _, ape_rot = pose_error(res.poses, gt)  # orientation drift: both start at the true first pose
        ms = res.ms_per_pair
        out[name] = {"ate_m": m.ate_rmse_m, "ate_rot_deg": float(np.sqrt(np.mean(ape_rot**2))),
                     "ate_alignment": m.ate_alignment, "rpe_trans_m": m.rpe_trans_rmse_m,
                     "rpe_rot_deg": m.rpe_rot_rmse_deg, "ms_per_pair": ms,
                     "fps": None if name == "identity" else 1e3 / ms}
    return out


def run_pairs(frames, methods: dict, gt, gaps: list[int], progress: bool) -> dict:
    """Every pair (i, i + g), each aligned on its own: failure rate (> 2 deg or > 5 cm) and median errors."""
    prepared = {name: [a.prepare(*f) for f in frames] for name, a in methods.items()}
    n = len(frames)
    out = {name: {} for name in methods}
    total = sum(max(0, n - g) for g in gaps) * len(methods)
    with tqdm(total=total, desc="pairs", unit="pair", disable=not progress) as bar:
        for g in gaps:
            truth = relative_pose(gt[g:], gt[:-g]) if g < n else np.zeros((0, 4, 4))
            for name, a in methods.items():
                P = prepared[name]
                est = np.stack([np.asarray(a.align_frames(P[i], P[i + g], init=np.eye(4))[0], dtype=np.float64)
                                for i in range(n - g)]) if n > g else np.zeros((0, 4, 4))
                bar.update(max(0, n - g))
                dt, dr = pose_error(est, truth)
                bad = ~np.isfinite(dt) | ~np.isfinite(dr) | (dr > FAIL_ROT_DEG) | (dt > FAIL_TRANS_M)
                out[name][str(g)] = {"pairs": int(bad.size), "failed": int(bad.sum()),
                                     "failed_pct": 100.0 * float(bad.mean()) if bad.size else float("nan"),
                                     "median_rot_deg": float(np.median(dr)) if dr.size else float("nan"),
                                     "median_trans_m": float(np.median(dt)) if dt.size else float("nan")}
    return out


def run_motion(motion: str, ckpt: Path, args, tmp: Path) -> dict | None:
    if not ckpt.exists():
        print(f"{ckpt}: missing, {motion} skipped (train it: gvnn-warp vo --motion {motion} --out {ckpt.parent})",
              file=sys.stderr)
        return None
    network, spec = load_network(ckpt)
    cfg = read_checkpoint(ckpt)["config"]
    if spec["kwargs"]["motion"] != motion:
        raise SystemExit(f"benchmarks.vo_tracking: {ckpt} is a {spec['kwargs']['motion']} network, not {motion}")
    train_seeds = {1000 * cfg["seed"] + b + i for b, n in ((0, cfg["n_train_traj"]), (500, cfg["n_eval_traj"]))
                   for i in range(n)}
    if args.seed in train_seeds and not cfg.get("data"):
        raise SystemExit(f"benchmarks.vo_tracking: --seed {args.seed} is one of {ckpt}'s training or evaluation "
                         "trajectories; choose another")
    folder = tmp / motion
    t = time.perf_counter()
    render_sequence(folder, motion, args.frames, args.size, args.seed, progress=False,
                    scene_seed=cfg.get("scene_seed", 0))
    print(f"{motion}: rendered {args.frames} frames at {args.size[0]}x{args.size[1]} (room {cfg.get('scene_seed', 0)}, "
          f"trajectory seed {args.seed}) in {time.perf_counter() - t:.0f} s", file=sys.stderr)
    seq = read_tum(folder)
    frames = [(seq.image(i), seq.depth(i)) for i in range(len(seq))]
    gt = seq.gt_poses
    torch.set_num_threads(os.cpu_count() or 2)
    methods = make_methods(seq, network, spec)
    tracking = run_tracking(frames, methods, gt, seq.timestamps, not args.no_progress)
    pairs = run_pairs(frames, methods, gt, args.gaps, not args.no_progress)
    return {"checkpoint": str(ckpt), "network_size": list(spec["kwargs"]["size"]), "refine": spec.get("refine", 0),
            "frames": len(seq), "size": [seq.width, seq.height], "trajectory_seed": args.seed,
            "scene_seed": cfg.get("scene_seed", 0), "tracking": tracking, "pairs": pairs}


def table(results: dict, gaps: list[int]) -> str:
    head = ("| sequence | method | ATE trans | ATE rot | RPE trans | RPE rot | frames/s | "
            + " | ".join(f"failed, gap {g}" for g in gaps) + " |")
    lines = [head, "|" + "---|" * (7 + len(gaps))]
    for motion, r in results.items():
        label = f"{motion}, {r['frames']} frames {r['size'][0]}x{r['size'][1]}"
        for name in METHODS:
            t, p = r["tracking"][name], r["pairs"][name]
            fps = "-" if t["fps"] is None else f"{t['fps']:.0f}"
            fails = " | ".join(f"{p[str(g)]['failed_pct']:.0f}%" for g in gaps)
            lines.append(f"| {label} | {name} | {100 * t['ate_m']:.2f} cm | {t['ate_rot_deg']:.2f} deg | "
                         f"{100 * t['rpe_trans_m']:.3f} cm | "
                         f"{t['rpe_rot_deg']:.3f} deg | {fps} | {fails} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.vo_tracking", description=__doc__.split("\n\n")[0])
    p.add_argument("--se3", type=Path, default=Path("out/vo_se3/checkpoint.pt"), help="se3 checkpoint")
    p.add_argument("--so3", type=Path, default=Path("out/vo_so3/checkpoint.pt"), help="so3 checkpoint")
    p.add_argument("--frames", type=positive_int, default=200, help="frames per sequence (default 200)")
    p.add_argument("--size", type=image_size(16), default="320x240", help="frame size WxH (default 320x240)")
    p.add_argument("--seed", type=int, default=900, help="trajectory seed of the held-out sequences (default 900)")
    p.add_argument("--gaps", type=bounded_int_list(1), default="1,5,10", help="pair gaps (default 1,5,10)")
    p.add_argument("--motions", default="se3,so3", help="comma-separated: se3, so3 (default both)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--json", type=Path, default=None, help="also write the results as JSON here")
    args = p.parse_args(argv)
    args.gaps = list(args.gaps)
    print(f"machine: {machine()}")
    results = {}
    with tempfile.TemporaryDirectory(prefix="gvnn_vo_tracking_") as tmp:
        for motion in args.motions.split(","):
            if motion not in ("se3", "so3"):
                p.error(f"--motions: expected se3 and/or so3, got {motion!r}")
            r = run_motion(motion, getattr(args, motion), args, Path(tmp))
            if r is not None:
                results[motion] = r
    if not results:
        raise SystemExit("benchmarks.vo_tracking: no checkpoint found, nothing to run")
    print(table(results, args.gaps), flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"machine": machine(), "results": results}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
