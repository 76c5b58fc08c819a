"""gvnn_warp.depth: the depth metrics against closed forms, the networks' shapes and ranges, the
video triplets, and short runs of training, resuming and evaluation (the command line included)."""

import json
import math
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from gvnn_warp.cli import main
from gvnn_warp.datasets.tum import read_tum
from gvnn_warp.depth.checkpoint import load_checkpoint, load_depth_net
from gvnn_warp.depth.data import read_video
from gvnn_warp.depth.evaluate import depth_metrics, evaluate, summarise
from gvnn_warp.depth.model import DepthNet, PoseNet, disp_to_depth
from gvnn_warp.depth.predict import DepthPredictor
from gvnn_warp.depth.train import POSES, DepthConfig, train
from gvnn_warp.vo.frontend import resize_frame


def test_metrics_are_scale_free_and_match_closed_forms():
    g = torch.Generator().manual_seed(0)
    true = 1 + 4 * torch.rand(1, 20, 30, generator=g, dtype=torch.float64)
    m = depth_metrics(0.25 * true, true, 0.1, 10.0)  # a scaled copy: perfect after median scaling
    assert m["scale"] == pytest.approx(4.0)
    for k in ("abs_rel", "sq_rel", "rmse", "rmse_log"):
        assert m[k] == pytest.approx(0.0, abs=1e-12)
    assert m["a1"] == m["a2"] == m["a3"] == 1.0
    # half the pixels 1.5x too deep, half exact (same median): closed forms
    true = torch.full((1, 4, 4), 2.0, dtype=torch.float64)
    pred = true.clone()
    pred[..., :2, :] *= 1.5
    pred[0, 0, 0] = 2.0  # keeps the median at 2 (9 exact of 16)
    m = depth_metrics(pred, true, 0.1, 10.0)
    n_off = 7
    assert m["scale"] == pytest.approx(1.0)
    assert m["abs_rel"] == pytest.approx(n_off * 0.5 / 16)
    assert m["sq_rel"] == pytest.approx(n_off * 1.0**2 / 2.0 / 16)
    assert m["rmse"] == pytest.approx(math.sqrt(n_off * 1.0 / 16))
    assert m["rmse_log"] == pytest.approx(math.sqrt(n_off * math.log(1.5) ** 2 / 16))
    assert m["a1"] == pytest.approx(9 / 16) and m["a2"] == 1.0


def test_metrics_ignore_invalid_true_depth_and_summarise():
    true = torch.tensor([[0.0, float("nan"), 2.0, 4.0, 50.0]])
    pred = torch.tensor([[7.0, 7.0, 1.0, 2.0, 7.0]])
    m = depth_metrics(pred, true, 0.1, 10.0)  # only 2.0 and 4.0 count: pred is half of them
    assert m["scale"] == pytest.approx(2.0) and m["abs_rel"] == pytest.approx(0.0)
    assert depth_metrics(pred, torch.zeros_like(true), 0.1, 10.0) is None
    s = summarise([m, {**m, "scale": 4.0}])
    assert s["median_scale"] == pytest.approx(3.0) and s["median_scale_spread"] == pytest.approx(1 / 3)


def test_networks_shapes_and_ranges():
    net = DepthNet((4, 8, 8, 8, 8), min_depth=0.5, max_depth=20.0)
    disps = net(torch.rand(2, 3, 64, 96))
    assert [tuple(d.shape) for d in disps] == [(2, 1, 64 >> s, 96 >> s) for s in range(4)]
    depth = net.depth(torch.rand(1, 3, 64, 96))
    assert depth.min() >= 0.5 and depth.max() <= 20.0
    assert disp_to_depth(torch.tensor([0.0, 1.0]), 0.5, 20.0).tolist() == pytest.approx([20.0, 0.5])
    pose = PoseNet((4, 8, 8, 8, 8))(torch.rand(2, 3, 64, 96), torch.rand(2, 3, 64, 96))
    assert pose.shape == (2, 3, 4)
    torch.testing.assert_close(pose[:, :, :3] @ pose[:, :, :3].transpose(1, 2), torch.eye(3).expand(2, 3, 3))


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("depth_tum")
    out = []
    for s in (5, 6):
        assert main(["render", "--out", str(root / f"seq{s}"), "--frames", "5", "--size", "96x64", "--seed", str(s),
                     "--no-progress"]) == 0
        out.append(root / f"seq{s}")
    return out


def test_video_triplets_stay_inside_one_folder(folders):
    v = read_video(folders, (64, 64))
    assert v.images.shape == (10, 3, 64, 64) and v.depths is None
    assert v.targets.tolist() == [1, 2, 3, 6, 7, 8]
    target, sources = v.triplets(torch.tensor([3]))
    torch.testing.assert_close(target, v.images[6:7])
    torch.testing.assert_close(sources[0], v.images[[5, 7]])
    assert v.camera() is v.K  # rendered frames: a pinhole


def test_wider_triplets_and_cli_defaults(folders):
    from gvnn_warp.cli import depth as cli_depth

    v = read_video(folders, (64, 64), gap=2)
    assert v.targets.tolist() == [2, 7]
    target, sources = v.triplets(torch.tensor([1]))
    torch.testing.assert_close(sources[0], v.images[[5, 9]])
    target, sources = v.triplets(torch.tensor([0, 1, 1]), torch.tensor([1, 2, 1]))  # each triplet's own gap
    torch.testing.assert_close(target, v.images[[2, 7, 7]])
    torch.testing.assert_close(sources, torch.stack([v.images[[1, 3]], v.images[[5, 9]], v.images[[6, 8]]]))
    with pytest.raises(ValueError, match=r"Video.triplets: argument 'gaps' must be \(2,\) integers in \[1, 2\]"):
        v.triplets(torch.tensor([0, 1]), torch.tensor([1, 3]))  # (3 would read the other folder's frames)
    with pytest.raises(ValueError, match="at least 7"):
        read_video(folders, (64, 64), gap=3)
    # with vary_gap every frame with a neighbour on each side is a target, its gaps at most its
    # distance to the folder's nearer end (a 5-frame folder: 1, 2, 1)
    v = read_video(folders, (64, 64), gap=2, vary_gap=True)
    assert v.targets.tolist() == [1, 2, 3, 6, 7, 8] and v.reach.tolist() == [1, 2, 1, 1, 2, 1]
    target, sources = v.triplets(torch.tensor([0, 1, 5]))  # (no gaps: the largest each target has)
    torch.testing.assert_close(sources, torch.stack([v.images[[0, 2]], v.images[[0, 4]], v.images[[7, 9]]]))
    idx = torch.tensor([0, 1, 2, 4])
    assert v.draw_gaps(idx, torch.tensor([2, 2, 1, 2])).tolist() == [1, 2, 1, 2]
    with pytest.raises(ValueError, match=r"integers in \[1, 2\] and at most \[1, 2, 1, 2\]"):
        v.triplets(idx, torch.tensor([2, 2, 1, 2]))  # (frame -1 / the other folder's frame)
    v3 = read_video(folders, (64, 64), gap=3, vary_gap=True)  # (a gap larger than the folders allow)
    assert v3.reach.max() == 2 and len(v3.targets) == 6
    assert v.draw_gaps(idx, torch.tensor([1, 1, 2, 1])).tolist() == [1, 1, 1, 1]  # (draws below the reach stay)
    assert read_video(folders, (64, 64)).reach.tolist() == [1] * 6  # (one gap: each target's is the gap)
    with pytest.raises(ValueError, match="read_video: argument 'gap' must be an integer >= 1, got 0"):
        read_video(folders, (64, 64), gap=0, vary_gap=True)
    assert cli_depth._DEFAULT_GAP == DepthConfig.gap
    assert cli_depth._POSES == POSES and POSES[0] == DepthConfig.pose
    parsed = cli_depth.add_parser(__import__("argparse").ArgumentParser().add_subparsers()).parse_args(
        ["train", "--data", "x", "--out", "y"])
    assert parsed.lr == DepthConfig.lr and parsed.minutes == DepthConfig.minutes and parsed.size == DepthConfig.size
    assert parsed.fixed_gap is not DepthConfig.vary_gap and parsed.inner_targets is not DepthConfig.all_targets


def test_batch_normalisation_and_checkpoints_without_it(folders, tmp_path):
    net = DepthNet((4, 8, 8, 8, 8))
    assert net.norm == "batch" and any(isinstance(m, torch.nn.BatchNorm2d) for m in net.modules())
    plain = DepthNet((4, 8, 8, 8, 8), norm="none")
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in plain.modules())
    with pytest.raises(ValueError, match="DepthNet: argument 'norm' must be one of"):
        DepthNet((4, 8, 8, 8, 8), norm="group")
    # a checkpoint written before the setting existed holds a network without normalisation
    config = {"widths": [4, 8, 8, 8, 8], "min_depth": 0.1, "max_depth": 10.0}
    loaded = load_depth_net({"config": config, "depth_net": plain.state_dict()})
    image = torch.rand(1, 3, 64, 64)
    torch.testing.assert_close(loaded.depth(image), plain.eval().depth(image))
    # a run from before the settings existed resumes with them as they were then (norm "none",
    # one gap), and says which option to repeat otherwise
    out = tmp_path / "old"
    old = _cfg(folders, out, norm="none", vary_gap=False)
    train(old)
    ck = torch.load(out / "checkpoint.pt", weights_only=True)
    del ck["config"]["norm"], ck["config"]["vary_gap"]
    torch.save(ck, out / "checkpoint.pt")
    with pytest.raises(ValueError, match=r"the run has norm='none' \(command line: --norm\), this one 'batch'"):
        train(DepthConfig(**{**_cfg(folders, out).__dict__, "steps": 3, "resume": True, "vary_gap": False}))
    assert train(DepthConfig(**{**old.__dict__, "steps": 3, "resume": True}))["steps"] == 3
    # a run of varied gaps from before every frame was a target resumes only with all_targets False
    # (--inner-targets), on the targets it had
    out = tmp_path / "inner"
    inner = DepthConfig(**{**_cfg(folders, out).__dict__, "gap": 2, "all_targets": False})
    assert train(inner)["triplets"] == 2  # (the middle frame of each 5-frame folder)
    ck = torch.load(out / "checkpoint.pt", weights_only=True)
    del ck["config"]["all_targets"]
    torch.save(ck, out / "checkpoint.pt")
    with pytest.raises(ValueError, match=r"the run has all_targets=False \(command line: --inner-targets when "
                                         r"False\), this one True"):
        train(DepthConfig(**{**inner.__dict__, "all_targets": True, "steps": 3, "resume": True}))
    resumed = train(DepthConfig(**{**inner.__dict__, "steps": 3, "resume": True}))
    assert resumed["steps"] == 3 and resumed["triplets"] == 2
    # the deepest stage of one 32x32 item has one value per channel: refused, not a torch error
    with pytest.raises(ValueError, match="batch normalisation needs at least 2 items"):
        train(DepthConfig(**{**_cfg(folders, tmp_path / "bn").__dict__, "size": (32, 32), "batch_size": 1}))


@pytest.mark.parametrize("vary", [True, False])
def test_training_draws_each_triplets_gap(folders, tmp_path, monkeypatch, vary):
    from gvnn_warp.depth.data import Video

    seen = []
    triplets = Video.triplets

    def spy(self, idx, gaps=None):
        seen.append(gaps)
        return triplets(self, idx, gaps)

    monkeypatch.setattr(Video, "triplets", spy)
    m = train(DepthConfig(**{**_cfg(folders, tmp_path / "run").__dict__, "gap": 2, "steps": 3, "batch_size": 8,
                             "vary_gap": vary}))
    assert m["triplets"] == (6 if vary else 2)  # (every frame with a neighbour on each side, or gap from both ends)
    drawn = seen[:3]  # (the steps' calls; the figure's comes after)
    if vary:
        assert all(g is not None and g.shape == (8,) and 1 <= g.min() and g.max() <= 2 for g in drawn)
        assert len(torch.cat(drawn).unique()) == 2  # both gaps drawn in 24 triplets
    else:
        assert drawn == [None, None, None]


def _cfg(folders, out, **kw):
    return DepthConfig(data=tuple(map(str, folders)), out=str(out), size=(64, 64), steps=2, batch_size=2, gap=1,
                       widths=(4, 8, 8, 8, 8), progress=False, **kw)


@pytest.mark.parametrize("options", [{"pose": p} for p in POSES] + [{"supervised": True}, {"flip": True}])
def test_every_pose_source_and_the_supervised_bound_train(folders, tmp_path, options):
    m = train(DepthConfig(**{**_cfg(folders, tmp_path / "run").__dict__, "steps": 1, **options}))
    assert m["steps"] == 1 and math.isfinite(m["train_loss"][0])


def colour_only_copy(folder, dest):
    """The sequence folder as a colour video: rgb.txt, rgb/, intrinsics.txt, groundtruth.txt; no depth."""
    shutil.copytree(folder, dest, ignore=shutil.ignore_patterns("depth", "depth.txt"))
    assert not (dest / "depth.txt").exists() and (dest / "rgb.txt").exists()
    return dest


def test_colour_video_trains_evaluates_without_metrics_and_has_no_depth(folders, tmp_path):
    # folders holding colour images only (no depth.txt, no depth images): trained on as the same folders
    # with depth are (the same frames and steps: the same weights), evaluated without metrics
    videos = [colour_only_copy(f, tmp_path / f.name) for f in folders]
    seq, video = read_tum(folders[0]), read_tum(videos[0], colour_only=True)
    assert len(video) == len(seq) and video.colour_only and video.listed == (5, 0)
    np.testing.assert_array_equal(video.timestamps, seq.timestamps)
    with pytest.raises(ValueError, match=r"read without its depth \(colour_only\): frame 2 has no depth image"):
        video.depth(2)
    with pytest.raises(ValueError, match="depth.txt: missing depth list file"):
        read_tum(videos[0])
    a, b = train(_cfg(folders, tmp_path / "a")), train(_cfg(videos, tmp_path / "b"))
    assert a["train_loss"] == b["train_loss"]
    ev = tmp_path / "ev"
    assert main(["depth", "eval", "--checkpoint", str(tmp_path / "b" / "checkpoint.pt"), "--data", str(videos[1]),
                 "--out", str(ev), "--no-progress"]) == 0
    metrics = json.loads((ev / "metrics.json").read_text())
    assert metrics["abs_rel"] is None and metrics["frames"] == 5 and (ev / "depth.png").stat().st_size > 0
    # a colour image listed without a depth image is a frame of the video (not of the RGB-D sequence)
    extra = tmp_path / "extra"
    shutil.copytree(folders[0], extra)
    rows = (extra / "rgb.txt").read_text().splitlines()
    stamp, name = rows[-1].split()
    shutil.copy(extra / name, extra / "rgb" / "late.png")
    (extra / "rgb.txt").write_text("\n".join([*rows, f"{float(stamp) + 1:.6f} rgb/late.png"]) + "\n")
    assert len(read_tum(extra)) == 5 and len(read_tum(extra, colour_only=True)) == 6


@pytest.mark.parametrize("how", ["SIGTERM", "SIGINT"])
def test_a_stopped_run_says_how_to_go_on(folders, tmp_path, capsys, monkeypatch, how):
    # a signal in the first step: the step ends, the checkpoint is written, one line says how to resume,
    # and the status is the signal's (130 Ctrl-C, 143 SIGTERM)
    import signal

    import gvnn_warp.depth.train as T

    real = T.self_supervised_loss
    before = signal.getsignal(signal.SIGTERM)

    def stopped(*args, **kwargs):
        if how == "SIGTERM":  # (while training, under the run's handler: it stops after this step; not in
            # the figure's pass after training, where the default handler would end the test's process)
            if signal.getsignal(signal.SIGTERM) is not before:
                signal.raise_signal(signal.SIGTERM)
            return real(*args, **kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(T, "self_supervised_loss", stopped)
    out = tmp_path / "run"
    argv = ["depth", "train", "--data", *map(str, folders), "--out", str(out), "--size", "64x64", "--steps", "5",
            "--gap", "1", "--no-progress"]
    assert main(argv) == (143 if how == "SIGTERM" else 130)
    err = capsys.readouterr().err.strip().splitlines()
    by = "SIGTERM" if how == "SIGTERM" else "Ctrl-C"
    steps = 1 if how == "SIGTERM" else 0
    assert err[-1] == f"depth train: stopped by {by} at step {steps}; {out}/checkpoint.pt holds the run (no " \
                      "training.png): --resume continues it"
    assert json.loads((out / "metrics.json").read_text())["stopped_by"] == how
    assert torch.load(out / "checkpoint.pt", weights_only=True)["step"] == steps
    assert signal.getsignal(signal.SIGTERM) is before  # (the run's handler is gone)
    if how == "SIGTERM":  # a signal in the last step: the run is complete, not stopped
        done = tmp_path / "done"
        assert main(["depth", "train", "--data", *map(str, folders), "--out", str(done), "--size", "64x64",
                     "--steps", "1", "--gap", "1", "--no-progress"]) == 0
        assert json.loads((done / "metrics.json").read_text())["stopped_by"] is None
        assert (done / "training.png").exists()


def test_train_refuses_bad_settings_and_takes_one_folder(folders, tmp_path):
    # from Python (the command line checks its own options): one ValueError naming the setting
    for kw, message in (({"pose": "bogus"}, "pose must be one of"), ({"size": (70, 50)}, "multiples of 32"),
                        ({"data": ()}, "at least one folder"), ({"norm": "layer"}, "norm must be one of")):
        with pytest.raises(ValueError, match=rf"depth train: .*{message}"):
            train(DepthConfig(**{**_cfg(folders, tmp_path / "x").__dict__, **kw}))
    assert not (tmp_path / "x").exists()
    # a folder given as such, not in a tuple: that folder (not one per character of its name)
    m = train(DepthConfig(**{**_cfg(folders, tmp_path / "one").__dict__, "data": str(folders[0]), "steps": 1}))
    assert m["frames"] == 5


def test_a_batch_larger_than_the_triplets_is_said(folders, tmp_path, capsys):
    m = train(DepthConfig(**{**_cfg(folders, tmp_path / "run").__dict__, "batch_size": 8, "steps": 1}))
    assert m["triplets"] == 6 and m["steps"] == 1
    assert "the batch of 8 triplets is larger than the 6 the folders give" in capsys.readouterr().err
    train(DepthConfig(**{**_cfg(folders, tmp_path / "small").__dict__, "steps": 1}))
    assert "larger than" not in capsys.readouterr().err


def test_resume_refuses_other_frames(folders, tmp_path):
    # the same folders with a frame more: the resumed run would draw other batches than the run did
    data = [tmp_path / "a", tmp_path / "b"]
    for src, dst in zip(folders, data):
        shutil.copytree(src, dst)
    out = tmp_path / "run"
    train(_cfg(data, out))
    rows = (data[0] / "rgb.txt").read_text().splitlines()
    stamp, name = rows[-1].split()
    (data[0] / "rgb.txt").write_text("\n".join([*rows, f"{float(stamp) + 1:.6f} {name}"]) + "\n")
    with pytest.raises(ValueError, match=r"checkpoint.pt: the run trained on 10 frames, these folders give 11"):
        train(DepthConfig(**{**_cfg(data, out).__dict__, "steps": 3, "resume": True}))


def test_true_depth_of_a_frame_is_its_own_with_or_without_depth_read(folders, tmp_path):
    # (the training figure's true depth) a colour image without a depth image listed first: the colour
    # video's frames are one ahead of the RGB-D frames; each frame's true depth is its own either way
    extra = tmp_path / "extra"
    shutil.copytree(folders[0], extra)
    rows = (extra / "rgb.txt").read_text().splitlines()
    data = [r for r in rows if r and not r.startswith("#")]
    stamp, name = data[0].split()
    shutil.copy(extra / name, extra / "rgb" / "early.png")
    (extra / "rgb.txt").write_text("\n".join([f"{float(stamp) - 1:.6f} rgb/early.png", *data]) + "\n")
    colour = read_video([extra], (96, 64))
    rgbd = read_video([extra], (96, 64), with_depth=True)
    assert colour.images.shape[0] == 6 and rgbd.images.shape[0] == 5
    assert colour.true_depth(0) is None  # (the colour image without a depth image)
    for k in range(5):
        want = rgbd.depths[k][None]
        torch.testing.assert_close(rgbd.true_depth(k), want, rtol=0, atol=0)
        torch.testing.assert_close(colour.true_depth(k + 1), want, rtol=0, atol=0)


def test_train_resume_and_eval(folders, tmp_path):
    out = tmp_path / "run"
    m = train(_cfg(folders, out))
    assert m["steps"] == 2 and len(m["train_loss"]) == 2 and all(math.isfinite(x) for x in m["train_loss"])
    ck = torch.load(out / "checkpoint.pt", weights_only=True)
    assert ck["step"] == 2 and (out / "training.png").stat().st_size > 0
    m2 = train(DepthConfig(**{**_cfg(folders, out).__dict__, "steps": 3, "resume": True}))
    assert m2["steps"] == 3 and m2["train_loss"][:2] == m["train_loss"]
    with pytest.raises(ValueError, match="size"):
        train(DepthConfig(**{**_cfg(folders, out).__dict__, "size": (96, 64), "resume": True}))
    ev = tmp_path / "ev"
    assert main(["depth", "eval", "--checkpoint", str(out / "checkpoint.pt"), "--data", str(folders[1]), "--out",
                 str(ev), "--no-progress"]) == 0
    metrics = json.loads((ev / "metrics.json").read_text())
    assert 0 < metrics["abs_rel"] < 10 and 0 <= metrics["a1"] <= 1 and metrics["images"] == 5
    assert (ev / "depth.png").stat().st_size > 0 and "per_folder" not in metrics


def test_eval_of_several_folders_is_one_test_set_with_each_folder_beside(folders, tmp_path, capsys):
    # one folder of 5 frames and the other cut to 3 (its depth files of the last 2 removed from the
    # list): the pooled means weigh every image alike, not every folder
    out = tmp_path / "run"
    train(DepthConfig(**{**_cfg(folders, out).__dict__, "steps": 1}))
    short = tmp_path / "short"
    shutil.copytree(folders[1], short)
    for name in ("rgb.txt", "depth.txt"):
        lines = (short / name).read_text().splitlines()
        (short / name).write_text("\n".join(line for line in lines if line.startswith("#")) + "\n"
                                  + "\n".join([line for line in lines if not line.startswith("#")][:3]) + "\n")
    ck = str(out / "checkpoint.pt")
    single = [evaluate(ck, f, tmp_path / f"e{k}", progress=False) for k, f in enumerate((folders[0], short))]
    assert [m["images"] for m in single] == [5, 3]
    assert main(["depth", "eval", "--checkpoint", ck, "--data", str(folders[0]), str(short), "--out",
                 str(tmp_path / "both"), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    both = json.loads((tmp_path / "both" / "metrics.json").read_text())
    assert both["images"] == 8 and both["data"] == [str(folders[0]), str(short)]
    for k in ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3", "median_scale"):
        assert both[k] == pytest.approx((5 * single[0][k] + 3 * single[1][k]) / 8, rel=1e-12)
        for f, m in zip((folders[0], short), single):
            assert both["per_folder"][str(f)][k] == pytest.approx(m[k], rel=1e-12)
    assert "8 frames with true depth in 2 folders" in printed and f"{short}: 3 frames, abs_rel" in printed
    with pytest.raises(SystemExit) as status:  # (a command-line mistake: the usage line, status 2)
        main(["depth", "eval", "--checkpoint", ck, "--data", str(short), f"{short}/", "--out", str(tmp_path / "t"),
              "--no-progress"])
    assert status.value.code == 2 and f"--data names the folder {short} twice" in capsys.readouterr().err
    with pytest.raises(ValueError, match=f"evaluate: data names the folder {short} twice"):
        evaluate(ck, [short, folders[0], short.parent / ".." / short.parent.name / "short"], tmp_path / "twice",
                 progress=False)


def test_the_network_kept_is_the_moving_average_of_the_trained_one(folders, tmp_path, monkeypatch):
    # the trained network after each step, seen through the averaging's own update; the average
    # computed here by hand from them: every float parameter and batch statistic
    import gvnn_warp.depth.train as T

    seen = []

    class Spy(T.AveragedModel):
        def update_parameters(self, model):
            seen.append({k: v.detach().clone() for k, v in model.state_dict().items()})
            super().update_parameters(model)

    monkeypatch.setattr(T, "AveragedModel", Spy)
    out = tmp_path / "run"
    train(DepthConfig(**{**_cfg(folders, out, ema=0.75).__dict__, "steps": 3}))
    ck = load_checkpoint(out / "checkpoint.pt")
    assert len(seen) == 3
    for key, kept in ck["depth_net"].items():
        if not kept.is_floating_point():
            continue
        want = seen[0][key]
        for later in seen[1:]:
            want = 0.75 * want + 0.25 * later[key]
        torch.testing.assert_close(kept, want, rtol=1e-5, atol=1e-6, msg=key)
        torch.testing.assert_close(ck["depth_net_trained"][key], seen[-1][key], rtol=0, atol=0, msg=key)
    # resumed: training goes on from the trained network, the average from the kept one (a resume
    # with no step to take leaves both as they were)
    train(DepthConfig(**{**_cfg(folders, out, ema=0.75, resume=True).__dict__, "steps": 3}))
    again = load_checkpoint(out / "checkpoint.pt")
    for name in ("depth_net", "depth_net_trained"):
        for key, value in ck[name].items():
            torch.testing.assert_close(again[name][key], value, rtol=0, atol=0, msg=f"{name} {key}")
    seen.clear()
    train(DepthConfig(**{**_cfg(folders, out, ema=0.75, resume=True).__dict__, "steps": 4}))
    assert len(seen) == 1
    ck2 = load_checkpoint(out / "checkpoint.pt")
    key = "encoder.0.0.weight"
    torch.testing.assert_close(ck2["depth_net"][key], 0.75 * ck["depth_net"][key] + 0.25 * seen[0][key])
    # ema 0: the last step's network, nothing beside it; a decay outside [0, 1) is refused
    train(_cfg(folders, tmp_path / "last", ema=0.0))
    assert "depth_net_trained" not in load_checkpoint(tmp_path / "last" / "checkpoint.pt")
    with pytest.raises(ValueError, match=r"ema must be a decay in \[0, 1\)"):
        train(_cfg(folders, tmp_path / "bad", ema=1.0))
    with pytest.raises(SystemExit) as e:
        main(["depth", "train", "--data", "x", "--out", str(tmp_path / "y"), "--ema", "1.5"])
    assert e.value.code == 2


def test_predicted_depth_has_one_scale_and_tracks_a_sequence(folders, tmp_path, capsys):
    out = tmp_path / "run"
    train(_cfg(folders, out))
    seq = read_tum(folders[0])
    predict = DepthPredictor(out / "checkpoint.pt", first_median=2.0)
    first = predict(seq.image(0))
    assert first.shape == (1, 64, 96) and first.dtype == np.float32 and np.median(first) == pytest.approx(2.0)
    # later frames keep the first frame's scale: the network's own depth, resized, times that scale
    net = load_depth_net(load_checkpoint(out / "checkpoint.pt"))
    small, _ = resize_frame(torch.from_numpy(seq.image(3)), torch.zeros(1, 64, 96), (64, 64))
    with torch.no_grad():
        raw = torch.nn.functional.interpolate(net.depth(small), size=(64, 96), mode="bilinear")[0].numpy()
    np.testing.assert_allclose(predict(seq.image(3)), raw * predict.scale, rtol=1e-6)
    with pytest.raises(ValueError, match="first_median"):
        DepthPredictor(out / "checkpoint.pt", first_median=0.0)
    # bad images: integer refused with what to do; channel-last named; 8-bit values and NaN warned about once
    # (NaN pixels read as black: a finite depth)
    fresh = DepthPredictor(out / "checkpoint.pt")
    with pytest.raises(TypeError, match=r"DepthPredictor: argument 'image' must be float32 or float64, got uint8 "
                                        r"\(images in \[0, 1\]: divide 8-bit ones by 255\)"):
        fresh((255 * seq.image(0)).astype(np.uint8))
    with pytest.raises(ValueError, match=r"argument 'image' must be \(3, H, W\) RGB, got \(64, 96, 3\), which looks "
                                         "channel-last"):
        fresh(seq.image(0).transpose(1, 2, 0))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fresh(255 * seq.image(0))
        fresh(255 * seq.image(1))
        holes = seq.image(2).copy()
        holes[:, 10:20, 30:40] = np.nan
        holes[0, 0, 0] = np.inf
        d = fresh(holes)
        fresh(holes)
    assert [str(w.message).split(": ", 1)[1][:30] for w in caught] == [
        "argument 'image' has values up", "argument 'image' has NaN or in"]
    assert np.isfinite(d).all()
    plain = seq.image(2).copy()
    plain[:, 10:20, 30:40], plain[0, 0, 0] = 0.0, 0.0
    np.testing.assert_array_equal(d, fresh(plain))
    with warnings.catch_warnings(record=True) as caught:  # (an inf pixel is not taken for 8-bit values)
        warnings.simplefilter("always")
        DepthPredictor(out / "checkpoint.pt")(np.where(np.arange(96) == 5, np.inf, seq.image(0)).astype(np.float32))
    assert [str(w.message).split(": ", 1)[1][:30] for w in caught] == ["argument 'image' has NaN or in"]

    track = tmp_path / "track"
    assert main(["track", str(folders[0]), "--out", str(track), "--depth", "predicted", "--checkpoint",
                 str(out / "checkpoint.pt"), "--no-progress"]) == 0
    metrics = json.loads((track / "metrics.json").read_text())
    assert metrics["settings"]["depth"] == "predicted" and metrics["ate_alignment"].startswith("Sim(3)")
    assert math.isfinite(metrics["ate_rmse_m"]) and metrics["alignment_scale"] > 0
    assert "Sim(3)-aligned" in capsys.readouterr().out
    # fused in its units, against the model of the predicted depth (--model) or after tracking (--fuse): on
    # a colour video (the folder without depth.txt and depth images), so every frame integrated is predicted
    blank = colour_only_copy(folders[0], tmp_path / "blank")
    for mode in ("--model", "--fuse"):
        res = tmp_path / mode.strip("-")
        assert main(["track", str(blank), "--out", str(res), "--depth", "predicted", "--checkpoint",
                     str(out / "checkpoint.pt"), mode, "--voxel", "0.05", "--no-progress"]) == 0
        metrics = json.loads((res / "metrics.json").read_text())
        assert metrics["settings"]["depth"] == "predicted" and metrics["fusion"]["frames_skipped"] == []
        assert metrics["fusion"]["frames_integrated"] == 5 and metrics["fusion"]["units"].startswith("the predicted")
        assert "predicted depth's units" in capsys.readouterr().out and (res / "mesh.ply").exists()
    assert metrics["settings"]["mode"] == "frame-to-frame"  # (--fuse: tracked first, then fused)
    for argv, message in ((["--method", "vo"], "--method direct only"), ([], "needs --checkpoint"),
                          (["--depth-weight", "1"], "--depth-weight"),
                          (["--depth-scale", "1000"], "--depth-scale applies to the depth images")):
        ck = [] if message == "needs --checkpoint" else ["--checkpoint", str(out / "checkpoint.pt")]
        with pytest.raises(SystemExit) as e:
            main(["track", str(folders[0]), "--out", str(tmp_path / "t2"), "--depth", "predicted", *ck, *argv])
        assert e.value.code == 2 and message in capsys.readouterr().err


def test_cli_data_errors_are_one_line(folders, tmp_path, capsys):
    bad = tmp_path / "bad.pt"
    torch.save({"format": "something else"}, bad)
    assert main(["depth", "eval", "--checkpoint", str(bad), "--data", str(folders[0]), "--out", str(tmp_path / "e"),
                 "--no-progress"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "usage" not in err[0]
    assert main(["depth", "train", "--data", str(tmp_path / "missing"), "--out", str(tmp_path / "t"),
                 "--steps", "1", "--no-progress"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing" in err[0]
    assert not (tmp_path / "t").exists()  # (a refused run leaves no empty folder behind)
    # the results of eval are not written among a sequence's files
    with pytest.raises(SystemExit) as e:
        main(["depth", "eval", "--checkpoint", str(bad), "--data", str(folders[0]), "--out", str(folders[0])])
    assert e.value.code == 2 and "holds a sequence (rgb.txt)" in capsys.readouterr().err


def test_training_commands_keep_an_earlier_run(tmp_path, capsys):
    # depth train and vo refuse an --out holding a checkpoint unless --resume or --overwrite (one
    # line, status 2, before any work); --resume with nothing to resume says it starts a new run
    from gvnn_warp.cli.args import CHECKPOINT
    from gvnn_warp.vo.checkpoint import CHECKPOINT as WRITTEN

    assert CHECKPOINT == WRITTEN  # (the name the check looks for is the one the runs write)
    for command in (["depth", "train", "--data", str(tmp_path / "missing")], ["vo", "--motion", "so3"]):
        out = tmp_path / command[0]
        out.mkdir()
        (out / WRITTEN).write_bytes(b"an earlier run")
        with pytest.raises(SystemExit) as e:
            main([*command, "--out", str(out), "--steps", "1", "--no-progress"])
        err = capsys.readouterr().err
        assert e.value.code == 2 and "already holds a training run" in err and "--overwrite" in err
    # --overwrite gets past it (to the missing data folder: status 1, one line)
    out = tmp_path / "depth"
    assert main(["depth", "train", "--data", str(tmp_path / "missing"), "--out", str(out), "--steps", "1",
                 "--no-progress", "--overwrite"]) == 1
    assert "missing" in capsys.readouterr().err
    assert main(["depth", "train", "--data", str(tmp_path / "missing"), "--out", str(tmp_path / "new"), "--steps",
                 "1", "--no-progress", "--resume"]) == 1
    assert "no checkpoint in" in capsys.readouterr().err


def test_cli_rejects_sizes_the_network_cannot_take(capsys):
    with pytest.raises(SystemExit) as e:
        main(["depth", "train", "--data", "x", "--out", "y", "--size", "100x96"])
    assert e.value.code == 2 and "multiple of 32" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["depth", "train", "--data", "x", "--out", "y", "--size", "128x96x"])
    assert e.value.code == 2 and "e.g. 128x96" in capsys.readouterr().err  # (a size it takes)


def test_load_checkpoint_refuses_other_files(tmp_path, monkeypatch):
    p = tmp_path / "x.pt"
    p.write_text("not a checkpoint")
    with pytest.raises(ValueError, match="no such file"):
        load_checkpoint(Path(tmp_path / "none.pt"))
    with pytest.raises(ValueError, match=r"x.pt: not a checkpoint of gvnn-warp depth train \(.*not a torch file"):
        load_checkpoint(p)
    # a file that cannot be read is not blamed on its contents
    def unreadable(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(torch, "load", unreadable)
    with pytest.raises(ValueError, match=r"x.pt: cannot be read \(Permission denied\)$"):
        load_checkpoint(p)
    monkeypatch.undo()
    # a run's folder instead of its file: the file named when it is there
    run = tmp_path / "run"
    run.mkdir()
    with pytest.raises(ValueError, match=r"run: a folder, not a file \(gvnn-warp depth train writes"):
        load_checkpoint(run)
    torch.save({"format": "gvnn_warp.depth/1"}, run / "checkpoint.pt")
    with pytest.raises(ValueError, match=r"run: a folder, not a file: give the file in it, .*run.checkpoint\.pt"):
        load_checkpoint(run)
    # a learned-VO checkpoint (gvnn_warp.vo.checkpoint's numbered formats) is named as one
    vo = tmp_path / "vo.pt"
    torch.save({"format": 4, "config": {}, "model": {}, "network": {}, "step": 1}, vo)
    with pytest.raises(ValueError, match=r"a learned-VO checkpoint \(gvnn-warp vo\).*--method vo --checkpoint"):
        load_checkpoint(vo)
