"""Evaluation of a trained VO network and the report of a run: pose errors and photometric
residuals of its predictions against the identity (zero-motion) prediction, ``metrics.json`` and
the figures (:mod:`.plots`).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .checkpoint import atomic_write_text
from .data import PairSet
from .loss import photometric_loss, pose_errors
from .model import CascadeVO
from .plots import plot_panel, plot_training_curve

__all__ = ["METRICS", "evaluate", "evaluate_and_report", "even_subset", "predict_pairs"]

METRICS = "metrics.json"  # its file name in a run's output directory


def even_subset(n_total: int, n: int) -> Tensor:
    """At most ``n`` indices spread evenly over ``range(n_total)``, ascending."""
    return torch.from_numpy(np.unique(np.linspace(0, n_total - 1, min(n, n_total)).round().astype(np.int64)))


def predict_pairs(model: CascadeVO, ps: PairSet, idx: Tensor, refine: int = 0, chunk: int = 64,
                  symmetries: tuple[str, ...] = ()) -> Tensor:
    """The model's predictions (``CascadeVO.predict``, in eval mode, no gradient) for pairs ``idx``,
    in chunks of ``chunk`` pairs."""
    out = []
    was_training = model.training
    model.eval()
    with torch.no_grad():
        for i in range(0, len(idx), chunk):
            ref, live, ref_d, live_d, _, _ = ps.batch(idx[i : i + chunk])
            out.append(model.predict(ref, live, ref_d, live_d, ps.K, refine=refine, symmetries=symmetries))
    model.train(was_training)
    return torch.cat(out) if out else torch.zeros(0, model.out_dim, dtype=torch.float32)


def evaluate(pred: Tensor, ps: PairSet, gt_warp: Tensor, gt_valid: Tensor, idx: Tensor) -> dict:
    """Mean rotation (deg) / translation (m) errors and mean photometric residual (mean |r| over the
    channels of the pixels valid in both warps, per pair, then averaged) of predictions on pairs ``idx``."""
    _, live, ref_d, _, pose, _ = ps.batch(idx)
    rot, trans = pose_errors(pred, pose)
    with torch.no_grad():
        photo, _, _ = photometric_loss(pred, live, ref_d, gt_warp[idx], gt_valid[idx], ps.K, "l1")
    return {
        "rot_deg": float(rot.mean()),
        "trans_m": float(trans.mean()),
        "photometric": float(photo.mean()),
        "rot_deg_median": float(rot.median()),
        "trans_m_median": float(trans.median()),
        "n_pairs": int(len(idx)),
    }


def evaluate_and_report(
    cfg, model, history, snapshots, train_set, train_gt, train_valid, eval_set, eval_gt, eval_valid,
    eval_idx, panel_idx, t_data, train_seconds, t_so_far, step, ddp,
) -> dict:
    """Evaluate the trained ``model`` and the identity on the held-out pairs ``eval_idx`` (overall and
    per frame gap) and on as many training pairs, draw the training curve and the registration panel,
    and write ``metrics.json`` into ``cfg.out``; returns the metrics."""
    t0 = time.perf_counter()
    zero = torch.zeros(len(eval_idx), model.out_dim, dtype=torch.float32)
    trained = predict_pairs(model, eval_set, eval_idx, cfg.refine, symmetries=cfg.symmetries)
    train_idx = even_subset(len(train_set), cfg.n_eval)
    ev = {
        "identity": evaluate(zero, eval_set, eval_gt, eval_valid, eval_idx),
        "trained": evaluate(trained, eval_set, eval_gt, eval_valid, eval_idx),
    }
    gap = (eval_set.live[eval_idx] - eval_set.ref[eval_idx]).abs()
    by_gap = {}
    for g in sorted({int(v) for v in gap}):
        sel = gap == g
        by_gap[str(g)] = {
            "identity": evaluate(zero[sel], eval_set, eval_gt, eval_valid, eval_idx[sel]),
            "trained": evaluate(trained[sel], eval_set, eval_gt, eval_valid, eval_idx[sel]),
        }
    ev_train = {
        "identity": evaluate(
            torch.zeros(len(train_idx), model.out_dim, dtype=torch.float32), train_set, train_gt, train_valid, train_idx
        ),
        "trained": evaluate(
            predict_pairs(model, train_set, train_idx, cfg.refine, symmetries=cfg.symmetries), train_set, train_gt,
            train_valid, train_idx,
        ),
    }
    n = max(1, min(20, len(history) // 10))
    out = Path(cfg.out)
    metrics = {
        "motion": cfg.motion,
        "steps": step,
        "train_loss": history,
        "train_loss_first": float(np.mean(history[:n])) if history else None,
        "train_loss_last": float(np.mean(history[-n:])) if history else None,
        "eval": ev,
        "eval_by_gap": by_gap,
        "eval_train_pairs": ev_train,
        "ratios": {
            "rot_deg": ev["trained"]["rot_deg"] / max(ev["identity"]["rot_deg"], 1e-12),
            "trans_m": ev["trained"]["trans_m"] / max(ev["identity"]["trans_m"], 1e-12),
            "photometric": ev["trained"]["photometric"] / max(ev["identity"]["photometric"], 1e-12),
        },
        "distributed": ddp,
        "n_train_pairs": len(train_set),
        "n_eval_pairs_total": len(eval_set),
        "seconds": {"data": t_data, "train": train_seconds},
        "config": {k: v for k, v in dataclasses.asdict(cfg).items() if k not in ("extra",)},
    }
    stages = {int(k): v for k, v in snapshots.items()}
    plot_training_curve(history, out / "training_curve.png", title=f"VO {cfg.motion}: training loss ({cfg.loss})")
    plot_panel(eval_set, eval_gt, eval_valid, panel_idx, stages, out / "registration.png", motion=cfg.motion)
    metrics["seconds"]["eval"] = time.perf_counter() - t0
    metrics["seconds"]["total_this_process"] = t_so_far + metrics["seconds"]["eval"]
    atomic_write_text(json.dumps(metrics, indent=1), out / METRICS)
    return metrics

