"""The self-supervised reprojection objective (Monodepth2's, with auto-masking) and edge-aware
smoothness written the way users write them today in plain torch (``grid_sample``, SSIM through
``avg_pool2d`` on reflection-padded images, a full-resolution tensor per source and per SSIM
term), against ``gvnn_warp.reprojection_loss``. The torch functions here are also the tests'
reference (``tests/functional/test_reprojection.py``): they follow the definitions of
``gvnn_warp.kernels.reprojection`` and use nothing of gvnn_warp.

    .venv/bin/python -m benchmarks.reprojection [--size 640x192] [--batch 4] [--sources 2] [--repeats 7]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

import torch
import torch.nn.functional as F

SSIM_C1, SSIM_C2 = 0.01**2, 0.03**2


def ssim_error(x, y):
    """clamp((1 - SSIM) / 2, 0, 1) per channel, 3x3 windows, reflection padding (Monodepth2)."""
    x, y = F.pad(x, (1, 1, 1, 1), mode="reflect"), F.pad(y, (1, 1, 1, 1), mode="reflect")
    mu_x, mu_y = F.avg_pool2d(x, 3, 1), F.avg_pool2d(y, 3, 1)
    sigma_x = F.avg_pool2d(x * x, 3, 1) - mu_x**2
    sigma_y = F.avg_pool2d(y * y, 3, 1) - mu_y**2
    sigma_xy = F.avg_pool2d(x * y, 3, 1) - mu_x * mu_y
    n = (2 * mu_x * mu_y + SSIM_C1) * (2 * sigma_xy + SSIM_C2)
    d = (mu_x**2 + mu_y**2 + SSIM_C1) * (sigma_x + sigma_y + SSIM_C2)
    return torch.clamp((1 - n / d) / 2, 0, 1)


def photometric_error(target, pred, alpha=0.85):
    """(B, 1, H, W): alpha * mean_c SSIM term + (1 - alpha) * mean_c |target - pred|."""
    l1 = (target - pred).abs().mean(1, keepdim=True)
    return alpha * ssim_error(target, pred).mean(1, keepdim=True) + (1 - alpha) * l1


def torch_reprojection_loss(target, sources, depth, poses, K, *, alpha=0.85, automask=True, min_depth=1e-3,
                            return_maps=False):
    """Plain-torch reprojection loss, pinhole K (B, 3, 3) or (3, 3); see gvnn_warp.reprojection_loss."""
    B, S, C, H, W = sources.shape
    K = K.expand(B, 3, 3)
    ys, xs = torch.meshgrid(torch.arange(H, dtype=depth.dtype), torch.arange(W, dtype=depth.dtype), indexing="ij")
    pix = torch.stack([xs, ys, torch.ones_like(xs)]).reshape(1, 3, H * W)
    d = depth.reshape(B, 1, H * W)
    depth_ok = (d > min_depth) & torch.isfinite(d)
    points = torch.linalg.inv(K) @ pix * torch.where(depth_ok, d, torch.ones_like(d))  # (B, 3, HW)
    candidates, fronts = [], []
    for s in range(S):
        moved = poses[:, s, :3, :3] @ points + poses[:, s, :3, 3:]
        z = moved[:, 2:3]
        front = depth_ok & (z > min_depth)
        uv = (K @ moved)[:, :2] / torch.where(front, z, torch.ones_like(z))
        grid = torch.stack([2 * uv[:, 0] / (W - 1) - 1, 2 * uv[:, 1] / (H - 1) - 1], -1).reshape(B, H, W, 2)
        grid = torch.where(front.reshape(B, H, W, 1), grid, torch.zeros_like(grid))  # no NaN reaches grid_sample
        warped = F.grid_sample(sources[:, s], grid, padding_mode="border", align_corners=True)
        front = front.reshape(B, 1, H, W)
        warped = warped * front  # gvnn_warp's warp gives 0 where a point cannot be projected
        pe = photometric_error(target, warped, alpha)
        candidates.append(torch.where(front, pe, torch.full_like(pe, float("inf"))))
        fronts.append(front)
    if automask:
        candidates += [photometric_error(target, sources[:, s], alpha) for s in range(S)]
    error, index = torch.cat(candidates, 1).min(1, keepdim=True)  # ties: the first (reprojections first)
    counted = depth_ok.reshape(B, 1, H, W) & torch.isfinite(error)
    error = torch.where(counted, error, torch.zeros_like(error))
    n = counted.sum((1, 2, 3))
    loss = error.sum((1, 2, 3)) / n.clamp(min=1)
    if not return_maps:
        return loss
    return loss, {"error": error.detach(), "automask": counted & (index < S),
                  "source": torch.where(counted, index % S, -1)}


def torch_edge_aware_smoothness(disp, img):
    """Monodepth2's get_smooth_loss on the mean-normalised disparity, per batch item (B,)."""
    disp = disp / (disp.mean((2, 3), keepdim=True) + 1e-7)
    gdx = (disp[:, :, :, :-1] - disp[:, :, :, 1:]).abs()
    gdy = (disp[:, :, :-1, :] - disp[:, :, 1:, :]).abs()
    gix = (img[:, :, :, :-1] - img[:, :, :, 1:]).abs().mean(1, keepdim=True)
    giy = (img[:, :, :-1, :] - img[:, :, 1:, :]).abs().mean(1, keepdim=True)
    return (gdx * torch.exp(-gix)).mean((1, 2, 3)) + (gdy * torch.exp(-giy)).mean((1, 2, 3))


# ----------------------------------------------------------------------------- the benchmark


def scene(B: int, S: int, C: int, H: int, W: int, dtype=torch.float32, seed: int = 0):
    """Smooth random frames (low-frequency waves), depth 2-6 m, motions of ~1 deg / 3 cm, KITTI-like K."""
    import gvnn_warp as G

    g = torch.Generator().manual_seed(seed)
    ys, xs = torch.meshgrid(torch.linspace(0, 1, H), torch.linspace(0, 1, W), indexing="ij")

    def frames(*lead):
        f = torch.rand(*lead, C, 1, 1, 4, generator=g)
        return (0.5 + 0.25 * torch.sin(xs * (3 + 9 * f[..., 0]) + ys * (2 + 7 * f[..., 1]) + 6 * f[..., 2])
                + 0.1 * torch.rand(*lead, C, H, W, generator=g)).to(dtype)

    target, sources = frames(B), frames(B, S)
    depth = (2 + 4 * torch.rand(B, 1, 1, 1, generator=g) * (1 - ys)).to(dtype).expand(B, 1, H, W).contiguous()
    xi = (torch.rand(B * S, 6, generator=g) * 2 - 1) * torch.tensor([0.02] * 3 + [0.03] * 3)
    poses = G.se3_to_matrix(xi.to(dtype)).reshape(B, S, 3, 4)
    K = torch.tensor([[0.58 * W, 0, 0.5 * W], [0, 1.92 * H, 0.5 * H], [0, 0, 1]], dtype=dtype)
    return target, sources, depth, poses, K


def _step(impl: str, target, sources, depth, poses, K):
    import gvnn_warp as G

    d = depth.clone().requires_grad_()
    p = poses.clone().requires_grad_()
    fn = G.reprojection_loss if impl == "ours" else torch_reprojection_loss
    fn(target, sources, d, p, K).sum().backward()


def time_both(B, S, C, H, W, repeats):
    """Medians (s) of forward+backward (gradients for depth and poses), ours and torch's,
    interleaved in this process."""
    args = scene(B, S, C, H, W)
    times = {"ours": [], "torch": []}
    for impl in times:  # warm-up (compiles or loads kernels)
        _step(impl, *args)
    for _ in range(repeats):
        for impl in times:
            t = time.perf_counter()
            _step(impl, *args)
            times[impl].append(time.perf_counter() - t)
    return {k: sorted(v)[len(v) // 2] for k, v in times.items()}


def peak_memory(impl, B, S, C, H, W, threads) -> int:
    """Peak extra resident memory (bytes) of one forward+backward beyond its inputs, in a fresh
    process: VmHWM reset once the inputs exist and the heap's free memory is returned to the system
    (malloc_trim), as in benchmarks.memory."""
    code = "\n".join([
        f"import ctypes, torch, json; torch.set_num_threads({threads})",
        "from benchmarks.reprojection import scene, _step",
        "from benchmarks.memory import _rss_kb, _reset_peak",
        f"_step({impl!r}, *scene(1, {S}, {C}, 16, 32))",
        f"args = scene({B}, {S}, {C}, {H}, {W})",
        "ctypes.CDLL('libc.so.6').malloc_trim(0)",
        "base = _rss_kb('VmRSS'); assert _reset_peak()",
        f"_step({impl!r}, *args)",
        "print(json.dumps((_rss_kb('VmHWM') - base) * 1024))",
    ])
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return int(json.loads(out.stdout.strip().splitlines()[-1]))


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", default="640x192", help="WxH (default: Monodepth2's KITTI size 640x192)")
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--sources", type=int, default=2)
    p.add_argument("--channels", type=int, default=3)
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--json", default=None, help="also write the results here")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    W, H = (int(v) for v in args.size.split("x"))
    torch.set_num_threads(args.threads)
    B, S, C = args.batch, args.sources, args.channels
    t = time_both(B, S, C, H, W, args.repeats)
    mem = {impl: peak_memory(impl, B, S, C, H, W, args.threads) for impl in ("ours", "torch")}
    result = {
        "size": [B, S, C, H, W], "threads": args.threads, "ms": {k: 1000 * v for k, v in t.items()},
        "time_ratio": t["ours"] / t["torch"], "peak_extra_bytes": mem, "memory_ratio": mem["ours"] / mem["torch"],
    }
    print(f"reprojection_loss fwd+bwd (depth, poses), B={B} S={S} C={C} {H}x{W}, {args.threads} threads: "
          f"ours {1000 * t['ours']:.1f} ms, torch {1000 * t['torch']:.1f} ms, ratio {result['time_ratio']:.2f}; "
          f"peak extra memory ours {mem['ours'] / 2**20:.0f} MiB, torch {mem['torch'] / 2**20:.0f} MiB, "
          f"ratio {result['memory_ratio']:.2f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
