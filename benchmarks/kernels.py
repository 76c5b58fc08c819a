"""Kernel microbenchmarks: each Warp kernel's forward and adjoint launch, through
``gvnn_warp.kernels.core.launch.launch``, on 1 thread and on N threads (no torch autograd, no
allocation: only the launches). Reports milliseconds, ns per element and the threaded speed-up.

Usage: ``python -m benchmarks.kernels [--threads 2] [--quick]``.
"""

from __future__ import annotations

import argparse
import json

import torch
import warp as wp
from gvnn_warp.kernels.core import launch
from gvnn_warp.kernels.geometry import kernels as geometry_kernels
from gvnn_warp.kernels.sampling import kernels as sampling_kernels

import gvnn_warp  # noqa: F401  (initialises Warp quietly)
from benchmarks.common import Case, affine_grid, interleaved, wfd_scene
from gvnn_warp.ops.bridge import descriptor, null_array

F32 = wp.float32


def _launch_case(fk, n, ins, kinds, outs, out_kinds, params=(), launches=None, adjoint=True):
    """(forward, adjoint) callables launching fk on float32 tensors over ``launches`` threads
    (default ``n``, the elements reported); adjoint None if ``adjoint`` is false."""
    launches = n if launches is None else launches
    k = fk[F32]
    d_in = [descriptor(t, kd, F32) for t, kd in zip(ins, kinds)]
    d_out = [descriptor(t, kd, F32) for t, kd in zip(outs, out_kinds)]

    def fwd(keep=(ins, outs)):  # descriptors hold no references: the closures keep the tensors
        launch.launch(k, launches, [*d_in, *params], d_out)

    if not adjoint:
        return fwd, None
    grads = [torch.zeros_like(t) for t in ins]
    adj_outs = [torch.ones_like(t) if kd != "bool" else None for t, kd in zip(outs, out_kinds)]
    keep = (ins, outs, grads, adj_outs)
    d_grads = [descriptor(g, kd, F32) for g, kd in zip(grads, kinds)]
    d_adj_out = [descriptor(g, kd, F32) if g is not None else null_array(kd, F32) for g, kd in zip(adj_outs, out_kinds)]

    def adj(keep=keep):
        launch.launch(
            k, launches, [*d_in, *params], d_out, adjoint=True, adj_inputs=[*d_grads, *params], adj_outputs=d_adj_out
        )

    return fwd, adj


def kernel_cases(quick: bool) -> dict:
    """name -> (elements, forward, adjoint or None)."""
    B, C, H, W = (2, 3, 120, 160) if quick else (8, 3, 240, 320)
    n_rot = 100_000 if quick else 1_000_000
    image, depth, pose, _, K = wfd_scene(B, C, H, W)
    pose = pose.contiguous()
    cases = {}
    omega = torch.randn(n_rot, 3)
    R = torch.empty(n_rot, 3, 3)
    cases["so3_exp"] = (n_rot, *_launch_case(geometry_kernels.so3_exp, n_rot, [omega], ["vec3"], [R], ["mat33"]))
    u = torch.randn(n_rot, 3)
    T = torch.empty(n_rot, 3, 4)
    cases["se3_exp"] = (
        n_rot, *_launch_case(geometry_kernels.se3_exp, n_rot, [omega, u], ["vec3", "vec3"], [T], ["mat34"])
    )
    n_pix = B * H * W
    flat_depth = depth.reshape(-1).contiguous()
    points = torch.empty(n_pix, 3)
    cases["depth_to_points"] = (
        n_pix,
        *_launch_case(
            geometry_kernels.depth_to_points, n_pix, [flat_depth, K], ["scalar", "mat33"], [points], ["vec3"], (H, W)
        ),
    )
    pts = torch.randn(n_pix, 3) + torch.tensor([0.0, 0.0, 3.0])
    pix = torch.empty(n_pix, 2)
    cases["project_points"] = (
        n_pix,
        *_launch_case(
            geometry_kernels.project_points, n_pix, [pts, K], ["vec3", "mat33"], [pix], ["vec2"], (H * W, 1e-3)
        ),
    )
    grid = affine_grid(B, H, W).reshape(-1, 2).contiguous()
    out = torch.empty(B, C, H * W)
    cases["bilinear_sample"] = (
        n_pix,
        *_launch_case(
            sampling_kernels.bilinear_sample, n_pix, [image, grid], ["scalar", "vec2"], [out], ["scalar"],
            (C, H, W, H * W, 0, 0),
        ),
    )
    # the same samples, 8 output locations per thread (forward only: its backward is the above's adjoint)
    fwd_lanes, _ = _launch_case(
        sampling_kernels.bilinear_sample_lanes(C, 0, 0), n_pix, [image, grid], ["scalar", "vec16"], [out], ["vec8"],
        (C, H, W, H * W, 0, 0), launches=n_pix // 8, adjoint=False,
    )
    cases["bilinear_sample_lanes"] = (n_pix, fwd_lanes, None)
    warped = torch.empty_like(image)
    valid = torch.empty(B, 1, H, W, dtype=torch.bool)
    cases["warp_frame_depth"] = (
        n_pix,
        *_launch_case(
            sampling_kernels.warp_frame_depth, n_pix, [image, depth, pose, K], ["scalar", "scalar", "mat34", "mat33"],
            [warped, valid], ["scalar", "bool"], (C, H, W, 1e-3, 0), launches=B * H,  # one thread per row
        ),
    )
    if sampling_kernels.fits_row_lanes(H, W):  # what the op runs here: a row per thread, 8 pixels at a time
        cases["warp_frame_depth_lanes"] = (
            n_pix,
            *_launch_case(
                sampling_kernels.warp_frame_depth_lanes(C, 0), n_pix, [image, depth, pose, K],
                ["scalar", "vec8", "mat34", "mat33"], [warped, valid], ["vec8", "bool"], (C, H, W, 1e-3, 0),
                launches=B * H,
            ),
        )
    return cases


def run(threads: int, quick: bool, repeats: int) -> list[dict]:
    rows = []
    for name, (n, fwd, adj) in kernel_cases(quick).items():
        for direction, fn in (("forward", fwd), ("adjoint", adj)):
            if fn is None:
                continue
            def one(fn=fn):
                launch.set_num_threads(1)
                fn()

            def many(fn=fn):
                launch.set_num_threads(threads)
                fn()

            res = interleaved([Case("1", one), Case("N", many)], repeats)
            rows.append(
                {
                    "kernel": name,
                    "direction": direction,
                    "elements": n,
                    "ms_1_thread": res["1"],
                    f"ms_{threads}_threads": res["N"],
                    "ns_per_element_1_thread": 1e6 * res["1"] / n,
                    "speedup": res["1"] / res["N"],
                }
            )
    launch.set_num_threads(None)
    return rows


def format_rows(rows: list[dict], threads: int) -> str:
    lines = [
        f"| kernel | pass | elements | 1 thread (ms) | {threads} threads (ms) | ns/element (1 thread) | speed-up |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['kernel']} | {r['direction']} | {r['elements']:,} | {r['ms_1_thread']:.2f} | "
            f"{r[f'ms_{threads}_threads']:.2f} | {r['ns_per_element_1_thread']:.1f} | {r['speedup']:.2f}x |"
        )
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--repeats", type=int, default=None)
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    rows = run(a.threads, a.quick, a.repeats or (3 if a.quick else 9))
    print(format_rows(rows, a.threads))
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
