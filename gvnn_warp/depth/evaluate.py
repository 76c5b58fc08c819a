"""Evaluation of a trained depth network against true depth: the standard metrics of the field
(Eigen et al. 2014, with Monodepth2's names), each image's prediction scaled by the ratio of the
medians of true and predicted depth over its valid pixels (monocular depth has no scale).

For an image with valid true depth d* (finite, in [min_depth, max_depth]) and scaled prediction d
(clamped to the same range), over its valid pixels: ``abs_rel`` = mean |d - d*| / d*, ``sq_rel`` =
mean (d - d*)^2 / d*, ``rmse`` = sqrt(mean (d - d*)^2), ``rmse_log`` = sqrt(mean (log d - log d*)^2),
``a1``, ``a2``, ``a3`` = the fraction with max(d / d*, d* / d) < 1.25, 1.25^2, 1.25^3. The reported
values are means over the images; ``median_scale`` is the mean of the images' scales and
``median_scale_spread`` their standard deviation over their mean. A test set of several folders is
measured as one set of images (every image weighs the same, as the field averages over a test
split's images), each folder's own means reported beside.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from torch import Tensor

from ..datasets.tum import read_tum
from ..progress import progress_bar
from ..vo.checkpoint import atomic_write_text
from .checkpoint import load_checkpoint, load_depth_net
from .data import read_video

__all__ = ["METRICS", "depth_metrics", "evaluate", "repeated_folder"]

METRICS = ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")


def depth_metrics(pred: Tensor, true: Tensor, min_depth: float, max_depth: float) -> dict | None:
    """The metrics of one image (see the module docstring) and its ``scale``; None when it has no
    valid true depth. ``pred`` and ``true``: same shape, metres."""
    valid = torch.isfinite(true) & (true >= min_depth) & (true <= max_depth)
    if not valid.any():
        return None
    t = true[valid].double()
    p = pred[valid].double()
    scale = float(t.median() / p.median())
    p = (p * scale).clamp(min_depth, max_depth)
    ratio = torch.maximum(p / t, t / p)
    return {
        "abs_rel": float(((p - t).abs() / t).mean()),
        "sq_rel": float(((p - t) ** 2 / t).mean()),
        "rmse": float(((p - t) ** 2).mean().sqrt()),
        "rmse_log": float(((p.log() - t.log()) ** 2).mean().sqrt()),
        "a1": float((ratio < 1.25).double().mean()),
        "a2": float((ratio < 1.25**2).double().mean()),
        "a3": float((ratio < 1.25**3).double().mean()),
        "scale": scale,
    }


def summarise(per_image: list[dict]) -> dict:
    """Means over images of :func:`depth_metrics`' results, with ``median_scale`` and its spread."""
    n = len(per_image)
    out = {k: sum(m[k] for m in per_image) / n for k in METRICS}
    scales = torch.tensor([m["scale"] for m in per_image], dtype=torch.float64)
    out["median_scale"] = float(scales.mean())
    out["median_scale_spread"] = float(scales.std(unbiased=False) / scales.mean())
    out["images"] = n
    return out


def evaluate(checkpoint: str | Path, data, out: str | Path, *, progress: bool = True,
             batch_size: int = 16) -> dict:
    """Predict the depth of every frame of the folder ``data`` (or of each folder of a list of them)
    at the network's size and, where the folders have depth files, write ``OUT/metrics.json`` (see
    the module docstring: the means over every image of every folder, ``None`` without true depth;
    with several folders, each one's own under ``per_folder``, keyed by its path) and
    ``OUT/depth.png`` (the first folder's middle frame, its depth, the true depth, the error). The
    folders are read one at a time: they need not share a camera."""
    ck = load_checkpoint(checkpoint)
    net = load_depth_net(ck)
    c = ck["config"]
    size = tuple(c["size"])
    folders = [Path(data)] if isinstance(data, (str, Path)) else [Path(d) for d in data]
    if not folders:
        raise ValueError("evaluate: data must name at least one folder")
    twice = repeated_folder(folders)
    if twice is not None:
        raise ValueError(f"evaluate: data names the folder {twice[0]} twice (also as {twice[1]})")
    has_depth = {folder: (folder / "depth.txt").exists() for folder in folders}  # (else a colour video: no metrics)
    for folder in folders:  # (each folder's lists read before any frame: a bad one fails first)
        read_tum(folder, colour_only=not has_depth[folder])
    every, per_folder, shown = [], {}, None
    for folder in folders:
        video = read_video([folder], size, with_depth=has_depth[folder], progress=progress)
        preds = []
        with torch.no_grad():
            for i in progress_bar(range(0, video.images.shape[0], batch_size), desc=f"depth eval {folder.name}",
                                  unit="batch", disable=not progress, mininterval=0.5):
                preds.append(net.depth(video.images[i:i + batch_size]))
        pred = torch.cat(preds)
        true = video.depths if has_depth[folder] else torch.zeros_like(pred)  # (zeros: no valid true depth)
        mine = [depth_metrics(pred[i], true[i], c["min_depth"], c["max_depth"]) for i in range(pred.shape[0])]
        every += mine
        per_folder[str(folder)] = _summary(mine, pred.shape[0])
        if shown is None:  # the figure's frame: the first folder's middle one
            i = pred.shape[0] // 2
            shown = (folder, i, video.images[i], pred[i, 0], true[i, 0], mine[i])
    metrics = _summary(every, len(every))
    metrics.update(checkpoint=str(checkpoint), data=[str(f) for f in folders], size=list(size),
                   train_steps=ck["step"])
    if len(folders) > 1:
        metrics["per_folder"] = per_folder
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(json.dumps(metrics, indent=1), out / "metrics.json")
    from .plots import depth_panel  # (matplotlib is slow to import: only for the figure)

    folder, i, image, pred, true, m = shown
    err = None
    if m is not None:  # the error of the prediction scaled as the metrics scaled it
        err = torch.where(true > 0, (pred * m["scale"] - true).abs() / true.clamp(min=1e-6), torch.nan)
    depth_panel(image, pred, true if (true > 0).any() else None, err, out / "depth.png",
                title=f"{folder.name}, frame {i}", last_title="|error| / true depth (median-scaled)",
                last_cmap="viridis")
    return metrics


def repeated_folder(folders) -> tuple[Path, Path] | None:
    """(earlier, later): the first of ``folders`` (paths) that names a folder named before it (once
    resolved), with that earlier path; None if every folder is named once."""
    seen = {}
    for folder in map(Path, folders):
        earlier = seen.setdefault(folder.resolve(), folder)
        if earlier is not folder:
            return earlier, folder
    return None


def _summary(every: list[dict | None], frames: int) -> dict:
    """:func:`summarise` over the images with true depth (``None`` values when there is none), and
    the frames predicted."""
    per_image = [m for m in every if m is not None]
    metrics = summarise(per_image) if per_image else {k: None for k in (*METRICS, "median_scale")}
    metrics["frames"] = frames
    return metrics
