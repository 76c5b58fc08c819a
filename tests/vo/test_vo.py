"""Tests of the visual-odometry application (gvnn_warp.vo, gvnn-warp vo)."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from gvnn_warp.datasets.errors import DatasetError
from gvnn_warp.vo import CascadeVO, SiameseVO, compose_pose, default_config, photometric_loss, pose_errors, train
from gvnn_warp.vo.data import render_split
from gvnn_warp.vo.loss import warp_live

TINY = (64, 48)


def _tiny_config(out: Path, **kw):
    base = dict(
        steps=30, size=TINY, batch_size=8, lr=2e-3, warmup=5, n_train_traj=2, n_eval_traj=1, n_frames=16,
        n_eval=16, n_panel=2, checkpoint_every=10, progress=False, stage_scales=(1,),
    )
    base.update(kw)
    return default_config("so3", str(out), **base)


def _env():
    env = dict(os.environ)
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    return env


@pytest.fixture(scope="module")
def tiny_pairs():
    return render_split("so3", [7], 6, TINY)


# ----------------------------------------------------------------------------- network


@pytest.mark.parametrize("motion,dim", [("so3", 3), ("se3", 6)])
@pytest.mark.parametrize("depth_input", [True, False])
def test_network_shape_and_identity_init(motion, dim, depth_input):
    torch.manual_seed(0)
    net = SiameseVO(motion, size=(96, 64), depth_input=depth_input)
    ref, live = torch.rand(3, 3, 64, 96), torch.rand(3, 3, 64, 96)
    depth = 1.0 + torch.rand(3, 1, 64, 96)
    out = net(ref, live, depth, depth)
    assert out.shape == (3, dim)
    assert torch.equal(out, torch.zeros(3, dim))  # last layer initialised to zero: identity pose
    # but the network is not dead: the last layer receives a gradient
    loss = (net(ref, live, depth, depth) - torch.ones(dim)).square().sum()
    loss.backward()
    assert net.tail[-1].weight.grad.abs().sum() > 0
    # PReLU after every convolution but the last three
    convs = [m for m in net.modules() if isinstance(m, torch.nn.Conv2d)]
    prelus = [m for m in net.modules() if isinstance(m, torch.nn.PReLU)]
    assert len(prelus) == len(convs) - 3
    assert all(c.stride == (2, 2) for c in convs[:-3])
    assert not any(isinstance(m, (torch.nn.MaxPool2d, torch.nn.AvgPool2d)) for m in net.modules())


def test_network_rejects_wrong_size():
    net = SiameseVO("so3", size=(64, 48))
    with pytest.raises(ValueError, match="64x48"):
        net(torch.rand(1, 3, 48, 80), torch.rand(1, 3, 48, 80), torch.ones(1, 1, 48, 80), torch.ones(1, 1, 48, 80))


@pytest.mark.parametrize("dim", [3, 6])
def test_compose_pose_matches_matrix_product(dim):
    """compose_pose(d, xi) is the pose vector of the product T(d) T(xi), including near-pi and zero rotations."""
    from gvnn_warp import se3_to_matrix

    g = torch.Generator().manual_seed(3)
    d = torch.randn(6, 6, generator=g, dtype=torch.float64) * 0.3
    xi = torch.randn(6, 6, generator=g, dtype=torch.float64) * 0.5
    d[0], xi[0] = 0.0, 0.0  # identity
    xi[1, :3] = torch.tensor([0.0, 0.0, np.pi - 1e-3], dtype=torch.float64)  # near pi
    d[1, :3] = 0.0
    d, xi = d[:, :dim], xi[:, :dim]
    full = lambda v: v if v.shape[1] == 6 else torch.cat([v, torch.zeros_like(v)], 1)  # noqa: E731

    def mat(v):
        T = torch.eye(4, dtype=torch.float64).repeat(len(v), 1, 1)
        T[:, :3] = se3_to_matrix(full(v))
        return T

    out = compose_pose(d, xi)
    assert out.shape == (6, dim)
    torch.testing.assert_close(mat(out), mat(d) @ mat(xi), atol=1e-9, rtol=0)
    # differentiable in both arguments (Warp adjoints of so3_exp / so3_log)
    dd, xx = d[2:].clone().requires_grad_(), xi[2:].clone().requires_grad_()
    assert torch.autograd.gradcheck(compose_pose, (dd, xx))


def test_cascade_composition_order_matches_the_warp():
    """A later stage sees the live image warped by T(xi); warping that again by the stage's correction
    T(d) samples the live image at T(xi) T(d) X, so the estimate is compose_pose(xi, d), not
    compose_pose(d, xi). Exact for pure rotations (the warp is then independent of depth, even a random
    one), checked on a coordinate image, whose warps are the sample positions themselves."""
    from gvnn_warp import se3_to_matrix, warp_frame_depth

    H, W = 48, 64
    K = torch.tensor([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]], dtype=torch.float64)
    ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float64), torch.arange(W, dtype=torch.float64), indexing="ij")
    coords = torch.stack([xs, ys])[None]  # (1, 2, H, W): every pixel holds its own (x, y)
    depth = 1.0 + 2.0 * torch.rand(1, 1, H, W, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    no_t = torch.zeros(1, 3, dtype=torch.float64)
    xi = torch.cat([torch.tensor([[0.06, -0.08, 0.03]], dtype=torch.float64), no_t], 1)
    d = torch.cat([torch.tensor([[-0.05, 0.02, 0.09]], dtype=torch.float64), no_t], 1)

    def warp(image, pose_vec):
        return warp_frame_depth(image, depth, se3_to_matrix(pose_vec), K)[0]

    twice = warp(warp(coords, xi), d)  # what the stage after xi sees, warped by its correction
    inner = (0, slice(None), slice(10, -10), slice(12, -12))  # away from the border: every sample valid
    right = (twice - warp(coords, compose_pose(xi, d)))[inner].abs().max()
    wrong = (twice - warp(coords, compose_pose(d, xi)))[inner].abs().max()
    assert right < 2e-3, right  # bilinear interpolation of a smooth map: ~5e-4 px
    assert wrong > 0.2, wrong  # the rotations do not commute: ~0.5 px


def test_cascade_identity_at_init_and_refines_on_the_warped_image(tiny_pairs):
    ps = tiny_pairs
    idx = torch.arange(len(ps))
    ref, live, ref_d, live_d, pose, xi = ps.batch(idx)
    torch.manual_seed(0)
    net = CascadeVO("se3", scales=(2, 1), size=TINY)
    assert [s.size for s in net.stages] == [(32, 24), TINY]
    outs = net(ref, live, ref_d, live_d, ps.K, all_stages=True)
    assert len(outs) == 2 and all(torch.equal(o, torch.zeros(len(ps), 6)) for o in outs)
    # the second stage's input is the live image warped with the first stage's pose: give stage 1 the
    # ground truth (its bias), and stage 2 then sees an aligned pair
    seen = {}
    net.stages[1].register_forward_pre_hook(lambda m, args: seen.update(live=args[1]))
    with torch.no_grad():
        net.stages[0].tail[-1].bias.copy_(xi[0] / net.stages[0].out_scale)
        net.stages[0].depth_normalised_t = False
    out = net(ref[:1], live[:1], ref_d[:1], live_d[:1], ps.K)
    torch.testing.assert_close(out, xi[:1], atol=1e-5, rtol=0)  # stage 2 adds the identity
    warped, valid = warp_live(live[:1], ref_d[:1], pose[:1], ps.K)
    torch.testing.assert_close(seen["live"], torch.where(valid, warped, torch.full_like(warped, 0.5)))
    # gradients reach both stages
    net.zero_grad()
    o1, o2 = net(ref, live, ref_d, live_d, ps.K, all_stages=True)
    (o2 - xi).square().sum().backward()
    assert all(s.tail[-1].weight.grad.abs().sum() > 0 for s in net.stages)
    with pytest.raises(ValueError, match="scales"):
        CascadeVO("se3", scales=(3, 1), size=TINY)
    with pytest.raises(ValueError, match="need K"):
        net(ref, live, ref_d, live_d)


def test_cascade_refine_reapplies_the_last_stage(tiny_pairs):
    """refine=n runs the last network n more times, each on the live image re-warped with the latest
    estimate, and composes its corrections."""
    ps = tiny_pairs
    ref, live, ref_d, live_d, _, _ = ps.batch(torch.arange(3))
    torch.manual_seed(0)
    net = CascadeVO("se3", scales=(1, 1), size=TINY)
    with torch.no_grad():  # non-zero corrections, so that every application shows, and a first estimate
        # rotating about another axis, so that the order of composition shows too
        net.stages[0].tail[-1].bias.copy_(torch.tensor([-0.3, 0.2, 0.4, -0.1, 0.2, 0.1]))
        net.stages[1].tail[-1].bias.copy_(torch.tensor([0.1, -0.2, 0.05, 0.3, 0.1, -0.2]))
    seen = []
    net.stages[1].register_forward_hook(lambda m, args, out: seen.append((args[1], out)))
    with torch.no_grad():
        outs = net(ref, live, ref_d, live_d, ps.K, all_stages=True, refine=2)
    assert len(outs) == 4 and len(seen) == 3
    for k in range(1, 4):
        # estimate k = estimate k - 1 composed with the correction of application k, T(xi) T(d) ...
        torch.testing.assert_close(outs[k], compose_pose(outs[k - 1], seen[k - 1][1]), atol=1e-5, rtol=0)
    # ... and application k saw the live image warped with estimate k - 1
    from gvnn_warp import se3_to_matrix

    warped, valid = warp_live(live, ref_d, se3_to_matrix(outs[2]), ps.K)
    torch.testing.assert_close(seen[2][0], torch.where(valid, warped, torch.full_like(warped, 0.5)))
    with pytest.raises(ValueError, match="refine"):
        CascadeVO("se3", size=TINY)(ref, live, ref_d, live_d, ps.K, refine=1)
    # configuration: a single stage drops the per-motion refine default, an explicit one is an error
    assert default_config("se3", "x", stage_scales=(1,)).refine == 0
    assert default_config("se3", "x").refine > 0
    with pytest.raises(ValueError, match="refine"):
        default_config("se3", "x", stage_scales=(1,), refine=2)


@pytest.mark.parametrize("dim", [3, 6])
def test_invert_and_mirror_pose_match_the_matrices(dim):
    """invert_pose is the matrix inverse and mirror_pose is M T M (M = diag(-1, 1, 1) or diag(1, -1, 1))."""
    from gvnn_warp import se3_to_matrix
    from gvnn_warp.vo import invert_pose, mirror_pose
    from gvnn_warp.vo.loss import full_xi

    xi = torch.randn(5, dim, dtype=torch.float64, generator=torch.Generator().manual_seed(dim)) * 0.4

    def mat(x):
        T = torch.eye(4, dtype=torch.float64).repeat(x.shape[0], 1, 1)
        T[:, :3, :] = se3_to_matrix(full_xi(x))
        return T

    torch.testing.assert_close(mat(invert_pose(xi)), torch.linalg.inv(mat(xi)), atol=1e-12, rtol=0)
    for axis in (0, 1):
        M = torch.eye(4, dtype=torch.float64)
        M[axis, axis] = -1.0
        torch.testing.assert_close(mat(mirror_pose(xi, axis)), M @ mat(xi) @ M, atol=1e-12, rtol=0)


def test_predict_averages_over_the_symmetries(tiny_pairs):
    """CascadeVO.predict: no symmetry is forward(); "swap" averages with the inverse of the reversed
    pair's estimate; a mirror averages with the mirrored pair's estimate mirrored back, and is
    skipped when the principal point is off the centre; an exactly symmetric estimate is unchanged."""
    from gvnn_warp.vo import invert_pose, mirror_pose

    ps = tiny_pairs
    ref, live, ref_d, live_d, _, _ = ps.batch(torch.arange(3))
    torch.manual_seed(1)
    net = CascadeVO("se3", scales=(1, 1), size=TINY)
    with torch.no_grad():
        for st in net.stages:
            st.tail[-1].weight.normal_(0.0, 0.05)
        net.eval()
        xi = net(ref, live, ref_d, live_d, ps.K, refine=1)
        torch.testing.assert_close(net.predict(ref, live, ref_d, live_d, ps.K, refine=1), xi)
        back = invert_pose(net(live, ref, live_d, ref_d, ps.K, refine=1))
        torch.testing.assert_close(net.predict(ref, live, ref_d, live_d, ps.K, refine=1, symmetries=("swap",)),
                                   (xi + back) / 2)
        assert (xi - back).abs().max() > 1e-3  # the two estimates differ: the average is a real one
        up = mirror_pose(net(ref.flip(-2), live.flip(-2), ref_d.flip(-2), live_d.flip(-2), ps.K, refine=1), 1)
        torch.testing.assert_close(net.predict(ref, live, ref_d, live_d, ps.K, refine=1, symmetries=("mirror_y",)),
                                   (xi + up) / 2)
        K_off = ps.K.clone()
        K_off[1, 2] += 0.5
        torch.testing.assert_close(
            net.predict(ref, live, ref_d, live_d, K_off, refine=1, symmetries=("mirror_y",)),
            net(ref, live, ref_d, live_d, K_off, refine=1))
        # the identity network (zero last layers) predicts 0 whatever the symmetries
        zero = CascadeVO("se3", scales=(1, 1), size=TINY).eval()
        out = zero.predict(ref, live, ref_d, live_d, ps.K, refine=1, symmetries=("swap", "mirror_x", "mirror_y"))
        assert out.abs().max() == 0
    with pytest.raises(ValueError, match="unknown symmetries"):
        net.predict(ref, live, ref_d, live_d, ps.K, symmetries=("rotate",))
    with pytest.raises(ValueError, match="--symmetries: unknown rotate"):
        default_config("se3", "x", symmetries=("rotate",))
    assert default_config("se3", "x").symmetries == ("swap", "mirror_y")
    assert default_config("so3", "x").symmetries == ()


# ----------------------------------------------------------------------------- data and loss


def test_gt_pose_reproduces_reference(tiny_pairs):
    ps = tiny_pairs
    idx = torch.arange(len(ps))
    ref, live, ref_d, _, pose, xi = ps.batch(idx)
    warped, valid = warp_live(live, ref_d, pose, ps.K)
    m = valid.expand_as(warped)
    assert valid.float().mean() > 0.6
    err = (warped - ref).abs()[m].mean()
    ident = (live - ref).abs().mean()
    assert err < 0.01, err
    assert ident > 5 * err
    # the stored regression target [omega, t] gives the same pose through the SE3 layer
    from gvnn_warp import se3_to_matrix

    assert torch.allclose(se3_to_matrix(xi), pose[:, :3, :], atol=1e-5)
    # so3 trajectories are pure rotations
    assert xi[:, 3:].abs().max() < 1e-5


def test_loss_zero_at_gt_and_pose_errors(tiny_pairs):
    ps = tiny_pairs
    idx = torch.arange(len(ps))
    _, live, ref_d, _, pose, xi = ps.batch(idx)
    gt_w, gt_v = warp_live(live, ref_d, pose, ps.K)
    at_gt, _, _ = photometric_loss(xi[:, :3], live, ref_d, gt_w, gt_v, ps.K, "l1")
    at_id, _, _ = photometric_loss(torch.zeros(len(ps), 3), live, ref_d, gt_w, gt_v, ps.K, "l1")
    assert at_gt.max() < 1e-4
    assert (at_id > 10 * at_gt + 1e-3).all()
    rot, trans = pose_errors(xi[:, :3], pose)
    assert rot.max() < 1e-3 and trans.max() < 1e-6
    rot0, _ = pose_errors(torch.zeros(len(ps), 3), pose)
    assert rot0.min() > 1.0  # several degrees per frame
    # gradients reach the pose vector through the 3D spatial transformer
    p = torch.zeros(len(ps), 3, requires_grad=True)
    photometric_loss(p, live, ref_d, gt_w, gt_v, ps.K, "l2")[0].sum().backward()
    assert p.grad.abs().sum() > 0


def test_flip_augmentation_is_consistent(tiny_pairs):
    """Mirroring a pair (images, depths, GT warp) equals warping the mirrored pair with the mirrored pose."""
    from gvnn_warp.vo.train import _flip, _symmetric_intrinsics

    ps = tiny_pairs
    idx = torch.arange(4)
    _, live, ref_d, _, pose, _ = ps.batch(idx)
    assert _symmetric_intrinsics(ps.K, *TINY)
    gt_w, gt_v = warp_live(live, ref_d, pose, ps.K)
    f = torch.tensor([[True, False], [False, True], [True, True], [False, False]])
    live_f, ref_d_f, gt_w_f, gt_v_f = _flip(f, live, ref_d, gt_w, gt_v.float())
    M = torch.eye(4).repeat(4, 1, 1)
    M[f[:, 0], 0, 0] = -1.0
    M[f[:, 1], 1, 1] = -1.0
    warped, valid = warp_live(live_f, ref_d_f, M @ pose @ M, ps.K)
    both = (valid & (gt_v_f > 0.5)).expand_as(warped)
    assert (valid == (gt_v_f > 0.5)).float().mean() > 0.99
    assert (warped - gt_w_f).abs()[both].max() < 1e-4


def test_robust_loss_option(tiny_pairs):
    ps = tiny_pairs
    _, live, ref_d, _, pose, _ = ps.batch(torch.arange(2))
    gt_w, gt_v = warp_live(live, ref_d, pose, ps.K)
    try:
        import gvnn_warp.functional.perpixel  # noqa: F401
    except ImportError:
        with pytest.raises(RuntimeError, match="robust_rho"):
            photometric_loss(torch.zeros(2, 3), live, ref_d, gt_w, gt_v, ps.K, "huber")
        return
    for kind in ("huber", "cauchy", "geman_mcclure", "tukey"):
        loss, _, _ = photometric_loss(torch.zeros(2, 3), live, ref_d, gt_w, gt_v, ps.K, kind)
        assert torch.isfinite(loss).all() and (loss > 0).all()


# ----------------------------------------------------------------------------- training, resume


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("vo_full")
    metrics = train(_tiny_config(out))
    return out, metrics


def test_run_writes_metrics_figures_and_checkpoint(tiny_run):
    out, metrics = tiny_run
    assert len(metrics["train_loss"]) == 30 and metrics["steps"] == 30
    on_disk = json.loads((out / "metrics.json").read_text())
    for which in ("identity", "trained"):
        assert set(on_disk["eval"][which]) >= {"rot_deg", "trans_m", "photometric"}
    assert on_disk["motion"] == "so3"
    assert on_disk["eval"]["identity"]["rot_deg"] > 1.0
    for name in ("training_curve.png", "registration.png", "checkpoint.pt"):
        assert (out / name).stat().st_size > 0
    assert not list(out.glob(".*tmp*"))  # atomic writes leave no temporaries behind


@pytest.mark.long
def test_short_training_reduces_loss(tmp_path):
    # a handful of pairs seen again and again: the photometric loss on them must fall clearly
    metrics = train(_tiny_config(tmp_path, steps=60, n_train_traj=1, n_frames=5, lr=3e-3))
    fixed = metrics["eval_train_pairs"]
    assert fixed["trained"]["photometric"] < 0.7 * fixed["identity"]["photometric"]
    h = metrics["train_loss"]
    assert np.mean(h[-10:]) < 0.7 * np.mean(h[:10])


def test_resume_continues_exactly(tiny_run, tmp_path, monkeypatch):
    import importlib

    train_module = importlib.import_module("gvnn_warp.vo.train")  # the module, not the function
    _, full = tiny_run

    class StopAfter20(train_module._StopFlag):
        """An interruption (as by Ctrl-C) seen after step 20: the loop reads ``stop`` once a step."""

        reads = 0

        @property
        def stop(self):
            StopAfter20.reads += 1
            return StopAfter20.reads >= 20

        @stop.setter
        def stop(self, value):
            pass

    monkeypatch.setattr(train_module, "_StopFlag", StopAfter20)
    first = train(_tiny_config(tmp_path, steps=30))  # the same run as tiny_run, interrupted
    monkeypatch.undo()
    ck = torch.load(tmp_path / "checkpoint.pt", weights_only=True)  # plain tensors and containers
    assert ck["step"] == 20 and len(ck["train_loss"]) == 20
    resumed = train(_tiny_config(tmp_path, steps=30, resume=True))
    assert resumed["steps"] == 30
    assert resumed["train_loss"][:20] == ck["train_loss"]
    # batches are drawn per step and the optimiser state is restored: same as never stopping
    np.testing.assert_allclose(resumed["train_loss"], full["train_loss"], rtol=1e-5, atol=1e-7)
    del first


@pytest.mark.parametrize("change", [dict(seed=1), dict(n_frames=17), dict(n_train_traj=3)])
def test_resume_refuses_a_run_on_other_data(tiny_run, change):
    from gvnn_warp.vo.train import ConfigError

    out, _ = tiny_run
    before = (out / "checkpoint.pt").stat().st_mtime_ns
    key = next(iter(change))
    with pytest.raises(ConfigError, match=f"cannot resume: checkpoint has {key}="):
        train(_tiny_config(out, resume=True, **change))
    assert (out / "checkpoint.pt").stat().st_mtime_ns == before


@pytest.mark.parametrize("old", ["pickled numpy", "no format", "format 2", "format 3"])
def test_resume_refuses_checkpoints_of_other_versions(tmp_path, old):
    """Checkpoints load with weights_only=True; one written by an older version (numpy arrays
    pickled inside, no format number, format 2 without the network's description, format 3 without
    its symmetries) gets a clear
    one-line error, not a traceback or a silent resume."""
    from gvnn_warp.vo.checkpoint import CheckpointError

    cfg = _tiny_config(tmp_path, resume=True)
    ck = {"config": dataclasses.asdict(cfg), "step": 3, "train_loss": [1.0, 1.0, 1.0]}
    if old == "pickled numpy":
        ck["rng"] = {"numpy": np.random.get_state()}
    if old in ("format 2", "format 3"):
        ck.update(format=int(old[-1]), model=CascadeVO("so3", size=TINY).state_dict())
    torch.save(ck, tmp_path / "checkpoint.pt")
    with pytest.raises(CheckpointError, match="cannot resume: .*checkpoint.pt: .*(older|another) version") as e:
        train(cfg)
    assert "\n" not in str(e.value)
    if old != "pickled numpy":
        found = 1 if old == "no format" else int(old[-1])
        assert f"checkpoint format {found}, this gvnn_warp reads format 4" in str(e.value)


def test_training_curve_legend_and_panel_text(tiny_pairs):
    import matplotlib.pyplot as plt
    import matplotlib.text

    from gvnn_warp.vo.plots import panel_figure, training_curve_figure

    short = training_curve_figure([1.0, 0.9, 0.8] * 10)
    assert short.axes[0].get_legend() is None  # one curve: no "mean of 1"
    long = training_curve_figure(list(np.linspace(1, 0.1, 600)))
    assert [t.get_text() for t in long.axes[0].get_legend().get_texts()] == ["per step", "running mean over 12 steps"]
    ps = tiny_pairs
    idx = torch.arange(2)
    _, live, ref_d, _, pose, xi = ps.batch(idx)
    gt_w, gt_v = warp_live(live, ref_d, pose, ps.K)
    fig = panel_figure(ps, gt_w, gt_v, idx, {0: torch.zeros(2, 3), 5: xi[:, :3]}, motion="so3")
    try:
        texts = [t.get_text() for t in fig.findobj(matplotlib.text.Text) if t.get_text().strip()]
        assert min(t.get_fontsize() for t in fig.findobj(matplotlib.text.Text) if t.get_text().strip()) >= 9
        # the per-pair error is the predicted pose's, named so (the ground truth's is ~0)
        assert sum(t.startswith("pose error ") for t in texts) == 4
        assert any(t.startswith("pose error 0.00 deg") for t in texts)
        assert not any("residual" in t and "deg" in t for t in texts)
        (label,) = [ax.get_ylabel() for ax in fig.axes if ax.get_label() == "<colorbar>"]
        assert "intensity" in label
    finally:
        for f in (short, long, fig):
            plt.close(f)


def test_too_few_training_pairs_for_the_batch(tmp_path):
    from gvnn_warp.vo.train import ConfigError

    with pytest.raises(ConfigError, match="2 training pairs are fewer than --batch-size 8"):
        train(_tiny_config(tmp_path, n_train_traj=1, n_frames=2))


@pytest.mark.long
def test_stop_flag_records_the_signal_and_the_cli_its_status(tmp_path, monkeypatch):
    # SIGTERM: the flag says which signal stopped the run, the handlers come back, and the command's
    # status is the signal's default one (143; Ctrl-C 130), as depth train's
    import importlib

    from gvnn_warp.cli.vo import main

    T = importlib.import_module("gvnn_warp.vo.train")  # (the module: gvnn_warp.vo's `train` is its function)
    before = signal.getsignal(signal.SIGTERM)
    with T._StopFlag() as flag:
        signal.raise_signal(signal.SIGTERM)
    assert flag.stop and flag.signal == "SIGTERM" and signal.getsignal(signal.SIGTERM) is before
    for by, status in (("SIGTERM", 143), ("SIGINT", 130)):
        monkeypatch.setattr(T, "train", lambda cfg, by=by: {"interrupted": True, "step": 3, "stopped_by": by})
        assert main(["--motion", "so3", "--out", str(tmp_path / by), "--steps", "5", "--no-progress"]) == status


def test_cli_interrupt_and_resume(tmp_path):
    """SIGINT mid-run saves a checkpoint and exits 130; --resume continues from its step."""
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "gvnn_warp.cli.vo", "--motion", "se3", "--out", str(out), "--size", "64x48",
           "--batch-size", "4", "--frames", "12", "--trajectories", "1", "--no-progress",
           "--stages", "1", "--refine", "0", "--gaps", "1"]  # the smallest network: the test is about the CLI
    proc = subprocess.Popen([*cmd, "--steps", "100000", "--checkpoint-every", "5"], env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    ck_path = out / "checkpoint.pt"
    try:
        deadline = time.time() + 60
        while not ck_path.exists() and time.time() < deadline and proc.poll() is None:
            time.sleep(0.2)
        assert ck_path.exists(), proc.communicate(timeout=5)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    ck = torch.load(ck_path, weights_only=True)
    n = ck["step"]
    assert n >= 5 and len(ck["train_loss"]) == n
    # the resumed run in this process (the same command line; the interrupt needed a process of its own)
    from gvnn_warp.cli.vo import main

    assert main([*cmd[3:], "--steps", str(n + 3), "--resume"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["steps"] == n + 3
    assert metrics["train_loss"][:n] == ck["train_loss"]
    assert len(metrics["eval"]["trained"]) and metrics["eval"]["identity"]["trans_m"] > 0


# ----------------------------------------------------------------------------- DDP


# ----------------------------------------------------------------------------- TUM folders, checkpoint format


def _render_tum(root: Path, seed: int, frames: int = 6, size: str = "96x72") -> Path:
    from gvnn_warp.cli import main

    out = root / f"seq{seed}"
    assert main(["render", "--out", str(out), "--frames", str(frames), "--size", size, "--seed", str(seed),
                 "--scene-seed", "0", "--no-progress"]) == 0
    return out


@pytest.fixture(scope="module")
def tum_folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("vo_tum")
    return [_render_tum(root, s) for s in (3, 4)]


def test_read_split_resizes_frames_and_scales_intrinsics(tum_folders):
    """Pairs read from TUM folders at 96x72 and resized to 64x48: K is the renderer's K at 64x48 (pixel
    centres kept), and the ground-truth pose warps the resized live frame onto the resized reference."""
    from gvnn_warp.synthetic import default_intrinsics
    from gvnn_warp.vo.data import read_split

    ps = read_split(tum_folders[:1], TINY, gaps=(1, 3), both_directions=True)
    torch.testing.assert_close(ps.K, torch.from_numpy(default_intrinsics(*TINY)).float())
    assert len(ps) == 2 * (5 + 3) and ps.images.shape == (6, 3, 48, 64) and ps.depths.shape == (6, 1, 48, 64)
    assert sorted({int(g) for g in (ps.live - ps.ref).abs()}) == [1, 3]
    ref, live, ref_d, _, pose, xi = ps.batch(torch.arange(len(ps)))
    warped, valid = warp_live(live, ref_d, pose, ps.K)
    m = valid.expand_as(warped)
    err = (warped - ref).abs()[m].mean()
    assert valid.float().mean() > 0.5 and err < 0.02, err  # PNG quantisation and resampling, not geometry
    assert (live - ref).abs().mean() > 4 * err
    # the resized frames are the frames rendered at 64x48 directly up to texture filtering and PNG
    # rounding, and better than with the pixel grid half a pixel off either way
    import torch.nn.functional as F

    from gvnn_warp.datasets.tum import read_tum
    from gvnn_warp.synthetic import make_room_scene, render_rgbd

    img, dep = render_rgbd(make_room_scene(0), read_tum(tum_folders[0]).gt_poses, default_intrinsics(*TINY), *TINY)
    img = torch.from_numpy(img)

    def off(dx):
        theta = torch.tensor([[1.0, 0.0, 2 * dx / TINY[0]], [0.0, 1.0, 0.0]]).repeat(len(img), 1, 1)
        grid = F.affine_grid(theta, list(img.shape), align_corners=False)
        moved = F.grid_sample(ps.images, grid, align_corners=False, padding_mode="border")
        return (moved - img)[..., 4:-4, 4:-4].abs().mean()

    assert off(0.0) < 0.8 * min(off(-0.5), off(0.5)), (off(0.0), off(-0.5), off(0.5))
    dep = torch.from_numpy(dep)
    near = (ps.depths - dep).abs() < 0.03 * dep  # the depth of a source pixel within half a pixel
    assert near.float().mean() > 0.9, near.float().mean()  # everywhere but at depth edges


def test_train_on_tum_folders_holds_out_the_last(tum_folders, tmp_path):
    from gvnn_warp.vo.checkpoint import CHECKPOINT_FORMAT, load_network
    from gvnn_warp.vo.train import ConfigError

    cfg = _tiny_config(tmp_path, steps=3, data=tuple(tum_folders), gaps=(1, 2), n_eval=64)
    assert cfg.data == (str(tum_folders[0]),) and cfg.eval_data == (str(tum_folders[1]),)
    metrics = train(cfg)
    assert metrics["n_train_pairs"] == metrics["n_eval_pairs_total"] == 2 * (5 + 4)
    assert set(metrics["eval_by_gap"]) == {"1", "2"}
    by_gap = metrics["eval_by_gap"]
    assert by_gap["2"]["identity"]["rot_deg"] > by_gap["1"]["identity"]["rot_deg"]  # twice the motion
    # the checkpoint: plain tensors, this format, and the network it describes is the trained one
    ck = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    assert ck["format"] == CHECKPOINT_FORMAT and ck["network"]["kwargs"]["size"] == TINY
    net, spec = load_network(tmp_path / "checkpoint.pt")
    assert not net.training and spec["refine"] == cfg.refine
    for k, v in net.state_dict().items():
        assert torch.equal(v, ck["model"][k]), k
    with pytest.raises(ConfigError, match="--data with one folder needs --eval-data"):
        _tiny_config(tmp_path, data=tuple(tum_folders[:1]))
    with pytest.raises(DatasetError, match="groundtruth.txt: missing"):
        bare = tmp_path / "bare"
        shutil.copytree(tum_folders[0], bare)
        (bare / "groundtruth.txt").unlink()
        train(_tiny_config(tmp_path / "o2", data=(str(bare), str(tum_folders[1]))))
