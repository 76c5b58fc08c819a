"""``gvnn-warp track``: direct RGB-D odometry over a TUM RGB-D folder, evaluated with evo.

Usage::

    gvnn-warp track DIR --out OUT [--overwrite] [--method direct|vo|vo+direct [--checkpoint CKPT]]
                    [--intrinsics fr1|fr2|fr3|icl|fx,fy,cx,cy[,k1,k2,p1,p2,k3]] [--depth-scale S]
                    [--max-frames N] [--keyframes [--keyframe-trans M] [--keyframe-rot DEG]
                    [--keyframe-valid F]] [--init identity|velocity] [--levels L] [--robust KIND]
                    [--depth-weight W] [--color]

Aligns every frame of the sequence in DIR (``gvnn_warp.datasets.tum``: rgb.txt, depth.txt,
groundtruth.txt when present) to the previous one - or, with ``--keyframes``, to a keyframe kept
until the motion or the valid fraction passes a threshold - with ``gvnn_warp.odometry.DirectAligner``
on grey images (``--color``: RGB) - through the camera's radial-tangential distortion when the
intrinsics have one (the fr1/fr2 presets, nine numbers in ``--intrinsics`` or intrinsics.txt) -
or, with ``--method vo``, by the network of a ``gvnn-warp vo``
checkpoint (``--checkpoint``; frames are resized to the network's size and the intrinsics scaled),
or with ``--method vo+direct`` by the direct aligner starting from the network's estimate (instead
of the identity or ``--init``) - and writes:

- ``OUT/trajectory.txt``: the estimate in the TUM format (``timestamp tx ty tz qx qy qz qw``,
  ``T_world_cam``), one pose per frame, starting at the ground truth's first pose (identity
  without ground truth);
- ``OUT/metrics.json``: ``frames``, ``ms_per_pair`` (alignment incl. pyramids; file reading
  excluded), ``unconverged_pairs`` / ``unconverged_frames`` and, with ground truth, ``ate_rmse_m``
  (SE(3) Umeyama-aligned, as ``evo_ape -a``), ``rpe_trans_rmse_m`` and ``rpe_rot_rmse_deg``
  (1-frame steps, as ``evo_rpe``), ``failed_pairs`` (RPE above 1 cm or 0.25 deg) - all by evo;
- ``OUT/trajectory.png`` (top view, estimate vs truth) and, with ground truth, ``OUT/errors.png``
  (per-frame translation and rotation error).

Before the first frame is tracked it checks every image to be tracked (exists, format, size: from
the headers), and refuses an OUT that is the sequence's folder or holds an earlier run's results
(unless ``--overwrite``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from .args import UsageError, bounded_int, description, finite_float, output_dir, positive_float

__all__ = ["add_parser", "check", "make_aligner", "run"]

# checked by gvnn_warp.cli before run(): evo computes the metrics, matplotlib draws the figures; the
# aligner, the reader and the tracking loop are numpy and Warp (no torch)
REQUIRES = ("evo", "matplotlib", "tqdm")

ROBUST = ("huber", "l2", "cauchy", "geman_mcclure", "tukey")  # DirectAligner's
PRESETS = ("fr1", "fr2", "fr3", "icl")
METHODS = ("direct", "vo", "vo+direct")
MAX_LEVELS = 12  # a 4096-pixel side halved 11 times is 2 pixels
MAX_ITERATIONS = 1000
LOW_VALID_FRACTION = 0.05  # below this median fraction of usable pixels the summary warns (depth scale, images)
PLAUSIBLE_DEPTH_M = (0.05, 100.0)  # outside, the first frame's median depth suggests a wrong --depth-scale


def intrinsics_arg(text: str):
    """``type=`` for ``--intrinsics``: a preset name, ``fx,fy,cx,cy`` (finite, fx, fy > 0), or
    ``fx,fy,cx,cy,k1,k2,p1,p2,k3`` (with radial-tangential distortion, finite)."""
    if text in PRESETS:
        return text
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) not in (4, 9) or not all(math.isfinite(v) for v in values) or values[0] <= 0 or values[1] <= 0:
        raise argparse.ArgumentTypeError(f"expected one of {', '.join(PRESETS)} or fx,fy,cx,cy (finite, fx, fy > 0) "
                                         f"or fx,fy,cx,cy,k1,k2,p1,p2,k3, got {text!r}")
    return tuple(values)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..odometry.tracking import KeyframePolicy

    kf = KeyframePolicy()
    p.add_argument("data", type=Path, metavar="DIR", help="TUM RGB-D folder (rgb.txt, depth.txt[, groundtruth.txt])")
    p.add_argument("--out", type=output_dir, required=True, metavar="OUT",
                   help="output folder for trajectory.txt, metrics.json and the figures (made if missing; not the "
                        "sequence's own folder)")
    p.add_argument("--overwrite", action="store_true", help="replace the results of an earlier run in --out")
    p.add_argument("--method", choices=METHODS, default="direct",
                   help="direct: the direct aligner; vo: the trained network of --checkpoint alone; vo+direct: the "
                        "direct aligner starting from the network's estimate")
    p.add_argument("--checkpoint", type=Path, default=None, metavar="CKPT",
                   help="checkpoint.pt of gvnn-warp vo (needed by --method vo and vo+direct; default: none)")
    p.add_argument("--intrinsics", type=intrinsics_arg, default=None, metavar="PRESET|FX,FY,CX,CY[,K1,K2,P1,P2,K3]",
                   help="fr1, fr2, fr3, icl (published 640x480 values; fr1, fr2 with their radial-tangential "
                        "distortion) or fx,fy,cx,cy[,k1,k2,p1,p2,k3] (default: DIR/intrinsics.txt, "
                        "else the Freiburg preset named by the folder)")
    p.add_argument("--depth-scale", type=positive_float, default=5000.0, metavar="S",
                   help="raw depth units per metre (5000 in TUM RGB-D and ICL-NUIM)")
    p.add_argument("--max-frames", type=bounded_int(2), default=None, metavar="N",
                   help="track only the first N frames (default: all)")
    p.add_argument("--max-difference", type=finite_float(0, 1, "s", above_minimum=True), default=0.02, metavar="SEC",
                   help="seconds: colour/depth association and ground-truth matching")
    p.add_argument("--keyframes", action="store_true",
                   help="align to a keyframe, replaced when the thresholds below are passed (default: previous frame)")
    # (defaults None: given without --keyframes they are refused; the policy's defaults in the help)
    p.add_argument("--keyframe-trans", type=positive_float, default=None, metavar="M",
                   help=f"with --keyframes: new keyframe beyond this translation, metres (default: {kf.max_trans_m:g})")
    p.add_argument("--keyframe-rot", type=finite_float(0, 180, "deg", above_minimum=True), default=None,
                   metavar="DEG", help=f"with --keyframes: new keyframe beyond this rotation, degrees "
                                       f"(default: {kf.max_rot_deg:g})")
    p.add_argument("--keyframe-valid", type=finite_float(0, 1), default=None, metavar="F",
                   help=f"with --keyframes: new keyframe below this fraction of usable pixels "
                        f"(default: {kf.min_valid:g})")
    p.add_argument("--init", choices=("identity", "velocity"), default="identity",
                   help="initial guess: identity or constant velocity")
    p.add_argument("--levels", type=bounded_int(1, MAX_LEVELS), default=None, metavar="L",
                   help="pyramid levels (default: the aligner's, as many as keep the coarsest level >= 6 px; "
                        "fewer where the image is too small)")
    p.add_argument("--iterations", type=bounded_int(1, MAX_ITERATIONS), default=None, metavar="N",
                   help="iterations per level (default: the aligner's, 4 at the finest level to 30 at the coarsest)")
    p.add_argument("--robust", choices=ROBUST, default="huber", help="photometric penalty")
    p.add_argument("--depth-weight", type=finite_float(0, 1e6), default=0.0, metavar="W",
                   help="weight of the depth term (0: photometric only)")
    p.add_argument("--color", action="store_true", help="photometric term on RGB instead of grey")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "track",
        help="direct RGB-D odometry over a TUM RGB-D folder; trajectory, evo metrics and figures",
        description=description(__doc__),
    )
    add_arguments(p)
    p.set_defaults(func=run)
    return p


def make_aligner(K, *, levels: int | None = None, iterations: int | None = None, robust: str = "huber",
                 depth_weight: float = 0.0, color: bool = False, dist=None):
    """The ``gvnn_warp.odometry.DirectAligner`` that ``gvnn-warp track`` uses (None: the aligner's default;
    ``dist``: radial-tangential coefficients (k1, k2, p1, p2, k3) of the images, None for a pinhole)."""
    from ..odometry.aligner import DirectAligner

    kwargs = {"robust": robust, "depth_weight": depth_weight, "color": color}
    if dist is not None:
        kwargs.update(model="radtan", dist=dist)
    if levels is not None:
        kwargs["levels"] = levels
    if iterations is not None:
        kwargs["iterations"] = iterations
    return DirectAligner(K, **kwargs)


def _summary(rows: list[tuple[str, str]]) -> str:
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)


RESULT_FILES = ("trajectory.txt", "metrics.json", "trajectory.png", "errors.png")
KEYFRAME_OPTIONS = {"keyframe_trans": "max_trans_m", "keyframe_rot": "max_rot_deg", "keyframe_valid": "min_valid"}
# (option -> its KeyframePolicy field)


def check(args: argparse.Namespace):
    """Checks that need what is on disk (raises UsageError before any work): --out is not the
    sequence's folder and holds no earlier results unless --overwrite; the sequence's lists are read
    and associated, every image to be tracked exists and has the right format and size (from its
    header; the pixels are read while tracking), there are at least 2 frames, and the principal
    point is inside the image. Returns (sequence, number of frames to track)."""
    from ..datasets.tum import DatasetError, read_tum

    if not getattr(args, "keyframes", False):
        given = [name for name in KEYFRAME_OPTIONS if getattr(args, name, None) is not None]
        if given:
            raise UsageError(f"--{given[0].replace('_', '-')} applies with --keyframes only")
    if args.out.exists() and args.data.exists() and args.out.resolve() == args.data.resolve():
        raise UsageError(f"--out {args.out} is the sequence's own folder; choose another")
    if (args.out / "rgb.txt").exists():
        raise UsageError(f"--out {args.out} holds a sequence (rgb.txt); choose another folder")
    existing = [name for name in RESULT_FILES if (args.out / name).exists()]
    if existing and not getattr(args, "overwrite", False):
        raise UsageError(f"--out {args.out} already holds results ({existing[0]}); pass --overwrite or choose "
                         "another folder")
    try:
        seq = read_tum(args.data, intrinsics=args.intrinsics, depth_scale=args.depth_scale,
                       max_difference=args.max_difference)
        n = len(seq) if args.max_frames is None else min(args.max_frames, len(seq))
        if n < 2:
            raise UsageError(f"{args.data}: need at least 2 frames to track, found {n}")
        seq.check_files(n)
    except DatasetError as e:
        raise UsageError(str(e)) from None
    cx, cy = seq.K[0, 2], seq.K[1, 2]
    if not (0 <= cx <= seq.width - 1 and 0 <= cy <= seq.height - 1):
        source = "--intrinsics" if seq.intrinsics_source == "given" else seq.intrinsics_source
        raise UsageError(f"the principal point ({cx:g}, {cy:g}) of the intrinsics ({source}) is outside the "
                         f"{seq.width}x{seq.height} images")
    return seq, n


def check_method(args: argparse.Namespace):
    """--method and --checkpoint (raises UsageError before any work); returns the network and its
    checkpoint entry ``network`` for --method vo / vo+direct, else None."""
    method = getattr(args, "method", "direct")
    ckpt = getattr(args, "checkpoint", None)
    if method == "direct":
        if ckpt is not None:
            raise UsageError("--checkpoint is used by --method vo and vo+direct only (this run is --method direct)")
        return None
    if ckpt is None:
        raise UsageError(f"--method {method} needs --checkpoint CKPT (the checkpoint.pt written by gvnn-warp vo)")
    from . import INSTALL_HINTS, missing_packages

    if missing_packages(("torch",)):
        raise UsageError(f"--method {method} needs {INSTALL_HINTS['torch']}")
    from ..vo.checkpoint import CheckpointError, load_network

    try:
        return load_network(ckpt)
    except CheckpointError as e:
        raise UsageError(str(e)) from None


def run(args: argparse.Namespace) -> int:
    from ..datasets.tum import DatasetError

    seq, n = check(args)
    network = check_method(args)
    aligner = None
    if getattr(args, "method", "direct") != "vo":
        aligner = make_aligner(seq.K, levels=args.levels, iterations=args.iterations, robust=args.robust,
                               depth_weight=args.depth_weight, color=args.color, dist=seq.dist)
    if network is not None:
        from ..vo.frontend import NetworkAligner

        net, spec = network
        aligner = NetworkAligner(net, seq.K, (seq.width, seq.height), refine=spec.get("refine", 0), direct=aligner,
                                 symmetries=tuple(spec.get("symmetries", ())))
    try:
        return _track_and_report(args, seq, n, aligner)
    except DatasetError as e:  # an unreadable image met while tracking: one line naming the file
        print(f"gvnn-warp track: error: {e}", file=sys.stderr)
        return 1


def _track_and_report(args, seq, n: int, aligner) -> int:
    import numpy as np

    from ..datasets.tum import write_trajectory
    from ..odometry.evaluation import (
        ATE_ALIGNMENT,
        FAIL_ROT_DEG,
        FAIL_TRANS_M,
        evaluate_trajectory,
        plot_errors,
        plot_top_view,
    )
    from ..odometry.tracking import KeyframePolicy, track

    method = getattr(args, "method", "direct")
    gray = not args.color and method == "direct"  # the network takes RGB (the direct aligner makes it grey)
    has_gt = seq.gt_poses is not None and int(seq.gt_valid[:n].sum()) >= 2
    start = seq.gt_poses[0] if has_gt and seq.gt_valid[0] else np.eye(4)
    policy = None
    if args.keyframes:  # the options given, else the policy's defaults
        given = {field: getattr(args, option, None) for option, field in KEYFRAME_OPTIONS.items()}
        policy = KeyframePolicy(**{field: v for field, v in given.items() if v is not None})
    result = track(lambda i: (seq.image(i, gray=gray), seq.depth(i)), n, aligner, start_pose=start,
                   keyframes=policy, init=args.init, progress=not args.no_progress)

    stamps = seq.timestamps[:n]
    # only now, with the run done: make --out, and (--overwrite) remove the earlier run's files, so
    # that a run that fails leaves nothing, or the earlier results, and no file of theirs is left
    # beside the new ones
    args.out.mkdir(parents=True, exist_ok=True)
    for name in RESULT_FILES:
        (args.out / name).unlink(missing_ok=True)
    write_trajectory(args.out / "trajectory.txt", stamps, result.poses,
                     comment=f"gvnn-warp track {seq.root}: estimated T_world_cam")
    unconverged = result.unconverged_frames
    metrics = {
        "sequence": str(seq.root),
        "frames": n,
        "pairs": n - 1,
        "size": [seq.width, seq.height],
        "intrinsics": {"fx": seq.K[0, 0], "fy": seq.K[1, 1], "cx": seq.K[0, 2], "cy": seq.K[1, 2],
                       "radtan": None if seq.dist is None else [float(v) for v in seq.dist],
                       "source": seq.intrinsics_source},
        "settings": {"method": method,
                     "checkpoint": str(args.checkpoint) if getattr(args, "checkpoint", None) else None,
                     "mode": "keyframe" if policy else "frame-to-frame",
                     "init": args.init if method == "direct" else "network",
                     "levels": args.levels or "auto", "iterations": args.iterations, "robust": args.robust,
                     "depth_weight": args.depth_weight,
                     "channels": "grey" if gray else "rgb", "depth_scale": seq.depth_scale},
        "ms_per_pair": result.ms_per_pair,
        "ms_per_pair_note": "alignment incl. the live frame's pyramid; file reading excluded",
        "keyframes": len(result.keyframes) if policy else None,
        "unconverged_pairs": len(unconverged),
        "unconverged_frames": unconverged,
        "median_valid_fraction": _median_valid(result.valid_fraction),
        "ground_truth": has_gt,
    }
    K = seq.K
    rows = [("frames", f"{n} ({seq.width}x{seq.height}, {metrics['settings']['mode']}, method {method})"),
            ("intrinsics", f"fx {K[0, 0]:g} fy {K[1, 1]:g} cx {K[0, 2]:g} cy {K[1, 2]:g}"
                           f"{' with radial-tangential distortion' if seq.dist is not None else ''} "
                           f"({seq.intrinsics_source})"),
            ("ms per pair", f"{result.ms_per_pair:.2f}"),
            ("unconverged pairs", f"{len(unconverged)}" + (f" (frames {_frames_text(unconverged)})" if unconverged
                                                           else ""))]
    if policy:
        rows.append(("keyframes", str(len(result.keyframes))))
    depth0 = seq.depth(0)
    depth0 = depth0[np.isfinite(depth0) & (depth0 > 0)]
    median0 = metrics["first_frame_median_depth_m"] = float(np.median(depth0)) if depth0.size else None
    if median0 is not None and not PLAUSIBLE_DEPTH_M[0] <= median0 <= PLAUSIBLE_DEPTH_M[1]:
        rows.append(("warning", f"the first frame's median depth is {median0:.4g} m: check --depth-scale "
                                f"({seq.depth_scale:g} units per metre)"))
    valid = metrics["median_valid_fraction"]
    if valid is not None and valid < LOW_VALID_FRACTION:
        rows.append(("warning", f"only {100 * valid:.1f}% of the pixels were usable (median over the pairs): check "
                                f"the depth images and --depth-scale ({seq.depth_scale:g} units per metre)"))
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
        if m.frames.size < n:
            rows.append(("evaluated frames", f"{m.frames.size} of {n} (the others have no ground-truth pose within "
                                             f"--max-difference {args.max_difference:g} s)"))
        plot_top_view(args.out / "trajectory.png", m.aligned, m.ground_truth,
                      title=f"{seq.root.name}: estimate ({aligned_by}) vs ground truth")
        plot_errors(args.out / "errors.png", m, np.array(unconverged))
    else:
        plot_top_view(args.out / "trajectory.png", result.poses, None, title=f"{seq.root.name}: estimate")
        if seq.gt_poses is None:
            why = "none (no groundtruth.txt): no ATE/RPE"
        else:
            why = (f"none usable: {int(seq.gt_valid[:n].sum())} of the {n} frames have a pose in groundtruth.txt "
                   f"within --max-difference {args.max_difference:g} s (2 needed): no ATE/RPE")
        rows.append(("ground truth", why))
        metrics["ground_truth_note"] = why
    (args.out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    print(f"track {seq.root}:\n{_summary(rows)}\nwrote {args.out}")
    return 0


def _median_valid(fractions) -> float | None:
    """The median of the pairs' valid fractions (NaN: unknown, e.g. frame 0), None if none known."""
    import numpy as np

    known = np.asarray(fractions, dtype=np.float64)
    known = known[np.isfinite(known)]
    return float(np.median(known)) if known.size else None


def _frames_text(frames: list[int], limit: int = 12) -> str:
    text = ", ".join(str(f) for f in frames[:limit])
    return text + (f", ... ({len(frames)} in all)" if len(frames) > limit else "")


def main(argv: list[str] | None = None) -> int:
    """``python -m gvnn_warp.cli.track ...``: the same as ``gvnn-warp track ...``."""
    from . import main as cli_main

    return cli_main(["track", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
