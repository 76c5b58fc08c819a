"""``gvnn-warp vo``: train the siamese visual-odometry network through the 3D spatial transformer.

Usage::

    gvnn-warp vo --motion so3|se3 --out DIR [--steps N] [--size WxH] [--seed S] [--resume]
                 [--loss l1|l2|huber|cauchy|geman_mcclure|tukey] [--batch-size B] [--lr LR]

    torchrun --nproc_per_node=2 -m gvnn_warp.demos.vo --motion so3 --out DIR   # DDP over gloo

Writes ``DIR/checkpoint.pt`` (atomically, every 50 steps / 30 s, on Ctrl-C / SIGTERM and at the
end; ``--resume`` continues from it), ``DIR/metrics.json`` (training loss per step, held-out
rotation / translation errors and photometric residual of the identity and the trained network),
``DIR/training_curve.png`` and ``DIR/registration.png``.
"""

from __future__ import annotations

import argparse
import os
import sys

# Idle OpenMP threads sleep instead of spinning: on 2 shared cores (Warp launches, other processes)
# spinning threads made training steps several times slower. Only effective if set before torch
# is first imported (this module does not import torch at import time).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from ._args import image_size, nonnegative_int, positive_float, positive_int

_SIZE = image_size(32)

__all__ = ["add_parser", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    from gvnn_warp.vo.loss import LOSSES

    p.add_argument("--motion", required=True, choices=("so3", "se3"),
                   help="so3: pure rotation (3 outputs); se3: rotation and translation (6 outputs)")
    p.add_argument("--out", required=True, help="output directory (checkpoint, metrics.json, figures)")
    p.add_argument("--steps", type=positive_int, default=None, help="total training steps (default per motion)")
    p.add_argument("--size", type=_SIZE, default=None, help="image size WxH (default 128x96; e.g. 320x240)")
    p.add_argument("--seed", type=nonnegative_int, default=None,
                   help="seed of weights, trajectories and batches (default 0)")
    p.add_argument("--resume", action="store_true", help="continue from DIR/checkpoint.pt")
    p.add_argument("--loss", choices=LOSSES, default=None,
                   help="per-pixel penalty: l1 (default), l2, or an M-estimator (gvnn_warp.perpixel)")
    p.add_argument("--loss-scale", type=positive_float, default=None, help="M-estimator scale (default 0.1)")
    p.add_argument("--batch-size", type=positive_int, default=None, help="global batch size (default 16)")
    p.add_argument("--lr", type=positive_float, default=None, help="peak Adam learning rate (default 1e-3)")
    p.add_argument("--trajectories", type=positive_int, default=None,
                   help="training trajectories to render (default 8 for so3, 16 for se3; held-out: 2 others)")
    p.add_argument("--frames", type=positive_int, default=None, help="frames per trajectory (default 80)")
    p.add_argument("--stages", type=positive_int, default=None,
                   help="networks in the cascade; each later one refines the pose on the live image warped by "
                        "the pose so far (default: 1 for so3, 2 for se3)")
    p.add_argument("--refine", type=nonnegative_int, default=None,
                   help="when predicting, apply the last stage this many more times to the re-warped live image "
                        "(default: 0 for so3, 2 for se3)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "vo",
        help="train a siamese VO network through the 3D spatial transformer (paper's application)",
        description=__doc__.split("\n\n")[0],
    )
    add_arguments(p)
    p.set_defaults(func=run)
    return p


def _config(args: argparse.Namespace):
    from gvnn_warp.vo.train import default_config

    return default_config(
        args.motion,
        args.out,
        steps=args.steps,
        size=args.size,
        seed=args.seed,
        loss=args.loss,
        loss_scale=args.loss_scale,
        batch_size=args.batch_size,
        lr=args.lr,
        n_train_traj=getattr(args, "trajectories", None),
        n_frames=getattr(args, "frames", None),
        stage_scales=(1,) * args.stages if getattr(args, "stages", None) else None,
        refine=getattr(args, "refine", None),
        resume=bool(args.resume),
        progress=not getattr(args, "no_progress", False),
    )


def run(args: argparse.Namespace) -> int:
    from gvnn_warp.vo.train import ConfigError, train

    try:
        cfg = _config(args)
        metrics = train(cfg)
    except ConfigError as e:  # inconsistent options, e.g. --refine with a single stage, or --resume
        raise SystemExit(f"gvnn-warp vo: error: {e}") from None
    if metrics.get("interrupted"):
        return 130
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
    """Stand-alone entry (``python -m gvnn_warp.demos.vo ...``, also under torchrun)."""
    parser = argparse.ArgumentParser(prog="gvnn-warp vo", description=__doc__.split("\n\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
