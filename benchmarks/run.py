"""Every performance comparison of gvnn_warp against what users would run instead, in one command.

    python -m benchmarks.run [--quick] [--json PATH] [--threads 2] [--no-kernels]

(run from the repository root). All timings: one process, float32, torch on ``--threads`` threads
(gvnn_warp follows torch's thread count), ours and the peers timed round-robin (interleaved) in
the same loop, medians of wall-clock times. Forward+backward means the forward call plus
``out.sum().backward()`` with gradients for every differentiable input named below. Prints
markdown tables (targets, scaling, kernel microbenchmarks, memory, start-up) and writes JSON to
``--json`` (default ``benchmarks/results/latest.json``, git-ignored).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import kornia  # noqa: E402
import torch.nn.functional as F  # noqa: E402

import gvnn_warp as G  # noqa: E402
from benchmarks import kernels as kernel_bench  # noqa: E402
from benchmarks import memory, startup  # noqa: E402
from benchmarks.common import (  # noqa: E402
    Case,
    affine_grid,
    clear_grads,
    interleaved,
    leaves,
    machine,
    random_grid,
    wfd_scene,
)

# ----------------------------------------------------------------------------- cases


def wfd_cases(B, C, H, W, forward_only=False, peers=("grid_sample", "kornia"), image_grad=True) -> list[Case]:
    """Ours, grid_sample (image + grid grads) and kornia's warp_frame_depth, forward+backward.
    ``image_grad=False``: the image is data (no gradient for it, nor for grid_sample's image)."""
    image, depth, pose, pose44, K = wfd_scene(B, C, H, W)
    grid = affine_grid(B, H, W)
    if image_grad:
        ours = leaves(image, depth, pose)
        kor = leaves(image, depth, pose44)
        gs = leaves(image, grid)
    else:
        ours = [image, *leaves(depth, pose)]
        kor = [image, *leaves(depth, pose44)]
        gs = [image, *leaves(grid)]
    cases = []
    if forward_only:
        def ours_f():
            with torch.no_grad():
                G.warp_frame_depth(image, depth, pose, K)

        def kornia_f():
            with torch.no_grad():
                kornia.geometry.depth.warp_frame_depth(image, depth, pose44, K)

        def gs_f():
            with torch.no_grad():
                F.grid_sample(image, grid, align_corners=True)

        cases.append(Case("ours", ours_f))
        if "grid_sample" in peers:
            cases.append(Case("grid_sample", gs_f))
        if "kornia" in peers:
            cases.append(Case("kornia", kornia_f))
        return cases

    cases.append(Case("ours", lambda: G.warp_frame_depth(*ours, K)[0].sum().backward(), clear_grads(ours)))
    if "grid_sample" in peers:
        cases.append(
            Case("grid_sample", lambda: F.grid_sample(*gs, align_corners=True).sum().backward(), clear_grads(gs))
        )
    if "kornia" in peers:
        cases.append(
            Case(
                "kornia",
                lambda: kornia.geometry.depth.warp_frame_depth(*kor, K).sum().backward(),
                clear_grads(kor),
            )
        )
    return cases


def bilinear_cases(B, C, H, W, grid_kind="affine") -> list[Case]:
    g = torch.Generator().manual_seed(3)
    image = torch.rand(B, C, H, W, generator=g)
    grid = affine_grid(B, H, W) if grid_kind == "affine" else random_grid(B, H, W)
    ours = leaves(image, grid)
    theirs = leaves(image, grid)

    def ours_f():
        with torch.no_grad():
            G.bilinear_sample(image, grid)

    def gs_f():
        with torch.no_grad():
            F.grid_sample(image, grid, align_corners=False)

    return [
        Case("ours", lambda: G.bilinear_sample(*ours).sum().backward(), clear_grads(ours)),
        Case("grid_sample", lambda: F.grid_sample(*theirs, align_corners=False).sum().backward(), clear_grads(theirs)),
        Case("ours_forward", ours_f),
        Case("grid_sample_forward", gs_f),
    ]


def so3_cases(n) -> list[Case]:
    omega = torch.randn(n, 3, generator=torch.Generator().manual_seed(4))
    ours = leaves(omega)
    theirs = leaves(omega)
    return [
        Case("ours", lambda: G.so3_exp(*ours).sum().backward(), clear_grads(ours)),
        Case(
            "kornia",
            lambda: kornia.geometry.conversions.axis_angle_to_rotation_matrix(*theirs).sum().backward(),
            clear_grads(theirs),
        ),
    ]


# ----------------------------------------------------------------------------- sections


def targets(args, R: int) -> list[dict]:
    rows = []

    def row(target, ours_ms, peer, peer_ms, limit, note=""):
        ratio = ours_ms / peer_ms
        rows.append({"target": target, "ours_ms": ours_ms, "peer": peer, "peer_ms": peer_ms, "ratio": ratio,
                     "limit": limit, "met": ratio <= limit, "note": note})
        print(f"  {target}: ours {ours_ms:.2f} ms, {peer} {peer_ms:.2f} ms, ratio {ratio:.2f} (<= {limit})",
              flush=True)

    B, C, H, W = 8, 3, 240, 320
    res = interleaved(wfd_cases(B, C, H, W), R)
    row("1. warp_frame_depth fwd+bwd vs grid_sample fwd+bwd", res["ours"], "grid_sample", res["grid_sample"], 1.0,
        "B=8 C=3 240x320; grads: image, depth, pose vs image, grid")
    row("1. warp_frame_depth fwd+bwd vs kornia warp_frame_depth fwd+bwd", res["ours"], "kornia", res["kornia"], 0.25)
    res = interleaved(wfd_cases(B, C, H, W, image_grad=False), R)
    row("   (info) warp_frame_depth fwd+bwd, image as data (grads: depth, pose) vs grid_sample (grads: grid)",
        res["ours"], "grid_sample", res["grid_sample"], float("inf"), "only the gradients asked for are computed")
    row("   (info) warp_frame_depth fwd+bwd, image as data vs kornia (grads: depth, pose)", res["ours"], "kornia",
        res["kornia"], float("inf"))
    res_f = interleaved(wfd_cases(B, C, H, W, forward_only=True), R)
    row("   (info) warp_frame_depth forward vs kornia forward", res_f["ours"], "kornia", res_f["kornia"], float("inf"))

    res = interleaved(bilinear_cases(B, C, H, W), R)
    row("2. bilinear_sample fwd+bwd vs grid_sample fwd+bwd", res["ours"], "grid_sample", res["grid_sample"], 1.5,
        "affine (spatial-transformer) grid")
    row("2. bilinear_sample forward vs grid_sample forward", res["ours_forward"], "grid_sample",
        res["grid_sample_forward"], 2.0)
    res = interleaved(bilinear_cases(B, C, H, W, grid_kind="random"), R)
    row("   (info) bilinear_sample fwd+bwd, random grid", res["ours"], "grid_sample", res["grid_sample"],
        float("inf"), "uniformly random positions: every sample a cache miss")
    row("   (info) bilinear_sample forward, random grid", res["ours_forward"], "grid_sample",
        res["grid_sample_forward"], float("inf"))

    n = 100_000 if args.quick else 1_000_000
    res = interleaved(so3_cases(n), R)
    row(f"3. so3_exp fwd+bwd ({n:,} vectors) vs kornia axis_angle_to_rotation_matrix", res["ours"], "kornia",
        res["kornia"], 0.5)

    res = interleaved(wfd_cases(1, 1, 32, 32, peers=("kornia",)), max(R, 25), warmup=3)
    row("6. warp_frame_depth fwd+bwd B=1 C=1 32x32 vs kornia", res["ours"], "kornia", res["kornia"], 1.0)
    return rows


def scaling(args, R: int) -> dict:
    sizes = [(60, 80), (240, 320)] if args.quick else [(60, 80), (120, 160), (240, 320), (480, 640)]
    batches = [1, 8] if args.quick else [1, 2, 4, 8]
    out = {"image_size": [], "batch": []}
    for H, W in sizes:
        res = interleaved(wfd_cases(8, 3, H, W), R)
        out["image_size"].append({"B": 8, "H": H, "W": W, **res})
        print(f"  B=8 {H}x{W}: " + ", ".join(f"{k} {v:.2f} ms" for k, v in res.items()), flush=True)
    for B in batches:
        res = interleaved(wfd_cases(B, 3, 240, 320), R)
        out["batch"].append({"B": B, "H": 240, "W": 320, **res})
        print(f"  B={B} 240x320: " + ", ".join(f"{k} {v:.2f} ms" for k, v in res.items()), flush=True)
    return out


def memory_section(args) -> dict:
    res = {}
    for impl in ("ours", "kornia"):
        res[impl] = memory.run_subprocess(impl, 8, 3, 240, 320, args.threads)
        r = res[impl]
        mib = 2**20
        print(f"  {impl}: peak {r['peak_bytes'] / mib:.1f} MiB, inputs+outputs+grads {r['io_bytes'] / mib:.1f} "
              f"MiB, ratio {r['ratio']:.2f}", flush=True)
    return res


def startup_section(args) -> dict:
    res = {"warm": startup.run(cold=False)}
    warm = res["warm"]
    print(f"  warm cache: import gvnn_warp + first warp_frame_depth fwd+bwd {warm['import_and_first_call_s']:.2f} s"
          f" (torch import before it: {warm['torch_import_s']:.2f} s)", flush=True)
    if not args.quick:
        res["cold"] = startup.run(cold=True)
        print(f"  cold cache: {res['cold']['import_and_first_call_s']:.1f} s", flush=True)
        res["cold_all_modules"] = startup.run(cold=True, all_modules=True)
        print(f"  cold cache, every gvnn_warp module compiled: {res['cold_all_modules']['all_modules_loaded_s']:.1f} s",
              flush=True)
    return res


# ----------------------------------------------------------------------------- report


def fmt_ratio_table(rows) -> str:
    lines = ["| target | ours (ms) | peer | peer (ms) | ratio | limit | met |", "|---|---:|---|---:|---:|---:|---|"]
    for r in rows:
        limit = "-" if r["limit"] == float("inf") else f"<= {r['limit']:g}"
        met = "-" if r["limit"] == float("inf") else ("yes" if r["met"] else "**no**")
        lines.append(f"| {r['target'].strip()} | {r['ours_ms']:.2f} | {r['peer']} | {r['peer_ms']:.2f} | "
                     f"{r['ratio']:.2f} | {limit} | {met} |")
    return "\n".join(lines)


def fmt_scaling(sc) -> str:
    lines = []
    for key, label in (("image_size", "image size (B=8, C=3)"), ("batch", "batch (C=3, 240x320)")):
        lines += [f"\nwarp_frame_depth forward+backward vs {label}, ms (ratio ours/peer):\n",
                  "| B | H x W | ours | grid_sample | kornia | ours / grid_sample | ours / kornia |",
                  "|---:|---|---:|---:|---:|---:|---:|"]
        for r in sc[key]:
            lines.append(f"| {r['B']} | {r['H']}x{r['W']} | {r['ours']:.2f} | {r['grid_sample']:.2f} | "
                         f"{r['kornia']:.2f} | {r['ours'] / r['grid_sample']:.2f} | {r['ours'] / r['kornia']:.2f} |")
    return "\n".join(lines)


def fmt_summary(report: dict, threads: int) -> str:
    m = report["machine"]
    load = m.get("load_average") or ()
    load_end = m.get("load_average_end") or ()
    out = [
        f"Machine: {m['cpu']}, nproc {m['nproc']}; Python {m['python']}, torch {m['torch']}, warp {m['warp']}, "
        f"kornia {m['kornia']}; torch and gvnn_warp on {threads} threads; {report['repeats']} interleaved repeats "
        f"(medians); {report['started']} - {report['finished']}; load average at start "
        f"{', '.join(f'{x:.2f}' for x in load)}, at end {', '.join(f'{x:.2f}' for x in load_end)}.",
        "",
        fmt_ratio_table(report["targets"]),
    ]
    if "memory" in report:
        mem, mib = report["memory"], 2**20
        out.append(
            f"\nPeak memory, warp_frame_depth fwd+bwd B=8 C=3 240x320: ours {mem['ours']['peak_bytes'] / mib:.1f} MiB "
            f"= {mem['ours']['ratio']:.2f}x its inputs+outputs+gradients ({mem['ours']['io_bytes'] / mib:.1f} MiB; "
            f"limit 3x); kornia {mem['kornia']['peak_bytes'] / mib:.1f} MiB = {mem['kornia']['ratio']:.2f}x "
            f"({mem['ours']['method']})."
        )
        s = report["startup"]
        line = (
            f"\nStart-up, new process: import gvnn_warp + first warp_frame_depth fwd+bwd "
            f"{s['warm']['import_and_first_call_s']:.2f} s with a warm kernel cache (limit 1 s; torch's own "
            f"import before it: {s['warm']['torch_import_s']:.2f} s)"
        )
        if "cold" in s:
            line += (
                f"; {s['cold']['import_and_first_call_s']:.1f} s with an empty kernel cache (limit 30 s); every "
                f"gvnn_warp module compiled (wp.force_load, incl. the per-pixel and render modules): "
                f"{s['cold_all_modules']['all_modules_loaded_s']:.1f} s"
            )
        out.append(line + ".")
    out.append(fmt_scaling(report["scaling"]))
    if "kernels" in report:
        out.append(f"\nKernel launches alone (float32, through launch(); 1 vs {threads} threads):\n")
        out.append(kernel_bench.format_rows(report["kernels"], threads))
    return "\n".join(out)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="fewer repeats and sizes: a smoke run")
    p.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "latest.json"))
    p.add_argument("--threads", type=int, default=2, help="torch threads (gvnn_warp follows)")
    p.add_argument("--repeats", type=int, default=None)
    p.add_argument("--no-kernels", action="store_true", help="skip the kernel microbenchmarks")
    p.add_argument("--no-subprocess", action="store_true", help="skip memory and start-up (fresh processes)")
    p.add_argument("--markdown", default=None, help="also write the summary tables to this markdown file")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    os.environ.pop("GVNN_WARP_NUM_THREADS", None)
    R = args.repeats or (3 if args.quick else 11)
    report = {"machine": machine(), "threads": args.threads, "repeats": R, "quick": args.quick,
              "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    print(f"# gvnn_warp benchmarks ({report['machine']['cpu']}, nproc {report['machine']['nproc']}, "
          f"torch {report['machine']['torch']}, warp {report['machine']['warp']}, {args.threads} threads)", flush=True)

    print("\n## targets", flush=True)
    report["targets"] = targets(args, R)
    if not args.no_subprocess:
        print("\n## memory (fresh process)", flush=True)
        report["memory"] = memory_section(args)
        print("\n## start-up (fresh process)", flush=True)
        report["startup"] = startup_section(args)
    print("\n## scaling", flush=True)
    report["scaling"] = scaling(args, max(3, R // 2))
    if not args.no_kernels:
        print("\n## kernel microbenchmarks", flush=True)
        report["kernels"] = kernel_bench.run(args.threads, args.quick, max(3, R // 2))
        torch.set_num_threads(args.threads)
    report["finished"] = time.strftime("%Y-%m-%d %H:%M:%S")
    report["machine"]["load_average_end"] = os.getloadavg() if hasattr(os, "getloadavg") else None

    summary = fmt_summary(report, args.threads)
    print("\n# summary\n")
    print(summary)
    if args.markdown:
        Path(args.markdown).write_text(summary + "\n")
        print(f"\nmarkdown: {args.markdown}")

    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=1, default=str))
    print(f"\nJSON: {path}")
    return report


if __name__ == "__main__":
    main()
