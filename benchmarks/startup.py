"""Start-up cost in a new process: ``import gvnn_warp`` plus the first ``warp_frame_depth``
forward+backward call, with a warm kernel cache and with an empty one (every kernel the call needs
is compiled). torch's own import is measured separately (a user has imported torch to make
tensors before calling us).

Usage: ``python -m benchmarks.startup [--cold] [--all-modules]`` prints JSON; ``--cold`` points
``WARP_CACHE_PATH`` at a new empty directory.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

_CHILD = r"""
import json, os, sys, time
t0 = time.perf_counter()
import torch
t1 = time.perf_counter()
image = torch.rand(1, 3, 32, 32, requires_grad=True)
depth = torch.full((1, 1, 32, 32), 2.0, requires_grad=True)
pose = torch.eye(4)[None].requires_grad_()
K = torch.tensor([[25.0, 0, 15.5], [0, 25.0, 15.5], [0, 0, 1]])
t2 = time.perf_counter()
import gvnn_warp as G
out, valid = G.warp_frame_depth(image, depth, pose, K)
t3 = time.perf_counter()
out.sum().backward()
t4 = time.perf_counter()
res = {"torch_import_s": t1 - t0, "import_and_first_forward_s": t3 - t2, "import_and_first_call_s": t4 - t2}
if "--all-modules" in sys.argv:
    import warp as wp
    import gvnn_warp.functional, gvnn_warp.nn, gvnn_warp.odometry, gvnn_warp.synthetic  # noqa: F401
    t5 = time.perf_counter()
    wp.force_load(device="cpu", max_workers=os.cpu_count())  # compile modules in parallel
    res["all_modules_loaded_s"] = time.perf_counter() - t2
    res["all_modules_after_first_call_s"] = time.perf_counter() - t5
print(json.dumps(res))
"""


def run(cold: bool, all_modules: bool = False) -> dict:
    env = dict(os.environ)
    with tempfile.TemporaryDirectory(prefix="gvnn_warp_cold_cache_") as tmp:
        if cold:
            env["WARP_CACHE_PATH"] = tmp
        args = [sys.executable, "-c", _CHILD] + (["--all-modules"] if all_modules else [])
        t0 = time.perf_counter()
        out = subprocess.run(args, env=env, capture_output=True, text=True, check=True)
        wall = time.perf_counter() - t0
    res = json.loads(out.stdout.strip().splitlines()[-1])
    res["process_wall_s"] = wall
    res["cache"] = "cold" if cold else "warm"
    return res


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cold", action="store_true")
    p.add_argument("--all-modules", action="store_true")
    a = p.parse_args()
    print(json.dumps(run(a.cold, a.all_modules)))


if __name__ == "__main__":
    main()
