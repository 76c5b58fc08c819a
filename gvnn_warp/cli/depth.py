"""``gvnn-warp depth``: learn single-image depth and ego-motion from video without labels, and
evaluate the depth.

Usage::

    gvnn-warp depth train --data DIR [DIR ...] --out OUT [--size WxH] [--minutes M] [--gap G] [--fixed-gap]
                          [--inner-targets] [--norm batch|none] [--pose direct|network] [--supervised] [--ema DECAY]
                          [--steps N] [--batch-size B] [--lr LR] [--seed S] [--resume] [--overwrite]
                          [--no-progress]
    gvnn-warp depth eval --checkpoint CKPT --data DIR [DIR ...] --out OUT [--no-progress]

``train`` reads the colour frames and intrinsics of TUM-format folders (``gvnn-warp render`` writes
them; TUM RGB-D downloads are read the same way, with the fr1/fr2 lens distortion), never their depth
files, and trains a depth network (and, with ``--pose network``, a pose network) on triplets
(t - g, t, t + g) through the fused self-supervised objective (``gvnn_warp.reprojection_loss`` at
four scales plus edge-aware smoothness: Monodepth2's). It writes ``OUT/checkpoint.pt`` (atomically, every minute, on
Ctrl-C / SIGTERM and at the end; ``--resume`` continues from it), ``OUT/metrics.json`` (the loss per
step) and ``OUT/training.png`` (a frame, its depth, the true depth if the folder has it, the
auto-mask).

A folder of colour images alone (``rgb.txt``, no ``depth.txt``) is a video: every colour image
listed is a frame (also for ``eval``, which then predicts without metrics).

``eval`` predicts every frame's depth and, where the folders have depth files, writes
``OUT/metrics.json`` with abs_rel, sq_rel, rmse, rmse_log, a1, a2, a3 (each image median-scaled: a
monocular network has no scale; means over every image of every folder given, as a test set of
several sequences is measured, with each folder's own means beside) and ``OUT/depth.png``.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

# Idle OpenMP threads sleep instead of spinning (see gvnn_warp.cli.vo); before torch is imported.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from .args import (  # noqa: E402
    CHECKPOINT,
    UsageError,
    bounded_int,
    description,
    finite_float,
    image_size,
    output_dir,
    positive_float,
    positive_int,
    refuse_earlier_run,
    refuse_sequence_folder,
    seed,
)
from .runner import command_main  # noqa: E402

__all__ = ["add_parser", "run", "run_eval", "run_train"]

REQUIRES = ("torch", "matplotlib")  # checked by gvnn_warp.cli before run()
_SIZE = image_size(64, 1024, example="128x96")
_DEFAULT_GAP = 4  # DepthConfig's (not imported here: that would import torch for --help)
_POSES = ("direct", "network")  # gvnn_warp.depth.train.POSES, the default first (a test checks they agree)


def _multiple_of_32(text: str) -> tuple[int, int]:
    w, h = _SIZE(text)
    if w % 32 or h % 32:
        raise argparse.ArgumentTypeError(f"each side must be a multiple of 32 (the network halves it 5 times), "
                                          f"got {text!r}")
    return w, h


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("depth", help="learn depth and motion from video without labels, and evaluate it",
                              description=description(__doc__))
    sub = p.add_subparsers(dest="depth_command", required=True, metavar="{train,eval}")
    t = sub.add_parser("train", help="train a depth network on TUM-format folders' colour frames (no labels)",
                       description="Train a depth network (and, with --pose network, a pose network) on the colour "
                                   "frames of TUM-format folders through the self-supervised objective; see "
                                   "docs/depth.md.")
    t.add_argument("--data", type=Path, nargs="+", required=True, metavar="DIR", help="TUM-format folders")
    t.add_argument("--out", type=output_dir, required=True, metavar="OUT",
                   help="output folder (checkpoint, metrics.json, training.png; made if missing)")
    t.add_argument("--size", type=_multiple_of_32, default=(128, 96), metavar="WxH",
                   help="network input size, multiples of 32 (default: 128x96)")
    t.add_argument("--minutes", type=positive_float, default=8.0, metavar="M", help="training time (default: 8)")
    t.add_argument("--gap", type=bounded_int(1, 100), default=None, metavar="G",
                   help="a triplet is frames (t - g, t, t + g), g drawn for each triplet from 1..G: baselines "
                        f"of every length up to G (default: {_DEFAULT_GAP})")
    t.add_argument("--fixed-gap", action="store_true", help="g = G for every triplet")
    t.add_argument("--inner-targets", action="store_true",
                   help="targets only the frames G or more from both ends of a folder (the default before "
                        "2026-11-29, to --resume such runs; by default every frame with a neighbour on each side "
                        "is a target, g at most its distance to the nearer end)")
    t.add_argument("--norm", choices=("batch", "none"), default="batch",
                   help="normalisation after each convolution (default: batch; none: the networks of checkpoints "
                        "written before the option, to resume them)")
    t.add_argument("--pose", choices=_POSES, default=_POSES[0],
                   help="where each triplet's poses come from: direct (the direct aligner on the predicted depth, "
                        "no gradient; default) or network (a pose network trained with the depth network, "
                        "Monodepth2's)")
    t.add_argument("--supervised", action="store_true",
                   help="train on the folders' depth files instead (scale-invariant log loss): the upper bound "
                        "to compare the self-supervised network with")
    t.add_argument("--ema", type=finite_float(0.0, 1.0, below_maximum=True), default=0.99, metavar="DECAY",
                   help="the network kept is the exponential moving average of the trained one over the steps, "
                        "with this decay per step (default: 0.99; 0: the last step's network)")
    t.add_argument("--steps", type=positive_int, default=None, metavar="N", help="or stop after N steps")
    t.add_argument("--batch-size", type=bounded_int(1, 1024), default=8, metavar="B", help="triplets per step "
                   "(default: 8)")
    t.add_argument("--lr", type=positive_float, default=5e-4, metavar="LR", help="Adam's step size (default: 5e-4)")
    t.add_argument("--seed", type=seed, default=0, metavar="S", help="seed (default: 0)")
    t.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt (a new run if there is none)")
    t.add_argument("--overwrite", action="store_true", help="start again in an OUT that holds an earlier run")
    t.add_argument("--no-progress", action="store_true", help="no progress bar")
    t.set_defaults(func=run, _parser=t)  # (its usage for its own mistakes)
    e = sub.add_parser("eval", help="predict a folder's depth and measure it against its depth files (if it has them)",
                       description="Predict every frame's depth and, where the folders have depth files, write the "
                                   "standard metrics (median-scaled) to OUT/metrics.json, with OUT/depth.png; see "
                                   "docs/depth.md.")
    e.add_argument("--checkpoint", type=Path, required=True, metavar="CKPT", help="OUT/checkpoint.pt of train")
    e.add_argument("--data", type=Path, nargs="+", required=True, metavar="DIR",
                   help="TUM-format folders (one test set: the metrics are means over all their frames)")
    e.add_argument("--out", type=output_dir, required=True, metavar="OUT", help="output folder (metrics.json, "
                   "depth.png)")
    e.add_argument("--no-progress", action="store_true", help="no progress bar")
    e.set_defaults(func=run, _parser=e)
    return p


def run(args: argparse.Namespace) -> int:
    """``gvnn-warp depth train|eval``: the subcommand's run."""
    return run_train(args) if args.depth_command == "train" else run_eval(args)


def run_train(args: argparse.Namespace) -> int:
    # torch (through gvnn_warp.depth) only now: after gvnn_warp.cli checked it is installed
    from ..depth.train import DepthConfig, train

    refuse_earlier_run(args.out, args.resume, args.overwrite)
    cfg = DepthConfig(
        data=tuple(str(d) for d in args.data), out=str(args.out), size=args.size, minutes=args.minutes,
        gap=args.gap or _DEFAULT_GAP, vary_gap=not args.fixed_gap, all_targets=not args.inner_targets,
        norm=args.norm, pose=args.pose, ema=args.ema,
        steps=args.steps, batch_size=args.batch_size, lr=args.lr,
        seed=args.seed, resume=args.resume, progress=not args.no_progress, supervised=args.supervised,
    )
    m = train(cfg)  # (a folder or checkpoint that cannot be used: one line, status 1, by the runner)
    if not m:  # a rank other than 0 of a data-parallel run: rank 0 reports
        return 0
    if m["interrupted"]:  # (the checkpoint is written: say how to go on; the status of the signal's default)
        by = "SIGTERM" if m.get("stopped_by") == "SIGTERM" else "Ctrl-C"
        print(f"depth train: stopped by {by} at step {m['steps']}; {args.out / CHECKPOINT} holds the run (no "
              "training.png): --resume continues it", file=sys.stderr)
        return 143 if by == "SIGTERM" else 130
    loss = m["train_loss"]
    change = f"loss {loss[0]:.4f} -> {loss[-1]:.4f}" if loss else "no step"
    print(f"depth train: {m['steps']} steps in {m['train_seconds'] / 60:.1f} min on {m['triplets']} triplets, "
          f"{change}; wrote {cfg.out}")
    return 0


def run_eval(args: argparse.Namespace) -> int:
    from ..depth.evaluate import evaluate, repeated_folder

    twice = repeated_folder(args.data)
    if twice is not None:
        raise UsageError(f"--data names the folder {twice[0]} twice")
    refuse_sequence_folder(args.out)
    m = evaluate(args.checkpoint, args.data, args.out, progress=not args.no_progress)
    folders = " ".join(str(d) for d in args.data)
    if m.get("abs_rel") is None:
        print(f"depth eval: {m['frames']} frames predicted; {folders}: no valid true depth to compare with; "
              f"wrote {args.out}")
        return 0
    several = m.get("per_folder")
    print(f"depth eval ({m['images']} frames with true depth{f' in {len(several)} folders' if several else ''}, "
          f"median-scaled): {_metrics_text(m)}; wrote {args.out}")
    for folder, fm in (several or {}).items():
        print(f"  {folder}: " + ("no valid true depth" if fm.get("abs_rel") is None else
                                 f"{fm['images']} frames, {_metrics_text(fm)}"))
    return 0


def _metrics_text(m: dict) -> str:
    return (f"abs_rel {m['abs_rel']:.3f}, sq_rel {m['sq_rel']:.3f}, rmse {m['rmse']:.3f} m, rmse_log "
            f"{m['rmse_log']:.3f}, a1 {m['a1']:.3f}, a2 {m['a2']:.3f}, a3 {m['a3']:.3f}")


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m gvnn_warp.cli.depth train ...``): the same as ``gvnn-warp depth ...``."""
    return command_main(add_parser, REQUIRES, argv)


if __name__ == "__main__":
    sys.exit(main())
