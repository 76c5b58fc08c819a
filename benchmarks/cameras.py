"""Camera models: our distorting ops against kornia.geometry.calibration (the torch code a user
would otherwise run), and against the pinhole (what a distortion model costs).

    .venv/bin/python -m benchmarks.cameras [--size 640x480] [--repeats 15] [--threads 2]

float32, one 640x480 image's worth of pixels or points (B = 1), TUM freiburg1's radial-tangential
coefficients. Forward+backward = the call plus ``out.sum().backward()`` with gradients for the
pixels (or points), K and the coefficients. Times are medians of interleaved runs (ms); ratios are
to the first row of each group. Accuracy: max |error| in pixels against OpenCV
(``cv2.undistortPoints`` with tight termination criteria), in float64.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import kornia.geometry.calibration as KC  # noqa: E402

import gvnn_warp as G  # noqa: E402
from benchmarks.common import Case, clear_grads, interleaved, leaves, machine  # noqa: E402

TUM_K = [[517.3, 0.0, 318.6], [0.0, 516.5, 255.3], [0.0, 0.0, 1.0]]
TUM_D = [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]


def pixel_grid(W: int, H: int, dtype) -> torch.Tensor:
    ys, xs = torch.meshgrid(torch.arange(H, dtype=dtype), torch.arange(W, dtype=dtype), indexing="ij")
    return torch.stack([xs, ys], -1).reshape(1, H * W, 2).contiguous()


def fwd_bwd(fn, ts):
    def run():
        out = fn(*ts)
        out.sum().backward()

    return Case("", run, clear_grads(ts))


def groups(W: int, H: int) -> dict[str, list[tuple[str, Case]]]:
    f32 = torch.float32
    K = torch.tensor(TUM_K, dtype=f32)
    d = torch.tensor(TUM_D, dtype=f32)
    px = pixel_grid(W, H, f32)
    depth = torch.rand(1, 1, H, W, dtype=f32) + 1.0
    pts = G.depth_to_points(depth, K).reshape(1, -1, 3).contiguous()
    out: dict[str, list[tuple[str, Case]]] = {}

    def both(name, fn, tensors):
        fwd = Case("", lambda: fn(*tensors))
        return [(f"{name} forward", fwd), (f"{name} fwd+bwd", fwd_bwd(fn, leaves(*tensors)))]

    out["undistort_points"] = [
        *both("ours (Newton, to 1e-10)", lambda p, k, c: G.undistort_points(p, G.RadTanCamera(k, c))[0], (px, K, d)),
        *both("kornia num_iters=5", lambda p, k, c: KC.undistort_points(p, k, c), (px, K, d)),
        *both("kornia num_iters=20", lambda p, k, c: KC.undistort_points(p, k, c, num_iters=20), (px, K, d)),
    ]
    out["distort_points"] = [
        *both("ours", lambda p, k, c: G.distort_points(p, G.RadTanCamera(k, c))[0], (px, K, d)),
        *both("kornia", lambda p, k, c: KC.distort_points(p, k, c), (px, K, d)),
    ]
    out["project_points"] = [
        *both("pinhole K", lambda p, k: G.project_points(p, k), (pts, K)),
        *both("RadTanCamera", lambda p, k, c: G.project_points(p, G.RadTanCamera(k, c)), (pts, K, d)),
        *both(
            "FisheyeCamera",
            lambda p, k, c: G.project_points(p, G.FisheyeCamera(k, c)),
            (pts, K, torch.tensor([0.02, -0.005, 0.001, -0.0002])),
        ),
    ]
    out["depth_to_points"] = [
        *both("pinhole K", lambda z, k: G.depth_to_points(z, k), (depth, K)),
        *both("RadTanCamera", lambda z, k, c: G.depth_to_points(z, G.RadTanCamera(k, c)), (depth, K, d)),
    ]
    return out


def accuracy(W: int, H: int) -> dict[str, float]:
    import cv2  # OpenCV, the reference, is in the test extra only: needed by this measurement alone

    f64 = torch.float64
    K = torch.tensor(TUM_K, dtype=f64)
    d = torch.tensor(TUM_D, dtype=f64)
    px = pixel_grid(W, H, f64)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    ref = cv2.undistortPoints(px[0].numpy()[:, None], K.numpy(), d.numpy(), None, None, K.numpy(), crit)[:, 0]
    ref = torch.from_numpy(np.ascontiguousarray(ref))
    return {
        "ours": (G.undistort_points(px, G.RadTanCamera(K, d))[0][0] - ref).abs().max().item(),
        "kornia num_iters=5": (KC.undistort_points(px, K, d)[0] - ref).abs().max().item(),
        "kornia num_iters=20": (KC.undistort_points(px, K, d, num_iters=20)[0] - ref).abs().max().item(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    W, H = (int(v) for v in args.size.split("x"))
    torch.set_num_threads(args.threads)
    m = machine()
    print(f"# camera models, {W}x{H}, float32, {args.threads} threads, load {m['load_average']}")
    for title, rows in groups(W, H).items():
        cases = [c for _, c in rows]
        for (name, c) in rows:
            c.name = name
        times = interleaved(cases, args.repeats)
        print(f"\n## {title}\n\n| case | ms | ratio |\n| --- | --- | --- |")
        base = {kind: None for kind in ("forward", "fwd+bwd")}
        for name, _ in rows:
            kind = "forward" if name.endswith("forward") else "fwd+bwd"
            base[kind] = base[kind] or times[name]
            print(f"| {name} | {times[name]:.2f} | {times[name] / base[kind]:.2f}x |")
    print("\n## undistort_points accuracy vs OpenCV (float64, max |error| px over the whole image)\n")
    for name, err in accuracy(W, H).items():
        print(f"- {name}: {err:.2e}")


if __name__ == "__main__":
    main()
