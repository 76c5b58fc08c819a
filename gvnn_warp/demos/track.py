"""``gvnn-warp track``: direct RGB-D odometry over a TUM RGB-D folder, evaluated with evo.

Usage::

    gvnn-warp track DIR --out OUT [--intrinsics fr1|fr2|fr3|icl|fx,fy,cx,cy] [--depth-scale S]
                    [--max-frames N] [--keyframes [--keyframe-trans M] [--keyframe-rot DEG]
                    [--keyframe-valid F]] [--init identity|velocity] [--levels L] [--robust KIND]
                    [--depth-weight W] [--color]

Aligns every frame of the sequence in DIR (``gvnn_warp.datasets.tum``: rgb.txt, depth.txt,
groundtruth.txt when present) to the previous one - or, with ``--keyframes``, to a keyframe kept
until the motion or the valid fraction passes a threshold - with ``gvnn_warp.odometry.DirectAligner``
on grey images (``--color``: RGB), and writes:

- ``OUT/trajectory.txt``: the estimate in the TUM format (``timestamp tx ty tz qx qy qz qw``,
  ``T_world_cam``), one pose per frame, starting at the ground truth's first pose (identity
  without ground truth);
- ``OUT/metrics.json``: ``frames``, ``ms_per_pair`` (alignment incl. pyramids; file reading
  excluded), ``unconverged_pairs`` / ``unconverged_frames`` and, with ground truth, ``ate_rmse_m``
  (SE(3) Umeyama-aligned, as ``evo_ape -a``), ``rpe_trans_rmse_m`` and ``rpe_rot_rmse_deg``
  (1-frame steps, as ``evo_rpe``), ``failed_pairs`` (RPE above 1 cm or 0.25 deg) - all by evo;
- ``OUT/trajectory.png`` (top view, estimate vs truth) and, with ground truth, ``OUT/errors.png``
  (per-frame translation and rotation error).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from ._args import positive_float, positive_int

__all__ = ["add_parser", "make_aligner", "run"]

ROBUST = ("huber", "l2", "cauchy", "geman_mcclure", "tukey")  # DirectAligner's
PRESETS = ("fr1", "fr2", "fr3", "icl")


def intrinsics_arg(text: str):
    """``type=`` for ``--intrinsics``: a preset name, or ``fx,fy,cx,cy`` (fx, fy > 0)."""
    if text in PRESETS:
        return text
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 4 or not all(math.isfinite(v) for v in values) or values[0] <= 0 or values[1] <= 0:
        raise argparse.ArgumentTypeError(f"expected one of {', '.join(PRESETS)} or fx,fy,cx,cy with fx, fy > 0, "
                                         f"got {text!r}")
    return tuple(values)


def nonnegative_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}") from None
    if not 0 <= v < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return v


def fraction(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}") from None
    if not 0 <= v <= 1:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}")
    return v


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..tracking import KeyframePolicy

    kf = KeyframePolicy()
    p.add_argument("data", type=Path, metavar="DIR", help="TUM RGB-D folder (rgb.txt, depth.txt[, groundtruth.txt])")
    p.add_argument("--out", type=Path, required=True, help="output folder (trajectory.txt, metrics.json, figures)")
    p.add_argument("--intrinsics", type=intrinsics_arg, default=None, metavar="PRESET|FX,FY,CX,CY",
                   help="fr1, fr2, fr3, icl (published 640x480 values) or fx,fy,cx,cy (default: DIR/intrinsics.txt, "
                        "else the Freiburg preset named by the folder)")
    p.add_argument("--depth-scale", type=positive_float, default=5000.0, metavar="S",
                   help="raw depth units per metre (default 5000, as TUM and ICL-NUIM)")
    p.add_argument("--max-frames", type=positive_int, default=None, metavar="N", help="track only the first N frames")
    p.add_argument("--max-difference", type=positive_float, default=0.02, metavar="SEC",
                   help="seconds: colour/depth association and ground-truth matching (default 0.02)")
    p.add_argument("--keyframes", action="store_true",
                   help="align to a keyframe, replaced when the thresholds below are passed (default: previous frame)")
    p.add_argument("--keyframe-trans", type=positive_float, default=kf.max_trans_m, metavar="M",
                   help=f"new keyframe beyond this translation (default {kf.max_trans_m} m)")
    p.add_argument("--keyframe-rot", type=positive_float, default=kf.max_rot_deg, metavar="DEG",
                   help=f"new keyframe beyond this rotation (default {kf.max_rot_deg} deg)")
    p.add_argument("--keyframe-valid", type=fraction, default=kf.min_valid, metavar="F",
                   help=f"new keyframe below this valid fraction (default {kf.min_valid})")
    p.add_argument("--init", choices=("identity", "velocity"), default="identity",
                   help="initial guess: identity (the default) or constant velocity")
    p.add_argument("--levels", type=positive_int, default=None, metavar="L",
                   help="pyramid levels (default: the aligner's, as many as keep the coarsest level >= 6 px)")
    p.add_argument("--iterations", type=positive_int, default=None, metavar="N",
                   help="iterations per level (default: the aligner's)")
    p.add_argument("--robust", choices=ROBUST, default="huber", help="photometric penalty (default huber)")
    p.add_argument("--depth-weight", type=nonnegative_float, default=0.0, metavar="W",
                   help="weight of the depth term (default 0: photometric only)")
    p.add_argument("--color", action="store_true", help="photometric term on RGB instead of grey")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "track",
        help="direct RGB-D odometry over a TUM RGB-D folder; trajectory, evo metrics and figures",
        description=__doc__.split("\n\n")[0],
    )
    add_arguments(p)
    p.set_defaults(func=run)
    return p


def _error(message: str) -> SystemExit:
    return SystemExit(f"gvnn-warp track: error: {message}")


def make_aligner(K, *, levels: int | None = None, iterations: int | None = None, robust: str = "huber",
                 depth_weight: float = 0.0, color: bool = False):
    """The ``gvnn_warp.odometry.DirectAligner`` that ``gvnn-warp track`` uses (None: the aligner's default)."""
    from ..odometry import DirectAligner

    kwargs = {"robust": robust, "depth_weight": depth_weight, "color": color}
    if levels is not None:
        kwargs["levels"] = levels
    if iterations is not None:
        kwargs["iterations"] = iterations
    return DirectAligner(K, **kwargs)


def _summary(rows: list[tuple[str, str]]) -> str:
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)


def run(args: argparse.Namespace) -> int:
    from ..datasets.tum import DatasetError, read_tum

    if args.out.exists() and not args.out.is_dir():
        raise _error(f"--out {args.out} exists and is not a directory")
    try:
        seq = read_tum(args.data, intrinsics=args.intrinsics, depth_scale=args.depth_scale,
                       max_difference=args.max_difference)
    except DatasetError as e:
        raise _error(str(e)) from None
    n = len(seq) if args.max_frames is None else min(args.max_frames, len(seq))
    if n < 2:
        raise _error(f"{args.data}: need at least 2 frames to track, found {n}")
    try:
        aligner = make_aligner(seq.K, levels=args.levels, iterations=args.iterations, robust=args.robust,
                               depth_weight=args.depth_weight, color=args.color)
    except ImportError as e:
        raise _error(f"the direct aligner (gvnn_warp.odometry) is not available: {e}") from None
    except ValueError as e:  # e.g. more pyramid levels than the image size allows
        raise _error(str(e)) from None
    try:
        args.out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise _error(f"cannot create --out {args.out}: {e.strerror or e}") from None

    try:
        return _track_and_report(args, seq, n, aligner)
    except DatasetError as e:  # an unreadable image met while tracking
        raise _error(str(e)) from None
    except KeyboardInterrupt:
        print("gvnn-warp track: interrupted", file=sys.stderr)
        return 130


def _track_and_report(args, seq, n: int, aligner) -> int:
    import numpy as np

    from ..datasets.tum import write_trajectory
    from ..evaluation import ATE_ALIGNMENT, FAIL_ROT_DEG, FAIL_TRANS_M, evaluate_trajectory, plot_errors, plot_top_view
    from ..tracking import KeyframePolicy, track

    gray = not args.color
    has_gt = seq.gt_poses is not None and int(seq.gt_valid[:n].sum()) >= 2
    start = seq.gt_poses[0] if has_gt and seq.gt_valid[0] else np.eye(4)
    policy = (KeyframePolicy(args.keyframe_trans, args.keyframe_rot, args.keyframe_valid)
              if args.keyframes else None)
    result = track(lambda i: (seq.image(i, gray=gray), seq.depth(i)), n, aligner, start_pose=start,
                   keyframes=policy, init=args.init, progress=not args.no_progress)

    stamps = seq.timestamps[:n]
    write_trajectory(args.out / "trajectory.txt", stamps, result.poses,
                     comment=f"gvnn-warp track {seq.root}: estimated T_world_cam")
    unconverged = result.unconverged_frames
    metrics = {
        "sequence": str(seq.root),
        "frames": n,
        "pairs": n - 1,
        "size": [seq.width, seq.height],
        "intrinsics": {"fx": seq.K[0, 0], "fy": seq.K[1, 1], "cx": seq.K[0, 2], "cy": seq.K[1, 2],
                       "source": seq.intrinsics_source},
        "settings": {"mode": "keyframe" if policy else "frame-to-frame", "init": args.init,
                     "levels": args.levels or "auto", "iterations": args.iterations, "robust": args.robust,
                     "depth_weight": args.depth_weight,
                     "channels": "grey" if gray else "rgb", "depth_scale": seq.depth_scale},
        "ms_per_pair": result.ms_per_pair,
        "ms_per_pair_note": "alignment incl. pyramids and image gradients; file reading excluded",
        "keyframes": len(result.keyframes) if policy else None,
        "unconverged_pairs": len(unconverged),
        "unconverged_frames": unconverged,
        "ground_truth": has_gt,
    }
    rows = [("frames", f"{n} ({seq.width}x{seq.height}, {metrics['settings']['mode']})"),
            ("ms per pair", f"{result.ms_per_pair:.2f}"),
            ("unconverged pairs", f"{len(unconverged)}" + (f" (frames {_frames_text(unconverged)})" if unconverged
                                                           else ""))]
    if policy:
        rows.append(("keyframes", str(len(result.keyframes))))
    if has_gt:
        m = evaluate_trajectory(stamps, result.poses, seq.gt_poses[:n], seq.gt_valid[:n])
        failed = m.pair_frames[m.failed]
        metrics.update({
            "evaluated_frames": int(m.frames.size),
            "ate_rmse_m": m.ate_rmse_m,
            "ate_alignment": m.ate_alignment,
            "rpe_trans_rmse_m": m.rpe_trans_rmse_m,
            "rpe_rot_rmse_deg": m.rpe_rot_rmse_deg,
            "rpe_delta": "1 frame (consecutive pairs)",
            "failed_pairs": int(failed.shape[0]),
            "failed_pair_frames": failed.tolist(),
            "failure_threshold": {"trans_m": FAIL_TRANS_M, "rot_deg": FAIL_ROT_DEG},
            "metrics_by": "evo",
        })
        aligned_by = "SE(3)-aligned" if m.ate_alignment == ATE_ALIGNMENT else "first pose aligned"
        rows += [("ATE RMSE", f"{100 * m.ate_rmse_m:.2f} cm ({aligned_by})"),
                 ("RPE trans RMSE", f"{100 * m.rpe_trans_rmse_m:.3f} cm per frame"),
                 ("RPE rot RMSE", f"{m.rpe_rot_rmse_deg:.4f} deg per frame"),
                 ("failed pairs", f"{failed.shape[0]} of {m.pair_frames.shape[0]} (> 1 cm or > 0.25 deg)")]
        plot_top_view(args.out / "trajectory.png", m.aligned, m.ground_truth,
                      title=f"{seq.root.name}: estimate ({aligned_by}) vs ground truth")
        plot_errors(args.out / "errors.png", m, np.array(unconverged))
    else:
        plot_top_view(args.out / "trajectory.png", result.poses, None, title=f"{seq.root.name}: estimate")
        rows.append(("ground truth", "none: no ATE/RPE"))
    (args.out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    print(f"track {seq.root}:\n{_summary(rows)}\nwrote {args.out}")
    return 0


def _frames_text(frames: list[int], limit: int = 12) -> str:
    text = ", ".join(str(f) for f in frames[:limit])
    return text + (f", ... ({len(frames)} in all)" if len(frames) > limit else "")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="gvnn-warp track", description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
