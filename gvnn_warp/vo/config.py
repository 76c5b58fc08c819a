"""The configuration of a ``gvnn-warp vo`` run (:class:`VOConfig`), its tuned defaults per motion,
and every check that can be made before rendering: the options together, the data's size, and the
checkpoint a run resumes from.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .checkpoint import CHECKPOINT, CheckpointError, read_checkpoint
from .data import tum_frames
from .loss import DEFAULT_LOSS, LOSSES
from .model import SYMMETRIES

__all__ = ["MAX_DATA_BYTES", "RESUME_KEYS", "ConfigError", "VOConfig", "check_config", "default_config", "n_pairs"]

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
    """Frames with ground truth used from each TUM folder (DatasetError for a folder that cannot be
    used)."""
    out = []
    for root in roots:
        _, frames = tum_frames(root, cfg.data_max_frames or None)
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
    ``cfg.out``. Raises :class:`ConfigError` (``DatasetError``/``CheckpointError`` for a folder or
    checkpoint that cannot be used); returns the checkpoint to resume from (or None)."""
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
    except CheckpointError as e:  # a data error (one line, status 1), not the options'
        raise CheckpointError(f"cannot resume: {e}; start a new run in another directory") from None
    for key in RESUME_KEYS:
        if tuple(np.atleast_1d(ck["config"].get(key))) != tuple(np.atleast_1d(getattr(cfg, key))):
            raise ConfigError(f"cannot resume: checkpoint has {key}={ck['config'].get(key)!r}, "
                              f"this run {getattr(cfg, key)!r} (repeat the options the run was started with)")
    return ck
