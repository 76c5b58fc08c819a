"""The relative pose of two rendered views recovered by gradient descent (``gvnn-warp align``).

Two views of the synthetic room (``gvnn_warp.synthetic``) are rendered a known motion apart
(:func:`.views.make_views`); starting from the identity, a 6-vector ``xi = [omega, t]`` (radians, metres)
is fitted by Adam on the photometric error of ``warp_frame_depth(live, ref_depth, se3_to_matrix(xi),
K)`` against the reference image, coarse to fine over an image pyramid (:func:`fit_pose`).
:func:`align_demo` does it all and writes ``align.png`` (:func:`figure`: reference, live, warped
before and after, residuals).

Example::

    from pathlib import Path
    from gvnn_warp.demos.align import align_demo

    result = align_demo(Path("out"), size=(64, 48), steps=20, levels=2)
    print(result.errors_after)  # (degrees, metres)
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from matplotlib.figure import Figure

from ..functional import se3_to_matrix, warp_frame_depth
from ..progress import progress_bar
from .views import make_views, max_levels, pose_error

__all__ = ["AlignResult", "align_demo", "figure", "fit_pose", "save_figure"]

RESIDUAL_MAX = 0.3  # colour scale of the residual panels (intensities are in [0, 1])


def fit_pose(ref: torch.Tensor, depth: torch.Tensor, live: torch.Tensor, K: torch.Tensor, *, levels: int,
             steps: int, T_gt: np.ndarray | None = None, progress: bool | None = None) -> torch.Tensor:
    """``xi`` (1, 6) = [omega (radians), t (metres)] such that ``warp_frame_depth(live, depth,
    se3_to_matrix(xi), K)`` matches ``ref``: Adam from the identity, ``steps`` steps on each of
    ``levels`` pyramid levels (area-averaged images, subsampled depth), coarse to fine, the rate
    shrinking at each finer level. ``ref``, ``live`` (1, 3, H, W), ``depth`` (1, 1, H, W) metres, ``K``
    (3, 3) pixels, float32. ``T_gt``: the true (3, 4) pose, for the progress bar's errors;
    ``progress``: a tqdm bar (None: only on a terminal)."""
    xi = torch.zeros(1, 6, dtype=torch.float32, requires_grad=True)
    optim = torch.optim.Adam([xi], lr=0.01)
    with progress_bar(total=levels * steps, desc="align", unit="step", mininterval=0.5,
              disable=None if progress is None else not progress) as bar:
        for level in reversed(range(levels)):
            s = 2**level
            for group in optim.param_groups:  # finer levels refine: smaller steps
                group["lr"] = 0.01 * 0.4 ** (levels - 1 - level)
            # pyramid: area-averaged images, depth subsampled (averaging would blend across edges)
            ref_l = F.avg_pool2d(ref, s) if s > 1 else ref
            live_l = F.avg_pool2d(live, s) if s > 1 else live
            depth_l = depth[..., s // 2 :: s, s // 2 :: s][..., : ref_l.shape[-2], : ref_l.shape[-1]]
            K_l = K.clone()
            K_l[:2] /= s
            K_l[0, 2] = (K[0, 2] - (s - 1) / 2) / s  # pixel centres of the coarse grid
            K_l[1, 2] = (K[1, 2] - (s - 1) / 2) / s
            for _ in range(steps):
                warped, valid = warp_frame_depth(live_l, depth_l, se3_to_matrix(xi), K_l)
                mask = valid.to(ref_l.dtype)
                loss = ((warped - ref_l).square() * mask).sum() / mask.sum().clamp_min(1)
                optim.zero_grad()
                loss.backward()
                optim.step()
                postfix = {"level": level, "loss": f"{loss.item():.4f}"}
                if T_gt is not None:
                    rot, trans = pose_error(se3_to_matrix(xi.detach())[0].double().numpy(), T_gt)
                    postfix.update(rot_err=f"{rot:.2f}deg", trans_err=f"{100 * trans:.2f}cm")
                bar.set_postfix(**postfix)
                bar.update()
    return xi.detach()


@dataclass
class AlignResult:
    """What :func:`align_demo` found: ``xi`` (1, 6) [omega (radians), t (metres)]; the pose errors
    (degrees, metres) of the identity (``errors_before``) and of ``xi`` (``errors_after``); the mean
    |residual| (intensity) of the live view warped by each against the reference; the figure's path."""

    xi: torch.Tensor
    errors_before: tuple[float, float]
    errors_after: tuple[float, float]
    residual_before: float
    residual_after: float
    figure: Path


def align_demo(out: Path, size: tuple[int, int] = (160, 120), *, steps: int = 60, levels: int = 3,
               rotation_deg: float = 4.0, translation_cm: float = 8.0, seed: int = 0,
               log: Callable[[str], None] = print) -> AlignResult:
    """Render two views ``size`` (width, height) pixels, ``rotation_deg`` degrees and
    ``translation_cm`` cm apart (``seed``: the room and the motion), recover their relative pose
    (:func:`fit_pose`, ``steps`` Adam steps on each of ``levels`` levels, at most
    :func:`.views.max_levels`), and write ``out/align.png`` (``out`` is made if missing). Progress lines go
    to ``log``; a progress bar to stderr when it is a terminal."""
    width, height = size
    if not 1 <= levels <= max_levels(width, height):
        raise ValueError(f"levels must be from 1 to {max_levels(width, height)} for {width}x{height}, got {levels}")
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(seed)
    t0 = time.perf_counter()
    ref_np, depth_np, live_np, K_np, T_gt_np = make_views(width, height, rotation_deg, translation_cm, seed)
    ref, depth, live = (torch.from_numpy(a)[None] for a in (ref_np, depth_np, live_np))
    K = torch.from_numpy(K_np).float()
    T_gt = T_gt_np[:3]
    log(f"rendered 2 views {width}x{height} in {time.perf_counter() - t0:.2f} s; true motion "
        f"{rotation_deg:.1f} deg, {translation_cm:.1f} cm")

    xi = fit_pose(ref, depth, live, K, levels=levels, steps=steps, T_gt=T_gt)

    with torch.no_grad():
        before, valid0 = warp_frame_depth(live, depth, torch.eye(3, 4, dtype=torch.float32)[None], K)
        after, valid1 = warp_frame_depth(live, depth, se3_to_matrix(xi), K)
    rot0, trans0 = pose_error(np.eye(4)[:3], T_gt)
    rot1, trans1 = pose_error(se3_to_matrix(xi)[0].double().numpy(), T_gt)
    res0 = ((before - ref).abs() * valid0).mean().item()
    res1 = ((after - ref).abs() * valid1).mean().item()
    log(f"pose error: {rot0:.2f} deg, {100 * trans0:.2f} cm at the start -> {rot1:.3f} deg, "
        f"{100 * trans1:.3f} cm after; mean |residual| {res0:.4f} -> {res1:.4f}")
    path = out / "align.png"
    save_figure(path, ref[0], live[0], before[0], after[0], valid0[0], valid1[0],
                errors=((rot0, trans0), (rot1, trans1)))
    log(f"wrote {path} ({time.perf_counter() - t0:.1f} s in all)")
    return AlignResult(xi, (rot0, trans0), (rot1, trans1), res0, res1, path)


def figure(ref, live, before, after, valid0, valid1, errors=None) -> Figure:
    """The matplotlib figure of ``align.png``: the two views (3, H, W), the live view warped with the
    identity and with the recovered pose, and the |residual| maps against the reference (``valid0``,
    ``valid1`` (1, H, W) masks), with a colour bar. ``errors``: optional ((deg, m) before, (deg, m)
    after) pose errors for the titles."""

    def rgb(t):
        return t.permute(1, 2, 0).clamp(0, 1).numpy()

    def residual(w, v):
        return ((w - ref).abs().mean(0) * v[0]).numpy()

    e0 = e1 = ""
    if errors is not None:
        (r0, t0), (r1, t1) = errors
        e0, e1 = f"\npose error {r0:.2f} deg, {100 * t0:.2f} cm", f"\npose error {r1:.2f} deg, {100 * t1:.2f} cm"
    res0, res1 = residual(before, valid0), residual(after, valid1)
    panels = [
        ("reference view", rgb(ref)), ("live view", rgb(live)), ("live warped with the identity" + e0, rgb(before)),
        ("live warped with the recovered pose" + e1, rgb(after)),
        (f"|residual| before (mean {res0.mean():.4f})", res0), (f"|residual| after (mean {res1.mean():.4f})", res1),
    ]
    # a Figure of its own, not pyplot's: no backend chosen, no global state (the caller saves it)
    fig = Figure(figsize=(12, 6.8), layout="constrained")
    axes = fig.subplots(2, 3)
    for ax, (title, img) in zip(axes.ravel(), panels):
        if img.ndim == 2:
            im = ax.imshow(img, cmap="magma", vmin=0, vmax=RESIDUAL_MAX)
        else:
            ax.imshow(img)
        ax.set_title(title, fontsize=11)
        ax.axis("off")
    bar = fig.colorbar(im, ax=axes[1, 1:].tolist(), extend="max")
    bar.set_label("|warped - reference| (intensity, 0-1)", fontsize=10)
    fig.suptitle("gvnn-warp align: photometric gradient descent through warp_frame_depth\n"
                 "residuals: mean over RGB of |live warped - reference|, 0 at invalid pixels", fontsize=12)
    return fig


def save_figure(path: Path, *images, errors=None) -> None:
    """:func:`figure` of ``images`` written to ``path`` (PNG, 90 dpi)."""
    figure(*images, errors=errors).savefig(path, dpi=90)
