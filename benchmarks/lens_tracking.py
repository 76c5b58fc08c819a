"""Tracking through a lens at pinhole speed (issue 32): the same frames through the pinhole and through
a radial-tangential lens, side by side in one process.

    python -m benchmarks.lens_tracking [--frames 60] [--size 640x480] [--seed 5] [--repeats 3]

A se3 sequence is rendered through a pinhole; its lens twin is made by resampling every frame into
the image of the same K with the Freiburg 1 distortion (each lens pixel takes the pinhole image at
its undistorted ray: colour bilinear, depth from the nearest pixel). Both are tracked frame to frame
by ``gvnn-warp track``'s aligner: the pinhole frames with the pinhole aligner, the lens frames with
``lens="resample"`` (each frame resampled once into the ideal pinhole image) and ``lens="exact"``
(rays through the lens model inside the aligner). It prints ms per pair (the best of ``--repeats``
interleaved runs) and the ATE of each against the true poses.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from gvnn_warp.kernels.sampling.remap import RemapTable, remap

from gvnn_warp.cli.args import image_size, positive_int
from gvnn_warp.datasets.intrinsics import DISTORTION_PRESETS
from gvnn_warp.datasets.tum import TUMWriter, read_tum
from gvnn_warp.odometry.evaluation import evaluate_trajectory
from gvnn_warp.odometry.sequence import make_aligner
from gvnn_warp.odometry.tracking import track
from gvnn_warp.synthetic.sequence import render_sequence


def pinhole_positions(K: np.ndarray, dist, width: int, height: int) -> np.ndarray:
    """(H * W, 2) positions in the pinhole image of each lens pixel (fixed-point undistortion)."""
    k1, k2, p1, p2, k3 = dist
    x, y = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    xd, yd = (x - K[0, 2]) / K[0, 0], (y - K[1, 2]) / K[1, 1]
    xn, yn = xd.copy(), yd.copy()
    for _ in range(100):
        r2 = xn * xn + yn * yn
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xn = (xd - 2 * p1 * xn * yn - p2 * (r2 + 2 * xn * xn)) / radial
        yn = (yd - p1 * (r2 + 2 * yn * yn) - 2 * p2 * xn * yn) / radial
    return np.stack([K[0, 0] * xn + K[0, 2], K[1, 1] * yn + K[1, 2]], -1).reshape(-1, 2).astype(np.float32)


def lens_twin(seq, out: Path, dist) -> None:
    """Write ``seq`` (a pinhole TUM sequence) as seen through a lens with ``dist`` and the same K."""
    pos = RemapTable(pinhole_positions(seq.K, dist, seq.width, seq.height), seq.width, seq.height)
    shape = (seq.height, seq.width)
    with TUMWriter(out, seq.K, depth_scale=seq.depth_scale) as writer:
        for i in range(len(seq)):
            image = np.clip(remap(seq.image(i), pos, shape), 0, 1)
            depth = remap(seq.depth(i), pos, shape, nearest=True)
            writer.add(seq.timestamps[i], image, depth, seq.gt_poses[i])
    K = seq.K
    (out / "intrinsics.txt").write_text(" ".join(f"{v:.10g}" for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2], *dist))
                                        + "\n")


def run(frames: int, size: tuple[int, int], seed: int, repeats: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        render_sequence(Path(tmp) / "pin", "se3", frames, size, seed, progress=False)
        pin = read_tum(Path(tmp) / "pin")
        dist = DISTORTION_PRESETS["fr1"]
        lens_twin(pin, Path(tmp) / "lens", dist)
        lens = read_tum(Path(tmp) / "lens")
        assert lens.dist is not None
        cases = {"pinhole": (pin, make_aligner(pin.K)),
                 "lens, resampled": (lens, make_aligner(lens.K, dist=lens.dist, size=size, lens="resample")),
                 "lens, exact": (lens, make_aligner(lens.K, dist=lens.dist, lens="exact"))}
        frames_of = {name: [(s.image(i, gray=True), s.depth(i)) for i in range(frames)] for name, (s, _) in
                     cases.items()}
        best = {name: np.inf for name in cases}
        ate = {}
        for _ in range(repeats):
            for name, (s, aligner) in cases.items():
                fr = frames_of[name]
                r = track(lambda i, fr=fr: fr[i], frames, aligner, start_pose=s.gt_poses[0], progress=False)
                best[name] = min(best[name], r.ms_per_pair)
                ate[name] = evaluate_trajectory(s.timestamps, r.poses, s.gt_poses).ate_rmse_m
    return {"ms": best, "ate_m": ate}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=positive_int, default=60)
    p.add_argument("--size", type=image_size(16), default=(640, 480))
    p.add_argument("--seed", type=int, default=5)
    p.add_argument("--repeats", type=positive_int, default=3)
    args = p.parse_args(argv)
    r = run(args.frames, args.size, args.seed, args.repeats)
    base = r["ms"]["pinhole"]
    print(f"lens tracking, {args.size[0]}x{args.size[1]}, {args.frames} frames (best of {args.repeats}):")
    for name, ms in r["ms"].items():
        print(f"  {name:<16} {ms:6.2f} ms per pair ({ms / base:.2f}x the pinhole), ATE {100 * r['ate_m'][name]:.3f} cm")


if __name__ == "__main__":
    main()
