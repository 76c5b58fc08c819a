"""Training of the siamese VO network through the 3D spatial transformer (the paper's application).

:func:`train` renders the data once (:mod:`.data`), precomputes the ground-truth warps, trains with
Adam on the photometric cost (:mod:`.loss`), checkpoints atomically and resumes, evaluates on
held-out trajectories against the identity (zero-motion) prediction, and writes ``metrics.json``
and figures into the output directory. Launched by ``torchrun`` (``RANK``/``WORLD_SIZE`` set) it
trains with DistributedDataParallel over gloo; only rank 0 writes files and progress.

Determinism: the pairs of step ``s`` are drawn from ``numpy.random.default_rng([seed, s])``, so a
resumed run draws exactly the batches the uninterrupted run would have; the global batch is split
between the ranks.

The configuration and its checks: :mod:`.config`; checkpoints: :mod:`.checkpoint`; evaluation and
the report: :mod:`.evaluation`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import signal
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch import Tensor

from ..datasets.errors import DatasetError
from ..progress import progress_bar
from .checkpoint import CHECKPOINT, CHECKPOINT_FORMAT, atomic_save, network_spec, rng_state, set_rng_state
from .config import ConfigError, VOConfig, check_config, default_config
from .data import PairSet, read_split, render_split, split_seeds
from .distributed import finish, setup
from .evaluation import METRICS, evaluate, evaluate_and_report, even_subset, predict_pairs
from .loss import photometric_loss, pose_loss, warp_live
from .model import CascadeVO

# the names of the configuration, checkpoint and evaluation modules this module has always exported
__all__ = ["CHECKPOINT", "METRICS", "VOConfig", "check_config", "default_config", "evaluate", "train"]


# ----------------------------------------------------------------------------- distributed


def _log(rank: int, msg: str) -> None:
    if rank == 0:
        print(msg, file=sys.stderr, flush=True)



# ----------------------------------------------------------------------------- helpers


def _lr_at(cfg: VOConfig, step: int) -> float:
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    p = min(1.0, (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup))
    return cfg.lr * (cfg.lr_final_frac + (1 - cfg.lr_final_frac) * 0.5 * (1 + math.cos(math.pi * p)))


def _gt_warps(ps: PairSet, chunk: int = 64) -> tuple[Tensor, Tensor]:
    """Live images warped with the ground-truth poses (and valid masks) for every pair."""
    n, (C, H, W) = len(ps), ps.images.shape[1:]
    warps = torch.empty(n, C, H, W, dtype=ps.images.dtype)  # filled in place: no second copy at the end
    valids = torch.empty(n, 1, H, W, dtype=torch.bool)
    with torch.no_grad():
        for i in range(0, n, chunk):
            idx = torch.arange(i, min(i + chunk, n))
            _, live, ref_d, _, pose, _ = ps.batch(idx)
            warps[idx], valids[idx] = warp_live(live, ref_d, pose, ps.K)
    return warps, valids


def _symmetric_intrinsics(K: Tensor, W: int, H: int) -> bool:
    """Mirroring the images is a valid augmentation only if the principal point is the image centre."""
    return abs(float(K[0, 2]) - (W - 1) / 2) < 1e-4 and abs(float(K[1, 2]) - (H - 1) / 2) < 1e-4 and float(K[0, 1]) == 0


def _flip(f: Tensor, *images: Tensor) -> list[Tensor]:
    """Mirror batch items left-right where ``f[:, 0]`` and upside-down where ``f[:, 1]``.

    With the principal point at the image centre, mirroring every image and depth of a pair is the
    same as mirroring the world: the pair stays consistent, its pose becomes M T M (M = diag(-1, 1, 1)
    or diag(1, -1, 1)), and the mirrored ground-truth warp is the warp with that pose.
    """
    out = []
    for x in images:
        x = torch.where(f[:, 0].view(-1, 1, 1, 1), x.flip(-1), x)
        out.append(torch.where(f[:, 1].view(-1, 1, 1, 1), x.flip(-2), x))
    return out


def _flip_pose(f: Tensor, pose: Tensor) -> Tensor:
    """The poses ``M T M`` of the pairs :func:`_flip` mirrored (M = diag(-1, 1, 1, 1) left-right,
    diag(1, -1, 1, 1) upside-down)."""
    m = torch.ones(pose.shape[0], 4, dtype=pose.dtype)
    m[f[:, 0], 0] = -1.0
    m[f[:, 1], 1] = -1.0
    return m[:, :, None] * pose * m[:, None, :]


def _stage_steps(total: int) -> list[int]:
    return sorted({0, total // 10, total // 2, total})



# ----------------------------------------------------------------------------- training


class _StopFlag:
    """SIGINT / SIGTERM set a flag; the loop checks it between steps (all ranks agree on it)."""

    def __init__(self):
        self.stop = False
        self.signal: str | None = None  # the first one received ("SIGINT" / "SIGTERM")
        self._old: dict = {}

    def _handler(self, signum, frame):
        if self.stop and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.stop = True
        self.signal = self.signal or signal.Signals(signum).name

    def __enter__(self):
        for s in (signal.SIGINT, signal.SIGTERM):
            try:
                self._old[s] = signal.signal(s, self._handler)
            except ValueError:  # not in the main thread
                pass
        return self

    def __exit__(self, *exc):
        for s, h in self._old.items():
            signal.signal(s, h)
        return False


def train(cfg: VOConfig) -> dict:
    """Run (or resume) training and evaluation; returns the metrics dict (rank 0; others get {})."""
    t_start = time.perf_counter()
    rank, world = setup()
    out = Path(cfg.out)
    threads = cfg.threads or max(1, (os.cpu_count() or 2) // world)
    torch.set_num_threads(threads)
    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)

    ckpt_path = out / CHECKPOINT
    ck = check_config(cfg, world)  # before anything is rendered
    local_batch = cfg.batch_size // world
    W, H = cfg.size

    # ---- data, rendered once
    t0 = time.perf_counter()
    common = dict(
        n_frames=cfg.n_frames, size=cfg.size, gaps=tuple(cfg.gaps), both_directions=cfg.both_directions,
        scene_seed=cfg.scene_seed, supersample=cfg.supersample, n_threads=threads, n_boxes=cfg.n_boxes,
        trajectory_kwargs=dict(cfg.trajectory_kwargs),
    )
    if cfg.data:
        kw = dict(size=cfg.size, gaps=tuple(cfg.gaps), both_directions=cfg.both_directions,
                  max_frames=cfg.data_max_frames or None)
        try:
            train_set, eval_set = read_split(list(cfg.data), **kw), read_split(list(cfg.eval_data), **kw)
        except DatasetError as e:
            raise ConfigError(str(e)) from None
        if not torch.allclose(train_set.K, eval_set.K, rtol=1e-4, atol=1e-3):
            raise ConfigError(f"--eval-data {' '.join(cfg.eval_data)}: intrinsics differ from the training "
                              f"folders' once resized to {W}x{H} (evaluate on the camera trained for)")
    else:
        train_set = render_split(cfg.motion, split_seeds(cfg.seed, "train", cfg.n_train_traj), **common)
        eval_set = render_split(cfg.motion, split_seeds(cfg.seed, "eval", cfg.n_eval_traj), **common)
    train_gt, train_valid = _gt_warps(train_set)
    eval_gt, eval_valid = _gt_warps(eval_set)
    t_data = time.perf_counter() - t0
    _log(rank, f"vo {cfg.motion}: {len(train_set)} training pairs, {len(eval_set)} held-out pairs at "
         f"{W}x{H}, rendered in {t_data:.1f} s")
    eval_idx = even_subset(len(eval_set), cfg.n_eval)
    panel_idx = eval_idx[even_subset(len(eval_idx), cfg.n_panel + 2)[1:-1]][: cfg.n_panel]

    # ---- model and optimiser (identical initial weights on every rank)
    torch.manual_seed(cfg.seed)
    model = CascadeVO(
        cfg.motion, scales=tuple(cfg.stage_scales), size=cfg.size, widths=tuple(cfg.widths),
        depth_input=cfg.depth_input,
        n_head_layers=cfg.n_head_layers, omega_scale=cfg.omega_scale, t_scale=cfg.t_scale,
        depth_normalised_t=cfg.depth_normalised_t,
    )
    net = torch.nn.parallel.DistributedDataParallel(model) if world > 1 else model
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)

    step, history, snapshots, elapsed_before = 0, [], {}, 0.0
    if ck is not None:
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        step, history, snapshots = ck["step"], list(ck["train_loss"]), dict(ck["snapshots"])
        elapsed_before = ck.get("train_seconds", 0.0)
        if rank == 0:
            set_rng_state(ck["rng"])
        _log(rank, f"resumed from {ckpt_path} at step {step}")
    elif cfg.resume:
        _log(rank, f"no checkpoint in {out}, starting from scratch")

    def save_checkpoint(train_seconds: float) -> None:
        if rank != 0:
            return
        atomic_save(
            {
                "format": CHECKPOINT_FORMAT,
                "config": dataclasses.asdict(cfg),
                "network": network_spec(cfg, train_set.K),
                "model": model.state_dict(),
                "optimizer": opt.state_dict(),
                "step": step,
                "train_loss": history,
                "snapshots": snapshots,
                "rng": rng_state(),
                "train_seconds": train_seconds,
            },
            ckpt_path,
        )

    def snapshot() -> None:
        if rank == 0 and step not in snapshots:
            snapshots[step] = predict_pairs(model, eval_set, panel_idx, cfg.refine, symmetries=cfg.symmetries)

    flips = cfg.flip_augment and _symmetric_intrinsics(train_set.K, W, H)
    stages = _stage_steps(cfg.steps)
    bar = progress_bar(total=cfg.steps, initial=step, desc=f"vo {cfg.motion}", unit="step", mininterval=0.5,
               disable=not (cfg.progress and rank == 0))
    t_train0 = time.perf_counter()
    last_ckpt_t, last_ckpt_step = t_train0, step
    interrupted = False
    net.train()
    with _StopFlag() as flag:
        while step < cfg.steps:
            if step in stages:
                snapshot()
            rng = np.random.default_rng([cfg.seed, step])
            gidx = torch.from_numpy(rng.choice(len(train_set), size=cfg.batch_size, replace=False))
            idx = gidx[rank * local_batch : (rank + 1) * local_batch]
            for g in opt.param_groups:
                g["lr"] = _lr_at(cfg, step)
            ref, live, ref_d, live_d, pose, _ = train_set.batch(idx)
            gt_w, gt_v = train_gt[idx], train_valid[idx]
            if flips:
                f = torch.from_numpy(rng.random((cfg.batch_size, 2)) < 0.5)[rank * local_batch :][:local_batch]
                ref, live, ref_d, live_d, gt_w, gt_v = _flip(f, ref, live, ref_d, live_d, gt_w, gt_v)
                pose = _flip_pose(f, pose)
            preds = net(ref, live, ref_d, live_d, train_set.K, all_stages=True)
            # every stage's estimate is scored (deep supervision); the last one is the output
            loss = sum(
                photometric_loss(p, live, ref_d, gt_w, gt_v, train_set.K, cfg.loss, cfg.loss_scale, cfg.loss_levels)[0]
                for p in preds
            ).mean() / len(preds)
            if cfg.pose_weight > 0:
                loss = loss + cfg.pose_weight * sum(
                    pose_loss(p, pose, ref_d, cfg.pose_t_weight) for p in preds
                ).mean() / len(preds)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            stat = torch.tensor([loss.item(), float(flag.stop)], dtype=torch.float64)
            if world > 1:
                dist.all_reduce(stat)
                stat[0] /= world
            history.append(float(stat[0]))
            step += 1
            bar.update()
            bar.set_postfix(loss=f"{history[-1]:.4g}", refresh=False)
            now = time.perf_counter()
            stop = bool(stat[1] > 0)
            if stop or step == cfg.steps or step - last_ckpt_step >= cfg.checkpoint_every or (
                now - last_ckpt_t >= cfg.checkpoint_seconds
            ):
                if step == cfg.steps and step in stages:
                    snapshot()
                save_checkpoint(elapsed_before + now - t_train0)
                last_ckpt_t, last_ckpt_step = now, step
            if stop:
                interrupted = True
                break
    bar.close()
    train_seconds = elapsed_before + time.perf_counter() - t_train0
    if step >= cfg.steps and cfg.steps not in snapshots:
        snapshot()
        save_checkpoint(train_seconds)
    if interrupted:
        _log(rank, f"interrupted at step {step}; checkpoint saved in {ckpt_path} (continue with --resume)")
        finish(world)
        return {"interrupted": True, "step": step, "stopped_by": flag.signal or "SIGINT"}

    ddp = {"world_size": world}
    if world > 1:  # sanity check: DDP must leave every rank with the same weights
        flat = torch.cat([p.detach().flatten() for p in model.parameters()])
        gathered = [torch.empty_like(flat) for _ in range(world)]
        dist.all_gather(gathered, flat)
        ddp["max_param_diff_between_ranks"] = max(float((g - flat).abs().max()) for g in gathered)
    metrics: dict = {}
    if rank == 0:
        metrics = evaluate_and_report(
            cfg, model, history, snapshots, train_set, train_gt, train_valid, eval_set, eval_gt, eval_valid,
            eval_idx, panel_idx, t_data, train_seconds, time.perf_counter() - t_start, step, ddp,
        )
    finish(world)
    return metrics
