"""``gvnn-warp track``: direct RGB-D odometry over a TUM RGB-D folder, evaluated with evo.

Usage::

    gvnn-warp track DIR --out OUT [--overwrite] [--method direct|vo|vo+direct [--checkpoint CKPT]]
                    [--depth sensor|predicted --checkpoint CKPT] [--fuse | --model] [--voxel M]
                    [--truncation M] [--fuse-memory MB]
                    [--intrinsics fr1|fr2|fr3|icl|fx,fy,cx,cy[,k1,k2,p1,p2,k3]] [--depth-scale S]
                    [--max-frames N] [--gt-interpolate] [--keyframes [--keyframe-trans M] [--keyframe-rot DEG]
                    [--keyframe-valid F]] [--init identity|velocity] [--levels L] [--robust KIND]
                    [--depth-weight W] [--color]

Aligns every frame of the sequence in DIR (``gvnn_warp.datasets.tum``: rgb.txt, depth.txt,
groundtruth.txt when present) to the previous one - or, with ``--keyframes``, to a keyframe kept
until the motion or the valid fraction passes a threshold - with ``gvnn_warp.odometry.DirectAligner``
on grey images (``--color``: RGB) - through the camera's radial-tangential distortion when the
intrinsics have one (the fr1/fr2 presets, nine numbers in ``--intrinsics`` or intrinsics.txt) -
or, with ``--method vo``, by the network of a ``gvnn-warp vo``
checkpoint (``--checkpoint``; frames are resized to the network's size and the intrinsics scaled),
or with ``--method vo+direct`` by the direct aligner starting from the network's estimate (instead
of the identity or ``--init``) - and writes the results below. With ``--depth predicted`` the
depth files are not read (nor need they exist: every colour image listed is a frame): each
frame's depth is predicted from its colour by the network of a ``gvnn-warp depth train`` checkpoint
(``--checkpoint``; ``gvnn_warp.depth.predict``, one scale for the sequence, the first frame's
median depth 1 m), monocular direct odometry with learned depth; the
ATE and RPE are then those of the estimate after a similarity alignment (``evo_ape -as``). With
``--fuse`` the frames are then integrated at the estimated poses into a TSDF of ``--voxel``-metre
voxels (``gvnn_warp.fusion``) whose marching-cubes mesh is written to ``OUT/mesh.ply`` with a
picture of it from the first pose (``OUT/mesh.png``); with ``--model`` each frame is tracked
against the model raycast at the previous pose instead of the previous frame, and integrated as it
goes (KinectFusion's loop). With ``--depth predicted`` too, the predicted depth is what is
integrated, and ``--voxel`` and ``--truncation`` are in its units (the first frame's median depth
is 1): the model averages the network's depth over the frames, which ``--model`` then tracks
against (monocular dense tracking with learned depth). It writes:

- ``OUT/trajectory.txt``: the estimate in the TUM format (``timestamp tx ty tz qx qy qz qw``,
  ``T_world_cam``), one pose per frame, starting at the ground truth's first pose (identity
  without ground truth);
- ``OUT/metrics.json``: ``frames``, ``ms_per_pair`` (alignment incl. pyramids; file reading
  excluded), ``unconverged_pairs`` / ``unconverged_frames`` and, with ground truth, ``ate_rmse_m``
  (SE(3) Umeyama-aligned, as ``evo_ape -a``), ``rpe_trans_rmse_m`` and ``rpe_rot_rmse_deg``
  (1-frame steps, as ``evo_rpe``), ``failed_pairs`` (RPE above 1 cm or 0.25 deg) - all by evo,
  each frame's ground truth the pose of nearest stamp (``--gt-interpolate``: interpolated at the
  frame's stamp) - and ``rpe_trans_m_per_s``, ``rpe_rot_deg_per_s`` (the drift over 1-second
  steps, as TUM's ``evaluate_rpe.py --fixed_delta --delta 1 --delta_unit s``);
- ``OUT/trajectory.png`` (top view, estimate vs truth) and, with ground truth, ``OUT/errors.png``
  (per-frame translation and rotation error).

Before the first frame is tracked it checks every image to be tracked (exists, format, size: from
the headers), and refuses an OUT that is the sequence's folder or holds an earlier run's results
(unless ``--overwrite``).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from ..datasets.tum import DEFAULT_DEPTH_SCALE, DatasetError, read_tum
from ..errors import InputError
from ..odometry.sequence import LENS_MODES, RESULT_FILES, make_aligner, track_sequence
from ..odometry.tracking import INITS, KeyframePolicy, TrackingStopped
from .args import (
    UsageError,
    bounded_int,
    description,
    finite_float,
    output_dir,
    positive_float,
    refuse_sequence_folder,
)
from .runner import INSTALL_HINTS, command_main, missing_packages

__all__ = ["add_parser", "check", "run"]

# checked by gvnn_warp.cli before run(): evo computes the metrics, matplotlib draws the figures; the
# aligner, the reader and the tracking loop are numpy and Warp (no torch)
REQUIRES = ("evo", "matplotlib", "tqdm")

ROBUST = ("huber", "l2", "cauchy", "geman_mcclure", "tukey")  # DirectAligner's
PRESETS = ("fr1", "fr2", "fr3", "icl")
METHODS = ("direct", "vo", "vo+direct")
FUSE_VOXEL = 0.01  # metres
FUSE_MEMORY_MB = 4096.0
FUSE_OPTIONS = ("voxel", "truncation", "fuse_memory")  # (refused without --fuse or --model)
DEPTHS = ("sensor", "predicted")
MAX_LEVELS = 12  # a 4096-pixel side halved 11 times is 2 pixels
MAX_ITERATIONS = 1000


def intrinsics_arg(text: str):
    """``type=`` for ``--intrinsics``: a preset name, ``fx,fy,cx,cy`` (finite, fx, fy > 0), or
    ``fx,fy,cx,cy,k1,k2,p1,p2,k3`` (with radial-tangential distortion, finite)."""
    if text in PRESETS:
        return text
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) not in (4, 9) or not all(math.isfinite(v) for v in values) or values[0] <= 0 or values[1] <= 0:
        raise argparse.ArgumentTypeError(f"expected one of {', '.join(PRESETS)} or fx,fy,cx,cy (finite, fx, fy > 0) "
                                         f"or fx,fy,cx,cy,k1,k2,p1,p2,k3, got {text!r}")
    return tuple(values)


def add_arguments(p: argparse.ArgumentParser) -> None:
    kf = KeyframePolicy()
    p.add_argument("data", type=Path, metavar="DIR", help="TUM RGB-D folder (rgb.txt, depth.txt[, groundtruth.txt])")
    p.add_argument("--out", type=output_dir, required=True, metavar="OUT",
                   help="output folder for trajectory.txt, metrics.json and the figures (made if missing; not the "
                        "sequence's own folder)")
    p.add_argument("--overwrite", action="store_true", help="replace the results of an earlier run in --out")
    p.add_argument("--method", choices=METHODS, default="direct",
                   help="direct: the direct aligner; vo: the trained network of --checkpoint alone; vo+direct: the "
                        "direct aligner starting from the network's estimate")
    p.add_argument("--checkpoint", type=Path, default=None, metavar="CKPT",
                   help="checkpoint.pt of gvnn-warp vo (needed by --method vo and vo+direct) or, with --depth "
                        "predicted, of gvnn-warp depth train (default: none)")
    p.add_argument("--depth", choices=DEPTHS, default="sensor",
                   help="sensor: the folder's depth files; predicted: each frame's depth predicted from its colour "
                        "by the depth network of --checkpoint (the ATE is then similarity-aligned)")
    p.add_argument("--intrinsics", type=intrinsics_arg, default=None, metavar="PRESET|FX,FY,CX,CY[,K1,K2,P1,P2,K3]",
                   help="fr1, fr2, fr3, icl (published 640x480 values; fr1, fr2 with their radial-tangential "
                        "distortion) or fx,fy,cx,cy[,k1,k2,p1,p2,k3] (default: DIR/intrinsics.txt, "
                        "else the Freiburg preset named by the folder)")
    p.add_argument("--depth-scale", type=positive_float, default=None, metavar="S",
                   help="raw depth units per metre of the depth images (default: 5000, as in TUM RGB-D and ICL-NUIM)")
    p.add_argument("--max-frames", type=bounded_int(2), default=None, metavar="N",
                   help="track only the first N frames (default: all)")
    p.add_argument("--max-difference", type=finite_float(0, 1, "s", above_minimum=True), default=0.02, metavar="SEC",
                   help="seconds: colour/depth association and ground-truth matching")
    p.add_argument("--gt-interpolate", action="store_true",
                   help="evaluate against the ground truth interpolated at each frame's stamp (default: the pose of "
                        "nearest stamp, as evo and TUM's scripts associate)")
    p.add_argument("--keyframes", action="store_true",
                   help="align to a keyframe, replaced when the thresholds below are passed (default: previous frame)")
    # (defaults None: given without --keyframes they are refused; the policy's defaults in the help)
    p.add_argument("--keyframe-trans", type=positive_float, default=None, metavar="M",
                   help=f"with --keyframes: new keyframe beyond this translation, metres (default: {kf.max_trans_m:g})")
    p.add_argument("--keyframe-rot", type=finite_float(0, 180, "deg", above_minimum=True), default=None,
                   metavar="DEG", help=f"with --keyframes: new keyframe beyond this rotation, degrees "
                                       f"(default: {kf.max_rot_deg:g})")
    p.add_argument("--keyframe-valid", type=finite_float(0, 1), default=None, metavar="F",
                   help=f"with --keyframes: new keyframe below this fraction of usable pixels "
                        f"(default: {kf.min_valid:g})")
    p.add_argument("--init", choices=INITS, default="identity",
                   help="initial guess: identity or constant velocity")
    p.add_argument("--levels", type=bounded_int(1, MAX_LEVELS), default=None, metavar="L",
                   help="pyramid levels (default: the aligner's, as many as keep the coarsest level >= 6 px; "
                        "fewer where the image is too small)")
    p.add_argument("--iterations", type=bounded_int(1, MAX_ITERATIONS), default=None, metavar="N",
                   help="iterations per level (default: the aligner's, 4 at the finest level to 30 at the coarsest)")
    p.add_argument("--robust", choices=ROBUST, default="huber", help="photometric penalty")
    p.add_argument("--depth-weight", type=finite_float(0, 1e6), default=0.0, metavar="W",
                   help="weight of the depth term (0: photometric only)")
    p.add_argument("--color", action="store_true", help="photometric term on RGB instead of grey")
    p.add_argument("--lens", choices=LENS_MODES, default="resample",
                   help="through a lens (radial-tangential intrinsics): resample each frame once into the ideal "
                        "pinhole image and track that with the pinhole's kernels (~1.1x the pinhole's time; default), "
                        "or move every ray through the lens model (exact; ~3.2x)")
    fuse = p.add_mutually_exclusive_group()
    fuse.add_argument("--fuse", action="store_true",
                      help="integrate the frames at the estimated poses into a TSDF and write OUT/mesh.ply and "
                           "OUT/mesh.png")
    fuse.add_argument("--model", action="store_true",
                      help="track each frame against the raycast of the TSDF so far (frame-to-model), integrating "
                           "as it goes; writes the mesh as --fuse does")
    p.add_argument("--voxel", type=finite_float(0.001, 1.0, "m"), default=None, metavar="M",
                   help=f"with --fuse/--model: voxel size, metres (with --depth predicted in its units) "
                        f"(default {FUSE_VOXEL:g})")
    p.add_argument("--truncation", type=positive_float, default=None, metavar="M",
                   help="with --fuse/--model: truncation of the signed distance, metres (with --depth predicted in "
                        "its units) (default 4 voxels)")
    p.add_argument("--fuse-memory", type=positive_float, default=None, metavar="MB",
                   help=f"with --fuse/--model: the most memory the voxels may take (default {FUSE_MEMORY_MB:g} MiB)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "track",
        help="direct RGB-D odometry over a TUM RGB-D folder; trajectory, evo metrics and figures, and a TSDF "
             "map with --fuse or --model",
        description=description(__doc__),
    )
    add_arguments(p)
    p.set_defaults(func=run)
    return p


def _summary(rows: list[tuple[str, str]]) -> str:
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{width}}  {v}" for k, v in rows)


KEYFRAME_OPTIONS = {"keyframe_trans": "max_trans_m", "keyframe_rot": "max_rot_deg", "keyframe_valid": "min_valid"}
# (option -> its KeyframePolicy field)


def check(args: argparse.Namespace):
    """Checks that need what is on disk (raises UsageError before any work): --out is not the
    sequence's folder and holds no earlier results unless --overwrite; the sequence's lists are read
    and associated, every image to be tracked exists and has the right format and size (from its
    header; the pixels are read while tracking), there are at least 2 frames, and the principal
    point is inside the image. Returns (sequence, number of frames to track)."""
    if not getattr(args, "keyframes", False):
        given = [name for name in KEYFRAME_OPTIONS if getattr(args, name, None) is not None]
        if given:
            raise UsageError(f"--{given[0].replace('_', '-')} applies with --keyframes only")
    if args.out.exists() and args.data.exists() and args.out.resolve() == args.data.resolve():
        raise UsageError(f"--out {args.out} is the sequence's own folder; choose another")
    refuse_sequence_folder(args.out)
    existing = [name for name in RESULT_FILES if (args.out / name).exists()]
    if existing and not getattr(args, "overwrite", False):
        raise UsageError(f"--out {args.out} already holds results ({existing[0]}); pass --overwrite or choose "
                         "another folder")
    # (a file that cannot be used is a DatasetError: one line without the usage text, status 1)
    predicted = getattr(args, "depth", "sensor") == "predicted"
    if predicted and args.depth_scale is not None:
        raise UsageError("--depth-scale applies to the depth images; --depth predicted reads none")
    # (--depth predicted: a colour video, every colour image a frame, depth images neither needed nor read)
    seq = read_tum(args.data, intrinsics=args.intrinsics, depth_scale=args.depth_scale or DEFAULT_DEPTH_SCALE,
                   max_difference=args.max_difference, colour_only=predicted)
    n = len(seq) if args.max_frames is None else min(args.max_frames, len(seq))
    if n < 2:
        raise DatasetError(f"{args.data}: need at least 2 frames to track, found {n}")
    seq.check_files(n)
    cx, cy = seq.K[0, 2], seq.K[1, 2]
    if not (0 <= cx <= seq.width - 1 and 0 <= cy <= seq.height - 1):
        source = "--intrinsics" if seq.intrinsics_source == "given" else seq.intrinsics_source
        raise UsageError(f"the principal point ({cx:g}, {cy:g}) of the intrinsics ({source}) is outside the "
                         f"{seq.width}x{seq.height} images")
    return seq, n


def check_method(args: argparse.Namespace):
    """--method, --depth and --checkpoint (raises UsageError before any work); returns the network
    and its checkpoint entry ``network`` for --method vo / vo+direct, else None."""
    method = getattr(args, "method", "direct")
    ckpt = getattr(args, "checkpoint", None)
    fusing = getattr(args, "fuse", False) or getattr(args, "model", False)
    if not fusing:
        given = [name for name in FUSE_OPTIONS if getattr(args, name, None) is not None]
        if given:
            raise UsageError(f"--{given[0].replace('_', '-')} applies with --fuse or --model only")
    if getattr(args, "model", False):
        if method != "direct":
            raise UsageError(f"--model tracks with the direct aligner (--method direct), not --method {method}")
        if getattr(args, "keyframes", False):
            raise UsageError("--model tracks against the model, not keyframes: use one of --model, --keyframes")
    voxel = getattr(args, "voxel", None) or FUSE_VOXEL
    if fusing and getattr(args, "truncation", None) is not None and args.truncation < voxel:
        raise UsageError(f"--truncation {args.truncation:g} is less than a voxel ({voxel:g})")
    if getattr(args, "depth", "sensor") == "predicted":
        if method != "direct":
            raise UsageError(f"--depth predicted tracks with --method direct only (this run is --method {method})")
        if ckpt is None:
            raise UsageError("--depth predicted needs --checkpoint CKPT (the checkpoint.pt written by gvnn-warp "
                             "depth train)")
        if args.depth_weight:
            raise UsageError("--depth-weight needs the sensor's depth (the predicted depth would be compared with "
                             "itself); leave it at 0 with --depth predicted")
        return None
    if method == "direct":
        if ckpt is not None:
            raise UsageError("--checkpoint is used by --method vo and vo+direct (a gvnn-warp vo checkpoint) and by "
                             "--depth predicted (a gvnn-warp depth train one); this run is --method direct with the "
                             "sensor's depth")
        return None
    if ckpt is None:
        raise UsageError(f"--method {method} needs --checkpoint CKPT (the checkpoint.pt written by gvnn-warp vo)")
    if missing_packages(("torch",)):
        raise UsageError(f"--method {method} needs {INSTALL_HINTS['torch']}")
    # torch loads only here, for a network: --method direct (the default) never imports it
    from ..vo.checkpoint import load_network

    return load_network(ckpt)  # (a CheckpointError is one line, status 1)


def run(args: argparse.Namespace) -> int:
    seq, n = check(args)
    network = check_method(args)
    aligner = None
    if getattr(args, "method", "direct") != "vo":
        aligner = make_aligner(seq.K, levels=args.levels, iterations=args.iterations, robust=args.robust,
                               depth_weight=args.depth_weight, color=args.color, dist=seq.dist,
                               size=(seq.width, seq.height), lens=getattr(args, "lens", "resample"))
    if network is not None:
        from ..vo.frontend import NetworkAligner  # torch: only with a network (see check_method)

        net, spec = network
        aligner = NetworkAligner(net, seq.K, (seq.width, seq.height), refine=spec.get("refine", 0), direct=aligner,
                                 symmetries=tuple(spec.get("symmetries", ())))
    predictor = None
    if getattr(args, "depth", "sensor") == "predicted":
        if missing_packages(("torch",)):
            raise UsageError(f"--depth predicted needs {INSTALL_HINTS['torch']}")
        from ..depth.predict import DepthPredictor  # torch: only for a network (see check_method)

        predictor = DepthPredictor(args.checkpoint)  # (a CheckpointError is one line, status 1)
    policy = None
    if args.keyframes:  # the options given, else the policy's defaults
        given = {field: getattr(args, option, None) for option, field in KEYFRAME_OPTIONS.items()}
        policy = KeyframePolicy(**{field: v for field, v in given.items() if v is not None})
    volume = tracker = None
    if getattr(args, "fuse", False) or getattr(args, "model", False):
        from ..fusion import TSDFVolume  # (numpy and Warp: no torch)

        voxel = args.voxel or FUSE_VOXEL
        volume = TSDFVolume(voxel, args.truncation, max_memory_mb=args.fuse_memory or FUSE_MEMORY_MB)
        if args.model:
            from ..fusion.sequence import ModelTracker

            tracker = ModelTracker(seq, aligner, volume, depth=predictor, color=args.color, init=args.init)
    # an image that cannot be read while tracking is one line naming it (and, past frame 1, where the
    # results of the frames before it were written), status 1: gvnn_warp.cli.runner prints InputErrors
    try:
        report = track_sequence(
            seq, n, aligner, args.out, method=getattr(args, "method", "direct"),
            checkpoint=getattr(args, "checkpoint", None), color=args.color, keyframes=policy, init=args.init,
            levels=args.levels, iterations=args.iterations, robust=args.robust, depth_weight=args.depth_weight,
            max_difference=args.max_difference, predictor=predictor,
            interpolate_gt=getattr(args, "gt_interpolate", False), tracker=tracker, progress=not args.no_progress,
        )
    except TrackingStopped as e:
        # --model stopped mid-run (a frame that cannot be read, a map beyond --fuse-memory): the results
        # of the frames before it are written (from frame 2 on); so is the mesh of the model they made
        from ..fusion import MapFull

        cause, message = e.__cause__, str(e)
        if isinstance(cause, MapFull):
            message = message.replace(str(cause), f"{cause} (--voxel, --fuse-memory)", 1)
        if tracker is not None and e.frame >= 2:
            _fuse_and_mesh(args, seq, [], e.result.poses, volume, tracker, predictor)
            message += ", and the mesh of the model they made (mesh.ply, mesh.png)"
        if message == str(e):
            raise
        raise TrackingStopped(e.frame, e.result, InputError(message)) from cause
    if volume is not None:
        status = _fuse_and_mesh(args, seq, report.rows, report.result.poses, volume, tracker, predictor)
        if status:
            return status
    print(f"track {seq.root}:\n{_summary(report.rows)}\nwrote {args.out}")
    return 0


def _fuse_and_mesh(args, seq, rows: list, poses, volume, tracker, predictor=None) -> int:
    """--fuse / --model after tracking: integrate (--fuse) at ``poses``, then OUT/mesh.ply and
    OUT/mesh.png (from ``poses[0]``), and the fusion's numbers added to metrics.json and to the
    summary's ``rows``. With --fuse, a map that outgrows --fuse-memory is one line, status 1 (the
    trajectory and metrics are written already); with --model it stops the tracking, whose results so
    far are written (TrackingStopped), and this writes the mesh of the frames before it."""
    import json
    import time
    import warnings

    from ..fusion import MapFull, write_ply
    from ..fusion.sequence import camera_of, fuse_sequence, render_picture
    from ..fusion.volume import EMPTY_VOLUME
    from ..odometry.sequence import frames_text

    try:
        fused = tracker.fuse if tracker is not None else fuse_sequence(volume, seq, poses, depth=predictor,
                                                                       progress=not args.no_progress)
    except MapFull as e:
        print(f"gvnn-warp track: error: {e} (--voxel, --fuse-memory); {args.out} holds the trajectory and metrics, "
              "not the mesh", file=sys.stderr)
        return 1
    s = time.perf_counter()
    with warnings.catch_warnings():  # (an empty mesh: the summary's warning says it, naming the options)
        warnings.filterwarnings("ignore", message=f".*extract_mesh: {EMPTY_VOLUME}", category=UserWarning)
        vertices, faces, colours = volume.extract_mesh()
    mesh_seconds = time.perf_counter() - s
    write_ply(args.out / "mesh.ply", vertices, faces, colours, comment=f"gvnn-warp track {seq.root}")
    seen = render_picture(volume, camera_of(seq), poses[0], seq.height, seq.width, args.out / "mesh.png")
    fusion = {"voxel_m": volume.voxel_size, "truncation_m": volume.truncation, "blocks": volume.n_blocks,
              "memory_mib": volume.memory_bytes / 2**20, "frames_integrated": fused.integrated,
              "frames_skipped": fused.skipped, "ms_per_frame_integrate": fused.ms_per_frame,
              "mesh_vertices": int(len(vertices)), "mesh_faces": int(len(faces)), "mesh_seconds": mesh_seconds,
              "picture_coverage": seen,
              "units": "metres" if predictor is None else ("the predicted depth's (the first frame's median depth "
                                                           "is 1): voxel_m and truncation_m are in them")}
    metrics_path = args.out / "metrics.json"
    metrics = json.loads(metrics_path.read_text())
    metrics["fusion"] = fusion
    metrics_path.write_text(json.dumps(metrics, indent=2) + "\n")
    units = "m" if predictor is None else "(the predicted depth's units: the first frame's median depth is 1)"
    rows.append(("fusion", f"{volume.n_blocks} blocks of 8^3 voxels at {volume.voxel_size:g} {units} "
                           f"({volume.memory_bytes / 2**20:.0f} MiB), {fused.ms_per_frame:.1f} ms per frame to "
                           "integrate"))
    if fused.skipped:
        rows.append(("skipped", f"{len(fused.skipped)} frames with no valid depth or pose (frames "
                                f"{frames_text(fused.skipped)})"))
    if len(faces):
        rows.append(("mesh", f"{len(vertices)} vertices, {len(faces)} faces in {mesh_seconds:.1f} s: "
                             "mesh.ply, mesh.png (from the first pose)"))
    else:
        rows.append(("warning", "the mesh is empty: no surface was seen twice within the depth range "
                                + ("(check --depth-scale and the depth images)" if predictor is None else
                                   "(check the depth network's predictions)")))
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m gvnn_warp.cli.track ...``: the same as ``gvnn-warp track ...``."""
    return command_main(add_parser, REQUIRES, argv)


if __name__ == "__main__":
    sys.exit(main())
