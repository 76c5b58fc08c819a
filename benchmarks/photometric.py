"""The fused photometric objective against what users would run instead, one process, interleaved.

    python -m benchmarks.photometric [--quick] [--threads 2] [--repeats N]

(run from the repository root). float32, torch and gvnn_warp on ``--threads`` threads, medians of
wall-clock times, ours and the peers timed round-robin in the same loop (see benchmarks/common.py):

- ``photometric_error`` forward+backward (gradients for pose and depth; images are data), B=8,
  C=3, 240x320, against ``grid_sample`` forward+backward with the image as data (gradient for
  the grid only) and against kornia's ``warp_frame_depth`` + L1 + mean (gradients for depth and
  pose), the unfused code a user would write. Targets: <= 0.6x and <= 0.15x.
- ``photometric_normal_equations`` (C=1, B=1): the torch function and the pure-Warp host function
  with ``out=`` (what a Gauss-Newton loop calls) at 320x240 (target <= 0.5 ms) and 640x480, and the
  per-call time at 40x30 (per-call overhead), with the time of an empty recorded Warp launch for
  scale.
- One thread, CPU time of the calling thread (``time.thread_time``, best of a few calls): the same
  work with no thread hand-over and far less sensitive to other processes on a shared host than
  wall-clock time; nanoseconds per pixel.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import kornia  # noqa: E402
import numpy as np  # noqa: E402
import torch.nn.functional as F  # noqa: E402
import warp as wp  # noqa: E402
from gvnn_warp.kernels.core import launch  # noqa: E402
from gvnn_warp.kernels.core.launch import mat34f  # noqa: E402
from gvnn_warp.kernels.photometric import normal_equations as pk  # noqa: E402
from gvnn_warp.kernels.photometric import pipeline as photometric_pipeline  # noqa: E402
from gvnn_warp.kernels.photometric.normal_equations_reduce import ROW_STRIDE  # noqa: E402

import gvnn_warp as G  # noqa: E402
from benchmarks.common import Case, affine_grid, clear_grads, interleaved, leaves, machine, wfd_scene  # noqa: E402
from gvnn_warp.ops import photometric as ops  # noqa: E402


def error_cases(B=8, C=3, H=240, W=320) -> list[Case]:
    """Ours (photometric_error, grads depth + pose), grid_sample (grad grid), kornia + L1 + mean."""
    image, depth, pose, pose44, K = wfd_scene(B, C, H, W)
    ref = torch.rand(B, C, H, W, generator=torch.Generator().manual_seed(5))
    grid = affine_grid(B, H, W)
    ours = leaves(depth, pose)
    kor = leaves(depth, pose44)
    gs = leaves(grid)

    def ours_f():
        G.photometric_error(ref, ours[0], image, ours[1], K)[0].sum().backward()

    def gs_f():
        F.grid_sample(image, gs[0], align_corners=True).sum().backward()

    def kornia_f():
        warped = kornia.geometry.depth.warp_frame_depth(image, kor[0], kor[1], K)
        (warped - ref).abs().mean().backward()

    return [
        Case("ours", ours_f, clear_grads(ours)),
        Case("grid_sample", gs_f, clear_grads(gs)),
        Case("kornia", kornia_f, clear_grads(kor)),
    ]


def ne_arrays(H, W, seed=0):
    """A float32 scene for the normal equations (C=1, B=1): torch tensors and wp.arrays."""
    image, depth, pose, _, K = wfd_scene(1, 1, H, W, seed=seed)
    ref = image.roll(1, dims=-1).contiguous()
    arrays = (
        wp.from_torch(ref), wp.from_torch(depth), wp.from_torch(image),
        wp.array(pose.numpy(), dtype=mat34f), wp.array(K.numpy(), dtype=wp.mat33f),
    )
    return (ref, depth, image, pose, K), arrays


def ne_cases(H, W) -> list[Case]:
    tensors, arrays = ne_arrays(H, W)
    out = photometric_pipeline.photometric_normal_equations(*arrays, scale=0.1)
    return [
        Case("warp_out", lambda: photometric_pipeline.photometric_normal_equations(*arrays, scale=0.1, out=out)),
        Case("warp_new", lambda: photometric_pipeline.photometric_normal_equations(*arrays, scale=0.1)),
        Case("torch", lambda: G.photometric_normal_equations(*tensors, scale=0.1)),
    ]


@wp.kernel
def _empty(offset: int, a: wp.array(dtype=float)):
    pass


def per_call_us(fn, n=2000) -> float:
    """Median microseconds per call over 5 batches of n calls."""
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        times.append((time.perf_counter() - t0) / n)
    return 1e6 * float(np.median(times))


def cpu_ms(fn, n=5) -> float:
    """Best CPU time of the calling thread over ``n`` calls of ``fn``, ms (one thread: all the work)."""
    fn()
    best = float("inf")
    for _ in range(n):
        t0 = time.thread_time()
        fn()
        best = min(best, time.thread_time() - t0)
    return 1e3 * best


def one_thread_table(n: int) -> dict:
    """ns per pixel on one thread (thread CPU time)."""
    torch.set_num_threads(1)
    launch.set_num_threads(1)
    try:
        rows = {}
        B, C, H, W = 8, 3, 240, 320
        px = B * H * W
        image, depth, pose, pose44, K = wfd_scene(B, C, H, W)
        ref = torch.rand(B, C, H, W, generator=torch.Generator().manual_seed(5))
        d, p, p44 = leaves(depth, pose, pose44)
        grid = leaves(affine_grid(B, H, W))[0]

        def fwd():
            with torch.no_grad():
                G.photometric_error(ref, depth, image, pose, K)

        def fb():
            d.grad = p.grad = None
            G.photometric_error(ref, d, image, p, K)[0].sum().backward()

        def fb_reference():  # the same through the reference row kernel and its Warp adjoint
            d.grad = p.grad = None
            rows = ops.photometric_rows(ref, d, image, p, K, C, H, W, 5, 1.0, 1e-3)
            ops.photometric_mean(*rows, H, C)[0].sum().backward()

        def gs():
            grid.grad = None
            F.grid_sample(image, grid, align_corners=True).sum().backward()

        def kor():
            d.grad = p44.grad = None
            (kornia.geometry.depth.warp_frame_depth(image, d, p44, K) - ref).abs().mean().backward()

        for name, fn in (("photometric_error forward", fwd), ("photometric_error fwd+bwd (grads depth, pose)", fb),
                         ("... the same via the Warp adjoint of the reference row kernel", fb_reference),
                         ("grid_sample fwd+bwd (grad grid)", gs), ("kornia warp_frame_depth + L1 + mean fwd+bwd", kor)):
            rows[name] = 1e6 * cpu_ms(fn, n) / px
        for H, W in ((240, 320), (480, 640)):
            _, arrays = ne_arrays(H, W)
            out = photometric_pipeline.photometric_normal_equations(*arrays, scale=0.1)
            rows[f"normal_equations {W}x{H} (8-lane kernel, out=)"] = 1e6 * cpu_ms(
                lambda arrays=arrays, out=out: photometric_pipeline.photometric_normal_equations(
                    *arrays, scale=0.1, out=out), n
            ) / (H * W)
            scalar = wp.zeros(H * ROW_STRIDE, dtype=wp.float64)
            cmd = wp.launch(pk.normal_equations_rows(False, False)[wp.float32], dim=H, record_cmd=True, inputs=[
                0, arrays[0].flatten(), arrays[1].flatten(), arrays[2].flatten(), wp.zeros(0, dtype=wp.float32),
                arrays[3], arrays[4], 1, H, W, 0, 0.1, 1e-3, 0.0, 0.0, scalar])
            rows[f"normal_equations {W}x{H} (plain kernel, launch alone)"] = 1e6 * cpu_ms(cmd.launch, n) / (H * W)
        return rows
    finally:
        launch.set_num_threads(None)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="fewer repeats")
    p.add_argument("--threads", type=int, default=2, help="torch threads (gvnn_warp follows)")
    p.add_argument("--repeats", type=int, default=None)
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    os.environ.pop("GVNN_WARP_NUM_THREADS", None)
    R = args.repeats or (5 if args.quick else 15)
    m = machine()
    print(f"# photometric objective ({m['cpu']}, nproc {m['nproc']}, torch {m['torch']}, warp {m['warp']}, "
          f"{args.threads} threads, {R} interleaved repeats, load average {m['load_average']})", flush=True)
    report = {"machine": m, "threads": args.threads, "repeats": R}

    res = interleaved(error_cases(), R)
    report["error"] = res
    print("\n| photometric_error fwd+bwd, B=8 C=3 240x320 (grads: depth, pose) | ms | ours / peer | target |")
    print("|---|---:|---:|---|")
    print(f"| ours | {res['ours']:.2f} | | |")
    print(f"| grid_sample fwd+bwd (grad: grid) | {res['grid_sample']:.2f} | {res['ours'] / res['grid_sample']:.2f} "
          f"| <= 0.6 |")
    print(f"| kornia warp_frame_depth + L1 + mean | {res['kornia']:.2f} | {res['ours'] / res['kornia']:.2f} "
          f"| <= 0.15 |", flush=True)

    print("\n| photometric_normal_equations, C=1, B=1 | pure Warp, out= (ms) | pure Warp, new buffers (ms) "
          "| torch (ms) |")
    print("|---|---:|---:|---:|")
    report["normal_equations"] = {}
    for H, W in ((240, 320), (480, 640)):
        res = interleaved(ne_cases(H, W), max(R, 30) if H == 240 else R, warmup=3)
        report["normal_equations"][f"{W}x{H}"] = res
        note = " (target <= 0.5)" if H == 240 else ""
        print(f"| {W}x{H}{note} | {res['warp_out']:.3f} | {res['warp_new']:.3f} | {res['torch']:.3f} |", flush=True)

    # per-call cost where it dominates: 40x30, the coarsest pyramid level
    tensors, arrays = ne_arrays(30, 40)
    out = photometric_pipeline.photometric_normal_equations(*arrays, scale=0.1)
    a = wp.zeros(1, dtype=float)
    empty = wp.launch(_empty, dim=1, inputs=[0, a], record_cmd=True)
    n = 500 if args.quick else 2000
    small = {
        "warp_out_us": per_call_us(lambda: photometric_pipeline.photometric_normal_equations(*arrays, scale=0.1,
                                                                                              out=out), n),
        "warp_new_us": per_call_us(lambda: photometric_pipeline.photometric_normal_equations(*arrays, scale=0.1), n),
        "torch_us": per_call_us(lambda: G.photometric_normal_equations(*tensors, scale=0.1), n),
        "empty_recorded_launch_us": per_call_us(empty.launch, n),
        "empty_launch_us": per_call_us(lambda: wp.launch(_empty, dim=1, inputs=[0, a]), n),
    }
    report["normal_equations"]["40x30"] = small
    print(f"| 40x30 per call | {small['warp_out_us']:.1f} us | {small['warp_new_us']:.1f} us | "
          f"{small['torch_us']:.1f} us |")
    print(f"\n(an empty Warp launch: {small['empty_launch_us']:.1f} us; recorded: "
          f"{small['empty_recorded_launch_us']:.1f} us; load average {os.getloadavg()})")

    rows = one_thread_table(3 if args.quick else 7)
    report["one_thread_ns_per_pixel"] = rows
    print("\n| one thread, CPU time | ns per pixel |\n|---|---:|")
    for name, v in rows.items():
        print(f"| {name} | {v:.1f} |")
    print(f"\n(load average at end {os.getloadavg()})")
    return report


if __name__ == "__main__":
    main()
