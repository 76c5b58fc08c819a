"""gvnn_warp.odometry.evaluation (evo metrics against closed forms), gvnn_warp.odometry.tracking (pose
chaining, keyframes, failures reported) and `gvnn-warp track` end to end."""

import json
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from gvnn_warp.datasets.tum import read_trajectory, read_tum, write_trajectory
from gvnn_warp.odometry.evaluation import (
    ATE_ALIGNMENT,
    ATE_ALIGNMENT_ORIGIN,
    ATE_ALIGNMENT_SIM3,
    FAIL_ROT_DEG,
    FAIL_TRANS_M,
    evaluate_trajectory,
    nearest_groundtruth,
    pose_error,
    rpe_per_second,
)
from gvnn_warp.odometry.tracking import KeyframePolicy, Tracker, track
from gvnn_warp.synthetic import relative_pose


def _circle_trajectory(n=8, radius=1.0, seed=0):
    """Camera centres on a circle in the x-y plane at angles 2 pi k / n; random orientations."""
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    a = 2 * np.pi * np.arange(n) / n
    T[:, 0, 3], T[:, 1, 3] = radius * np.cos(a), radius * np.sin(a)
    return T


# ------------------------------------------------------------------------------------------------
# evaluation: evo's metrics on trajectories with closed-form errors


def test_rigidly_moved_estimate_has_zero_ate_and_rpe():
    gt = _circle_trajectory(12)
    A = np.eye(4)
    A[:3, :3] = Rotation.from_rotvec([0.3, -1.0, 2.0]).as_matrix()
    A[:3, 3] = [5.0, -2.0, 1.0]
    m = evaluate_trajectory(np.arange(12) / 30, A @ gt, gt)
    assert m.ate_rmse_m < 1e-9 and m.rpe_trans_rmse_m < 1e-9 and m.rpe_rot_rmse_deg < 1e-5
    np.testing.assert_allclose(m.aligned, gt, atol=1e-9)


def test_scaled_estimate_is_exact_after_a_similarity_alignment_only():
    # a monocular estimate: the truth moved rigidly and scaled by 3; Sim(3) (evo_ape -as) undoes it,
    # and its RPE is that of the scaled estimate; SE(3) cannot undo the scale
    gt = _circle_trajectory(12)
    A = np.eye(4)
    A[:3, :3] = Rotation.from_rotvec([0.3, -1.0, 2.0]).as_matrix()
    A[:3, 3] = [5.0, -2.0, 1.0]
    est = A @ gt
    est[:, :3, 3] *= 3.0
    m = evaluate_trajectory(np.arange(12) / 30, est, gt, correct_scale=True)
    assert m.ate_alignment == ATE_ALIGNMENT_SIM3 and m.scale == pytest.approx(1 / 3, rel=1e-9)
    assert m.ate_rmse_m < 1e-9 and m.rpe_trans_rmse_m < 1e-9 and m.rpe_rot_rmse_deg < 1e-5
    rigid = evaluate_trajectory(np.arange(12) / 30, est, gt)
    assert rigid.scale == 1.0 and rigid.ate_rmse_m > 0.1 and rigid.rpe_trans_rmse_m > 0.1


@pytest.mark.parametrize("eps", [0.004, 0.006])
def test_alternating_offset_gives_closed_form_ate_rpe_and_failures(eps):
    # centres k * 45 deg around a circle, moved by +-eps along z alternately: by symmetry the best
    # rigid alignment is the identity, so ATE = eps; each 1-frame step is off by 2 eps; rotations
    # are untouched
    gt = _circle_trajectory(8, seed=1)
    est = gt.copy()
    est[:, 2, 3] += eps * (-1.0) ** np.arange(8)
    m = evaluate_trajectory(np.arange(8) / 30, est, gt)
    assert m.ate_rmse_m == pytest.approx(eps, rel=1e-9) and m.ate_alignment == ATE_ALIGNMENT
    assert m.rpe_trans_rmse_m == pytest.approx(2 * eps, rel=1e-9)
    assert m.rpe_rot_rmse_deg < 1e-5
    np.testing.assert_allclose(m.rpe_trans_m, 2 * eps, rtol=1e-9)
    assert m.failed.all() == (2 * eps > FAIL_TRANS_M) and m.failed.any() == (2 * eps > FAIL_TRANS_M)
    np.testing.assert_array_equal(m.pair_frames, np.stack([np.arange(7), np.arange(1, 8)], 1))


def test_rotation_error_per_step_and_missing_ground_truth():
    # a camera turning about its optical axis (z) at a fixed centre; the estimate turns by an extra
    # theta_k about z, so step k is off by |theta_{k+1} - theta_k| in rotation and not in translation
    n = 6
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, :3, :3] = Rotation.from_rotvec(np.outer(np.linspace(0, 1, n), [0, 0, 1])).as_matrix()
    theta = np.radians([0.0, 0.1, 0.4, 0.2, 0.2, 0.9])
    est = gt @ np.stack([np.block([[Rotation.from_rotvec([0, 0, t]).as_matrix(), np.zeros((3, 1))],
                                   [np.zeros((1, 3)), np.ones((1, 1))]]) for t in theta])
    m = evaluate_trajectory(np.arange(n) / 30, est, gt)
    np.testing.assert_allclose(m.rpe_rot_deg, np.degrees(np.abs(np.diff(theta))), atol=1e-6)
    assert m.rpe_trans_rmse_m < 1e-12
    # all centres equal: no Umeyama alignment exists; the first poses are aligned instead (ATE 0 here)
    assert m.ate_alignment == ATE_ALIGNMENT_ORIGIN and m.ate_rmse_m < 1e-12
    np.testing.assert_array_equal(m.failed, np.degrees(np.abs(np.diff(theta))) > FAIL_ROT_DEG)
    # frames without ground truth are left out; steps join the frames that have it
    valid = np.array([True, True, False, True, True, True])
    gt_nan = gt.copy()
    gt_nan[2] = np.nan
    m = evaluate_trajectory(np.arange(n) / 30, est, gt_nan, valid)
    np.testing.assert_array_equal(m.frames, [0, 1, 3, 4, 5])
    np.testing.assert_array_equal(m.pair_frames[1], [1, 3])
    np.testing.assert_allclose(m.rpe_rot_deg[1], np.degrees(theta[3] - theta[1]), atol=1e-6)
    with pytest.raises(ValueError, match="at least 2 frames with ground truth"):
        evaluate_trajectory(np.arange(n) / 30, est, gt, np.eye(1, n, dtype=bool)[0])


def _constant_motion(stamps, velocity, yaw_deg_per_s):
    T = np.tile(np.eye(4), (stamps.size, 1, 1))
    T[:, :3, 3] = np.outer(stamps - stamps[0], velocity)
    T[:, :3, :3] = Rotation.from_euler("z", np.radians(yaw_deg_per_s) * (stamps - stamps[0])[:, None]).as_matrix()
    return T


def test_rpe_per_second_follows_tums_definition():
    # frames at 10 Hz for 5 s, ground truth at 100 Hz stamped 4 ms late; the estimate moves 20% too
    # fast along x and turns 0.5 deg/s too fast about z (the axis of the yaw), so every 1 s step is
    # off by exactly 2 cm and 0.5 deg; steps whose partner is the last frame are dropped (TUM's rule):
    # i = 0..39 are kept (t_i + 1 s is frame i + 10 <= 49)
    t = 100.0 + np.arange(51) / 10
    gt_t = 100.004 + np.arange(501) / 100
    v, w = np.array([0.1, 0.0, 0.0]), 10.0
    est = _constant_motion(t, 1.2 * v, 0.0)
    trans, rot, steps = rpe_per_second(t, est, gt_t, _constant_motion(gt_t, v, 0.0))
    assert steps == 40 and trans == pytest.approx(0.02, rel=1e-6) and rot < 1e-6
    assert rpe_per_second(t, est, gt_t, _constant_motion(gt_t, v, 0.0), scale=1 / 1.2)[0] < 1e-9
    # a rotation-only estimate: the angle error per step; the 4 ms stamp offset of the ground truth
    # is a 0.04 deg slip of a 10 deg/s motion, seen as the ground truth's (as in the script)
    trans, rot, steps = rpe_per_second(t, _constant_motion(t, 0 * v, w + 0.5), gt_t, _constant_motion(gt_t, 0 * v, w))
    assert rot == pytest.approx(0.5, abs=1e-6) and trans < 1e-9
    # a hole in the ground truth: steps with an end more than two intervals from a sample are skipped
    hole = (gt_t < 101.5) | (gt_t > 102.5)
    _, _, with_hole = rpe_per_second(t, est, gt_t[hole], _constant_motion(gt_t, v, 0.0)[hole])
    ends = np.stack([t[:40], t[10:50]], 1)
    kept = ~(((ends > 101.5 + 0.02) & (ends < 102.5 - 0.02)).any(1))
    assert with_hole == int(kept.sum()) < 40
    assert rpe_per_second(t[:1], est[:1], gt_t, _constant_motion(gt_t, v, 0.0)) is None


def test_nearest_groundtruth_is_evos_association():
    from evo.core import sync
    from evo.core.trajectory import PoseTrajectory3D

    rng = np.random.default_rng(0)
    t = 5.0 + np.arange(30) / 30 + rng.uniform(-0.003, 0.003, 30)
    gt_t = 5.004 + np.arange(80) / 100  # ends at 5.794 s: the last frames have none within 10 ms
    gt = _constant_motion(gt_t, np.array([0.3, -0.1, 0.05]), 20.0)
    poses, valid = nearest_groundtruth(t, gt_t, gt, 0.01)
    ref = PoseTrajectory3D(poses_se3=list(gt), timestamps=gt_t)
    est = PoseTrajectory3D(poses_se3=list(_constant_motion(t, np.zeros(3), 0.0)), timestamps=t)
    ref, est = sync.associate_trajectories(ref, est, max_diff=0.01)
    frames = np.searchsorted(t, est.timestamps)
    np.testing.assert_array_equal(np.flatnonzero(valid), frames)
    np.testing.assert_array_equal(poses[frames], np.stack(ref.poses_se3))
    within = np.abs(t[:, None] - gt_t[None]).min(1) <= 0.01
    np.testing.assert_array_equal(valid, within)
    assert np.isnan(poses[~valid]).all() and 4 <= (~valid).sum() <= 6


def test_tracker_refuses_a_start_pose_that_is_not_rigid():
    # (a scaled or 3x4 start pose used to run, every later pose carrying its scale, or to fail in numpy)
    from gvnn_warp.odometry import DirectAligner
    from gvnn_warp.odometry.tracking import Tracker

    aligner = DirectAligner(np.array([[100.0, 0, 31.5], [0, 100.0, 23.5], [0, 0, 1]]))
    for pose, message in ((np.diag([2.0, 2, 2, 1]), "must be a rigid transform"),
                          (np.eye(4)[:3], r"must be a finite \(4, 4\) pose, got shape \(3, 4\)")):
        with pytest.raises(ValueError, match=r"gvnn_warp.odometry.tracking.track: argument 'start_pose' " + message):
            Tracker(aligner, 3, start_pose=pose)
    assert np.array_equal(Tracker(aligner, 3, start_pose=np.eye(4)).poses[0], np.eye(4))


def test_pose_error_closed_form():
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0, np.radians(0.3), 0]).as_matrix()
    T[:3, 3] = [0.003, 0.004, 0.0]
    dt, dr = pose_error(T, np.eye(4))
    assert dt == pytest.approx(0.005) and dr == pytest.approx(0.3)
    dt, dr = pose_error(np.eye(4), np.eye(4))
    assert dt == 0 and dr == 0


# ------------------------------------------------------------------------------------------------
# tracking loop, with a test aligner that knows the true motion


class TrueMotion:
    """An aligner whose frames are frame indices (images numbered in order of first appearance) and
    whose answer is the true relative pose, optionally perturbed for some (ref, live) pairs and
    flagged not converged for some live frames."""

    def __init__(self, gt, perturb=None, unconverged=(), valid=0.9):
        self.gt, self.perturb, self.unconverged, self.valid = gt, perturb or {}, set(unconverged), valid
        self.pairs, self.inits, self.ids = [], [], {}

    def prepare(self, image, depth):
        return self.ids.setdefault(np.asarray(image).tobytes(), len(self.ids))

    def align_frames(self, ref, live, init=None):
        if ref == live:  # track's untimed warm-up
            return np.eye(4), {"converged": True}
        self.pairs.append((ref, live))
        self.inits.append(np.array(init))
        T = relative_pose(self.gt[live], self.gt[ref])
        if (ref, live) in self.perturb:
            T = self.perturb[(ref, live)] @ T
        info = {"converged": live not in self.unconverged,
                "levels": [{"valid_fraction": 0.1}, {"valid_fraction": self.valid}]}
        return T, info


def _nothing(i):
    return np.full((1, 2, 2), i, np.float32), np.ones((1, 2, 2), np.float32)


def _shift(x):
    T = np.eye(4)
    T[0, 3] = x
    return T


def test_track_chains_true_motion_frame_to_frame():
    gt = _circle_trajectory(7, seed=4)
    bad = _shift(0.02)
    al = TrueMotion(gt, perturb={(2, 3): bad}, unconverged=[5])
    res = track(_nothing, 7, al, start_pose=gt[0], progress=False, init="velocity")
    assert al.pairs == [(i, i + 1) for i in range(6)]
    np.testing.assert_allclose(res.poses[:3], gt[:3], atol=1e-12)
    # from the perturbed pair on, the trajectory is the truth moved rigidly: frame 3's error carried along
    C = gt[3] @ np.linalg.inv(bad) @ np.linalg.inv(gt[3])
    np.testing.assert_allclose(res.poses[3:], C @ gt[3:], atol=1e-12)
    assert res.unconverged_frames == [5]
    np.testing.assert_allclose(res.valid_fraction[1:], 0.9)  # the finest (last) level's
    # constant velocity: the guess for pair (i, i+1) is the motion of pair (i-1, i)
    np.testing.assert_allclose(al.inits[2], relative_pose(gt[2], gt[1]), atol=1e-12)
    m = evaluate_trajectory(np.arange(7) / 30, res.poses, gt)
    np.testing.assert_array_equal(m.pair_frames[m.failed], [[2, 3]])
    assert res.ms_per_pair > 0


def test_track_keyframes_switch_on_motion_and_valid_fraction():
    n = 9
    gt = np.tile(np.eye(4), (n, 1, 1))
    gt[:, 0, 3] = 0.02 * np.arange(n)  # 2 cm per frame along x
    al = TrueMotion(gt)
    res = track(_nothing, n, al, keyframes=KeyframePolicy(max_trans_m=0.05, max_rot_deg=5, min_valid=0.5),
                progress=False)
    # a frame > 5 cm from its keyframe becomes the next keyframe: 0 -> 3 -> 6
    assert res.keyframes == [0, 3, 6]
    assert list(res.reference[1:]) == [0, 0, 0, 3, 3, 3, 6, 6]
    np.testing.assert_allclose(res.poses, gt, atol=1e-12)
    # the identity guess of a keyframe pair is the previous frame's pose relative to the keyframe
    np.testing.assert_allclose(al.inits[1], relative_pose(gt[1], gt[0]), atol=1e-12)
    # too few valid pixels: every frame becomes a keyframe
    res = track(_nothing, 4, TrueMotion(gt, valid=0.3), keyframes=KeyframePolicy(min_valid=0.5), progress=False)
    assert res.keyframes == [0, 1, 2, 3]


def test_track_survives_a_non_finite_pose_and_reports_it():
    gt = _circle_trajectory(4, seed=2)

    class NaNOnce(TrueMotion):
        def align_frames(self, ref, live, init=None):
            T, info = super().align_frames(ref, live, init)
            return (np.full((4, 4), np.nan), info) if live == 2 else (T, info)

    res = track(_nothing, 4, NaNOnce(gt), progress=False)
    assert np.all(np.isfinite(res.poses)) and res.unconverged_frames == [2]
    np.testing.assert_allclose(res.poses[2], res.poses[1])  # the identity guess was kept


@pytest.mark.parametrize("keyframes", [None, KeyframePolicy(max_trans_m=0.05, max_rot_deg=5, min_valid=0.5)])
def test_pipelined_tracking_makes_the_same_calls_and_poses(keyframes):
    gt = _circle_trajectory(9, seed=5)
    gt[:, 0, 3] += 0.03 * np.arange(9)  # keyframes switch now and then
    runs = []
    for pipeline in (False, True):
        al = TrueMotion(gt, perturb={(2, 3): _shift(0.02)}, unconverged=[5])
        res = track(_nothing, 9, al, start_pose=gt[0], keyframes=keyframes, init="velocity", progress=False,
                    pipeline=pipeline)
        runs.append((al, res))
    (a0, r0), (a1, r1) = runs
    assert a1.pairs == a0.pairs
    np.testing.assert_array_equal(np.array(a1.inits), np.array(a0.inits))
    np.testing.assert_array_equal(r1.poses, r0.poses)
    np.testing.assert_array_equal(r1.reference, r0.reference)
    assert r1.keyframes == r0.keyframes and r1.unconverged_frames == r0.unconverged_frames == [5]
    assert r1.seconds.shape == (9,) and np.all(r1.seconds[1:] > 0)


def test_pipelined_tracking_reports_a_failing_prepare_and_keeps_working():
    class BadFrame(TrueMotion):
        def prepare(self, image, depth):
            if np.asarray(image).flat[0] == 3:
                raise ValueError("prepare: frame 3 is bad")
            return super().prepare(image, depth)

    gt = _circle_trajectory(5, seed=1)
    tracker = Tracker(BadFrame(gt), 5, pipeline=True, warmup=False)
    for i in range(3):
        tracker.add(*_nothing(i))
    with pytest.raises(ValueError, match="frame 3 is bad"):
        tracker.add(*_nothing(3))
    # the frame before it was aligned in the same step; the helper thread is free again
    res = Tracker(TrueMotion(gt), 5, pipeline=True, warmup=False)
    for i in range(5):
        res.add(*_nothing(i))
    np.testing.assert_allclose(res.result().poses, np.linalg.inv(gt[0]) @ gt, atol=1e-12)


def test_direct_aligner_pipelines_with_bitwise_the_sequential_poses(tmp_path):
    from gvnn_warp.datasets.tum import read_tum
    from gvnn_warp.odometry.aligner import DirectAligner

    seq = read_tum(_render(tmp_path, frames=6, size="80x60", seed=3))
    frames = [(seq.image(i, gray=True), seq.depth(i)) for i in range(len(seq))]
    al = DirectAligner(seq.K, levels=2)
    assert al.concurrent_prepare
    poses = [track(lambda i: frames[i], len(frames), al, progress=False, pipeline=p).poses for p in (False, True)]
    np.testing.assert_array_equal(poses[1], poses[0])
    assert Tracker(al, 2).pipeline  # the default for an aligner that allows it


# ------------------------------------------------------------------------------------------------
# gvnn-warp track


def _render(tmp_path, frames=6, size="80x60", seed=0):
    from gvnn_warp.cli import main

    out = tmp_path / "seq"
    assert main(["render", "--out", str(out), "--frames", str(frames), "--size", size, "--seed", str(seed),
                 "--no-progress"]) == 0
    return out


def test_track_cli_writes_files_and_reports_failures(tmp_path, monkeypatch, capsys):
    # the CLI around a test aligner that knows the truth, perturbed once: files, metrics, figures
    from gvnn_warp.cli import main
    from gvnn_warp.cli import track as track_cli

    data = _render(tmp_path)
    gt = read_tum(data).gt_poses
    made = {}

    def fake(K, **kwargs):
        made.update(kwargs, K=K)
        return TrueMotion(gt, perturb={(3, 4): _shift(0.015)}, unconverged=[2])

    monkeypatch.setattr(track_cli, "make_aligner", fake)
    out = tmp_path / "out"
    assert main(["track", str(data), "--out", str(out), "--no-progress", "--robust", "cauchy", "--levels", "3"]) == 0
    assert made["robust"] == "cauchy" and made["levels"] == 3 and made["depth_weight"] == 0.0
    np.testing.assert_allclose(made["K"], read_tum(data).K)
    text = capsys.readouterr().out
    assert re.search(r"failed pairs +1 of 5", text) and re.search(r"unconverged pairs +1 \(frames 2\)", text)
    m = json.loads((out / "metrics.json").read_text())
    assert m["frames"] == 6 and m["failed_pairs"] == 1 and m["failed_pair_frames"] == [[3, 4]]
    assert m["unconverged_pairs"] == 1 and m["unconverged_frames"] == [2]
    assert m["rpe_trans_rmse_m"] == pytest.approx(0.015 / np.sqrt(5), rel=1e-6)
    assert m["rpe_rot_rmse_deg"] < 1e-5 and 0 < m["ate_rmse_m"] < 0.015
    assert "Umeyama" in m["ate_alignment"] and m["metrics_by"] == "evo"
    stamps, poses = read_trajectory(out / "trajectory.txt")
    np.testing.assert_allclose(stamps, read_tum(data).timestamps, atol=1e-6)
    np.testing.assert_allclose(poses[:4], gt[:4], atol=1e-8)  # starts at the ground truth's first pose
    for png in ("trajectory.png", "errors.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_track_cli_metrics_are_evos_for_the_files_it_wrote(tmp_path, monkeypatch, capsys):
    # ground truth stamped 4 ms after each frame: the metrics are evo's for trajectory.txt against
    # groundtruth.txt (nearest stamps); --gt-interpolate evaluates against interpolated poses instead
    from evo.core import metrics as evo_metrics
    from evo.core import sync
    from evo.tools import file_interface

    from gvnn_warp.cli import main
    from gvnn_warp.cli import track as track_cli

    data = _render(tmp_path, frames=40)
    seq = read_tum(data)
    write_trajectory(data / "groundtruth.txt", seq.timestamps + 0.004, seq.gt_poses)
    gt = seq.gt_poses
    monkeypatch.setattr(track_cli, "make_aligner", lambda K, **kw: TrueMotion(
        gt, perturb={(i, i + 1): _shift(0.004 * (-1) ** i) for i in range(0, 39, 3)}))
    results = {}
    for extra in ([], ["--gt-interpolate"]):
        out = tmp_path / f"out{len(extra)}"
        assert main(["track", str(data), "--out", str(out), "--no-progress", *extra]) == 0
        results[len(extra)] = json.loads((out / "metrics.json").read_text())
    m = results[0]
    ref = file_interface.read_tum_trajectory_file(str(data / "groundtruth.txt"))
    est = file_interface.read_tum_trajectory_file(str(tmp_path / "out0" / "trajectory.txt"))
    ref, est = sync.associate_trajectories(ref, est, max_diff=0.02)
    for relation, key in ((evo_metrics.PoseRelation.translation_part, "rpe_trans_rmse_m"),
                          (evo_metrics.PoseRelation.rotation_angle_deg, "rpe_rot_rmse_deg")):
        rpe = evo_metrics.RPE(relation, delta=1, delta_unit=evo_metrics.Unit.frames)
        rpe.process_data((ref, est))
        assert m[key] == pytest.approx(rpe.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-5, abs=1e-9)
    est.align(ref)
    ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    assert m["ate_rmse_m"] == pytest.approx(ape.get_statistic(evo_metrics.StatisticsType.rmse), rel=1e-5)
    assert "nearest" in m["gt_association"] and "interpolated" in results[1]["gt_association"]
    assert results[1]["rpe_rot_rmse_deg"] != pytest.approx(m["rpe_rot_rmse_deg"], rel=1e-3)
    # the per-second RPE: 40 frames at 30 Hz, steps of 30 frames from frames 0..8 (9 is the last's)
    assert m["rpe_per_second_steps"] == 9 and m["rpe_trans_m_per_s"] > 0 and m["rpe_rot_deg_per_s"] >= 0
    assert "cm/s" in capsys.readouterr().out


def test_track_cli_says_when_given_intrinsics_replace_the_folders(tmp_path, monkeypatch, capsys):
    from gvnn_warp.cli import main
    from gvnn_warp.cli import track as track_cli

    data = _render(tmp_path, frames=3, size="32x24")
    gt = read_tum(data).gt_poses
    monkeypatch.setattr(track_cli, "make_aligner", lambda K, **kw: TrueMotion(gt))
    assert main(["track", str(data), "--out", str(tmp_path / "o"), "--no-progress", "--intrinsics", "fr1"]) == 0
    text = capsys.readouterr().out
    assert re.search(r"warning +the intrinsics given \(fx .*\) replace .*intrinsics.txt, which differs", text), text
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert "which differs" in m["intrinsics"]["override"]


def test_track_cli_fuses_a_mesh_and_tracks_against_the_model(tmp_path, capsys):
    # a rendered room: --fuse writes a mesh on the room's true surfaces; --model tracks frame to
    # model (each frame against the raycast of the TSDF so far) as accurately
    from gvnn_warp.cli import main
    from gvnn_warp.fusion.ply import read_ply
    from gvnn_warp.synthetic import make_room_scene, surface_distance

    data = _render(tmp_path, frames=8, size="160x120", seed=4)
    results = {}
    for mode in ("--fuse", "--model"):
        out = tmp_path / mode.strip("-")
        assert main(["track", str(data), "--out", str(out), "--no-progress", mode, "--voxel", "0.02"]) == 0
        text = capsys.readouterr().out
        assert re.search(r"fusion +\d+ blocks of 8\^3 voxels at 0.02 m", text) and "mesh.ply" in text
        m = json.loads((out / "metrics.json").read_text())
        results[mode] = m
        v, f, c = read_ply(out / "mesh.ply")
        assert m["fusion"]["mesh_faces"] == len(f) > 1000 and m["fusion"]["mesh_vertices"] == len(v)
        dist = surface_distance(make_room_scene(seed=4), v)  # (the room of the rendered seed)
        assert np.median(dist) < 0.3 * 0.02, mode  # (within 0.3 voxel of the room's true surfaces)
        assert Image.open(out / "mesh.png").size == (160, 120) and m["fusion"]["picture_coverage"] > 0.9
    assert results["--model"]["settings"]["mode"] == "frame-to-model"
    assert results["--model"]["failed_pairs"] == 0 and results["--model"]["ate_rmse_m"] < 0.01


REAL = Path(__file__).parents[1] / "data" / "rgbd_dataset_freiburg1_xyz"  # six Kinect frames (README there)


@pytest.mark.long
def test_real_kinect_frames_track_fuse_and_track_against_the_model(tmp_path, capsys):
    # real frames (holes, noise, the freiburg1 lens chosen by the folder's name): every track mode
    # runs unchanged and stays within a few millimetres of the motion capture (which is itself
    # good to ~1 mm here), and the fused mesh lies on the depth the sensor measured
    from gvnn_warp.cli import main
    from gvnn_warp.fusion.ply import read_ply

    seq = read_tum(REAL)
    assert seq.dist is not None and len(seq) == 5  # (six colour frames, five with a depth image within 20 ms)
    assert seq.listed == (6, 6) and seq.max_difference == 0.02
    for extra in (["--fuse"], ["--model"]):  # (--fuse tracks frame to frame, then fuses)
        out = tmp_path / "-".join(extra)
        assert main(["track", str(REAL), "--out", str(out), "--no-progress", *extra]) == 0
        m = json.loads((out / "metrics.json").read_text())
        assert m["ate_rmse_m"] < 0.01 and m["unconverged_pairs"] == 0, (extra, m["ate_rmse_m"])
        v, f, _ = read_ply(out / "mesh.ply")
        assert len(f) > 10000 and m["fusion"]["frames_skipped"] == []
        assert m["colour_images_without_depth"] == 1  # (said in the summary too)
    out = capsys.readouterr().out
    assert "radial-tangential" in out and "1 of the 6 colour images listed have no depth image within 0.02 s" in out


def test_track_cli_fusion_options_and_limits(tmp_path, capsys, monkeypatch):
    from gvnn_warp.cli import main

    data = _render(tmp_path, frames=3, size="64x48")
    for argv, message in ((["--voxel", "0.02"], "--voxel applies with --fuse or --model only"),
                          (["--model", "--keyframes"], "use one of --model, --keyframes"),
                          (["--fuse", "--model"], "not allowed with argument"),
                          (["--fuse", "--truncation", "0.001"], "less than a voxel"),
                          (["--model", "--method", "vo"], "--model tracks with the direct aligner")):
        with pytest.raises(SystemExit) as e:
            main(["track", str(data), "--out", str(tmp_path / "o"), *argv])
        assert e.value.code == 2 and message in capsys.readouterr().err
    # a map larger than the memory given: one line, status 1; the trajectory is kept
    out = tmp_path / "small"
    assert main(["track", str(data), "--out", str(out), "--no-progress", "--fuse", "--voxel", "0.002",
                 "--fuse-memory", "0.1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the map needs more than" in err[0] and "--fuse-memory" in err[0]
    assert (out / "trajectory.txt").exists() and not (out / "mesh.ply").exists()
    # with --model the map is the tracking's reference: it stops there (here at the first frame: one
    # line, nothing to write)
    out = tmp_path / "small_model"
    assert main(["track", str(data), "--out", str(out), "--no-progress", "--model", "--voxel", "0.002",
                 "--fuse-memory", "0.1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the map needs more than" in err[0] and not out.exists(), err
    assert "(--voxel, --fuse-memory)" in err[0], err  # (the options, not the Python argument's name alone)
    # depths in the wrong units: nothing integrated, said once, in the summary (no Python warning)
    out = tmp_path / "empty"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["track", str(data), "--out", str(out), "--no-progress", "--fuse", "--depth-scale", "5"]) == 0
    summary = capsys.readouterr().out
    assert "warning            the mesh is empty: no surface was seen twice" in summary
    assert json.loads((out / "metrics.json").read_text())["fusion"]["frames_skipped"] == [0, 1, 2]
    # an unreadable frame mid-run: the model tracking so far is written, marked partial
    images = sorted((data / "rgb").glob("*.png"))
    images[2].write_bytes(images[2].read_bytes()[: len(images[2].read_bytes()) // 2])
    out = tmp_path / "partial_model"
    assert main(["track", str(data), "--out", str(out), "--no-progress", "--model", "--voxel", "0.02"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and images[2].name in err[0] and "stopped at frame 2" in err[0], err
    partial = json.loads((out / "metrics.json").read_text())
    assert partial["partial"] and "raycast of the model" in partial["ms_per_pair_note"]
    # and the model those frames made: its mesh and picture, its numbers in metrics.json
    assert "mesh of the model they made (mesh.ply, mesh.png)" in err[0], err
    assert (out / "mesh.ply").exists() and (out / "mesh.png").exists()
    fusion = json.loads((out / "metrics.json").read_text())["fusion"]
    assert fusion["frames_integrated"] == 2 and fusion["mesh_faces"] > 0
    # colour and a constant-velocity start reach the model tracking (and its report)
    from gvnn_warp.fusion import sequence as fusion_sequence

    made = []

    class Recording(fusion_sequence.ModelTracker):
        def __init__(self, *args, **kwargs):
            made.append((kwargs.get("color"), kwargs.get("init"), args[1].color))
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(fusion_sequence, "ModelTracker", Recording)
    out = tmp_path / "model_rgb_velocity"
    assert main(["track", str(data), "--out", str(out), "--no-progress", "--model", "--voxel", "0.02", "--color",
                 "--init", "velocity", "--max-frames", "2"]) == 0
    assert made == [(True, "velocity", True)]  # (and the aligner made for colour)
    assert "frame-to-model, method direct, RGB, constant-velocity start)" in capsys.readouterr().out
    settings = json.loads((out / "metrics.json").read_text())["settings"]
    assert settings["mode"] == "frame-to-model" and settings["init"] == "velocity" and settings["channels"] == "rgb"


def test_track_cli_without_ground_truth(tmp_path, monkeypatch):
    from gvnn_warp.cli import main
    from gvnn_warp.cli import track as track_cli

    data = _render(tmp_path, frames=3, size="32x24")
    gt = read_tum(data).gt_poses
    (data / "groundtruth.txt").unlink()
    monkeypatch.setattr(track_cli, "make_aligner", lambda K, **kw: TrueMotion(gt))
    out = tmp_path / "out"
    assert main(["track", str(data), "--out", str(out), "--no-progress", "--max-frames", "2"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["frames"] == 2 and not m["ground_truth"] and "ate_rmse_m" not in m
    _, poses = read_trajectory(out / "trajectory.txt")
    np.testing.assert_allclose(poses[0], np.eye(4), atol=1e-9)  # identity start without ground truth
    np.testing.assert_allclose(poses[1], relative_pose(gt[0], gt[1]), atol=1e-8)
    assert (out / "trajectory.png").exists() and not (out / "errors.png").exists()


def test_track_cli_file_errors_name_the_file(tmp_path, capsys):
    # (every bad option is in test_cli.py's table; here: what is found on disk, a data error: one
    # line naming the file, status 1, no usage text)
    from gvnn_warp.cli import main

    data = _render(tmp_path, frames=4, size="16x16")
    out = tmp_path / "o"

    def one_line_error(*argv):
        assert main(["track", str(data), "--out", str(out), "--no-progress", *argv]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("gvnn-warp track: error: ") and "usage" not in err[0], err
        return err[0]

    (data / "rgb.txt").rename(data / "rgb.old")
    assert re.fullmatch(r"gvnn-warp track: error: .*rgb.txt: missing colour list file.*", one_line_error())
    (data / "rgb.txt").write_text("# an empty list\n")
    assert "rgb.txt" in one_line_error()
    (data / "rgb.old").rename(data / "rgb.txt")
    assert not out.exists()  # nothing is written before the files are checked
    # an image that is missing, not an image, or of the wrong format or size is found before any
    # frame is tracked (from the headers)
    images = sorted((data / "rgb").glob("*.png"))
    good = images[2].read_bytes()
    depths = sorted((data / "depth").glob("*.png"))
    for path, bad, says in [
        (images[2], b"not a png", "cannot read colour image"),
        (depths[2], None, "depth image is 8-bit"),
        (depths[1], (4, 4), "depth image is 4x4, the sequence's first image is 16x16"),
    ]:
        original = path.read_bytes()
        if bad is None:
            Image.open(path).convert("L").save(path)
        elif isinstance(bad, tuple):
            Image.open(path).resize(bad).save(path)
        else:
            path.write_bytes(bad)
        line = one_line_error()
        assert path.name in line and says in line, line
        assert not out.exists()
        path.write_bytes(original)
    depths[3].unlink()
    assert depths[3].name in one_line_error() and not out.exists()
    depths[3].write_bytes(depths[2].read_bytes())
    # pixel data that cannot be decoded behind a good header is met while tracking: one line naming
    # the file and saying where the results of the frames before it are, written and marked partial
    images[2].write_bytes(good[: len(good) // 2])
    line = one_line_error()
    assert images[2].name in line and "stopped at frame 2" in line and str(out) in line
    m = json.loads((out / "metrics.json").read_text())
    assert m["partial"] and m["stopped_at_frame"] == 2 and m["frames"] == 2 and images[2].name in m["stopped_by"]
    stamps, _ = read_trajectory(out / "trajectory.txt")
    assert stamps.shape == (2,)
    # frame 1 unreadable: nothing to report, nothing written
    shutil.rmtree(out)
    images[2].write_bytes(good)
    images[1].write_bytes(images[1].read_bytes()[:60])
    assert images[1].name in one_line_error() and not out.exists()


def test_track_cli_keeps_results_and_says_what_it_used(tmp_path, capsys):
    from gvnn_warp.cli import main

    data = _render(tmp_path, frames=3, size="32x24")
    out = tmp_path / "o"
    run = ["track", str(data), "--out", str(out), "--no-progress"]
    assert main(run) == 0
    summary = capsys.readouterr().out
    assert "intrinsics         fx 24 fy 24 cx 15.5 cy 11.5 (" in summary and "intrinsics.txt)" in summary
    first = (out / "metrics.json").read_text()
    with pytest.raises(SystemExit) as e:  # earlier results are not replaced silently
        main(run)
    assert e.value.code == 2
    assert "--out " + str(out) + " already holds results (trajectory.txt); pass --overwrite" in capsys.readouterr().err
    assert (out / "metrics.json").read_text() == first
    assert main([*run, "--overwrite"]) == 0
    capsys.readouterr()

    # ground truth for some frames only: the summary says how many were evaluated
    gt = data / "groundtruth.txt"
    lines = gt.read_text().splitlines()
    poses = [line for line in lines if not line.startswith("#")]
    gt.write_text("\n".join(poses[:2]) + "\n")  # frames 0 and 1 (frame 2 is 1/30 s > 0.02 s away)
    assert main([*run, "--overwrite"]) == 0
    assert ("evaluated frames   2 of 3 (the others have no ground-truth pose within --max-difference 0.02 s)"
            in capsys.readouterr().out)
    # ground truth that matches no frame, or none at all: the summary says why there is no ATE/RPE
    shifted = [" ".join([f"{float(w[0]) + 100:.6f}", *w[1:]]) for w in (line.split() for line in lines
                                                                           if not line.startswith("#"))]
    gt.write_text("\n".join(shifted) + "\n")
    assert main([*run, "--overwrite"]) == 0
    assert ("none usable: 0 of the 3 frames have a pose in groundtruth.txt within --max-difference 0.02 s"
            in capsys.readouterr().out)
    gt.unlink()
    assert main([*run, "--overwrite"]) == 0
    assert "ground truth       none (no groundtruth.txt): no ATE/RPE" in capsys.readouterr().out
    assert not (out / "errors.png").exists()  # the earlier run's, with ground truth: not left behind
    # depths read at the wrong scale leave no usable pixel, or are implausible: a warning, not only
    # unconverged pairs or a large error
    assert main([*run, "--overwrite", "--depth-scale", "1e9"]) == 0
    report = capsys.readouterr().out
    assert "warning            only 0.0% of the pixels were usable" in report and "--depth-scale (1e+09" in report
    assert "median depth is" in report
    assert json.loads((out / "metrics.json").read_text())["median_valid_fraction"] == 0.0
    assert main([*run, "--overwrite", "--depth-scale", "5"]) == 0  # TUM's 5000 read as 5: depths of km
    report = capsys.readouterr().out
    assert re.search(r"warning            the first frame's median depth is \d+ m: check --depth-scale \(5 units",
                     report), report
    assert main([*run, "--overwrite"]) == 0
    assert "warning" not in capsys.readouterr().out


def test_track_cli_end_to_end_with_the_direct_aligner(tmp_path, capsys):
    from gvnn_warp.cli import main

    data = _render(tmp_path, frames=6, size="160x120")
    out = tmp_path / "out"
    assert main(["track", str(data), "--out", str(out), "--no-progress"]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["frames"] == 6 and m["ms_per_pair"] > 0
    # every 1.5-4 cm / 0.6-1.6 deg step recovered within the failure thresholds (1 cm, 0.25 deg; at
    # 160x120, f = 120 px, 1 cm is ~0.5 px), and far better than standing still would be
    gt = read_tum(data).gt_poses
    still_t, still_r = pose_error(np.eye(4), relative_pose(gt[:-1], gt[1:]))
    assert m["failed_pairs"] == 0 and m["ate_rmse_m"] < 0.01
    assert m["rpe_trans_rmse_m"] < 0.4 * np.sqrt(np.mean(still_t**2))
    assert m["rpe_rot_rmse_deg"] < 0.4 * np.sqrt(np.mean(still_r**2))
    assert m["unconverged_pairs"] == 0
    assert (out / "trajectory.png").exists() and (out / "errors.png").exists()
    assert "ATE RMSE" in capsys.readouterr().out


def test_track_cli_ctrl_c_exits_130_with_one_line(tmp_path, monkeypatch, capsys):
    from gvnn_warp.cli import main
    from gvnn_warp.cli import track as track_cli

    data = _render(tmp_path, frames=3, size="16x16")

    class Interrupted(TrueMotion):
        def align_frames(self, ref, live, init=None):
            if ref != live:
                raise KeyboardInterrupt
            return super().align_frames(ref, live, init)

    monkeypatch.setattr(track_cli, "make_aligner", lambda K, **kw: Interrupted(read_tum(data).gt_poses))
    assert main(["track", str(data), "--out", str(tmp_path / "o"), "--no-progress"]) == 130
    assert capsys.readouterr().err.strip() == "gvnn-warp track: interrupted"


def test_odometry_benchmark_runs_without_open3d(tmp_path, monkeypatch, capsys):
    # benchmarks/odometry.py end to end on a tiny sequence, our tracker only (tests never need Open3D),
    # in this process (as `python -m benchmarks.odometry` from the repository's root)
    from pathlib import Path

    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2]))
    from benchmarks import odometry

    assert odometry.main(["--frames", "8", "--sizes", "80x60", "--strides", "5", "--no-open3d", "--no-progress",
                          "--json", str(tmp_path / "r.json")]) == 0
    printed = capsys.readouterr().out
    assert "| gvnn_warp DirectAligner |" in printed
    r = json.loads((tmp_path / "r.json").read_text())["results"]["80x60"]["gvnn_warp DirectAligner"]
    assert r["basin_5_pairs"] == 3 and 0 <= r["basin_5"] <= 1 and 0 <= r["failed_pairs"] <= 7
    assert r["ms_per_pair"] > 0 and 0 < r["rpe_trans_rmse_cm"] < 1.0 and r["ate_alignment"].startswith("SE(3)")
    ne = json.loads((tmp_path / "r.json").read_text())["normal_equations"]["80x60"]
    assert ne["pairs"] == 7 and 0 < ne["ms_per_call_median"] and "fraction_of_open3d_pair" not in ne
    # probed at the true relative pose of the last pair: 1.4e-4 per pixel here (identity 4.4e-4, inverted 9.6e-4)
    assert 0 < ne["last_pair_cost_per_pixel"] < 3e-4
    assert "normal equations (pure Warp, out=, C=1, 80x60)" in printed


def test_odometry_benchmark_normal_equations_summary():
    from benchmarks.odometry import NE_TARGET_FRACTION, normal_equations_summary

    ne, line = normal_equations_summary([1.0, 3.0, 2.0, 10.0], "320x240", {"ms_per_pair_median": 40.0})
    assert ne == {"ms_per_call_median": 2.5, "ms_per_call_mean": 4.0, "pairs": 4, "fraction_of_open3d_pair": 2.5 / 40}
    assert "0.062x Open3D's median time per pair" in line and f"{NE_TARGET_FRACTION:.3f}x" in line
    ne, line = normal_equations_summary([1.0], "640x480", {"ms_per_pair_median": 40.0})
    assert ne["fraction_of_open3d_pair"] == 1 / 40 and "target" not in line  # the target is at 320x240 only
    ne, line = normal_equations_summary([1.0], "320x240", None)
    assert "fraction_of_open3d_pair" not in ne and "Open3D" not in line


def test_track_passes_the_radtan_distortion_to_the_aligner(tmp_path, monkeypatch):
    from gvnn_warp.cli import main
    from gvnn_warp.cli import track as track_cli

    data = _render(tmp_path)
    gt = read_tum(data).gt_poses
    made = []
    real = track_cli.make_aligner

    def fake(K, **kwargs):
        made.append(kwargs)
        return TrueMotion(gt)

    monkeypatch.setattr(track_cli, "make_aligner", fake)
    out = tmp_path / "out"
    assert main(["track", str(data), "--out", str(out), "--no-progress"]) == 0
    assert made[-1]["dist"] is None  # the rendered folder's intrinsics.txt: a pinhole
    assert main(["track", str(data), "--out", str(out), "--no-progress", "--overwrite", "--intrinsics",
                 "100,100,20,15,0.1,-0.2,0.01,0.02,0.3"]) == 0
    np.testing.assert_array_equal(made[-1]["dist"], [0.1, -0.2, 0.01, 0.02, 0.3])
    assert json.loads((out / "metrics.json").read_text())["intrinsics"]["radtan"] == [0.1, -0.2, 0.01, 0.02, 0.3]
    assert main(["track", str(data), "--out", str(out), "--no-progress", "--overwrite", "--intrinsics", "fr1"]) == 0
    np.testing.assert_array_equal(made[-1]["dist"], [0.2624, -0.9531, -0.0054, 0.0026, 1.1633])
    assert made[-1]["lens"] == "resample" and made[-1]["size"] == (80, 60)
    assert main(["track", str(data), "--out", str(out), "--no-progress", "--overwrite", "--intrinsics", "fr1",
                 "--lens", "exact"]) == 0
    assert made[-1]["lens"] == "exact"
    aligner = real(read_tum(data).K, dist=[0.1, -0.2, 0.01, 0.02, 0.3], lens="exact")
    assert aligner.model == "radtan" and aligner.dist[4] == 0.3
    resampling = real(read_tum(data).K, dist=[0.1, -0.2, 0.01, 0.02, 0.3], size=(80, 60))
    assert type(resampling).__name__ == "UndistortingAligner" and resampling.aligner.model == "pinhole"


def test_a_lens_sequence_tracks_the_same_resampled_as_exact(tmp_path):
    # rendered frames seen through the Freiburg 1 lens (each lens pixel takes the pinhole image at
    # its ray): tracked through one resampling per frame (the default) and through the lens model
    # inside the aligner, both recover the true motion as the pinhole frames do
    from benchmarks.lens_tracking import lens_twin
    from gvnn_warp.datasets.intrinsics import DISTORTION_PRESETS
    from gvnn_warp.odometry.sequence import make_aligner
    from gvnn_warp.odometry.undistort import ideal_camera, lens_positions

    pin = read_tum(_render(tmp_path, frames=5, size="160x120", seed=2))
    dist = DISTORTION_PRESETS["fr1"]
    lens_twin(pin, tmp_path / "lens", dist)
    lens = read_tum(tmp_path / "lens")
    assert lens.dist is not None
    # the ideal camera of the resampling keeps every ideal pixel inside the lens image: a crop of the
    # lens's focal lengths, as large as that allows (little margin left: about a step of 8 columns
    # and a row, each side shrinking 0.8 / 0.6 pixels a step), for the rendered camera and for the
    # published fr1 one (principal point off the image's centre)
    fr1 = np.array([[517.3 / 4, 0, (318.6 + 0.5) / 4 - 0.5], [0, 516.5 / 4, (255.3 + 0.5) / 4 - 0.5], [0, 0, 1]])
    for K in (lens.K, fr1):
        Ki, (w, h) = ideal_camera(K, dist, 160, 120)
        pos = lens_positions(K, dist, w, h, Ki)
        assert np.array_equal(Ki[[0, 1], [0, 1]], K[[0, 1], [0, 1]]) and w % 8 == 0 and w < 160 and h < 120
        margins = pos[:, 0].min(), 159 - pos[:, 0].max(), pos[:, 1].min(), 119 - pos[:, 1].max()
        assert min(margins) >= 0 and margins[0] + margins[1] < 10 and margins[2] + margins[3] < 3, margins
    frames = [(lens.image(i, gray=True), lens.depth(i)) for i in range(5)]
    for mode in ("resample", "exact"):
        r = track(lambda i: frames[i], 5, make_aligner(lens.K, dist=lens.dist, size=(160, 120), lens=mode),
                  start_pose=lens.gt_poses[0], progress=False)
        t_err, r_err = pose_error(r.poses, lens.gt_poses)
        assert t_err.max() < 0.004 and r_err.max() < 0.15, mode


@pytest.mark.parametrize("C, W, color, crop", [(1, 64, False, False), (3, 64, False, False), (1, 60, False, False),
                                               (3, 60, True, False), (1, 64, False, True), (3, 60, True, True)])
def test_resampling_inside_the_base_level_equals_resampling_first(C, W, color, crop):
    # the lens frame resampled as the pyramid's base level is made (one pass) gives, bit for bit, the
    # pyramid of the frame resampled first (remap_rgbd) then prepared as a pinhole frame: NaN
    # intensities, missing depths, depth edges and positions with no source included; the 8-lane
    # kernel (one intensity, W % 8 == 0) and the scalar one (colour, other widths); into an image of
    # the source's size, and (crop) into a smaller one
    from gvnn_warp.kernels.sampling.remap import RemapTable

    from gvnn_warp.datasets.intrinsics import DISTORTION_PRESETS
    from gvnn_warp.odometry.aligner import DirectAligner
    from gvnn_warp.odometry.undistort import UndistortingAligner, lens_positions

    H = 48
    K = np.array([[60.0, 0, (W - 1) / 2], [0, 60.0, 23.5], [0, 0, 1]])
    dist = DISTORTION_PRESETS["fr1"]
    rng = np.random.default_rng(C)
    img = rng.uniform(size=(2, C, H, W)).astype(np.float32)
    img[0, 0, 3, 4] = np.nan
    dep = (1 + rng.uniform(size=(2, 1, H, W))).astype(np.float32)
    dep[:, 0, 10:20, 10:20] *= 3  # a depth edge
    dep[0, 0, 1, 1], dep[1, 0, 2, 2], dep[1, 0, 30, 40] = np.nan, 0, -1
    Wo, Ho = (W - 8, H - 6) if crop else (W, H)  # (the crop: the image's top left part)
    Ko = K.copy()
    pos = lens_positions(K, dist, Wo, Ho, Ko)  # with the lens's own K the corners fall outside the image
    pos[5] = -1
    assert (pos[:, 0] > W - 1).any() or (pos.min(1) < 0).sum() > 1
    table = RemapTable(pos, W, H, out_size=(Wo, Ho))
    fused = DirectAligner(Ko, resample=table, color=color).prepare(img, dep)
    undistorting = UndistortingAligner(K, dist, (W, H))
    undistorting.table = table
    pairs = [undistorting.undistort(img[b], dep[b]) for b in range(2)]
    assert pairs[0][0].shape[1:] == pairs[0][1].shape[1:] == (Ho, Wo)
    first = DirectAligner(Ko, color=color).prepare(np.stack([p[0] for p in pairs]), np.stack([p[1] for p in pairs]))
    assert fused.images[0].shape[1] == (C if color else 1)
    assert len(fused.images) == len(first.images) > 2
    for a, b in zip(fused.images + fused.depths, first.images + first.depths):
        np.testing.assert_array_equal(a.numpy(), b.numpy())
    assert (fused.depths[0].numpy() == 0).sum() > 100  # (the edge, the holes and the empty corners)
    with pytest.raises(ValueError, match="the resampling table's source"):
        DirectAligner(K, resample=table).prepare(img[:, :, :40], dep[:, :, :40])
    with pytest.raises(TypeError, match="DirectAligner: argument 'resample' must be None or a RemapTable"):
        DirectAligner(K, resample=pos)
    with pytest.raises(ValueError, match=f"RemapTable: {Wo * Ho - 1} positions for an output of {Wo}x{Ho}"):
        RemapTable(pos[:-1], W, H, out_size=(Wo, Ho))
    with pytest.raises(ValueError, match="argument 'resample' must have an output size"):
        DirectAligner(K, resample=RemapTable(pos[:-1], W, H))
    with pytest.raises(ValueError, match="argument 'resample' must make images of at least 4x4 pixels, got 8x3"):
        DirectAligner(K, resample=RemapTable(pos[:24], W, H, out_size=(8, 3)))
    with pytest.raises(ValueError, match="UndistortingAligner.prepare: argument 'depth' must be"):
        undistorting.prepare(img[0], dep[0, :, :40])
    with pytest.raises(ValueError, match="argument 'resample' resamples into a pinhole camera"):
        DirectAligner(K, resample=table, dist=dist)


def test_remap_is_bilinear_and_nearest_with_empty_outside():
    from gvnn_warp.kernels.sampling.remap import RemapTable, remap

    rng = np.random.default_rng(0)
    src = rng.uniform(size=(2, 5, 7)).astype(np.float32)
    src[1, 2, 3] = np.nan
    pos = np.array([[0, 0], [6, 4], [2.25, 1.5], [3.4, 2.2], [-0.6, 1], [6.4, 4.4], [7.2, 1]], np.float64)
    table = RemapTable(pos, 7, 5)
    lin = remap(src, table, (1, 7))[:, 0]
    near = remap(src, table, (1, 7), nearest=True)[:, 0]
    x0, y0, fx, fy = 2, 1, 0.25, 0.5
    expected = (1 - fy) * ((1 - fx) * src[0, y0, x0] + fx * src[0, y0, x0 + 1]) + fy * (
        (1 - fx) * src[0, y0 + 1, x0] + fx * src[0, y0 + 1, x0 + 1])
    np.testing.assert_allclose(lin[0, :3], [src[0, 0, 0], src[0, 4, 6], expected], rtol=1e-6)
    assert lin[0, 4] == 0 and lin[0, 6] == 0  # outside: no source
    np.testing.assert_array_equal(near[0, :4], [src[0, 0, 0], src[0, 4, 6], src[0, 2, 2], src[0, 2, 3]])
    assert near[1, 3] == 0  # a NaN source reads as 0 (no depth)
    assert near[0, 5] == src[0, 4, 6] and near[0, 6] == 0  # within half a pixel of the image, and beyond
    # the output's shape: the table's own when it has one, else given
    np.testing.assert_array_equal(remap(src, RemapTable(pos, 7, 5, out_size=(7, 1)), nearest=True)[:, 0], near)
    with pytest.raises(ValueError, match="remap: the table has no output size"):
        remap(src, table)
    with pytest.raises(ValueError, match=r"remap: 7 positions for an output of \(2, 7\)"):
        remap(src, table, (2, 7))


# ------------------------------------------------------------------------------------------------
# gvnn-warp track --method vo | vo+direct (the trained network as the front end)


def _vo_checkpoint(path, K, bias=None, size=(64, 48), symmetries=()):
    """A checkpoint of a 2-stage se3 network at ``size`` whose first stage predicts ``bias``
    ([omega, t], metres: no depth normalisation) for every pair, the second stage the identity;
    its predictions averaged over ``symmetries``."""
    import dataclasses

    import torch

    from gvnn_warp.vo import default_config
    from gvnn_warp.vo.checkpoint import CHECKPOINT_FORMAT, build_network, network_spec

    cfg = default_config("se3", str(path.parent), size=size, stage_scales=(1, 1), refine=1, depth_normalised_t=False,
                         widths=(4, 8, 8, 8), symmetries=symmetries)
    spec = network_spec(cfg, torch.as_tensor(K))
    net = build_network(spec)
    if bias is not None:
        with torch.no_grad():
            net.stages[0].tail[-1].bias.copy_(torch.as_tensor(bias, dtype=torch.float32) / net.stages[0].out_scale)
    torch.save({"format": CHECKPOINT_FORMAT, "config": dataclasses.asdict(cfg), "network": spec,
                "model": net.state_dict(), "step": 0}, path)
    return path


def test_track_cli_vo_chains_the_network_pose_and_vo_direct_refines_it(tmp_path):
    import torch

    from gvnn_warp import se3_to_matrix
    from gvnn_warp.cli import main

    data = _render(tmp_path, frames=3, size="80x60")  # resized to the network's 64x48
    seq = read_tum(data)
    xi = [0.01, -0.02, 0.005, 0.01, 0.0, -0.02]
    T = np.eye(4)
    T[:3] = se3_to_matrix(torch.tensor([xi], dtype=torch.float64))[0].numpy()
    ckpt = _vo_checkpoint(tmp_path / "biased.pt", seq.K, bias=xi)
    assert main(["track", str(data), "--out", str(tmp_path / "vo"), "--method", "vo", "--checkpoint", str(ckpt),
                 "--no-progress"]) == 0
    m = json.loads((tmp_path / "vo" / "metrics.json").read_text())
    assert m["settings"]["method"] == "vo" and m["settings"]["init"] == "network" and m["frames"] == 3
    _, poses = read_trajectory(tmp_path / "vo" / "trajectory.txt")
    # every step is the network's T_live_ref = T: T_world_live = T_world_ref inv(T)
    expect = [seq.gt_poses[0]]
    for _ in range(2):
        expect.append(expect[-1] @ np.linalg.inv(T))
    np.testing.assert_allclose(poses, np.stack(expect), atol=2e-5)
    # the checkpoint's symmetries reach the prediction: with "swap", the constant estimate is averaged
    # with the inverse of itself (what the reversed pair predicts)
    from gvnn_warp.vo import invert_pose

    swap = _vo_checkpoint(tmp_path / "swap.pt", seq.K, bias=xi, symmetries=("swap",))
    assert main(["track", str(data), "--out", str(tmp_path / "vo_swap"), "--method", "vo", "--checkpoint", str(swap),
                 "--no-progress"]) == 0
    _, poses = read_trajectory(tmp_path / "vo_swap" / "trajectory.txt")
    x = torch.tensor([xi], dtype=torch.float64)
    T2 = np.eye(4)
    T2[:3] = se3_to_matrix((x + invert_pose(x)) / 2)[0].numpy()
    np.testing.assert_allclose(poses[1], seq.gt_poses[0] @ np.linalg.inv(T2), atol=2e-5)
    # an untrained network predicts the identity: vo+direct is then the direct method (the aligner from
    # the identity, on the same frames), up to the grey conversion of the colour images
    zero = _vo_checkpoint(tmp_path / "zero.pt", seq.K)
    for method, extra in (("vo+direct", ["--checkpoint", str(zero)]), ("direct", [])):
        assert main(["track", str(data), "--out", str(tmp_path / method), "--method", method, *extra,
                     "--no-progress"]) == 0
    _, refined = read_trajectory(tmp_path / "vo+direct" / "trajectory.txt")
    _, direct = read_trajectory(tmp_path / "direct" / "trajectory.txt")
    np.testing.assert_allclose(refined, direct, atol=1e-4)
    assert json.loads((tmp_path / "vo+direct" / "metrics.json").read_text())["settings"]["method"] == "vo+direct"


def test_network_aligner_gives_the_network_pose_to_the_direct_aligner_as_init(tmp_path):
    from gvnn_warp.vo.checkpoint import load_network
    from gvnn_warp.vo.frontend import NetworkAligner

    class Recorder:
        def __init__(self):
            self.inits = []

        def prepare(self, image, depth):
            return image.shape

        def align_frames(self, ref, live, init=None):
            self.inits.append(np.array(init))
            return np.eye(4), {"converged": False}

    K = np.array([[60.0, 0, 39.5], [0, 60.0, 29.5], [0, 0, 1]])
    xi = [0.0, 0.03, 0.0, 0.02, 0.0, 0.0]
    net, spec = load_network(_vo_checkpoint(tmp_path / "c.pt", K, bias=xi))
    rec = Recorder()
    al = NetworkAligner(net, K, (80, 60), refine=spec["refine"], direct=rec)
    rng = np.random.default_rng(0)
    frames = [al.prepare(rng.random((3, 60, 80), dtype=np.float32), np.full((1, 60, 80), 2.0, np.float32))
              for _ in range(2)]
    assert frames[0].image.shape == (1, 3, 48, 64) and frames[0].direct == (3, 60, 80)
    T, info = al.align_frames(frames[0], frames[1], init=np.eye(4))
    assert not info["converged"] and np.array_equal(T, np.eye(4))  # the direct aligner's answer ...
    np.testing.assert_allclose(rec.inits[0], info["network_pose"])  # ... from the network's pose
    np.testing.assert_allclose(info["network_pose"][:3, 3], [0.02, 0, 0], atol=1e-6)
    with pytest.raises(ValueError, match="must be 80x60"):
        al.prepare(np.zeros((3, 48, 64), np.float32), np.ones((1, 48, 64), np.float32))


STRAY_CHECKPOINT = "--checkpoint is used by --method vo and vo+direct (a gvnn-warp vo checkpoint) and by --depth"


def test_track_cli_method_errors_are_one_line(tmp_path, capsys):
    import torch

    from gvnn_warp.cli import main

    data = _render(tmp_path, frames=2, size="32x24")
    old = tmp_path / "old.pt"
    torch.save({"format": 2, "config": {}, "model": {}}, old)
    text = tmp_path / "notes.txt"
    text.write_text("not a checkpoint\n")
    depth_ck = tmp_path / "depth.pt"  # (the format gvnn-warp depth train writes)
    torch.save({"format": "gvnn_warp.depth/1", "config": {}}, depth_ck)
    cases = [
        (["--method", "vo"], "--method vo needs --checkpoint CKPT"),
        (["--method", "vo+direct", "--checkpoint", str(tmp_path / "none.pt")], "none.pt: no such file"),
        (["--method", "vo", "--checkpoint", str(old)], "checkpoint format 2, this gvnn_warp reads format 4"),
        (["--method", "vo", "--checkpoint", str(text)], "notes.txt: not a gvnn-warp vo checkpoint"),
        (["--method", "vo", "--checkpoint", str(depth_ck)], "depth.pt: a depth network's checkpoint (gvnn-warp depth "
                                                            "train), not a learned-VO one"),
        (["--checkpoint", str(old)], STRAY_CHECKPOINT),
        (["--method", "vo", "--checkpoint", str(tmp_path)], "a folder, not a file (gvnn-warp vo writes OUT/"),
    ]
    usage_mistakes = {"--method vo needs --checkpoint CKPT", STRAY_CHECKPOINT}
    for extra, message in cases:
        if message in usage_mistakes:  # the arguments' mistakes: after the usage text, status 2
            with pytest.raises(SystemExit) as e:
                main(["track", str(data), "--out", str(tmp_path / "o"), *extra])
            assert e.value.code == 2
        else:  # a checkpoint that cannot be used is a data error: one line, status 1
            assert main(["track", str(data), "--out", str(tmp_path / "o"), *extra]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith("gvnn-warp track: error: ") and message in err[-1], (extra, err)
        assert sum("error" in line for line in err) == 1
        assert (len(err) == 1) == (message not in usage_mistakes), err
    assert not (tmp_path / "o").exists()


def test_vo_tracking_benchmark_end_to_end(tmp_path):
    """benchmarks/vo_tracking.py on a tiny rendered sequence with an untrained (identity) network: vo is
    then the identity (same failures), vo+direct the direct method, and the identity's failures are the
    pairs whose true motion passes 2 deg or 5 cm."""
    from benchmarks import vo_tracking
    from gvnn_warp.synthetic import default_intrinsics, smooth_se3_trajectory

    ckpt = _vo_checkpoint(tmp_path / "zero.pt", default_intrinsics(80, 60))
    out = tmp_path / "r.json"
    assert vo_tracking.main(["--se3", str(ckpt), "--motions", "se3", "--frames", "8", "--size", "80x60", "--gaps",
                             "1,4", "--seed", "901", "--no-progress", "--json", str(out)]) == 0
    r = json.loads(out.read_text())["results"]["se3"]
    gt = smooth_se3_trajectory(8, 901)
    for g in (1, 4):
        dt, dr = pose_error(np.eye(4), relative_pose(gt[g:], gt[:-g]))
        expect = int(((dr > 2.0) | (dt > 0.05)).sum())
        assert r["pairs"]["identity"][str(g)]["failed"] == r["pairs"]["vo"][str(g)]["failed"] == expect
        assert r["pairs"]["vo+direct"][str(g)]["failed"] == r["pairs"]["direct"][str(g)]["failed"]
    assert r["pairs"]["identity"]["4"]["failed"] > 0 and r["pairs"]["identity"]["1"]["pairs"] == 7
    t = r["tracking"]
    assert t["vo+direct"]["ate_m"] == pytest.approx(t["direct"]["ate_m"], rel=1e-3, abs=1e-5)
    assert t["vo"]["ate_rot_deg"] == pytest.approx(t["identity"]["ate_rot_deg"], abs=1e-3)
    assert t["identity"]["fps"] is None and t["direct"]["fps"] > 0
