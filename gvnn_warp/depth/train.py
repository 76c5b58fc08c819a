"""Training the depth network on video through the fused self-supervised objective.

Per step, a batch of triplets (t - g, t, t + g) (g = ``gap``, or with ``vary_gap`` each triplet's
own in 1..gap, at most the frames to its folder's nearer end): the depth network's four
disparities of frame t, each upsampled to full resolution and made depth (``disp_to_depth``;
divided by its mean per frame with ``normalize``), and the motion of t into each neighbour
(``pose``: "direct", the direct aligner through the predicted depth; "network", a pose network
trained with it) give :func:`gvnn_warp.reprojection_loss` at every scale, plus ``smoothness`` x
:func:`gvnn_warp.edge_aware_smoothness` of that scale's disparity / 2^scale, the mean over the
scales (Monodepth2's objective). Adam; the run ends after ``minutes`` (or ``steps``). The depth
network kept (the checkpoint's ``depth_net``, which ``depth eval`` and ``track --depth predicted``
load) is the exponential moving average of the trained one's weights and batch statistics over the
steps (``ema``, torch's ``AveragedModel``; the trained one is kept beside it, ``depth_net_trained``,
to resume from). Launched by
``torchrun`` (``RANK``/``WORLD_SIZE`` set) it trains data-parallel (DistributedDataParallel over
gloo): every rank draws the same global batch and takes its share (``batch_size`` must be divisible
by the ranks), the ranks agree on when to stop, and only rank 0 writes files and progress.
``OUT/checkpoint.pt`` is written atomically every ``checkpoint_seconds``, on Ctrl-C / SIGTERM and at
the end (loadable with ``torch.load(..., weights_only=True)``; read by :mod:`.checkpoint`);
``resume`` continues from it.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

from ..functional.lie import se3_to_matrix
from ..functional.reprojection import edge_aware_smoothness, reprojection_loss
from ..odometry.aligner import DirectAligner
from ..progress import progress_bar
from ..vo.checkpoint import CHECKPOINT, CheckpointError, atomic_save, atomic_write_text, rng_state, set_rng_state
from ..vo.distributed import all_max, average_gradients, finish, setup
from ..vo.pose import invert_pose
from .checkpoint import BEFORE, CHECKPOINT_FORMAT, load_checkpoint, load_depth_net
from .data import Video, read_video
from .model import NORMS, DepthNet, PoseNet, disp_to_depth

# (CHECKPOINT_FORMAT, load_checkpoint and load_depth_net live in .checkpoint; still exported here)
__all__ = ["CHECKPOINT_FORMAT", "POSES", "DepthConfig", "colour_jitter", "direct_poses", "load_checkpoint",
           "load_depth_net", "network_poses", "self_supervised_loss", "train"]


@dataclass
class DepthConfig:
    """Settings of :func:`train` (the command line's options)."""

    data: tuple[str, ...]
    out: str
    size: tuple[int, int] = (128, 96)  # (W, H), multiples of 32
    minutes: float = 8.0  # training time (the figure and checkpoint come after)
    gap: int = 4  # a triplet is frames (t - g, t, t + g), g = gap
    # or g drawn for each triplet from 1..gap: baselines of every length (measured on unseen rooms,
    # RESULTS.md: better than one gap of 2 or 3)
    vary_gap: bool = True
    # with vary_gap, every frame with a neighbour on each side a target (near a folder's end g is at
    # most the frames to it; measured: 4 seeds of 5 met issue 31's target 3, 3 before); False: only the
    # frames gap from both ends, as runs before 2026-11-29 (to resume them)
    all_targets: bool = True
    pose: str = "direct"  # "direct": DirectAligner on the predicted depth; "network": PoseNet (Monodepth2)
    # the warp uses each item's depth over its mean (Wang et al. 2018, who pair a depth network with
    # direct alignment): monocular depth has no scale, and without this the depth drifts to the far
    # end of its range, where parallax, and so the depth's gradient, vanishes
    normalize: bool = True
    # train on the folders' true depth instead (a scale-invariant log loss): the supervised upper
    # bound to compare the self-supervised network with, not a way to learn without labels
    supervised: bool = False
    flip: bool = True  # mirror half the triplets (pinhole cameras with a centred principal point only)
    # the depth network sees each target with random brightness, contrast and saturation (+-20%;
    # Monodepth2's colour augmentation, without hue); the objective compares the frames as recorded
    jitter: bool = False  # (measured: it cost 0.015 / 0.036 abs_rel on the unseen rooms in 8 min; RESULTS.md)
    steps: int | None = None  # or stop after this many steps
    batch_size: int = 8
    lr: float = 5e-4
    # the learning rate's cosine decay over the run (time, or steps when given), to this fraction of
    # ``lr`` at the end; 1: constant
    lr_final: float = 1.0
    seed: int = 0
    min_depth: float = 0.1  # metres: the networks' depth range
    max_depth: float = 10.0
    smoothness: float = 1e-3
    alpha: float = 0.85
    widths: tuple[int, ...] = (8, 16, 32, 64, 128)  # half of (16, ..., 256): 0.30 s a step, not 0.53
    norm: str = "batch"  # the networks' normalisation after each convolution ("batch" or "none")
    # the depth network kept is the exponential moving average of the trained one's weights and
    # batch statistics over the steps (this decay per step; 0: the last step's network)
    ema: float = 0.99
    max_frames: int | None = None  # per folder
    checkpoint_seconds: float = 60.0
    resume: bool = False
    progress: bool = True


# settings a resumed run must share with its checkpoint
_SAME_ON_RESUME = ("data", "size", "widths", "norm", "min_depth", "max_depth", "max_frames", "gap", "vary_gap",
                   "all_targets", "pose", "normalize", "supervised")

# the command-line options of settings a resumed run must repeat (for the error message)
_OPTIONS = {"norm": "--norm", "vary_gap": "--fixed-gap when False", "gap": "--gap", "size": "--size", "pose": "--pose",
            "supervised": "--supervised", "all_targets": "--inner-targets when False"}

POSES = ("direct", "network")


def network_poses(pose_net: PoseNet):
    """Poses from the pose network, which always sees a pair in time order (Monodepth2's): target ->
    the later source, and the earlier source -> target, inverted. Differentiable."""

    def poses(target: Tensor, sources: Tensor, depth: Tensor) -> Tensor:
        later = se3_to_matrix(pose_net.xi(target, sources[:, 1]))
        earlier = se3_to_matrix(invert_pose(pose_net.xi(sources[:, 0], target)))
        return torch.stack([earlier, later], 1)

    return poses


def direct_poses(aligner: DirectAligner):
    """Poses from direct alignment of each source to the target through the predicted depth
    (``DirectAligner``, coarse to fine, from the identity): no labels, no gradient. The rotation
    needs no depth; the translation follows the depth's scale, which it so keeps consistent."""

    def poses(target: Tensor, sources: Tensor, depth: Tensor) -> Tensor:
        out = []
        for s in range(sources.shape[1]):
            T, _ = aligner.align(target, depth, sources[:, s])
            out.append(torch.as_tensor(T)[:, :3].to(target.dtype))
        return torch.stack(out, 1)

    return poses


def colour_jitter(image: Tensor, amount: float = 0.2) -> Tensor:
    """(B, 3, H, W) in [0, 1] with each item's brightness, contrast and saturation scaled by its own
    random factor in [1 - amount, 1 + amount] (torch's global generator), clamped to [0, 1]."""
    B = image.shape[0]

    def factor() -> Tensor:
        return (1 + amount * (2 * torch.rand(B, 1, 1, 1) - 1)).to(image.dtype)

    x = image * factor()
    mean = x.mean((1, 2, 3), keepdim=True)
    x = (x - mean) * factor() + mean
    grey = (0.299 * x[:, :1] + 0.587 * x[:, 1:2] + 0.114 * x[:, 2:3])
    return ((x - grey) * factor() + grey).clamp(0, 1)


def self_supervised_loss(depth_net: DepthNet, poser, target: Tensor, sources: Tensor, camera, cfg: DepthConfig,
                         return_maps: bool = False, depth_input: Tensor | None = None):
    """The objective of one batch (see the module docstring): a scalar, and with ``return_maps``
    the full-resolution depth and the maps of ``reprojection_loss`` at scale 0. ``sources``: the
    frames (t - gap, t + gap) of ``target`` t; ``poser(target, sources, depth)``: their poses
    (:func:`network_poses`, :func:`direct_poses`), given the predicted depth (detached);
    ``depth_input``: what the depth network sees instead of ``target`` (e.g. :func:`colour_jitter`'s)."""
    H, W = target.shape[-2:]
    disps = depth_net(target if depth_input is None else depth_input)
    depths = []
    for scale, disp in enumerate(disps):
        up = disp if scale == 0 else F.interpolate(disp, size=(H, W), mode="bilinear", align_corners=False)
        depth = disp_to_depth(up, cfg.min_depth, cfg.max_depth)
        if cfg.normalize:  # each item's depth divided by its mean (differentiably): see DepthConfig.normalize
            depth = depth / depth.mean((1, 2, 3), keepdim=True)
        depths.append(depth)
    poses = poser(target, sources, depths[0].detach())
    total = target.new_zeros(())
    maps = depth0 = None
    for scale, (disp, depth) in enumerate(zip(disps, depths)):
        if scale == 0 and return_maps:
            rep, maps = reprojection_loss(target, sources, depth, poses, camera, alpha=cfg.alpha, return_maps=True)
            depth0 = depth.detach()
        else:
            rep = reprojection_loss(target, sources, depth, poses, camera, alpha=cfg.alpha)
        image = target if scale == 0 else F.interpolate(target, size=disp.shape[-2:], mode="bilinear",
                                                        align_corners=False, antialias=True)
        smooth = edge_aware_smoothness(disp, image)
        total = total + rep.mean() + cfg.smoothness * smooth.mean() / 2**scale
    total = total / len(disps)
    return (total, depth0, maps) if return_maps else total


def supervised_loss(depth_net: DepthNet, target: Tensor, true_depth: Tensor, cfg: DepthConfig,
                    depth_input: Tensor | None = None) -> Tensor:
    """The scale-invariant log error (Eigen et al. 2014, lambda = 1: the monocular scale is free) of
    every scale's depth against the true depth (B, 1, H, W), over its valid pixels."""
    H, W = target.shape[-2:]
    valid = (true_depth > cfg.min_depth) & (true_depth < cfg.max_depth)
    log_true = torch.where(valid, true_depth, torch.ones_like(true_depth)).log()
    n = valid.sum((1, 2, 3)).clamp(min=1)
    total = target.new_zeros(())
    disps = depth_net(target if depth_input is None else depth_input)
    for disp in disps:
        up = F.interpolate(disp, size=(H, W), mode="bilinear", align_corners=False) if disp.shape[-1] != W else disp
        diff = torch.where(valid, disp_to_depth(up, cfg.min_depth, cfg.max_depth).log() - log_true, 0)
        mean = diff.sum((1, 2, 3)) / n
        total = total + ((diff - mean.view(-1, 1, 1, 1)).abs() * valid).sum((1, 2, 3)).div(n).mean()
    return total / len(disps)


def _networks(cfg: DepthConfig) -> tuple[DepthNet, PoseNet]:
    return DepthNet(cfg.widths, cfg.min_depth, cfg.max_depth, cfg.norm), PoseNet(cfg.widths, cfg.norm)


def _resume(cfg: DepthConfig, path: Path) -> dict | None:
    if not (cfg.resume and path.exists()):
        return None
    ck = load_checkpoint(path)
    want = _config_dict(cfg)
    def setting(config: dict, key: str):
        value = config.get(key, BEFORE.get(key))
        if key == "all_targets":  # (it changes the targets only with vary_gap)
            value = bool(value and config.get("vary_gap", BEFORE["vary_gap"]))
        return value

    for key in _SAME_ON_RESUME:
        had, mine = setting(ck["config"], key), setting(want, key)
        if had != mine:
            option = _OPTIONS.get(key)
            hint = f" (command line: {option})" if option else ""
            raise CheckpointError(f"{path}: the run has {key}={had!r}{hint}, this one {mine!r}; "
                                  "resume with the same settings or start a new run in another directory")
    return ck


def _config_dict(cfg: DepthConfig) -> dict:
    d = dataclasses.asdict(cfg)
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def train(cfg: DepthConfig) -> dict:
    """Train (see the module docstring); returns the metrics written to ``OUT/metrics.json``:
    ``steps``, ``train_loss`` (per step), ``train_seconds``, ``interrupted`` and ``stopped_by``
    ("SIGINT" for Ctrl-C, "SIGTERM", or None) (rank 0; the other ranks of a data-parallel run get {})."""
    rank, world = setup()
    if world > 1:  # the cores shared between the ranks (torch's and gvnn_warp's threads)
        from ..kernels.core.threads import set_num_threads

        threads = max(1, (os.cpu_count() or 2) // world)
        torch.set_num_threads(threads)
        set_num_threads(threads)
    if cfg.batch_size % world:
        finish(world)
        raise ValueError(f"depth train: the batch size {cfg.batch_size} must be divisible by the {world} ranks")
    if isinstance(cfg.data, (str, os.PathLike)):  # (one folder given as such, not as a tuple of them)
        cfg = dataclasses.replace(cfg, data=(str(cfg.data),))
    problem = None
    if cfg.norm not in NORMS:
        problem = f"norm must be one of {list(NORMS)}, got {cfg.norm!r}"
    elif cfg.pose not in POSES:
        problem = f"pose must be one of {list(POSES)}, got {cfg.pose!r}"
    elif not (len(cfg.size) == 2 and all(isinstance(v, (int, np.integer)) and v >= 32 and v % 32 == 0
                                         for v in cfg.size)):
        problem = f"size must be (W, H), multiples of 32 (the network halves them 5 times), got {cfg.size!r}"
    elif not cfg.data:
        problem = "data must name at least one folder"
    if problem is not None:
        finish(world)
        raise ValueError(f"depth train: {problem}")
    if not 0.0 <= cfg.ema < 1.0:
        finish(world)
        raise ValueError(f"depth train: ema must be a decay in [0, 1), got {cfg.ema!r}")
    deepest = 2 ** len(cfg.widths)  # (the deepest stage's statistics must be of more than one value per channel)
    if cfg.norm == "batch" and (cfg.batch_size // world) * (cfg.size[0] // deepest) * (cfg.size[1] // deepest) < 2:
        finish(world)
        raise ValueError(f"depth train: batch normalisation needs at least 2 items per rank or a size above "
                         f"{deepest}x{deepest}, got {cfg.batch_size // world} item(s) of {cfg.size[0]}x{cfg.size[1]}")
    out = Path(cfg.out)
    ck_path = out / CHECKPOINT
    ck = _resume(cfg, ck_path)
    if cfg.resume and rank == 0:
        print(f"depth train: resuming {ck_path} at step {ck['step']}" if ck is not None else
              f"depth train: no checkpoint in {out} to resume: a new run", file=sys.stderr)
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed)
    video = read_video(list(cfg.data), cfg.size, gap=cfg.gap, vary_gap=cfg.vary_gap and cfg.all_targets,
                       max_frames=cfg.max_frames,
                       progress=cfg.progress and rank == 0, with_depth=cfg.supervised)
    out.mkdir(parents=True, exist_ok=True)  # (once the data could be read: a refused run leaves no folder)
    if ck is not None and ck.get("frames", video.images.shape[0]) != video.images.shape[0]:
        finish(world)  # (other frames: the resumed run would not draw the batches the run would have)
        raise CheckpointError(f"{ck_path}: the run trained on {ck['frames']} frames, these folders give "
                              f"{video.images.shape[0]} (other folders, or frames added or removed); resume on the "
                              "same folders or start a new run in another directory")
    camera = video.camera()
    if rank == 0 and cfg.batch_size > video.targets.numel():  # (drawn with replacement: said, not refused)
        print(f"depth train: the batch of {cfg.batch_size} triplets is larger than the {video.targets.numel()} "
              "the folders give; triplets repeat within each step", file=sys.stderr)
    # a mirrored frame is a frame of the same camera only if its principal point is centred
    flip = cfg.flip and video.dist is None and abs(float(video.K[0, 2]) - (cfg.size[0] - 1) / 2) < 1e-3
    depth_net, pose_net = _networks(cfg)
    if cfg.pose == "network":
        poser = network_poses(pose_net)
        params = [*depth_net.parameters(), *pose_net.parameters()]
    else:
        poser = direct_poses(DirectAligner(video.camera() if video.dist is not None else video.K.double().numpy(),
                                           levels=3))
        params = list(depth_net.parameters())
    if world > 1:  # (the same initial weights on every rank: the same seed; DDP averages the gradients)
        depth_net = torch.nn.parallel.DistributedDataParallel(depth_net)
    opt = torch.optim.Adam(params, lr=cfg.lr)
    # (every rank has the same weights after each step, so the same averaged weights; the batch
    # statistics are each rank's own, and rank 0's are saved, as the trained network's)
    average = AveragedModel(_module(depth_net), multi_avg_fn=get_ema_multi_avg_fn(cfg.ema), use_buffers=True) \
        if cfg.ema > 0 else None
    local = cfg.batch_size // world
    step, history, elapsed = 0, [], 0.0
    if ck is not None:
        _module(depth_net).load_state_dict(ck.get("depth_net_trained", ck["depth_net"]))
        if average is not None:
            average.module.load_state_dict(ck["depth_net"])
            average.n_averaged.fill_(ck["step"])  # (0: the next update copies)
        _module(pose_net).load_state_dict(ck["pose_net"])
        opt.load_state_dict(ck["optimizer"])
        step, history, elapsed = ck["step"], list(ck["train_loss"]), ck["train_seconds"]
        set_rng_state(ck["rng"])

    def save(seconds: float) -> None:
        if rank != 0:
            return
        atomic_save({"format": CHECKPOINT_FORMAT, "config": _config_dict(cfg), "step": step, "train_loss": history,
                     "train_seconds": seconds, "depth_net": _kept(depth_net, average).state_dict(),
                     **({"depth_net_trained": _module(depth_net).state_dict()} if average is not None else {}),
                     "pose_net": _module(pose_net).state_dict(),
                     "optimizer": opt.state_dict(), "rng": rng_state(), "K": video.K,
                     "dist": video.dist if video.dist is not None else torch.zeros(0),
                     "frames": int(video.images.shape[0])}, ck_path)

    stop = {"flag": False}
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM,)}
    signal.signal(signal.SIGTERM, lambda *_: stop.update(flag=True))
    budget = 60.0 * cfg.minutes
    bar = progress_bar(desc="depth train", unit="step", initial=step, total=cfg.steps,
                       disable=not (cfg.progress and rank == 0),
               mininterval=0.5)
    t0 = last_ck = time.perf_counter()
    interrupted = False
    try:
        depth_net.train()
        pose_net.train()
        while True:
            finished = elapsed + time.perf_counter() - t0 >= budget or (cfg.steps is not None and step >= cfg.steps)
            if all_max(float(stop["flag"] or finished), world):  # (every rank stops at the same step)
                break
            # the same global batch on every rank (the same seed), each rank its share
            idx = torch.randint(len(video.targets), (cfg.batch_size,))
            idx = idx[rank * local:(rank + 1) * local]
            gaps = None
            if cfg.vary_gap:  # (drawn for the global batch, as idx: the same on every rank)
                drawn = torch.randint(1, cfg.gap + 1, (cfg.batch_size,))[rank * local:(rank + 1) * local]
                gaps = video.draw_gaps(idx, drawn)
            target, sources = video.triplets(idx, gaps)
            if flip:  # half the triplets mirrored left-right (Monodepth2's augmentation)
                mirror = (torch.rand(cfg.batch_size) < 0.5).view(-1, 1, 1, 1)[rank * local:(rank + 1) * local]
                target = torch.where(mirror, target.flip(-1), target)
                sources = torch.where(mirror.unsqueeze(1), sources.flip(-1), sources)
            seen = colour_jitter(target) if cfg.jitter else None
            if cfg.supervised:
                depths = video.depths[video.targets[idx]]
                if flip:
                    depths = torch.where(mirror, depths.flip(-1), depths)
                loss = supervised_loss(depth_net, target, depths, cfg, depth_input=seen)
            else:
                loss = self_supervised_loss(depth_net, poser, target, sources, camera, cfg, depth_input=seen)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if world > 1 and cfg.pose == "network":  # (DDP averages only what runs through its forward)
                average_gradients(_module(pose_net), world)
            if cfg.lr_final != 1.0:  # (the ranks' clocks differ: the largest fraction, the same on every rank)
                done_frac = all_max(min(1.0, step / cfg.steps) if cfg.steps is not None else
                                    min(1.0, (elapsed + time.perf_counter() - t0) / budget), world)
                scale = cfg.lr_final + (1 - cfg.lr_final) * 0.5 * (1 + math.cos(math.pi * done_frac))
                for group in opt.param_groups:
                    group["lr"] = cfg.lr * scale
            opt.step()
            if average is not None:
                average.update_parameters(_module(depth_net))
            step += 1
            history.append(float(loss.detach()))
            bar.update()
            bar.set_postfix(loss=f"{history[-1]:.4f}", refresh=False)
            if time.perf_counter() - last_ck >= cfg.checkpoint_seconds:
                save(elapsed + time.perf_counter() - t0)
                last_ck = time.perf_counter()
        # (a SIGTERM in the last step: the run is complete, not stopped)
        interrupted = bool(all_max(float(stop["flag"] and not finished), world))
        stopped_by = "SIGTERM" if interrupted else None
    except KeyboardInterrupt:
        interrupted, stopped_by = True, "SIGINT"
    finally:
        bar.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        seconds = elapsed + time.perf_counter() - t0
        save(seconds)
    metrics = {"steps": step, "train_loss": history, "train_seconds": seconds, "interrupted": interrupted,
               "stopped_by": stopped_by,
               "frames": int(video.images.shape[0]), "triplets": int(video.targets.numel()),
               "size": list(cfg.size), "config": _config_dict(cfg)}
    if world > 1:  # sanity check: DDP must leave every rank with the same weights
        import torch.distributed as dist

        nets = [_module(depth_net)] + ([_module(pose_net)] if cfg.pose == "network" else [])
        flat = torch.cat([p.detach().reshape(-1) for net in nets for p in net.parameters()])
        gathered = [torch.empty_like(flat) for _ in range(world)]
        dist.all_gather(gathered, flat)
        metrics["distributed"] = {"world_size": world,
                                  "max_param_diff_between_ranks": max(float((g - flat).abs().max()) for g in gathered)}
    if rank == 0:
        atomic_write_text(json.dumps(metrics, indent=1), out / "metrics.json")
        if not interrupted:
            pose_net.eval()  # (the figure's poses, with pose="network": the running statistics)
            _training_figure(_kept(depth_net, average), poser, video, camera, cfg, out / "training.png")
    finish(world)
    return metrics if rank == 0 else {}


def _kept(depth_net, average):
    """The depth network a checkpoint keeps: the moving average (``DepthConfig.ema``) or the trained one."""
    return average.module if average is not None else _module(depth_net)


def _module(net):
    """The network inside a DistributedDataParallel wrapper (or the network itself)."""
    return getattr(net, "module", net)


def _training_figure(depth_net, poser, video: Video, camera, cfg: DepthConfig, path: Path) -> None:
    from .plots import depth_panel  # (matplotlib is slow to import: only for the figure)

    depth_net.eval()
    with torch.no_grad():
        # (the first target with the widest baseline: frame `gap` of the first folder if it is that long)
        first = torch.tensor([0 if video.reach is None else int(video.reach.argmax())])
        target, sources = video.triplets(first)
        _, depth, maps = self_supervised_loss(depth_net, poser, target, sources, camera, cfg, return_maps=True)
    frame = int(video.targets[first[0]])
    depth_panel(target[0], depth[0, 0], video.true_depth(frame), maps["automask"][0, 0].bool(), path,
                title=f"depth after training ({video.roots[0].name}, frame {frame})")
