"""Every performance comparison of gvnn_warp against what users would run instead, in one command.

    .venv/bin/python -m benchmarks.run [--quick] [--json PATH] [--markdown PATH] [--threads 2] [--no-kernels]

Run it from the repository's folder (``benchmarks`` is not part of the installed package) with the
venv that has the ``test`` extra (kornia). All timings: one process, float32, torch on
``--threads`` threads (gvnn_warp follows torch's thread count), ours and the peers timed
round-robin (interleaved) in the same loop, medians of wall-clock times. Forward+backward means the
forward call plus ``out.sum().backward()`` with gradients for every differentiable input named
below. Progress goes to stderr; the report (markdown: targets, each explained, scaling, kernel
microbenchmarks, memory, start-up) to stdout, and as JSON to ``--json`` (default
``benchmarks/results/latest.json``, git-ignored).
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

from benchmarks import kernels as kernel_bench  # noqa: E402
from benchmarks import memory, startup  # noqa: E402
from benchmarks.cases import bilinear_cases, lens_cases, so3_cases, wfd_cases  # noqa: E402
from benchmarks.common import interleaved, machine  # noqa: E402

# ----------------------------------------------------------------------------- sections

# What each numbered target measures and why (printed above the table).
TARGETS = {
    1: "the fused 3D spatial transformer (unproject, move, project, sample in one pass) forward+backward, "
       "B=8 C=3 240x320, against grid_sample alone (only the sampling step of the same warp; gradients "
       "for image and grid) and against kornia's warp_frame_depth (the same op written with torch ops)",
    2: "the bilinear sampler alone against grid_sample (same semantics), on the same affine grid",
    3: "so3_exp (Rodrigues' formula) on many rotation vectors against kornia's axis_angle_to_rotation_matrix",
    4: "peak memory of warp_frame_depth forward+backward relative to its inputs, outputs and gradients",
    5: "start-up: a new process importing gvnn_warp and making its first warp_frame_depth call",
    6: "a tiny problem (B=1, C=1, 32x32) where the per-call cost dominates, against kornia",
    7: "warp_frame_depth through a distorted camera (gvnn_warp.cameras: TUM freiburg1's radial-tangential "
       "coefficients; a fisheye) against the same call with the pinhole K, forward+backward, B=8 C=3 240x320, "
       "gradients for image, depth and pose (issue 19)",
}


def _progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def targets(args, R: int) -> list[dict]:
    """Rows with ``limit`` (a target) or ``limit=None`` (measured for information)."""
    rows = []

    def row(number, what, ours_ms, peer, peer_ms, limit=None, note=""):
        ratio = ours_ms / peer_ms
        rows.append({"target": number, "what": what, "ours_ms": ours_ms, "peer": peer, "peer_ms": peer_ms,
                     "ratio": ratio, "limit": limit, "met": None if limit is None else ratio <= limit,
                     "note": note})
        goal = f", target <= {limit:g}" if limit is not None else " (for information)"
        _progress(f"  {number}. {what}: ours {ours_ms:.2f} ms, {peer} {peer_ms:.2f} ms, ratio {ratio:.2f}{goal}")

    B, C, H, W = 8, 3, 240, 320
    res = interleaved(wfd_cases(B, C, H, W), R)
    row(1, "warp_frame_depth fwd+bwd vs grid_sample fwd+bwd", res["ours"], "grid_sample", res["grid_sample"], 1.0,
        "grads: image, depth, pose vs image, grid")
    row(1, "warp_frame_depth fwd+bwd vs kornia warp_frame_depth fwd+bwd", res["ours"], "kornia", res["kornia"], 0.25)
    res = interleaved(wfd_cases(B, C, H, W, image_grad=False), R)
    row(1, "warp_frame_depth fwd+bwd, image as data (grads: depth, pose) vs grid_sample (grads: grid)",
        res["ours"], "grid_sample", res["grid_sample"], note="only the gradients asked for are computed")
    row(1, "warp_frame_depth fwd+bwd, image as data vs kornia (grads: depth, pose)", res["ours"], "kornia",
        res["kornia"])
    res_f = interleaved(wfd_cases(B, C, H, W, forward_only=True), R)
    row(1, "warp_frame_depth forward vs kornia forward", res_f["ours"], "kornia", res_f["kornia"])
    for b, h, w in ((B, H, W), (4, 192, 640)):  # (and at Monodepth2's size, the training objective's)
        res = interleaved(wfd_cases(b, C, h, w, peers=("grid_sample", "grid_sample_projected")), R)
        size = f"B={b} {h}x{w}"
        row(1, f"warp_frame_depth fwd+bwd vs grid_sample fwd+bwd at its own sample positions, {size}", res["ours"],
            "grid_sample", res["grid_sample_projected"], note="the same memory access pattern; grads: image and grid")
        if (b, h, w) != (B, H, W):
            row(1, f"warp_frame_depth fwd+bwd vs grid_sample fwd+bwd (affine grid), {size}", res["ours"],
                "grid_sample", res["grid_sample"])

    res = interleaved(bilinear_cases(B, C, H, W), R)
    row(2, "bilinear_sample fwd+bwd vs grid_sample fwd+bwd", res["ours"], "grid_sample", res["grid_sample"], 1.5,
        "affine (spatial-transformer) grid")
    row(2, "bilinear_sample forward vs grid_sample forward", res["ours_forward"], "grid_sample",
        res["grid_sample_forward"], 2.0)
    res = interleaved(bilinear_cases(B, C, H, W, grid_kind="random"), R)
    row(2, "bilinear_sample fwd+bwd, random grid", res["ours"], "grid_sample", res["grid_sample"],
        note="uniformly random positions: every sample a cache miss")
    row(2, "bilinear_sample forward, random grid", res["ours_forward"], "grid_sample", res["grid_sample_forward"])

    n = 100_000 if args.quick else 1_000_000
    res = interleaved(so3_cases(n), R)
    row(3, f"so3_exp fwd+bwd ({n:,} vectors) vs kornia axis_angle_to_rotation_matrix", res["ours"], "kornia",
        res["kornia"], 0.5)

    res = interleaved(wfd_cases(1, 1, 32, 32, peers=("kornia",)), max(R, 25), warmup=3)
    row(6, "warp_frame_depth fwd+bwd B=1 C=1 32x32 vs kornia", res["ours"], "kornia", res["kornia"], 1.0)

    res = interleaved(lens_cases(B, C, H, W), R)
    row(7, "warp_frame_depth fwd+bwd, radtan camera vs pinhole K", res["radtan"], "pinhole", res["pinhole"], 1.3)
    row(7, "warp_frame_depth fwd+bwd, fisheye camera vs pinhole K", res["fisheye"], "pinhole", res["pinhole"], 1.3)
    row(7, "warp_frame_depth fwd+bwd, radtan camera, rays recomputed every call, vs pinhole K",
        res["radtan_rays_each_call"], "pinhole", res["pinhole"], note="Newton's method for every pixel's ray")
    return rows


def scaling(args, R: int) -> dict:
    """warp_frame_depth fwd+bwd against the peers over image sizes (B=8) and batch sizes (240x320);
    a configuration in both series is measured once."""
    sizes = [(60, 80), (240, 320)] if args.quick else [(60, 80), (120, 160), (240, 320), (480, 640)]
    batches = [1, 8] if args.quick else [1, 2, 4, 8]
    measured: dict[tuple[int, int, int], dict] = {}

    def measure(B, H, W):
        if (B, H, W) not in measured:
            res = interleaved(wfd_cases(B, 3, H, W), R)
            measured[B, H, W] = {"B": B, "H": H, "W": W, **res}
            _progress(f"  B={B} {H}x{W}: " + ", ".join(f"{k} {v:.2f} ms" for k, v in res.items()))
        return measured[B, H, W]

    return {"image_size": [measure(8, H, W) for H, W in sizes], "batch": [measure(B, 240, 320) for B in batches]}


def memory_section(args) -> dict:
    res = {}
    for impl in ("ours", "kornia"):
        res[impl] = memory.run_subprocess(impl, 8, 3, 240, 320, args.threads)
        r = res[impl]
        mib = 2**20
        _progress(f"  {impl}: peak {r['peak_bytes'] / mib:.1f} MiB, inputs+outputs+grads "
                  f"{r['io_bytes'] / mib:.1f} MiB, ratio {r['ratio']:.2f}")
    return res


def startup_section(args) -> dict:
    res = {"warm": startup.run(cold=False)}
    warm = res["warm"]
    _progress(f"  warm cache: import gvnn_warp + first warp_frame_depth fwd+bwd {warm['import_and_first_call_s']:.2f} s"
              f" (torch import before it: {warm['torch_import_s']:.2f} s)")
    if not args.quick:
        res["cold"] = startup.run(cold=True)
        _progress(f"  cold cache: {res['cold']['import_and_first_call_s']:.1f} s")
        res["cold_all_modules"] = startup.run(cold=True, all_modules=True)
        _progress(f"  cold cache, every gvnn_warp module compiled: "
                  f"{res['cold_all_modules']['all_modules_loaded_s']:.1f} s")
    return res


# ----------------------------------------------------------------------------- report


def fmt_ratio_table(rows) -> str:
    """The targets (with limit and whether it is met), then the rows measured for information."""
    goals = [r for r in rows if r["limit"] is not None]
    info = [r for r in rows if r["limit"] is None]
    lines = ["| # | comparison | ours (ms) | peer (ms) | ratio ours/peer | target | met |",
             "|---|---|---:|---:|---:|---:|---|"]
    for r in goals:
        lines.append(f"| {r['target']} | {r['what']} | {r['ours_ms']:.2f} | {r['peer_ms']:.2f} | {r['ratio']:.2f} | "
                     f"<= {r['limit']:g} | {'yes' if r['met'] else '**no**'} |")
    if info:
        lines += ["", "Measured for information (no target):", "",
                  "| # | comparison | ours (ms) | peer (ms) | ratio ours/peer | note |", "|---|---|---:|---:|---:|---|"]
        for r in info:
            lines.append(f"| {r['target']} | {r['what']} | {r['ours_ms']:.2f} | {r['peer_ms']:.2f} | "
                         f"{r['ratio']:.2f} | {r['note']} |")
    return "\n".join(lines)


def fmt_targets_legend(numbers) -> str:
    return "\n".join(f"{n}. {TARGETS[n]}." for n in sorted(numbers))


def fmt_scaling(sc) -> str:
    """One table over both series (image size at B=8, batch at 240x320), each configuration once."""
    rows = {(r["B"], r["H"], r["W"]): r for r in [*sc["image_size"], *sc["batch"]]}
    lines = ["\nwarp_frame_depth forward+backward (C=3) over image size at B=8 and over batch size at 240x320, ms, "
             "and the ratios ours/peer:\n",
             "| B | H x W | ours | grid_sample | kornia | ours / grid_sample | ours / kornia |",
             "|---:|---|---:|---:|---:|---:|---:|"]
    for (B, H, W), r in sorted(rows.items(), key=lambda kv: (kv[0][0] != 8, kv[0][0], kv[0][1] * kv[0][2])):
        lines.append(f"| {B} | {H}x{W} | {r['ours']:.2f} | {r['grid_sample']:.2f} | {r['kornia']:.2f} | "
                     f"{r['ours'] / r['grid_sample']:.2f} | {r['ours'] / r['kornia']:.2f} |")
    return "\n".join(lines)


def fmt_summary(report: dict, threads: int) -> str:
    m = report["machine"]
    load = m.get("load_average") or ()
    load_end = m.get("load_average_end") or ()
    numbers = {r["target"] for r in report["targets"]} | ({4, 5} if "memory" in report else set())
    out = [
        "# gvnn_warp benchmarks",
        "",
        f"Machine: {m['cpu']}, nproc {m['nproc']}; Python {m['python']}, torch {m['torch']}, warp {m['warp']}, "
        f"kornia {m['kornia']}; torch and gvnn_warp on {threads} threads; {report['repeats']} interleaved repeats "
        f"(medians){'; --quick run' if report.get('quick') else ''}; {report['started']} - {report['finished']}; "
        f"load average at start {', '.join(f'{x:.2f}' for x in load)}, at end "
        f"{', '.join(f'{x:.2f}' for x in load_end)}.",
        "",
        "## Targets",
        "",
        "Ratios are ours / peer (below 1: ours is faster). What each target measures:",
        "",
        fmt_targets_legend(numbers),
        "",
        fmt_ratio_table(report["targets"]),
    ]
    if "memory" in report:
        mem, mib = report["memory"], 2**20
        ok = "met" if mem["ours"]["ratio"] <= 3 else "**not met**"
        out.append(
            f"\n4. Peak memory, warp_frame_depth fwd+bwd B=8 C=3 240x320: ours "
            f"{mem['ours']['peak_bytes'] / mib:.1f} MiB = {mem['ours']['ratio']:.2f}x its inputs+outputs+gradients "
            f"({mem['ours']['io_bytes'] / mib:.1f} MiB; "
            f"target <= 3x: {ok}); kornia {mem['kornia']['peak_bytes'] / mib:.1f} MiB = "
            f"{mem['kornia']['ratio']:.2f}x ({mem['ours']['method']})."
        )
        s = report["startup"]
        warm = s["warm"]["import_and_first_call_s"]
        line = (
            f"\n5. Start-up, new process: import gvnn_warp + first warp_frame_depth fwd+bwd {warm:.2f} s with a warm "
            f"kernel cache (target < 1 s: {'met' if warm < 1 else '**not met**'}; torch's own import before it: "
            f"{s['warm']['torch_import_s']:.2f} s)"
        )
        if "cold" in s:
            cold = s["cold"]["import_and_first_call_s"]
            line += (
                f"; {cold:.1f} s with an empty kernel cache (target < 30 s: {'met' if cold < 30 else '**not met**'});"
                f" every gvnn_warp module compiled (wp.force_load, incl. the per-pixel and render modules): "
                f"{s['cold_all_modules']['all_modules_loaded_s']:.1f} s"
            )
        out.append(line + ".")
    out += ["", "## Scaling", fmt_scaling(report["scaling"])]
    if "kernels" in report:
        out += ["", "## Kernel microbenchmarks", "",
                f"Each Warp kernel's launches alone (float32, through launch(), no autograd, no allocation), on 1 "
                f"and on {threads} threads:", "", kernel_bench.format_rows(report["kernels"], threads)]
    return "\n".join(out)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m benchmarks.run", description=__doc__.split("\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--quick", action="store_true", help="fewer repeats and sizes: a smoke run of ~1 min")
    p.add_argument("--json", default=str(ROOT / "benchmarks" / "results" / "latest.json"), help="JSON report")
    p.add_argument("--threads", type=int, default=2, help="torch threads (gvnn_warp follows)")
    p.add_argument("--repeats", type=int, default=None, help="interleaved repeats (default: 3 with --quick, else 11)")
    p.add_argument("--no-kernels", action="store_true", help="skip the kernel microbenchmarks")
    p.add_argument("--no-subprocess", action="store_true", help="skip memory and start-up (fresh processes)")
    p.add_argument("--markdown", default=None, help="also write the report to this markdown file")
    return p


def main(argv=None) -> dict:
    args = build_parser().parse_args(argv)
    torch.set_num_threads(args.threads)
    os.environ.pop("GVNN_WARP_NUM_THREADS", None)
    R = args.repeats or (3 if args.quick else 11)
    report = {"machine": machine(), "threads": args.threads, "repeats": R, "quick": args.quick,
              "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    _progress(f"gvnn_warp benchmarks ({report['machine']['cpu']}, nproc {report['machine']['nproc']}, "
              f"torch {report['machine']['torch']}, warp {report['machine']['warp']}, {args.threads} threads); "
              "the report follows on stdout at the end")

    _progress("targets:")
    report["targets"] = targets(args, R)
    if not args.no_subprocess:
        _progress("memory (fresh process):")
        report["memory"] = memory_section(args)
        _progress("start-up (fresh process):")
        report["startup"] = startup_section(args)
    _progress("scaling:")
    report["scaling"] = scaling(args, max(3, R // 2))
    if not args.no_kernels:
        _progress("kernel microbenchmarks ...")
        report["kernels"] = kernel_bench.run(args.threads, args.quick, max(3, R // 2))
        torch.set_num_threads(args.threads)
    report["finished"] = time.strftime("%Y-%m-%d %H:%M:%S")
    report["machine"]["load_average_end"] = os.getloadavg() if hasattr(os, "getloadavg") else None

    summary = fmt_summary(report, args.threads)
    print(summary, flush=True)
    if args.markdown:
        Path(args.markdown).write_text(summary + "\n")
        _progress(f"markdown: {args.markdown}")

    path = Path(args.json)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=1, default=str))
    _progress(f"JSON: {path}")
    return report


if __name__ == "__main__":
    main()
