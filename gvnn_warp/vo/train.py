"""Training of the siamese VO network through the 3D spatial transformer (the paper's application).

:func:`train` renders the data once (:mod:`.data`), precomputes the ground-truth warps, trains with
Adam on the photometric cost (:mod:`.loss`), checkpoints atomically and resumes, evaluates on
held-out trajectories against the identity (zero-motion) prediction, and writes ``metrics.json``
and figures into the output directory. Launched by ``torchrun`` (``RANK``/``WORLD_SIZE`` set) it
trains with DistributedDataParallel over gloo; only rank 0 writes files and progress.

Determinism: the pairs of step ``s`` are drawn from ``numpy.random.default_rng([seed, s])``, so a
resumed run draws exactly the batches the uninterrupted run would have; the global batch is split
between the ranks.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import random
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch import Tensor

from .checkpoint import CHECKPOINT_FORMAT, CheckpointError, network_spec, read_checkpoint
from .data import PairSet, read_split, render_split, split_seeds, tum_frames
from .loss import DEFAULT_LOSS, LOSSES, photometric_loss, pose_errors, pose_loss, warp_live
from .model import SYMMETRIES, CascadeVO

__all__ = ["CHECKPOINT", "METRICS", "VOConfig", "check_config", "default_config", "evaluate", "train"]

CHECKPOINT = "checkpoint.pt"
METRICS = "metrics.json"
# the checkpoint's format (CHECKPOINT_FORMAT) and contents: .checkpoint and docs/vo_checkpoint.md
MAX_DATA_BYTES = 8 * 2**30  # rendered frames and ground-truth warps kept in memory


@dataclass
class VOConfig:
    """Everything a run depends on (saved in the checkpoint and in ``metrics.json``)."""

    motion: str
    out: str
    steps: int = 600
    size: tuple[int, int] = (128, 96)
    seed: int = 0
    loss: str = DEFAULT_LOSS
    loss_scale: float = 0.1  # M-estimator epsilon / c (intensity units)
    loss_levels: int = 1  # >1: also compare 2x2, 4x4, ... means of the two warps
    pose_weight: float = 0.0  # weight of the pose term (.loss.pose_loss) added to the photometric cost ...
    pose_t_weight: float = 1.0  # ... and of its translation part relative to its rotation part
    batch_size: int = 16  # global batch (split between DDP ranks)
    lr: float = 1e-3
    warmup: int = 20  # linear lr warm-up steps, then cosine decay to lr_final_frac * lr
    lr_final_frac: float = 0.02
    weight_decay: float = 0.0
    n_train_traj: int = 8
    n_eval_traj: int = 2
    n_frames: int = 80
    gaps: tuple[int, ...] = (1,)  # pairs (k, k + g) for every g
    both_directions: bool = True
    flip_augment: bool = True  # random left-right / up-down mirroring of training pairs
    scene_seed: int = 0
    n_boxes: int = 6  # boxes in the room (make_room_scene)
    trajectory_kwargs: dict = field(default_factory=dict)  # extra arguments of the trajectory generator
    supersample: int = 2
    widths: tuple[int, ...] = (16, 32, 64, 128)
    depth_input: bool = True
    n_head_layers: int = 2  # convolutions per siamese head before the features are concatenated
    stage_scales: tuple[int, ...] = (1,)  # CascadeVO: per network its downsampling; later ones refine the pose
    refine: int = 0  # predictions (evaluation, panel) apply the last stage this many more times
    symmetries: tuple[str, ...] = ()  # ... averaged over these exact symmetries of a pair (CascadeVO.predict)
    omega_scale: float = 0.1  # network output units: radians ...
    t_scale: float = 0.05  # ... and metres per unit of the raw regression output ...
    depth_normalised_t: bool = True  # ... times the median reference depth (m) for translations
    n_eval: int = 128  # held-out pairs evaluated
    n_panel: int = 3  # held-out pairs shown in the registration panel
    checkpoint_every: int = 50  # steps
    checkpoint_seconds: float = 30.0
    resume: bool = False
    progress: bool = True
    threads: int = 0  # torch threads (and render threads) per process; 0: cores / ranks
    data: tuple[str, ...] = ()  # TUM-format folders to train on instead of rendered trajectories ...
    eval_data: tuple[str, ...] = ()  # ... and to evaluate on (default: the last of ``data``, held out)
    data_max_frames: int = 0  # frames used per folder (0: all)
    extra: dict = field(default_factory=dict)


class ConfigError(ValueError):
    """Options that cannot work together (or with the checkpoint being resumed); the CLI prints
    the message without a traceback."""


# Settings a resumed run must share with its checkpoint: the network's shape and the data it trains
# and is scored on (the same seed and trajectories re-render the same pairs).
RESUME_KEYS = (
    "motion", "size", "depth_input", "widths", "n_head_layers", "depth_normalised_t", "stage_scales",
    "seed", "n_train_traj", "n_eval_traj", "n_frames", "gaps", "both_directions", "scene_seed", "n_boxes",
    "supersample", "trajectory_kwargs", "data", "eval_data", "data_max_frames",
)


def default_config(motion: str, out: str, **overrides) -> VOConfig:
    """The tuned defaults for ``motion`` (``so3`` or ``se3``), with ``overrides`` (None = keep)."""
    per_motion: dict[str, dict] = {
        # steps: fit inside 5 minutes on 2 cores. A second network refines the pose on the live image
        # warped with the first estimate (CascadeVO), applied twice more when predicting (refine):
        # for se3 a single network learned the rotation but left the translation error at the
        # identity's; for so3 it took the held-out rotation error from 22% to 17% of the identity's.
        # The pose term (pose_weight) adds the distance of the estimate from the truth to the
        # photometric cost. se3 pairs span gaps up to 10 frames (15-40 cm, 6-16 deg), where the
        # direct aligner's basin ends (gvnn-warp track --method vo+direct).
        "so3": dict(gaps=(1,), steps=1400, stage_scales=(1, 1), refine=2, pose_weight=1.0),
        # symmetries (se3): the estimate averaged over the pair, the pair reversed, and both mirrored
        # upside down (4 network passes): held-out translation error 35% -> 22% of the identity's,
        # rotation 11% -> 6.7% (the same trained network; so3 is at 4% without it)
        "se3": dict(gaps=(1, 2, 3, 5, 7, 10), steps=1800, stage_scales=(1, 1), n_train_traj=16, refine=2,
                    pose_weight=1.0, symmetries=("swap", "mirror_y")),
    }
    if motion not in per_motion:
        raise ConfigError(f"motion must be one of {sorted(per_motion)}, got {motion!r}")
    kw = {**per_motion[motion], **{k: v for k, v in overrides.items() if v is not None}}
    cfg = VOConfig(motion=motion, out=out, **kw)
    cfg.gaps = tuple(sorted({int(g) for g in cfg.gaps}))
    cfg.data, cfg.eval_data = tuple(str(d) for d in cfg.data), tuple(str(d) for d in cfg.eval_data)
    if cfg.data and not cfg.eval_data:
        if len(cfg.data) < 2:
            raise ConfigError("--data with one folder needs --eval-data DIR (a held-out sequence to evaluate on), "
                              "or give at least two folders (the last one is held out)")
        cfg.data, cfg.eval_data = cfg.data[:-1], cfg.data[-1:]
    if cfg.eval_data and not cfg.data:
        raise ConfigError("--eval-data needs --data (training folders)")
    if not cfg.gaps or min(cfg.gaps) < 1:
        raise ConfigError(f"--gaps must be positive frame gaps, got {cfg.gaps!r}")
    if cfg.loss not in LOSSES:
        raise ConfigError(f"loss must be one of {LOSSES}, got {cfg.loss!r}")
    if len(cfg.stage_scales) < 2 and overrides.get("refine") is None:
        cfg.refine = 0  # the per-motion default refines with a second stage; a single network cannot
    cfg.symmetries = tuple(cfg.symmetries)
    unknown = [n for n in cfg.symmetries if n not in SYMMETRIES]
    if unknown:
        raise ConfigError(f"--symmetries: unknown {', '.join(unknown)} (expected some of {', '.join(SYMMETRIES)})")
    if cfg.refine < 0 or (cfg.refine and len(cfg.stage_scales) < 2):
        raise ConfigError(f"--refine {cfg.refine!r} must be >= 0 and needs a cascade of at least 2 networks "
                          f"(--stages), got {len(cfg.stage_scales)}")
    return cfg


def n_pairs(cfg: VOConfig, n_traj: int) -> int:
    """Pairs rendered from ``n_traj`` trajectories (see :mod:`.data`)."""
    per_traj = sum(max(0, cfg.n_frames - g) for g in cfg.gaps)
    return n_traj * per_traj * (2 if cfg.both_directions else 1)


def _folder_frames(cfg: VOConfig, roots) -> list[int]:
    """Frames with ground truth used from each TUM folder (DatasetError as ConfigError)."""
    from ..datasets.tum import DatasetError

    out = []
    for root in roots:
        try:
            _, frames = tum_frames(root, cfg.data_max_frames or None)
        except DatasetError as e:
            raise ConfigError(str(e)) from None
        out.append(int(frames.size))
    return out


def _pairs_of(cfg: VOConfig, frames: list[int]) -> int:
    return sum(max(0, n - g) for n in frames for g in cfg.gaps) * (2 if cfg.both_directions else 1)


def _data_bytes(cfg: VOConfig, frames: int | None = None, pairs: int | None = None) -> int:
    """Memory of the rendered frames (RGB + depth, float32) and ground-truth warps (RGB + mask)."""
    W, H = cfg.size
    if frames is None:
        frames = (cfg.n_train_traj + cfg.n_eval_traj) * cfg.n_frames
        pairs = n_pairs(cfg, cfg.n_train_traj) + n_pairs(cfg, cfg.n_eval_traj)
    return W * H * (frames * 4 * 4 + pairs * (3 * 4 + 1))


def check_config(cfg: VOConfig, world: int | None = None) -> dict | None:
    """Every check of ``cfg`` that can be made before rendering: the options together, the number of
    ranks (``world``, default: ``WORLD_SIZE``), and, with ``cfg.resume``, the checkpoint in
    ``cfg.out``. Raises :class:`ConfigError`; returns the checkpoint to resume from (or None)."""
    world = world if world is not None else int(os.environ.get("WORLD_SIZE", "1"))
    gap = max(cfg.gaps)
    if cfg.batch_size % world:
        raise ConfigError(f"--batch-size {cfg.batch_size} must be divisible by the {world} ranks")
    if cfg.data:
        train_frames, eval_frames = _folder_frames(cfg, cfg.data), _folder_frames(cfg, cfg.eval_data)
        n_train, n_eval = _pairs_of(cfg, train_frames), _pairs_of(cfg, eval_frames)
        if n_eval == 0:
            raise ConfigError(f"--eval-data {' '.join(cfg.eval_data)}: no frame pairs {gap} or fewer frames apart "
                              "with ground truth")
        nbytes = _data_bytes(cfg, sum(train_frames) + sum(eval_frames), n_train + n_eval)
        more = "more or longer --data folders"
    else:
        if cfg.n_frames <= gap:
            raise ConfigError(f"--frames {cfg.n_frames} is too few: pairs are up to {gap} frames apart (--gaps), so "
                              f"each trajectory needs at least {gap + 1} frames")
        n_train, nbytes = n_pairs(cfg, cfg.n_train_traj), _data_bytes(cfg)
        more = "render more (--trajectories, --frames)"
    if n_train < cfg.batch_size:
        raise ConfigError(f"{n_train} training pairs are fewer than --batch-size {cfg.batch_size}: "
                          f"{more} or use a smaller batch")
    if nbytes > MAX_DATA_BYTES:
        raise ConfigError(f"this run would keep {nbytes / 2**30:.0f} GiB of frames and warps in "
                          f"memory (at most {MAX_DATA_BYTES / 2**30:.0f}): use a smaller --size, fewer --frames, "
                          "--trajectories or --data folders")
    return _resume_checkpoint(cfg)


def _resume_checkpoint(cfg: VOConfig) -> dict | None:
    """The checkpoint in ``cfg.out`` if ``cfg.resume`` and it exists; ConfigError if it cannot be
    resumed with ``cfg`` (another format, other data or network)."""
    path = Path(cfg.out) / CHECKPOINT
    if not (cfg.resume and path.exists()):
        return None
    try:
        ck = read_checkpoint(path)
    except CheckpointError as e:
        raise ConfigError(f"cannot resume: {e}; start a new run in another directory") from None
    for key in RESUME_KEYS:
        if tuple(np.atleast_1d(ck["config"].get(key))) != tuple(np.atleast_1d(getattr(cfg, key))):
            raise ConfigError(f"cannot resume: checkpoint has {key}={ck['config'].get(key)!r}, "
                              f"this run {getattr(cfg, key)!r} (repeat the options the run was started with)")
    return ck


# ----------------------------------------------------------------------------- distributed


def _dist_setup() -> tuple[int, int]:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("gloo")
    if dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def _log(rank: int, msg: str) -> None:
    if rank == 0:
        print(msg, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- checkpoints


def _atomic_save(obj, path: Path) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def _atomic_write_text(text: str, path: Path) -> None:
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)


def _rng_state() -> dict:
    """The global generators' states as tensors and plain Python values (see CHECKPOINT_FORMAT)."""
    name, keys, pos, has_gauss, cached = np.random.get_state()
    numpy_state = {"name": name, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
                   "has_gauss": int(has_gauss), "cached_gaussian": float(cached)}
    return {"torch": torch.get_rng_state(), "numpy": numpy_state, "python": random.getstate()}


def _set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    n = state["numpy"]
    np.random.set_state((n["name"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"],
                         n["cached_gaussian"]))
    version, internal, gauss = state["python"]
    random.setstate((version, tuple(internal), gauss))


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


def _even_subset(n_total: int, n: int) -> Tensor:
    return torch.from_numpy(np.unique(np.linspace(0, n_total - 1, min(n, n_total)).round().astype(np.int64)))


def _predict(model: CascadeVO, ps: PairSet, idx: Tensor, refine: int = 0, chunk: int = 64,
             symmetries: tuple[str, ...] = ()) -> Tensor:
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


def _stage_steps(total: int) -> list[int]:
    return sorted({0, total // 10, total // 2, total})


# ----------------------------------------------------------------------------- training


class _StopFlag:
    """SIGINT / SIGTERM set a flag; the loop checks it between steps (all ranks agree on it)."""

    def __init__(self):
        self.stop = False
        self._old: dict = {}

    def _handler(self, signum, frame):
        if self.stop and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.stop = True

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
    rank, world = _dist_setup()
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
        from ..datasets.tum import DatasetError

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
    eval_idx = _even_subset(len(eval_set), cfg.n_eval)
    panel_idx = eval_idx[_even_subset(len(eval_idx), cfg.n_panel + 2)[1:-1]][: cfg.n_panel]

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
            _set_rng_state(ck["rng"])
        _log(rank, f"resumed from {ckpt_path} at step {step}")
    elif cfg.resume:
        _log(rank, f"no checkpoint in {out}, starting from scratch")

    def save_checkpoint(train_seconds: float) -> None:
        if rank != 0:
            return
        _atomic_save(
            {
                "format": CHECKPOINT_FORMAT,
                "config": dataclasses.asdict(cfg),
                "network": network_spec(cfg, train_set.K),
                "model": model.state_dict(),
                "optimizer": opt.state_dict(),
                "step": step,
                "train_loss": history,
                "snapshots": snapshots,
                "rng": _rng_state(),
                "train_seconds": train_seconds,
            },
            ckpt_path,
        )

    def snapshot() -> None:
        if rank == 0 and step not in snapshots:
            snapshots[step] = _predict(model, eval_set, panel_idx, cfg.refine, symmetries=cfg.symmetries)

    flips = cfg.flip_augment and _symmetric_intrinsics(train_set.K, W, H)
    stages = _stage_steps(cfg.steps)
    from tqdm import tqdm

    bar = tqdm(total=cfg.steps, initial=step, desc=f"vo {cfg.motion}", unit="step", mininterval=0.5,
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
        _finish_dist(world)
        return {"interrupted": True, "step": step}

    ddp = {"world_size": world}
    if world > 1:  # sanity check: DDP must leave every rank with the same weights
        flat = torch.cat([p.detach().flatten() for p in model.parameters()])
        gathered = [torch.empty_like(flat) for _ in range(world)]
        dist.all_gather(gathered, flat)
        ddp["max_param_diff_between_ranks"] = max(float((g - flat).abs().max()) for g in gathered)
    metrics: dict = {}
    if rank == 0:
        metrics = _evaluate_and_report(
            cfg, model, history, snapshots, train_set, train_gt, train_valid, eval_set, eval_gt, eval_valid,
            eval_idx, panel_idx, t_data, train_seconds, time.perf_counter() - t_start, step, ddp,
        )
    _finish_dist(world)
    return metrics


def _finish_dist(world: int) -> None:
    if world > 1 and dist.is_initialized():
        dist.barrier()
        dist.destroy_process_group()


def _evaluate_and_report(
    cfg, model, history, snapshots, train_set, train_gt, train_valid, eval_set, eval_gt, eval_valid,
    eval_idx, panel_idx, t_data, train_seconds, t_so_far, step, ddp,
) -> dict:
    from .plots import plot_panel, plot_training_curve

    t0 = time.perf_counter()
    zero = torch.zeros(len(eval_idx), model.out_dim, dtype=torch.float32)
    trained = _predict(model, eval_set, eval_idx, cfg.refine, symmetries=cfg.symmetries)
    train_idx = _even_subset(len(train_set), cfg.n_eval)
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
            _predict(model, train_set, train_idx, cfg.refine, symmetries=cfg.symmetries), train_set, train_gt,
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
    _atomic_write_text(json.dumps(metrics, indent=1), out / METRICS)
    return metrics

