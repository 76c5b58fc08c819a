"""Where a tracked frame pair's time goes: ``DirectAligner.prepare`` (the pyramid) and
``align_frames``, per pair of a TUM-format sequence (e.g. one written by ``gvnn-warp render``).

    python -m benchmarks.tracking_parts DIR [--reps 3] [--threads N] [--occlusion-levels L]

Prepares every frame once and aligns it to the previous one, as ``gvnn-warp track`` does, ``--reps``
times over the sequence (the first pass warms the caches and is not counted); prints the median
wall and CPU (``process_time``, all threads) milliseconds per pair of each part. ``--threads 1``
gives the steadier CPU figure on a shared host. ``--occlusion-levels`` overrides the aligner's
``OCCLUSION_LEVELS`` (how many of the finest levels run the occlusion test) to price it.

To compare two versions of the code, run it in separate processes with each version first on
``PYTHONPATH`` (a copy of its ``gvnn_warp/`` with ``kernels/`` copied in as
``gvnn_warp/kernels``), alternating, and compare the ratios.
"""

from __future__ import annotations

import argparse
import statistics
import time

from gvnn_warp.kernels.core import launch

from gvnn_warp.datasets.tum import read_tum
from gvnn_warp.odometry import aligner as odometry  # its OCCLUSION_LEVELS, set by --occlusion-levels
from gvnn_warp.odometry.sequence import make_aligner


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("data", help="a TUM-format folder (gvnn-warp render --out DIR)")
    p.add_argument("--reps", type=int, default=3, help="passes over the sequence (the first not counted)")
    p.add_argument("--threads", type=int, default=None, help="launch threads (default: the package's)")
    p.add_argument("--occlusion-levels", type=int, default=None)
    args = p.parse_args(argv)

    if args.threads is not None:
        launch.set_num_threads(args.threads)
    if args.occlusion_levels is not None:
        odometry.OCCLUSION_LEVELS = args.occlusion_levels
    seq = read_tum(args.data)
    frames = [(seq.image(i, gray=True), seq.depth(i)) for i in range(len(seq))]
    # as gvnn-warp track: through the camera's radial-tangential distortion when it has one
    aligner = make_aligner(seq.K, dist=seq.dist)
    wall = {"prepare": [], "align": []}
    cpu = {"prepare": [], "align": []}
    for rep in range(max(2, args.reps)):
        prev = aligner.prepare(*frames[0])
        for image, depth in frames[1:]:
            c0, t0 = time.process_time(), time.perf_counter()
            cur = aligner.prepare(image, depth)
            c1, t1 = time.process_time(), time.perf_counter()
            aligner.align_frames(prev, cur)
            c2, t2 = time.process_time(), time.perf_counter()
            if rep:
                wall["prepare"].append(t1 - t0)
                wall["align"].append(t2 - t1)
                cpu["prepare"].append(c1 - c0)
                cpu["align"].append(c2 - c1)
            prev = cur

    def ms(a):
        return f"{1e3 * statistics.median(a):.2f}"

    total_w = [a + b for a, b in zip(wall["prepare"], wall["align"])]
    total_c = [a + b for a, b in zip(cpu["prepare"], cpu["align"])]
    print(f"{args.data}: {len(frames) - 1} pairs x {max(2, args.reps) - 1} passes, threads "
          f"{launch.get_num_threads()}; median ms per pair (wall / CPU): prepare {ms(wall['prepare'])} / "
          f"{ms(cpu['prepare'])}, align {ms(wall['align'])} / {ms(cpu['align'])}, "
          f"total {ms(total_w)} / {ms(total_c)}")


if __name__ == "__main__":
    main()
