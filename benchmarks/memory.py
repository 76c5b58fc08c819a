"""Peak memory of one warp_frame_depth forward+backward, measured in a fresh process.

Method (Linux): in a new process, run the op once on a tiny input (loads modules, touches code
pages), allocate the real inputs, then reset the peak-RSS counter (``echo 5 >
/proc/self/clear_refs`` resets ``VmHWM``) and run forward+backward (``out.sum().backward()``, the
gradient of the image, depth and pose). Peak = ``VmHWM`` after the call - RSS before it + the
bytes of the inputs, i.e. the memory the computation needs including its inputs. RSS counts every
allocation, torch's included (tracemalloc does not see torch's CPU allocations). Where
clear_refs is unavailable, ``ru_maxrss`` (peak since process start) is used instead.

Usage: ``python -m benchmarks.memory --impl ours|kornia --B 8 --C 3 --H 240 --W 320`` prints JSON.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys


def _rss_kb(field: str) -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1])
    raise KeyError(field)


def _reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def measure(impl: str, B: int, C: int, H: int, W: int, threads: int) -> dict:
    # run in the measuring child process (main --impl), where torch's thread count is set before kornia
    # and gvnn_warp load; importing this module (benchmarks.run does, to start that child) loads none of them
    import torch

    torch.set_num_threads(threads)
    import kornia

    import gvnn_warp as G
    from benchmarks.common import wfd_scene

    def step(image, depth, pose, pose44, K):
        if impl == "ours":
            out, valid = G.warp_frame_depth(image, depth, pose, K)
        else:
            out = kornia.geometry.depth.warp_frame_depth(image, depth, pose44, K)
        out.sum().backward()
        return out

    def inputs(b, c, h, w):
        image, depth, pose, pose44, K = wfd_scene(b, c, h, w)
        return [image.requires_grad_(), depth.requires_grad_(), pose.requires_grad_(), pose44.requires_grad_(), K]

    step(*inputs(1, C, 16, 16))  # warm-up: modules, code pages
    args = inputs(B, C, H, W)
    if impl == "kornia":
        used = [args[0], args[1], args[3], args[4]]
    else:
        used = [args[0], args[1], args[2], args[4]]
    in_bytes = sum(t.numel() * t.element_size() for t in used)
    exact = _reset_peak()
    rss0 = _rss_kb("VmRSS")
    if not exact:
        peak0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    out = step(*args)
    if exact:
        peak_kb = _rss_kb("VmHWM") - rss0
    else:
        peak_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - max(peak0, rss0)
    out_bytes = out.numel() * out.element_size() + (B * H * W if impl == "ours" else 0)  # + valid mask
    grad_bytes = sum(t.grad.numel() * t.grad.element_size() for t in used if t.grad is not None)
    io = in_bytes + out_bytes + grad_bytes
    peak = peak_kb * 1024 + in_bytes
    return {
        "impl": impl,
        "shape": [B, C, H, W],
        "peak_bytes": peak,
        "io_bytes": io,
        "ratio": peak / io,
        "method": "VmHWM reset via /proc/self/clear_refs" if exact else "ru_maxrss delta (upper bound)",
    }


def run_subprocess(impl: str, B: int, C: int, H: int, W: int, threads: int) -> dict:
    """Run :func:`measure` in a fresh interpreter (so nothing allocated earlier hides the peak)."""
    cmd = [sys.executable, "-m", "benchmarks.memory", "--impl", impl, "--B", str(B), "--C", str(C),
           "--H", str(H), "--W", str(W), "--threads", str(threads)]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--impl", choices=["ours", "kornia"], default="ours")
    p.add_argument("--B", type=int, default=8)
    p.add_argument("--C", type=int, default=3)
    p.add_argument("--H", type=int, default=240)
    p.add_argument("--W", type=int, default=320)
    p.add_argument("--threads", type=int, default=2)
    a = p.parse_args()
    print(json.dumps(measure(a.impl, a.B, a.C, a.H, a.W, a.threads)))


if __name__ == "__main__":
    main()
