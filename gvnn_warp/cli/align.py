"""``gvnn-warp align``: recover the relative pose of two rendered views by gradient descent.

Two views of the synthetic room (``gvnn_warp.synthetic``) are rendered a known motion apart;
starting from the identity, a 6-vector [omega, t] is fitted by Adam on the photometric error of
``warp_frame_depth(live, ref_depth, se3_to_matrix(xi), K)`` against the reference image,
coarse to fine over an image pyramid. Writes ``align.png`` (reference, live, warped before and
after, residuals) into ``--out``.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from .args import UsageError, description, finite_float, image_size, output_dir, positive_int, seed

__all__ = ["add_parser", "run"]

REQUIRES = ("torch", "matplotlib", "tqdm")  # checked by gvnn_warp.cli before run()

MIN_LEVEL_SIZE = 4  # pixels along the shorter side of the coarsest pyramid level
MAX_STEPS = 100_000


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "align",
        help="align two rendered RGB-D views by photometric gradient descent",
        description=description(__doc__),
    )
    p.add_argument("--out", type=output_dir, required=True, metavar="DIR",
                   help="directory for align.png (made if missing)")
    p.add_argument("--size", type=image_size(16), default="160x120", metavar="WxH", help="image size WxH")
    p.add_argument("--steps", type=positive_int, default=60, metavar="N", help="Adam steps per pyramid level")
    p.add_argument("--levels", type=positive_int, default=3, metavar="N",
                   help=f"pyramid levels (the coarsest keeps >= {MIN_LEVEL_SIZE} pixels a side)")
    p.add_argument("--rotation-deg", type=finite_float(-180, 180, "degrees"), default=4.0, metavar="DEG",
                   help="true rotation between the views, degrees")
    p.add_argument("--translation-cm", type=finite_float(-50, 50, "cm"), default=8.0, metavar="CM",
                   help="true translation between the views, cm")
    p.add_argument("--seed", type=seed, default=0, metavar="S", help="seed of the scene and the motion")
    p.set_defaults(func=run)
    return p


def check(args: argparse.Namespace) -> None:
    """Argument checks that need several arguments (raises UsageError before any work)."""
    width, height = args.size
    max_levels = int(math.log2(min(width, height) // MIN_LEVEL_SIZE)) + 1
    if args.levels > max_levels:
        raise UsageError(f"--levels {args.levels} is too many for {width}x{height} (the coarsest level must "
                         f"keep >= {MIN_LEVEL_SIZE} pixels a side); use at most {max_levels}")
    if args.steps * args.levels > MAX_STEPS:
        raise UsageError(f"--steps {args.steps} x --levels {args.levels} is more than {MAX_STEPS} steps")


def make_views(width: int, height: int, rotation_deg: float, translation_cm: float, seed: int):
    """Render reference and live views; returns numpy (ref_img, ref_depth, live_img, K, T_live_ref)."""
    from ..synthetic import default_intrinsics, make_room_scene, relative_pose, render_rgbd, smooth_se3_trajectory

    rng = np.random.default_rng(seed)
    scene = make_room_scene(seed=seed)
    K = default_intrinsics(width, height)
    T_w_ref = smooth_se3_trajectory(2, seed=seed)[0]
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    angle = math.radians(rotation_deg)
    W = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    T_ref_live = np.eye(4)
    T_ref_live[:3, :3] = np.eye(3) + math.sin(angle) * W + (1 - math.cos(angle)) * W @ W
    T_ref_live[:3, 3] = direction * translation_cm / 100
    T_w_live = T_w_ref @ T_ref_live
    image, depth = render_rgbd(scene, np.stack([T_w_ref, T_w_live]), K, width, height)
    return image[0], depth[0], image[1], K, relative_pose(T_w_live, T_w_ref)


def pose_error(T_est, T_gt) -> tuple[float, float]:
    """(rotation error in degrees, translation error in metres) between two (3, 4) poses."""
    from ..synthetic import pose_error as errors

    rot, trans = errors(T_est, T_gt)
    return float(rot), float(trans)


def run(args: argparse.Namespace) -> int:
    import torch
    import torch.nn.functional as F
    from tqdm import tqdm

    from ..functional import geometry as G

    check(args)
    width, height = args.size
    args.out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(args.seed)
    t0 = time.perf_counter()
    ref_np, depth_np, live_np, K_np, T_gt_np = make_views(
        width, height, args.rotation_deg, args.translation_cm, args.seed
    )
    ref, depth, live = (torch.from_numpy(a)[None] for a in (ref_np, depth_np, live_np))
    K = torch.from_numpy(K_np).float()
    T_gt = T_gt_np[:3]
    print(f"rendered 2 views {width}x{height} in {time.perf_counter() - t0:.2f} s; true motion "
          f"{args.rotation_deg:.1f} deg, {args.translation_cm:.1f} cm")

    xi = torch.zeros(1, 6, dtype=torch.float32, requires_grad=True)
    optim = torch.optim.Adam([xi], lr=0.01)
    with tqdm(total=args.levels * args.steps, desc="align", unit="step", mininterval=0.5, disable=None) as bar:
        for level in reversed(range(args.levels)):
            s = 2**level
            for group in optim.param_groups:  # finer levels refine: smaller steps
                group["lr"] = 0.01 * 0.4 ** (args.levels - 1 - level)
            # pyramid: area-averaged images, depth subsampled (averaging would blend across edges)
            ref_l = F.avg_pool2d(ref, s) if s > 1 else ref
            live_l = F.avg_pool2d(live, s) if s > 1 else live
            depth_l = depth[..., s // 2 :: s, s // 2 :: s][..., : ref_l.shape[-2], : ref_l.shape[-1]]
            K_l = K.clone()
            K_l[:2] /= s
            K_l[0, 2] = (K[0, 2] - (s - 1) / 2) / s  # pixel centres of the coarse grid
            K_l[1, 2] = (K[1, 2] - (s - 1) / 2) / s
            for _ in range(args.steps):
                warped, valid = G.warp_frame_depth(live_l, depth_l, G.se3_to_matrix(xi), K_l)
                mask = valid.to(ref_l.dtype)
                loss = ((warped - ref_l).square() * mask).sum() / mask.sum().clamp_min(1)
                optim.zero_grad()
                loss.backward()
                optim.step()
                rot, trans = pose_error(G.se3_to_matrix(xi.detach())[0].double().numpy(), T_gt)
                bar.set_postfix(level=level, loss=f"{loss.item():.4f}", rot_err=f"{rot:.2f}deg",
                                trans_err=f"{100 * trans:.2f}cm")
                bar.update()

    with torch.no_grad():
        before, valid0 = G.warp_frame_depth(live, depth, torch.eye(3, 4, dtype=torch.float32)[None], K)
        after, valid1 = G.warp_frame_depth(live, depth, G.se3_to_matrix(xi), K)
    rot0, trans0 = pose_error(np.eye(4)[:3], T_gt)
    rot1, trans1 = pose_error(G.se3_to_matrix(xi.detach())[0].double().numpy(), T_gt)
    res0 = ((before - ref).abs() * valid0).mean().item()
    res1 = ((after - ref).abs() * valid1).mean().item()
    print(f"pose error: {rot0:.2f} deg, {100 * trans0:.2f} cm at the start -> {rot1:.3f} deg, "
          f"{100 * trans1:.3f} cm after; mean |residual| {res0:.4f} -> {res1:.4f}")
    path = args.out / "align.png"
    _figure(path, ref[0], live[0], before[0], after[0], valid0[0], valid1[0],
            errors=((rot0, trans0), (rot1, trans1)))
    print(f"wrote {path} ({time.perf_counter() - t0:.1f} s in all)")
    return 0


RESIDUAL_MAX = 0.3  # colour scale of the residual panels (intensities are in [0, 1])


def figure(ref, live, before, after, valid0, valid1, errors=None):
    """The matplotlib figure of ``align.png``: the two views, the live view warped with the identity
    and with the recovered pose, and the |residual| maps against the reference, with a colour bar.
    ``errors``: optional ((deg, m) before, (deg, m) after) pose errors for the titles."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.8), layout="constrained")
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


def _figure(path: Path, *images, errors=None) -> None:
    import matplotlib.pyplot as plt

    fig = figure(*images, errors=errors)
    fig.savefig(path, dpi=90)
    plt.close(fig)
