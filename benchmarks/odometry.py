"""Direct RGB-D odometry against Open3D's, on the same frames of a TUM-format sequence.

    python -m benchmarks.odometry [--frames 200] [--sizes 320x240,640x480] [--seed 0] [--data DIR]
                                  [--strides 5,10] [--no-open3d] [--no-ours] [--json PATH]

(run from the repository root; Open3D is the optional extra ``pip install -e ".[bench]"``, whose
wheel needs the system's libusb-1.0). For each size a se3 sequence (1.5-4 cm and 0.6-1.6 deg per
frame) is rendered by ``gvnn_warp.synthetic.sequence`` (``gvnn-warp render``'s library) into a
temporary TUM folder and read back through ``gvnn_warp.datasets.tum`` (or ``--data DIR`` is read:
one existing TUM folder). Then:

1. Tracking: frame-to-frame odometry over the whole sequence (identity initial guess, as Open3D's
   examples), by Open3D 0.20's tensor ``rgbd_odometry_multi_scale`` (``Method.Intensity``,
   its default pyramid of 3 levels with 10/5/3 iterations, depth_max 10 m) and by
   ``gvnn_warp.odometry.DirectAligner`` (grey images, as Open3D's Intensity term). Reported: ms per
   pair (alignment incl. the live frame's pyramid; file reading excluded), RPE translation /
   rotation RMSE over 1-frame steps, ATE RMSE (SE(3) Umeyama) - all by ``evo`` - and the failed
   pairs (RPE above 1 cm or 0.25 deg). Our tracker pipelines (``gvnn_warp.odometry.tracking``: frame i's
   pyramid is built on a helper thread while frame i - 1 is aligned; each step returns when its
   work is done); Open3D's call runs on both cores through OpenMP.
2. Basin: every pair (i, i + s) for s in ``--strides`` (every offset i), aligned from the identity;
   the fraction whose relative pose is within 0.25 deg and 1 cm.
3. The normal equations (issue 15's target 3) in the same lockstep: for each pair (i - 1, i), the
   median of three calls of the pure-Warp ``photometric_normal_equations`` (grey, full size, the
   true relative pose, Huber, ``out=``; its data copied in untimed, so warm in cache), reported
   as ms per call and as a fraction of Open3D's median time per pair. The fraction is a proxy for
   the machine's speed, not a measure of the same work: Open3D's pair is a whole multi-threaded
   three-level alignment. The issue's 0.5 ms (at 320x240) was set on a machine where Open3D took
   ~5.9 ms per pair, 0.085x; the benchmark prints that figure beside the 320x240 fraction.

The two trackers run in lockstep, frame by frame, in alternating order, so that both see the same
machine load (the machine is shared and noisy: compare the ratio), with Python's cyclic garbage
collector paused (a full collection took ~0.2 s here, charged to whichever tracker allocated).
ms per pair is the mean over the sequence (as ``gvnn-warp track`` reports it) and, in the JSON,
also the median. Idle OpenMP threads sleep (``OMP_WAIT_POLICY=PASSIVE`` unless set): Open3D's
spinning threads would otherwise steal the cores from the other method's, and torch is not imported.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import sys
import tempfile
import time
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before Open3D loads its OpenMP runtime

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import warp as wp  # noqa: E402
from gvnn_warp.kernels.core.launch import mat34f  # noqa: E402
from gvnn_warp.kernels.photometric import pipeline as photometric_pipeline  # noqa: E402
from PIL import Image  # noqa: E402
from tqdm import tqdm  # noqa: E402

from gvnn_warp.cli.args import image_size, positive_int  # noqa: E402  (argument types of this command line)
from gvnn_warp.datasets.tum import read_tum  # noqa: E402
from gvnn_warp.odometry.evaluation import FAIL_ROT_DEG, FAIL_TRANS_M, evaluate_trajectory, pose_error  # noqa: E402
from gvnn_warp.odometry.sequence import make_aligner  # noqa: E402
from gvnn_warp.odometry.tracking import Tracker, frame_aligner  # noqa: E402
from gvnn_warp.synthetic import relative_pose  # noqa: E402
from gvnn_warp.synthetic.sequence import render_sequence  # noqa: E402

OPEN3D_DEPTH_MAX = 10.0  # metres; the rendered room is 8 m deep (Open3D's default, 3 m, drops much of it)


class Open3DAligner:
    """Open3D's tensor multi-scale RGB-D odometry (Intensity term) behind the tracking interface."""

    name = "Open3D 0.20 Intensity"

    def __init__(self, K: np.ndarray, depth_scale: float, method: str = "Intensity"):
        # Open3D is an optional extra (``.[bench]``): an ImportError here skips it (see main)
        import open3d as o3d

        self.o3d = o3d
        self.odo = o3d.t.pipelines.odometry
        self.method = getattr(self.odo.Method, method)  # Intensity, Hybrid or PointToPlane
        self.name = f"Open3D 0.20 {method}"
        self.K = o3d.core.Tensor(np.asarray(K, dtype=np.float64))
        self.depth_scale = float(depth_scale)

    def prepare(self, image_u8: np.ndarray, depth_u16: np.ndarray):
        o3d = self.o3d
        return o3d.t.geometry.RGBDImage(o3d.t.geometry.Image(o3d.core.Tensor(image_u8)),
                                        o3d.t.geometry.Image(o3d.core.Tensor(depth_u16)))

    def align_frames(self, ref, live, init=None):
        init = np.eye(4) if init is None else np.asarray(init, dtype=np.float64)
        try:
            result = self.odo.rgbd_odometry_multi_scale(
                ref, live, self.K, self.o3d.core.Tensor(init), self.depth_scale, OPEN3D_DEPTH_MAX,
                method=self.method,
            )
        except RuntimeError:  # "Singular 6x6 linear system detected, tracking failed."
            return init, {"converged": False}
        # source = reference, target = live: the transformation maps reference points into the live camera
        return result.transformation.numpy(), {"valid_fraction": float(result.fitness)}


def _raw_reader(seq):
    """Frames as Open3D takes them from files: uint8 (H, W, 3) colour, uint16 (H, W) depth."""
    def read(i):
        rgb = np.ascontiguousarray(np.asarray(Image.open(seq.rgb_files[i]).convert("RGB")))
        depth = np.ascontiguousarray(np.asarray(Image.open(seq.depth_files[i])).astype(np.uint16))
        return rgb, depth

    return read


def _gray_reader(seq):
    return lambda i: (seq.image(i, gray=True), seq.depth(i))


def our_aligner(K: np.ndarray):
    """``gvnn_warp.odometry.DirectAligner`` with the settings ``gvnn-warp track`` uses."""
    return make_aligner(K)


def _cache(reader, n, aligner):
    """Every frame read and prepared once (for the basin test's many pairs)."""
    fa = frame_aligner(aligner)
    return [fa.prepare(*reader(i)) for i in range(n)]


def basin(prepared, aligner, gt_poses, stride: int) -> tuple[float, int]:
    """(fraction of pairs (i, i + stride), every i, aligned within 1 cm and 0.25 deg, number of pairs)."""
    fa = frame_aligner(aligner)
    ok = []
    for i in range(len(prepared) - stride):
        T, _ = fa.align_frames(prepared[i], prepared[i + stride], init=np.eye(4))
        T_true = relative_pose(gt_poses[i + stride], gt_poses[i])
        if not np.all(np.isfinite(T)):
            ok.append(False)
            continue
        dt, dr = pose_error(np.asarray(T, dtype=np.float64), T_true)
        ok.append(bool(dt <= FAIL_TRANS_M and dr <= FAIL_ROT_DEG))
    return (float(np.mean(ok)) if ok else float("nan")), len(ok)


#: issue 15's target 3 (0.5 ms per 320x240 call) over the Open3D time per 320x240 pair (~5.9 ms, from the
#: issue's text) on the machine where the targets were set
NE_TARGET_FRACTION = 0.5 / 5.9


class NormalEquationsProbe:
    """Times the pure-Warp ``photometric_normal_equations`` on one frame pair (grey, full size, the
    true relative pose, Huber, ``out=``): the median of ``calls`` calls, in ms. The frames are copied
    into the probe's arrays first (not timed)."""

    def __init__(self, K: np.ndarray, width: int, height: int, calls: int = 3):
        self.ne, self.calls = photometric_pipeline.photometric_normal_equations, calls
        shape = (1, 1, height, width)
        self.ref, self.depth, self.live = (wp.zeros(shape, dtype=wp.float32) for _ in range(3))
        self.pose = wp.zeros(1, dtype=mat34f)
        self.K = wp.array(np.asarray(K, dtype=np.float32)[None], dtype=wp.mat33f)
        self.out = None
        self.ms: list[float] = []
        self.cost_per_pixel = float("nan")  # of the last pair: small at the true pose (a check on the inputs)
        for _ in range(2):  # untimed: builds the output and the recorded launches (replayed from the second call)
            self._call()

    def _call(self):
        self.out = self.ne(self.ref, self.depth, self.live, self.pose, self.K, robust="huber", scale=0.1,
                           out=self.out)

    def __call__(self, ref_image: np.ndarray, ref_depth: np.ndarray, live_image: np.ndarray, T: np.ndarray) -> None:
        for a, v in ((self.ref, ref_image), (self.depth, ref_depth), (self.live, live_image)):
            a.numpy()[...] = np.asarray(v, dtype=np.float32).reshape(a.shape)
        self.pose.numpy()[0] = np.asarray(T, dtype=np.float32)[:3]
        times = []
        for _ in range(self.calls):
            t = time.perf_counter()
            self._call()
            times.append(time.perf_counter() - t)
        self.ms.append(1e3 * float(np.median(times)))
        count = float(self.out.count.numpy()[0])
        self.cost_per_pixel = float(self.out.cost.numpy()[0]) / count if count > 0 else float("nan")


def normal_equations_summary(ms: list[float], label: str, open3d: dict | None) -> tuple[dict, str]:
    """The probe's times at one size as a JSON entry and a printed line: the median and mean ms per
    call and, with Open3D's results at that size, the median as a fraction of its median time per
    pair (and, at 320x240, the fraction that target 3 implies)."""
    ne = {"ms_per_call_median": float(np.median(ms)), "ms_per_call_mean": float(np.mean(ms)), "pairs": len(ms)}
    line = (f"normal equations (pure Warp, out=, C=1, {label}): {ne['ms_per_call_median']:.3f} ms per call "
            f"(median over the pairs; mean {ne['ms_per_call_mean']:.3f})")
    if open3d is not None:
        ne["fraction_of_open3d_pair"] = ne["ms_per_call_median"] / open3d["ms_per_pair_median"]
        line += f" = {ne['fraction_of_open3d_pair']:.3f}x Open3D's median time per pair"
        if label == "320x240":
            line += f" (a proxy; target 3 was set at {NE_TARGET_FRACTION:.3f}x)"
    return ne, line


def run_size(seq, methods: dict, strides: list[int], progress: bool, probe: NormalEquationsProbe | None = None) -> dict:
    n = len(seq)
    gt, valid = seq.gt_poses, seq.gt_valid
    if gt is None or not valid.all():
        raise SystemExit("benchmarks.odometry: the sequence needs ground truth for every frame")
    names = list(methods)
    trackers = {name: Tracker(methods[name][0], n, start_pose=gt[0]) for name in names}
    # the cyclic garbage collector paused while the trackers run (as timeit does): a full collection
    # of this process's heap took ~0.2 s, charged to whichever tracker happened to allocate
    gc.collect()
    gc.disable()
    try:
        for i in tqdm(range(n), unit="frame", desc="tracking", disable=not progress):
            frames = {name: methods[name][1](i) for name in names}  # file reading: not timed
            for k in range(len(names)):
                name = names[(k + i) % len(names)]
                trackers[name].add(*frames[name])
            if probe is not None and i > 0:
                probe(seq.image(i - 1, gray=True), seq.depth(i - 1), seq.image(i, gray=True),
                      relative_pose(gt[i], gt[i - 1]))
    finally:
        gc.enable()
    results = {}
    for name in names:
        res = trackers[name].result()
        m = evaluate_trajectory(seq.timestamps, res.poses, gt, valid)
        results[name] = dict(
            ms_per_pair=res.ms_per_pair,
            ms_per_pair_median=1e3 * float(np.median(res.seconds[1:])),
            rpe_trans_rmse_cm=100 * m.rpe_trans_rmse_m,
            rpe_rot_rmse_deg=m.rpe_rot_rmse_deg,
            ate_rmse_cm=100 * m.ate_rmse_m,
            ate_alignment=m.ate_alignment,
            failed_pairs=int(m.failed.sum()),
            unconverged_pairs=len(res.unconverged_frames),
        )
    for name, (aligner, reader) in methods.items() if strides else ():  # no strides: no frames prepared
        prepared = _cache(reader, n, aligner)
        for s in strides:
            t = time.perf_counter()
            frac, pairs = basin(prepared, aligner, gt, s)
            results[name][f"basin_{s}"] = frac
            results[name][f"basin_{s}_pairs"] = pairs
            if progress:
                print(f"  basin {name} every {s}th: {100 * frac:.1f}% of {pairs} pairs "
                      f"({time.perf_counter() - t:.0f} s)", file=sys.stderr)
    return results


def table(size: str, n: int, results: dict, strides: list[int]) -> str:
    head = ["method", "ms/pair (mean / median)", "RPE trans (cm)", "RPE rot (deg)", "ATE (cm)", "failed pairs",
            "unconverged"]
    head += [f"every {s}th within 1 cm & 0.25 deg" for s in strides]
    lines = [f"### {size}, {n} frames", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, r in results.items():
        row = [name, f"{r['ms_per_pair']:.1f} / {r['ms_per_pair_median']:.1f}", f"{r['rpe_trans_rmse_cm']:.3f}",
               f"{r['rpe_rot_rmse_deg']:.4f}", f"{r['ate_rmse_cm']:.2f}", f"{r['failed_pairs']} of {n - 1}",
               str(r["unconverged_pairs"])]
        row += [f"{100 * r[f'basin_{s}']:.0f}% of {r[f'basin_{s}_pairs']}" for s in strides]
        lines.append("| " + " | ".join(row) + " |")
    if len(results) == 2:
        (a, ra), (b, rb) = results.items()
        lines += ["", f"time ratio {b} / {a}: {rb['ms_per_pair'] / ra['ms_per_pair']:.2f} (mean), "
                      f"{rb['ms_per_pair_median'] / ra['ms_per_pair_median']:.2f} (median); "
                      f"ATE ratio {rb['ate_rmse_cm'] / ra['ate_rmse_cm']:.2f}"]
    return "\n".join(lines)


def machine() -> dict:
    """nproc, CPU model, load and versions (without importing torch)."""
    model = platform.processor() or "unknown"
    try:
        with open("/proc/cpuinfo") as f:
            model = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), model)
    except OSError:
        pass
    info = {"nproc": os.cpu_count(), "cpu": model, "python": platform.python_version(),
            "load_average": os.getloadavg(), "OMP_WAIT_POLICY": os.environ.get("OMP_WAIT_POLICY")}
    for pkg in ("warp-lang", "open3d", "numpy", "evo"):
        try:
            info[pkg] = version(pkg)
        except PackageNotFoundError:
            info[pkg] = None
    return info


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.odometry", description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=positive_int, default=200, help="frames to render (default 200)")
    p.add_argument("--sizes", default="320x240,640x480", help="comma-separated WxH sizes (default 320x240,640x480)")
    p.add_argument("--seed", type=int, default=0, help="scene and trajectory seed (default 0)")
    p.add_argument("--data", type=Path, default=None, help="read this TUM folder instead of rendering")
    p.add_argument("--strides", default="5,10", help="basin-test frame strides (default 5,10; 'none': no basin test)")
    p.add_argument("--no-open3d", action="store_true", help="skip Open3D")
    p.add_argument("--no-ours", action="store_true", help="skip gvnn_warp's aligner")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--json", type=Path, default=None, help="also write the results as JSON here")
    args = p.parse_args(argv)
    size_type = image_size(16)
    try:
        sizes = [size_type(s) for s in args.sizes.split(",")]
        strides = [] if args.strides == "none" else [positive_int(s) for s in args.strides.split(",")]
    except argparse.ArgumentTypeError as e:
        p.error(str(e))

    print(f"machine: {machine()}")
    all_results = {}
    normal_equations = {}
    with tempfile.TemporaryDirectory(prefix="gvnn_odometry_") as tmp:
        sources = [(args.data, None)] if args.data else [(Path(tmp) / f"{w}x{h}", (w, h)) for w, h in sizes]
        for folder, size in sources:
            if size is not None:
                t = time.perf_counter()
                render_sequence(folder, "se3", args.frames, size, args.seed, progress=False)
                print(f"rendered {args.frames} frames at {size[0]}x{size[1]} in {time.perf_counter() - t:.0f} s",
                      file=sys.stderr)
            seq = read_tum(folder)
            methods = {}
            if not args.no_open3d:
                try:
                    methods[Open3DAligner.name] = (Open3DAligner(seq.K, seq.depth_scale), _raw_reader(seq))
                except ImportError:
                    print("Open3D is not installed (pip install -e '.[bench]'); skipped", file=sys.stderr)
            if not args.no_ours:
                methods["gvnn_warp DirectAligner"] = (our_aligner(seq.K), _gray_reader(seq))
            if not methods:
                raise SystemExit("benchmarks.odometry: nothing to run")
            label = f"{seq.width}x{seq.height}"
            probe = None if args.no_ours else NormalEquationsProbe(seq.K, seq.width, seq.height)
            results = run_size(seq, methods, strides, progress=not args.no_progress, probe=probe)
            all_results[label] = results
            print(table(label, len(seq), results, strides), flush=True)
            if probe is not None and probe.ms:
                ne, line = normal_equations_summary(probe.ms, label, results.get(Open3DAligner.name))
                ne["last_pair_cost_per_pixel"] = probe.cost_per_pixel
                normal_equations[label] = ne
                print(line, flush=True)
            print()
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"machine": machine(), "results": all_results,
                                         "normal_equations": normal_equations}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
