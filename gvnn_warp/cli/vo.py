"""``gvnn-warp vo``: train the siamese visual-odometry network through the 3D spatial transformer.

Usage::

    gvnn-warp vo --motion so3|se3 --out DIR [--data DIR [DIR ...] [--eval-data DIR ...]] [--gaps G,G,...]
                 [--steps N] [--size WxH] [--seed S] [--resume] [--checkpoint-every N]
                 [--loss l1|l2|huber|cauchy|geman_mcclure|tukey] [--batch-size B] [--lr LR]

Trains on frame pairs (k, k + g) for every gap g of ``--gaps``, in both directions. By default the
pairs come from trajectories it renders itself in a synthetic room (no downloads) and it is
evaluated on trajectories of other seeds in the same room; with ``--data`` from TUM-format folders
(``gvnn-warp render`` writes them; TUM RGB-D and ICL-NUIM downloads with ground truth are read the
same way), resized to ``--size`` with the intrinsics scaled, evaluated on ``--eval-data`` (default:
the last ``--data`` folder, held out).

Writes ``DIR/checkpoint.pt`` (atomically, every 50 steps (``--checkpoint-every``) / 30 s, on Ctrl-C / SIGTERM and at the
end; ``--resume`` continues from it), ``DIR/metrics.json`` (training loss per step, held-out
rotation / translation errors and photometric residual of the identity and the trained network),
``DIR/training_curve.png`` and ``DIR/registration.png``.

On two processes (DistributedDataParallel over gloo; the batch is split between them), with the
same options: ``torchrun --standalone --nproc_per_node=2 -m gvnn_warp.cli.vo --motion so3 --out DIR``
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

# Idle OpenMP threads sleep instead of spinning: on 2 shared cores (Warp launches, other processes)
# spinning threads made training steps several times slower. Only effective if set before torch
# is first imported (this module does not import torch at import time).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from ..kernels.robust import KINDS  # noqa: E402  (pure Warp: no torch)
from .args import (  # noqa: E402
    UsageError,
    bounded_int,
    bounded_int_list,
    description,
    finite_float,
    image_size,
    output_dir,
    positive_float,
    positive_int,
    refuse_earlier_run,
    seed,
)
from .runner import command_main  # noqa: E402

MAX_SIDE = 1024  # larger frames make the network and the rendered data set too big for a demo
_SIZE = image_size(32, MAX_SIDE)

__all__ = ["add_parser", "run"]

REQUIRES = ("torch", "matplotlib")  # checked by gvnn_warp.cli before run()


def _losses() -> tuple[str, ...]:
    # the choices of --loss without importing torch (gvnn_warp.vo.loss.LOSSES; a test checks they agree)
    return ("l1", "l2", *KINDS)


def _symmetries(text: str) -> tuple[str, ...]:
    # the network's module imports torch: only when --symmetries is given (not for --help, nor on import,
    # which must come before torch so that OMP_WAIT_POLICY above takes effect)
    from ..vo.model import SYMMETRIES

    names = () if text.strip() == "none" else tuple(n.strip() for n in text.split(",") if n.strip())
    bad = [n for n in names if n not in SYMMETRIES]
    if bad:
        raise argparse.ArgumentTypeError(
            f"unknown {', '.join(bad)}: expected 'none' or some of {', '.join(SYMMETRIES)}"
        )
    return names


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--motion", required=True, choices=("so3", "se3"),
                   help="so3: pure rotation (3 outputs); se3: rotation and translation (6 outputs)")
    p.add_argument("--out", type=output_dir, required=True, metavar="DIR",
                   help="output directory (checkpoint, metrics.json, figures; made if missing)")
    p.add_argument("--data", type=Path, nargs="+", default=None, metavar="DIR",
                   help="train on these TUM-format folders (with groundtruth.txt) instead of rendered trajectories; "
                        "the last one is held out for evaluation unless --eval-data is given (default: render)")
    p.add_argument("--eval-data", type=Path, nargs="+", default=None, metavar="DIR",
                   help="TUM-format folders to evaluate on (with --data; default: the last --data folder)")
    p.add_argument("--gaps", type=bounded_int_list(1, 1000), default=None, metavar="G,G,...",
                   help="frame gaps of the training and evaluation pairs (default: 1 for so3, "
                        "1,2,3,5,7,10 for se3)")
    p.add_argument("--steps", type=bounded_int(1, 10_000_000), default=None, metavar="N",
                   help="total training steps (default: 1400 for so3, 1800 for se3)")
    p.add_argument("--size", type=_SIZE, default=None, metavar="WxH", help="image size WxH (default: 128x96)")
    p.add_argument("--seed", type=seed, default=None, metavar="S",
                   help="seed of weights, trajectories and batches (default: 0)")
    p.add_argument("--resume", action="store_true", help="continue from DIR/checkpoint.pt (a new run if there is none)")
    p.add_argument("--overwrite", action="store_true", help="start again in a DIR that holds an earlier run")
    p.add_argument("--loss", choices=_losses(), default=None,
                   help="per-pixel penalty: l1, l2, or an M-estimator of gvnn_warp.functional.perpixel (default: l1)")
    p.add_argument("--loss-scale", type=positive_float, default=None, metavar="X",
                   help="M-estimator scale, intensity units (default: 0.1)")
    p.add_argument("--pose-weight", type=finite_float(0, 1e6), default=None, metavar="W",
                   help="weight of a pose term (L1 distance of the rotation vector, radians, and of the translation "
                        "over the median depth, from the truth) added to the photometric cost (default: 1 for se3 "
                        "and so3; 0: the paper's photometric cost alone)")
    p.add_argument("--pose-t-weight", type=finite_float(0, 1e6), default=None, metavar="W",
                   help="weight of the pose term's translation part relative to its rotation part (default: 1; 3 "
                        "did not lower the se3 translation error)")
    p.add_argument("--batch-size", type=positive_int, default=None, metavar="B",
                   help="global batch size, split between torchrun's ranks (default: 16)")
    p.add_argument("--lr", type=positive_float, default=None, metavar="LR",
                   help="peak Adam learning rate (default: 1e-3)")
    p.add_argument("--trajectories", type=bounded_int(1, 1000), default=None, metavar="N",
                   help="training trajectories to render (default: 8 for so3, 16 for se3; held-out: 2 others)")
    p.add_argument("--frames", type=bounded_int(2, 10_000), default=None, metavar="N",
                   help="frames per rendered trajectory, more than the largest gap (default: 80); with --data: "
                        "the first N frames of each folder (default: all)")
    p.add_argument("--stages", type=bounded_int(1, 8), default=None, metavar="N",
                   help="networks in the cascade; each later one refines the pose on the live image warped by "
                        "the pose so far (default: 2)")
    p.add_argument("--refine", type=bounded_int(0, 20), default=None, metavar="N",
                   help="when predicting, apply the last stage this many more times to the re-warped live image "
                        "(default: 2)")
    p.add_argument("--symmetries", type=_symmetries, default=None, metavar="S,S,...|none",
                   help="when predicting, average the pose over these exact symmetries of a pair: swap (the "
                        "pair reversed), mirror_x, mirror_y (both frames mirrored; only with the principal point "
                        "at the image centre) (default: swap,mirror_y for se3, none for so3)")
    p.add_argument("--checkpoint-every", type=bounded_int(1, 10_000_000), default=None, metavar="N",
                   help="write DIR/checkpoint.pt every N steps (default: 50; also every 30 s)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "vo",
        help="train a siamese VO network through the 3D spatial transformer (paper's application)",
        description=description(__doc__),
    )
    add_arguments(p)
    p.set_defaults(func=run)
    return p


def _config(args: argparse.Namespace):
    from ..vo.train import default_config  # torch: only when the command runs (see run)

    return default_config(
        args.motion,
        str(args.out),
        steps=args.steps,
        size=args.size,
        seed=args.seed,
        loss=args.loss,
        loss_scale=args.loss_scale,
        batch_size=args.batch_size,
        lr=args.lr,
        n_train_traj=getattr(args, "trajectories", None),
        n_frames=None if getattr(args, "data", None) else getattr(args, "frames", None),
        data_max_frames=getattr(args, "frames", None) if getattr(args, "data", None) else None,
        data=tuple(str(d) for d in args.data) if getattr(args, "data", None) else None,
        eval_data=tuple(str(d) for d in args.eval_data) if getattr(args, "eval_data", None) else None,
        gaps=getattr(args, "gaps", None),
        stage_scales=(1,) * args.stages if getattr(args, "stages", None) else None,
        refine=getattr(args, "refine", None),
        symmetries=getattr(args, "symmetries", None),
        pose_weight=getattr(args, "pose_weight", None),
        pose_t_weight=getattr(args, "pose_t_weight", None),
        checkpoint_every=getattr(args, "checkpoint_every", None),
        resume=bool(args.resume),
        progress=not getattr(args, "no_progress", False),
    )


def run(args: argparse.Namespace) -> int:
    # gvnn_warp.vo imports torch: only now, once gvnn_warp.cli has checked that torch is installed
    # (--help and the other commands never load it) and after OMP_WAIT_POLICY is set above
    from ..vo.train import ConfigError, check_config, train

    refuse_earlier_run(args.out, args.resume, args.overwrite)
    try:  # every check that needs several options, or the checkpoint to resume, before any work
        cfg = _config(args)
        check_config(cfg)
    except ConfigError as e:  # e.g. --refine with a single stage, or --resume of another run
        raise UsageError(str(e)) from None
    metrics = train(cfg)
    if metrics.get("interrupted"):  # (the status of the signal's default: 143 for SIGTERM, as depth train)
        return 143 if metrics.get("stopped_by") == "SIGTERM" else 130
    if metrics:
        ev = metrics["eval"]
        print(
            f"vo {cfg.motion}: held-out rot {ev['identity']['rot_deg']:.3f} -> {ev['trained']['rot_deg']:.3f} deg, "
            f"trans {ev['identity']['trans_m']:.4f} -> {ev['trained']['trans_m']:.4f} m, "
            f"photometric {ev['identity']['photometric']:.4f} -> {ev['trained']['photometric']:.4f}; "
            f"loss {metrics['train_loss_first']:.4g} -> {metrics['train_loss_last']:.4g}; wrote {cfg.out}"
        )
    return 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m gvnn_warp.cli.vo ...``, also under torchrun): the same as
    ``gvnn-warp vo ...``."""
    return command_main(add_parser, REQUIRES, argv)


if __name__ == "__main__":
    sys.exit(main())
