"""A TUM RGB-D sequence tracked and its results written (what ``gvnn-warp track`` does; no torch).

- :func:`make_aligner`: the :class:`.DirectAligner` with the settings ``gvnn-warp track`` uses;
- :func:`track_sequence`: every frame of a sequence (``gvnn_warp.datasets.tum.TUMSequence``) aligned
  by :func:`.tracking.track` with any pairwise aligner, then written into a folder:

  - ``trajectory.txt``: the estimate in the TUM format (``timestamp tx ty tz qx qy qz qw``,
    ``T_world_cam``, metres), one pose per frame, starting at the ground truth's first pose
    (identity without ground truth);
  - ``metrics.json``: ``frames``, ``ms_per_pair`` (alignment incl. pyramids; file reading
    excluded), ``unconverged_pairs`` / ``unconverged_frames``, the settings, and with ground truth
    ``ate_rmse_m`` (SE(3) Umeyama-aligned), ``rpe_trans_rmse_m``, ``rpe_rot_rmse_deg`` (1-frame
    steps) and ``failed_pairs`` - all by evo (:mod:`.evaluation`);
  - ``trajectory.png`` (top view, estimate vs truth) and, with ground truth, ``errors.png``;

  and returns them with the rows of a summary (label, text), whose warnings and notes name the
  options of ``gvnn-warp track`` that set what they are about (``--depth-scale``,
  ``--max-difference``).

Example::

    from pathlib import Path
    from gvnn_warp.datasets.tum import read_tum
    from gvnn_warp.odometry.sequence import make_aligner, track_sequence

    seq = read_tum("seq")
    report = track_sequence(seq, len(seq), make_aligner(seq.K, dist=seq.dist), Path("out"))
    print(report.metrics["ate_rmse_m"])
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..datasets.images import to_gray
from ..datasets.tum import TUMSequence, write_trajectory
from ..errors import InputError
from .evaluation import (
    ATE_ALIGNMENT,
    ATE_ALIGNMENT_SIM3,
    FAIL_ROT_DEG,
    FAIL_TRANS_M,
    evaluate_trajectory,
    nearest_groundtruth,
    plot_errors,
    plot_top_view,
    rpe_per_second,
)
from .tracking import KeyframePolicy, TrackingStopped, TrackResult, track

__all__ = [
    "LENS_MODES",
    "LOW_VALID_FRACTION",
    "PLAUSIBLE_DEPTH_M",
    "RESULT_FILES",
    "SequenceReport",
    "frames_text",
    "make_aligner",
    "track_sequence",
]

GT_NEAREST = "pose of nearest stamp (as evo and TUM's scripts associate)"
GT_INTERPOLATED = "interpolated at the frames' stamps (--gt-interpolate)"
# what track_sequence writes (and the mesh and its picture that gvnn-warp track --fuse writes after it)
RESULT_FILES = ("trajectory.txt", "metrics.json", "trajectory.png", "errors.png", "mesh.ply", "mesh.png")
LOW_VALID_FRACTION = 0.05  # below this median fraction of usable pixels the summary warns (depth scale, images)
PLAUSIBLE_DEPTH_M = (0.05, 100.0)  # outside, the first frame's median depth suggests a wrong depth scale


LENS_MODES = ("resample", "exact")  # how make_aligner tracks through a lens (see its docstring)


def make_aligner(K, *, levels: int | None = None, iterations: int | None = None, robust: str = "huber",
                 depth_weight: float = 0.0, color: bool = False, dist=None, size: tuple[int, int] | None = None,
                 lens: str = "resample"):
    """The aligner that ``gvnn-warp track`` uses for images of intrinsics ``K`` (3, 3), pixels.
    ``levels``, ``iterations``: None for the aligner's defaults; ``robust``: the photometric penalty;
    ``depth_weight``: weight of the depth term (0: photometric only); ``color``: the photometric term
    on RGB instead of grey; ``dist``: radial-tangential coefficients (k1, k2, p1, p2, k3) of the
    images, None for a pinhole. Through a lens, ``lens="resample"`` (the default; needs ``size`` =
    (W, H)) resamples each frame once into the ideal pinhole image and tracks that at pinhole speed
    (:class:`.undistort.UndistortingAligner`), ``"exact"`` moves every ray through the lens model
    inside the aligner (:class:`.DirectAligner` with ``model="radtan"``)."""
    if lens not in LENS_MODES:
        raise ValueError(f"make_aligner: lens must be one of {LENS_MODES}, got {lens!r}")
    kwargs = {"robust": robust, "depth_weight": depth_weight, "color": color}
    if levels is not None:
        kwargs["levels"] = levels
    if iterations is not None:
        kwargs["iterations"] = iterations
    if dist is not None and lens == "resample":
        if size is None:
            raise ValueError("make_aligner: lens='resample' needs the image size (W, H)")
        from .undistort import UndistortingAligner  # (the aligner's kernels load on first use: see below)

        return UndistortingAligner(K, dist, size, **kwargs)
    if dist is not None:
        kwargs.update(model="radtan", dist=dist)
    # (imported here: the aligner defines its kernels at import, which `gvnn-warp --help` and the
    # other commands, importing this module through `gvnn-warp track`'s parser, should not wait for)
    from .aligner import DirectAligner

    return DirectAligner(K, **kwargs)


@dataclass
class SequenceReport:
    """What :func:`track_sequence` wrote: ``result`` (the tracking, :class:`.TrackResult`),
    ``metrics`` (the contents of ``metrics.json``) and ``rows``, the summary as (label, text) pairs."""

    result: TrackResult
    metrics: dict
    rows: list[tuple[str, str]]


def track_sequence(seq: TUMSequence, n: int, aligner, out: Path, *, method: str = "direct",
                   checkpoint: Path | None = None, color: bool = False, keyframes: KeyframePolicy | None = None,
                   init: str = "identity", levels: int | None = None, iterations: int | None = None,
                   robust: str = "huber", depth_weight: float = 0.0, max_difference: float = 0.02, predictor=None,
                   interpolate_gt: bool = False, tracker=None,
                   progress: bool = True) -> SequenceReport:
    """Track the first ``n`` (>= 2) frames of ``seq`` with ``aligner`` and write the results into the
    folder ``out`` (see the module docstring); returns them (:class:`SequenceReport`).

    ``out`` is made, and the files of :data:`RESULT_FILES` in it removed, only once the tracking is
    done: a run that fails leaves nothing, or the earlier results, and no earlier file is left
    beside the new ones. A frame that cannot be read (after frame 1) ends the run with the results
    of the frames before it written (``metrics.json``: ``partial``, ``stopped_at_frame``,
    ``stopped_by``) and then :class:`.TrackingStopped`, whose message says so. The frames go to
    the aligner grey unless ``color`` or ``method`` is not
    ``"direct"`` (a network takes RGB). ``keyframes``: align to keyframes replaced by this policy
    (None: to the previous frame); ``init``: ``"identity"`` or ``"velocity"`` (constant velocity)
    initial guess; ``progress``: a tqdm bar. ``method``, ``checkpoint``, ``levels``, ``iterations``,
    ``robust`` and ``depth_weight`` describe the aligner, as recorded in ``metrics.json``'s
    ``settings``; ``max_difference`` (s) is the ground-truth matching the sequence was read with, for
    the summary's notes. ``predictor``: ``image (3, H, W) RGB -> depth (1, H, W)`` (e.g.
    ``gvnn_warp.depth.predict.DepthPredictor``) to track from colour alone, each frame's depth
    predicted in place of the sensor's; the estimate's scale is then free and the ATE and RPE are
    those of the estimate after a similarity alignment (``evo_ape -as``). The ground truth of each
    frame is the pose of nearest stamp in ``groundtruth.txt`` (as evo and TUM's scripts associate),
    or with ``interpolate_gt`` the sequence's interpolation at the frame's stamp. ``tracker``:
    ``tracker(n, start_pose, progress) -> TrackResult`` in place of :func:`.tracking.track` with
    ``aligner`` (e.g. ``gvnn_warp.fusion.ModelTracker``, frame-to-model); ``method`` then names it.
    """
    gray = not color and method == "direct"  # the network takes RGB (the direct aligner makes it grey)
    gt_poses = gt_valid = None
    if seq.gt_poses is not None:
        if interpolate_gt:
            gt_poses, gt_valid = seq.gt_poses[:n], seq.gt_valid[:n]
        else:
            gt_poses, gt_valid = nearest_groundtruth(seq.timestamps[:n], seq.gt_timestamps, seq.gt_raw_poses,
                                                     max_difference)
    has_gt = gt_poses is not None and int(gt_valid.sum()) >= 2
    start = gt_poses[0] if has_gt and gt_valid[0] else np.eye(4)

    def read_frame(i: int):
        if predictor is None:
            return seq.image(i, gray=gray), seq.depth(i)
        rgb = seq.image(i)  # (read once: the network takes the colour, the aligner its grey)
        return (to_gray(rgb) if gray else rgb), predictor(rgb)

    stopped = None
    try:
        if tracker is not None:
            result = tracker(n, start, progress)
        else:
            result = track(read_frame, n, aligner, start_pose=start, keyframes=keyframes, init=init,
                           progress=progress)
    except TrackingStopped as e:  # a frame that cannot be read: the frames before it are results too
        if e.frame < 2:
            raise
        stopped, result, n = e, e.result, e.frame
        gt_poses, gt_valid = (None, None) if gt_poses is None else (gt_poses[:n], gt_valid[:n])
        has_gt = gt_poses is not None and int(gt_valid.sum()) >= 2

    stamps = seq.timestamps[:n]
    # only now, with the run done: make out, and remove the earlier run's files, so that a run that
    # fails leaves nothing, or the earlier results, and no file of theirs is left beside the new ones
    out.mkdir(parents=True, exist_ok=True)
    for name in RESULT_FILES:
        (out / name).unlink(missing_ok=True)
    write_trajectory(out / "trajectory.txt", stamps, result.poses,
                     comment=f"gvnn-warp track {seq.root}: estimated T_world_cam")
    unconverged = result.unconverged_frames
    metrics = {
        "sequence": str(seq.root),
        "frames": n,
        "pairs": n - 1,
        "size": [seq.width, seq.height],
        "intrinsics": {"fx": seq.K[0, 0], "fy": seq.K[1, 1], "cx": seq.K[0, 2], "cy": seq.K[1, 2],
                       "radtan": None if seq.dist is None else [float(v) for v in seq.dist],
                       "source": seq.intrinsics_source},
        "settings": {"method": method,
                     "checkpoint": str(checkpoint) if checkpoint else None,
                     "mode": "frame-to-model" if tracker is not None else (
                         "keyframe" if keyframes else "frame-to-frame"),
                     "init": init if method == "direct" else "network",
                     "levels": levels or "auto", "iterations": iterations, "robust": robust,
                     "depth_weight": depth_weight,
                     "channels": "grey" if gray else "rgb",
                     "depth_scale": seq.depth_scale if predictor is None else None,  # (no depth file read)
                     "depth": "sensor" if predictor is None else "predicted",
                     "depth_checkpoint": str(getattr(predictor, "checkpoint", "")) or None},
        "ms_per_pair": result.ms_per_pair,
        "ms_per_pair_note": ("alignment incl. the live frame's pyramid; file reading excluded" if tracker is None else
                             "the tracker's time per frame (frame to model: the raycast of the model, the "
                             "alignment and the integration); file reading"
                             + (" excluded" if predictor is None else " and depth prediction excluded")),
        "keyframes": len(result.keyframes) if keyframes else None,
        "unconverged_pairs": len(unconverged),
        "unconverged_frames": unconverged,
        "median_valid_fraction": _median_valid(result.valid_fraction),
        "ground_truth": has_gt,
        "partial": stopped is not None,
    }
    if stopped is not None:
        metrics["stopped_at_frame"] = stopped.frame
        metrics["stopped_by"] = str(stopped)
    K = seq.K
    notes = [note for note, given in (("RGB", method == "direct" and not gray),
                                      ("constant-velocity start", method == "direct" and init == "velocity"),
                                      ("depth predicted", predictor is not None)) if given]
    notes_text = "".join(f", {note}" for note in notes)
    rows = [("frames", f"{n} ({seq.width}x{seq.height}, {metrics['settings']['mode']}, method {method}{notes_text})"),
            ("intrinsics", f"fx {K[0, 0]:g} fy {K[1, 1]:g} cx {K[0, 2]:g} cy {K[1, 2]:g}"
                           f"{' with radial-tangential distortion' if seq.dist is not None else ''} "
                           f"({seq.intrinsics_source})"),
            ("ms per pair", f"{result.ms_per_pair:.2f}") if tracker is None else
            ("ms per frame", f"{result.ms_per_pair:.2f} (raycast of the model, alignment, integration)"),
            ("unconverged pairs", f"{len(unconverged)}" + (f" (frames {frames_text(unconverged)})" if unconverged
                                                           else ""))]
    unpaired = metrics["colour_images_without_depth"] = max(seq.listed[0] - len(seq), 0)
    if unpaired:  # (colour images whose depth image is missing or too far in time)
        rows.append(("note", f"{unpaired} of the {seq.listed[0]} colour images listed have no depth image within "
                             f"{seq.max_difference:g} s: not frames (TUM's association)"))
    if seq.intrinsics_override is not None:
        differs = "differs" in seq.intrinsics_override or "cannot be read" in seq.intrinsics_override
        rows.append(("warning" if differs else "note", seq.intrinsics_override))
        metrics["intrinsics"]["override"] = seq.intrinsics_override
    if keyframes:
        rows.append(("keyframes", str(len(result.keyframes))))
    depth0 = seq.depth(0) if predictor is None else np.zeros(0)  # (a predicted depth's scale is set, not read)
    depth0 = depth0[np.isfinite(depth0) & (depth0 > 0)]
    median0 = metrics["first_frame_median_depth_m"] = float(np.median(depth0)) if depth0.size else None
    if median0 is not None and not PLAUSIBLE_DEPTH_M[0] <= median0 <= PLAUSIBLE_DEPTH_M[1]:
        rows.append(("warning", f"the first frame's median depth is {median0:.4g} m: check --depth-scale "
                                f"({_per_metre(seq.depth_scale)})"))
    valid = metrics["median_valid_fraction"]
    if valid is not None and valid < LOW_VALID_FRACTION:
        rows.append(("warning", f"only {100 * valid:.1f}% of the pixels were usable (median over the pairs): check "
                                f"the depth images and --depth-scale ({_per_metre(seq.depth_scale)})"))
    if has_gt:
        m = evaluate_trajectory(stamps, result.poses, gt_poses, gt_valid, correct_scale=predictor is not None)
        per_second = rpe_per_second(stamps, result.poses, seq.gt_timestamps, seq.gt_raw_poses, scale=m.scale)
        failed = m.pair_frames[m.failed]
        metrics.update({
            "evaluated_frames": int(m.frames.size),
            "ate_rmse_m": m.ate_rmse_m,
            "ate_alignment": m.ate_alignment,
            "alignment_scale": m.scale,
            "rpe_trans_rmse_m": m.rpe_trans_rmse_m,
            "rpe_rot_rmse_deg": m.rpe_rot_rmse_deg,
            "rpe_delta": "1 frame (consecutive pairs)",
            "rpe_trans_m_per_s": per_second[0] if per_second else None,
            "rpe_rot_deg_per_s": per_second[1] if per_second else None,
            "rpe_per_second_steps": per_second[2] if per_second else 0,
            "rpe_per_second_definition": "evaluate_rpe.py --fixed_delta --delta 1 --delta_unit s (TUM RGB-D), RMSE",
            "gt_association": GT_INTERPOLATED if interpolate_gt else GT_NEAREST,
            "failed_pairs": int(failed.shape[0]),
            "failed_pair_frames": failed.tolist(),
            "failure_threshold": {"trans_m": FAIL_TRANS_M, "rot_deg": FAIL_ROT_DEG},
            "metrics_by": "evo",
        })
        aligned_by = {ATE_ALIGNMENT: "SE(3)-aligned",
                      ATE_ALIGNMENT_SIM3: f"Sim(3)-aligned, scale {m.scale:.3g}, as evo_ape -as"}.get(
                          m.ate_alignment, "first pose aligned")
        scaled = "" if predictor is None else " (scaled estimate)"
        rows += [("ATE RMSE", f"{100 * m.ate_rmse_m:.2f} cm ({aligned_by})"),
                 ("RPE trans RMSE", f"{100 * m.rpe_trans_rmse_m:.3f} cm per frame{scaled}"),
                 ("RPE rot RMSE", f"{m.rpe_rot_rmse_deg:.4f} deg per frame"),
                 ("RPE per second", "none (no 1 s step with ground truth at both ends)" if per_second is None else
                  f"{100 * per_second[0]:.3f} cm/s, {per_second[1]:.4f} deg/s ({per_second[2]} steps of 1 s, "
                  "as TUM's evaluate_rpe.py)"),
                 ("ground truth", GT_INTERPOLATED if interpolate_gt else GT_NEAREST),
                 ("failed pairs", f"{failed.shape[0]} of {m.pair_frames.shape[0]} (> 1 cm or > 0.25 deg)")]
        if m.frames.size < n:  # (frames without a ground-truth pose)
            rows.append(("evaluated frames", f"{m.frames.size} of {n} (the others have no ground-truth pose within "
                                             f"--max-difference {max_difference:g} s)"))
        plot_top_view(out / "trajectory.png", m.aligned, m.ground_truth,
                      title=f"{seq.root.name}: estimate ({aligned_by}) vs ground truth")
        plot_errors(out / "errors.png", m, np.array(unconverged))
    else:
        plot_top_view(out / "trajectory.png", result.poses, None, title=f"{seq.root.name}: estimate")
        if seq.gt_poses is None:
            why = "none (no groundtruth.txt): no ATE/RPE"
        else:
            why = (f"none usable: {int(gt_valid.sum())} of the {n} frames have a pose in groundtruth.txt "
                   f"within --max-difference {max_difference:g} s (2 needed): no ATE/RPE")
        rows.append(("ground truth", why))
        metrics["ground_truth_note"] = why
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    if stopped is not None:  # the results so far are written: now the error, which says so
        raise TrackingStopped(stopped.frame, result, InputError(
            f"{stopped}; stopped at frame {stopped.frame}: {out} holds the results of the {n} frames before it "
            "(metrics.json: partial)")) from stopped.__cause__
    return SequenceReport(result, metrics, rows)


def _per_metre(scale: float) -> str:
    """The depth scale in words: 5000 units per metre, 1 unit per metre."""
    return f"{scale:g} unit{'' if scale == 1 else 's'} per metre"


def _median_valid(fractions) -> float | None:
    """The median of the pairs' valid fractions (NaN: unknown, e.g. frame 0), None if none known."""
    known = np.asarray(fractions, dtype=np.float64)
    known = known[np.isfinite(known)]
    return float(np.median(known)) if known.size else None


def frames_text(frames: list[int], limit: int = 12) -> str:
    """Frame numbers for a summary: the first ``limit``, then how many in all."""
    text = ", ".join(str(f) for f in frames[:limit])
    return text + (f", ... ({len(frames)} in all)" if len(frames) > limit else "")
