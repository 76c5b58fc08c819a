"""The gvnn-warp command line: every bad argument is refused with one line before any work,
Ctrl-C ends every command with one line and status 130, commands say what they need, help texts
are plain and show defaults; Warp's CUDA-driver line is not shown and a cold kernel cache is
announced once."""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from processes import run_python

from gvnn_warp import cli
from gvnn_warp.cli import args as _args

BAD = "BAD"  # replaced by the path of an existing file
FILE_CHILD = "BAD/sub"  # a directory below that file
NOWHERE = "NOWHERE"  # track: replaced by a folder that does not exist
SHORT = "SHORT"  # track: replaced by a sequence of 1 frame
SEQ = "SEQ"  # track: replaced by the (valid) sequence's own folder


def _bad_cases():
    cases = {
        "align": [
            (["--out", BAD], "argument --out: '{BAD}' exists and is not a directory"),
            (["--out", FILE_CHILD], "argument --out: cannot make directory"),
            (["--size", "5000x5000"], "argument --size: each side must be between 16 and 4096 pixels"),
            (["--size", "15x40"], "argument --size: each side must be between 16"),
            (["--size", "160"], "argument --size: size must be WxH"),
            (["--steps", "0"], "argument --steps: expected a positive integer, got '0'"),
            (["--steps", "2.5"], "argument --steps: expected a positive integer"),
            (["--steps", "50000", "--levels", "3"], "--steps 50000 x --levels 3 is more than 100000 steps"),
            (["--levels", "0"], "argument --levels: expected a positive integer"),
            (["--size", "16x16", "--levels", "4"], "--levels 4 is too many for 16x16"),
            (["--rotation-deg", "nan"],
             "argument --rotation-deg: expected a number from -180 to 180 degrees, got 'nan'"),
            (["--rotation-deg", "inf"], "argument --rotation-deg: expected a number from -180 to 180"),
            (["--rotation-deg", "181"], "argument --rotation-deg: expected a number from -180 to 180"),
            (["--rotation-deg", "four"], "argument --rotation-deg: expected a number"),
            (["--translation-cm", "nan"], "argument --translation-cm: expected a number from -50 to 50 cm"),
            (["--translation-cm=-1e9"], "argument --translation-cm: expected a number from -50 to 50 cm"),
            (["--seed", "-1"], "argument --seed: expected an integer from 0 to 4294967295"),
            (["--seed", str(2**32)], "argument --seed: expected an integer from 0 to 4294967295"),
        ],
        "flow": [
            (["--out", BAD], "argument --out: '{BAD}' exists and is not a directory"),
            (["--steps", "0"], "argument --steps: expected an integer from 1 to 100000"),
            (["--steps", "100001"], "argument --steps: expected an integer from 1 to 100000"),
            (["--size", "31x40"], "argument --size: each side must be between 32 and 4096"),
            (["--size", "100000x100000"], "argument --size: each side must be between 32 and 4096"),
            (["--seed", "-1"], "argument --seed: expected an integer from 0"),
            (["--seed", "x"], "argument --seed: expected an integer from 0"),
        ],
        "vo": [
            (["--out", BAD], "argument --out: '{BAD}' exists and is not a directory"),
            (["--steps", "0"], "argument --steps: expected an integer from 1 to 10000000"),
            (["--size", "2000x2000"], "argument --size: each side must be between 32 and 1024"),
            (["--seed", "-1"], "argument --seed: expected an integer from 0 to 4294967295"),
            (["--loss", "l3"], "argument --loss: invalid choice: 'l3'"),
            (["--loss-scale", "nan"], "argument --loss-scale: expected a positive number, got 'nan'"),
            (["--loss-scale", "0"], "argument --loss-scale: expected a positive number"),
            (["--lr", "inf"], "argument --lr: expected a positive number, got 'inf'"),
            (["--lr", "-1"], "argument --lr: expected a positive number"),
            (["--batch-size", "0"], "argument --batch-size: expected a positive integer"),
            (["--batch-size", "64", "--trajectories", "1", "--frames", "10"],
             "18 training pairs are fewer than --batch-size 64"),
            (["--trajectories", "0"], "argument --trajectories: expected an integer from 1 to 1000"),
            (["--frames", "1"], "argument --frames: expected an integer from 2 to 10000, got '1'"),
            (["--frames", "3", "--motion", "se3", "--gaps", "1,3"],
             "--frames 3 is too few: pairs are up to 3 frames apart (--gaps)"),
            (["--gaps", "0"], "argument --gaps: expected an integer from 1 to 1000, got '0'"),
            (["--gaps", "1,,2"], "argument --gaps: expected comma-separated integers"),
            (["--pose-weight", "-1"], "argument --pose-weight: expected a number from 0 to 1e+06"),
            (["--data", NOWHERE], "--data with one folder needs --eval-data DIR"),
            (["--eval-data", NOWHERE], "--eval-data needs --data"),
            (["--stages", "0"], "argument --stages: expected an integer from 1 to 8"),
            (["--refine", "-1"], "argument --refine: expected an integer from 0 to 20"),
            (["--stages", "1", "--refine", "2"], "--refine 2 must be >= 0 and needs a cascade of at least 2"),
            (["--size", "1024x1024", "--trajectories", "200"], "GiB of frames and warps in memory"),
            (["--motion", "se2"], "argument --motion: invalid choice: 'se2'"),
        ],
        "render": [
            (["--out", BAD], "argument --out: '{BAD}' exists and is not a directory"),
            (["--out", FILE_CHILD], "argument --out: cannot make directory"),
            (["--frames", "0"], "argument --frames: expected an integer from 1 to 100000, got '0'"),
            (["--frames", "1e9"], "argument --frames: expected an integer from 1 to 100000"),
            (["--size", "5000x5000"], "argument --size: each side must be between 16 and 2048 pixels"),
            (["--size", "2049x16"], "argument --size: each side must be between 16 and 2048 pixels"),
            (["--size", "15x40"], "argument --size: each side must be between 16"),
            (["--size", "320"], "argument --size: size must be WxH"),
            (["--motion", "se2"], "argument --motion: invalid choice: 'se2'"),
            (["--seed", "-1"], "argument --seed: expected an integer from 0 to 4294967295"),
            (["--seed", str(2**32)], "argument --seed: expected an integer from 0 to 4294967295"),
        ],
        "track": [
            (["--out", BAD], "argument --out: '{BAD}' exists and is not a directory"),
            (["--out", FILE_CHILD], "argument --out: cannot make directory"),
            (["--max-frames", "1"], "argument --max-frames: expected an integer >= 2, got '1'"),
            (["--intrinsics", "fr9"], "argument --intrinsics: expected one of fr1, fr2, fr3, icl or fx,fy,cx,cy"),
            (["--intrinsics", "1,2,3"], "argument --intrinsics: expected one of fr1"),
            (["--intrinsics", "0,1,2,3"], "argument --intrinsics: expected one of fr1"),
            (["--intrinsics", "500,500,nan,240"], "argument --intrinsics: expected one of fr1"),
            (["--depth-scale", "0"], "argument --depth-scale: expected a positive number, got '0'"),
            (["--depth-scale", "nan"], "argument --depth-scale: expected a positive number"),
            (["--max-difference", "inf"], "argument --max-difference: expected a number > 0 and <= 1 s"),
            (["--max-difference", "0"], "argument --max-difference: expected a number > 0 and <= 1 s, got '0'"),
            (["--keyframe-trans", "-1"], "argument --keyframe-trans: expected a positive number"),
            (["--keyframe-rot", "nan"], "argument --keyframe-rot: expected a number > 0 and <= 180 deg"),
            (["--keyframes", "--keyframe-rot", "0"], "argument --keyframe-rot: expected a number > 0 and <= 180 deg"),
            (["--keyframe-trans", "0.1"], "--keyframe-trans applies with --keyframes only"),
            (["--keyframe-valid", "0.5"], "--keyframe-valid applies with --keyframes only"),
            (["--intrinsics", "240,240,1000,7.5"],
             "the principal point (1000, 7.5) of the intrinsics (--intrinsics) is outside the 16x16 images"),
            (["--out", SEQ], "is the sequence's own folder; choose another"),
            (["--keyframe-valid", "1.5"], "argument --keyframe-valid: expected a number from 0 to 1, got '1.5'"),
            (["--init", "magic"], "argument --init: invalid choice: 'magic'"),
            (["--levels", "0"], "argument --levels: expected an integer from 1 to 12"),
            (["--levels", "13"], "argument --levels: expected an integer from 1 to 12"),
            (["--iterations", "0"], "argument --iterations: expected an integer from 1 to 1000"),
            (["--robust", "l7"], "argument --robust: invalid choice: 'l7'"),
            (["--depth-weight", "-1"], "argument --depth-weight: expected a number from 0 to 1e+06"),
            (["--depth-weight", "inf"], "argument --depth-weight: expected a number from 0 to 1e+06"),
            (["--method", "vo"], "--method vo needs --checkpoint CKPT"),
            (["--method", "magic"], "argument --method: invalid choice: 'magic'"),
        ],
    }
    for command, rows in cases.items():
        # an option the command does not have: refused after the command's usage, not the program's
        rows.append((["--no-such-option", "3"], "unrecognized arguments: --no-such-option 3"))
        for extra, message in rows:
            yield pytest.param(command, extra, message, id=f"{command}{' '.join(extra)}")


def _argv(command, extra, out, sequence):
    base = {"align": ["align"], "flow": ["flow"], "vo": ["vo", "--motion", "so3"], "render": ["render"],
            "track": ["track"]}[command]
    if command == "track" and (not extra or extra[0].startswith("-")):
        base.append(str(sequence))  # a valid sequence unless the case names another folder
    if "--out" not in extra:
        base += ["--out", str(out)]
    return base + extra


@pytest.fixture(scope="module")
def sequences(tmp_path_factory):
    """A 2-frame rendered sequence and a copy cut to 1 frame (for track's cases)."""
    root = tmp_path_factory.mktemp("sequences")
    assert cli.main(["render", "--out", str(root / "seq"), "--frames", "2", "--size", "16x16", "--no-progress"]) == 0
    short = root / "short"
    short.mkdir()
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt", "intrinsics.txt"):
        lines = (root / "seq" / name).read_text().splitlines()
        data = [line for line in lines if line and not line.startswith("#")]
        (short / name).write_text("\n".join([line for line in lines if line.startswith("#")] + data[:1]) + "\n")
    for kind in ("rgb", "depth"):
        (short / kind).symlink_to(root / "seq" / kind)
    return root / "seq", short


@pytest.mark.parametrize("command, extra, message", list(_bad_cases()))
def test_bad_arguments_get_one_line_after_the_usage_and_no_work(command, extra, message, tmp_path, capsys,
                                                                 request):
    bad_file = tmp_path / "a_file"
    bad_file.write_text("not a directory")
    out = tmp_path / "out"
    sequence = short = None
    if command == "track":
        sequence, short = request.getfixturevalue("sequences")
    replace = {BAD: str(bad_file), NOWHERE: str(tmp_path / "nowhere"), SHORT: str(short), SEQ: str(sequence)}
    extra = [replace.get(a, a.replace(BAD, str(bad_file))) for a in extra]
    with pytest.raises(SystemExit) as exc:
        cli.main(_argv(command, extra, out, sequence))
    assert exc.value.code == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert lines[0].startswith(f"usage: gvnn-warp {command} ")
    assert lines[-1].startswith(f"gvnn-warp {command}: error: "), err
    assert message.format(BAD=bad_file) in lines[-1], err
    assert "Traceback" not in err
    assert not out.exists()  # nothing was made: no work started
    assert bad_file.read_text() == "not a directory"


def test_an_unknown_option_before_the_command_is_the_programs(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["--no-such-option", "render", "--out", str(tmp_path / "o")])
    lines = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and lines[0].startswith("usage: gvnn-warp [-h] COMMAND")
    assert lines[-1] == "gvnn-warp: error: unrecognized arguments: --no-such-option"


@pytest.mark.parametrize("sub", ["train", "eval"])
def test_depth_subcommands_refuse_unknown_options_after_their_own_usage(sub, tmp_path, capsys):
    argv = ["depth", sub, "--data", str(tmp_path), "--out", str(tmp_path / "o"), "--no-such-option"]
    if sub == "eval":
        argv += ["--checkpoint", str(tmp_path / "c.pt")]
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    lines = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and lines[0].startswith(f"usage: gvnn-warp depth {sub} ")
    assert lines[-1] == f"gvnn-warp depth {sub}: error: unrecognized arguments: --no-such-option"
    assert not (tmp_path / "o").exists()


DATA_ERRORS = [  # a file or folder that cannot be used: one line naming it, status 1, no usage text
    ("vo", ["--data", NOWHERE, NOWHERE], "nowhere: no such directory"),
    ("track", [NOWHERE], "nowhere: no such directory"),
    ("track", [SHORT], "need at least 2 frames to track, found 1"),
    ("track", ["--method", "vo+direct", "--checkpoint", BAD], "not a gvnn-warp vo checkpoint"),
    ("track", ["--depth", "predicted", "--checkpoint", BAD], "not a checkpoint of gvnn-warp depth train"),
    ("depth", ["eval", "--checkpoint", BAD, "--data", SEQ], "not a checkpoint of gvnn-warp depth train"),
    ("depth", ["train", "--data", NOWHERE, "--steps", "1"], "nowhere: no such directory"),
]


@pytest.mark.parametrize("command, extra, message", DATA_ERRORS, ids=[f"{c} {' '.join(e)}" for c, e, _ in DATA_ERRORS])
def test_data_errors_are_one_line_without_the_usage(command, extra, message, tmp_path, capsys, request):
    bad_file = tmp_path / "a_file"
    bad_file.write_text("not a checkpoint")
    sequence, short = request.getfixturevalue("sequences")
    out = tmp_path / "out"
    replace = {BAD: str(bad_file), NOWHERE: str(tmp_path / "nowhere"), SHORT: str(short), SEQ: str(sequence)}
    extra = [replace.get(a, a) for a in extra]
    argv = ([command, *extra[:1]] if command == "depth" else [command]) + (extra[1:] if command == "depth" else extra)
    if command == "track" and extra[0].startswith("-"):
        argv.insert(1, str(sequence))
    argv += ["--out", str(out), "--no-progress"] if command != "vo" else ["--out", str(out), "--motion", "so3"]
    assert cli.main(argv) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"gvnn-warp {command}") and message in lines[0], lines
    assert not out.exists() or not any(out.iterdir())


def test_validators():
    with pytest.raises(argparse.ArgumentTypeError, match="finite"):
        _args.finite_float()("nan")
    assert _args.finite_float(-1, 1)("-1") == -1.0
    assert _args.image_size(16, 64)("64x16") == (64, 16)
    with pytest.raises(argparse.ArgumentTypeError):
        _args.image_size(16, 64)("65x16")
    assert _args.bounded_int(2, 3)("3") == 3
    with pytest.raises(argparse.ArgumentTypeError):
        _args.bounded_int(2, 3)("4")
    assert _args.positive_int("7") == 7 and _args.nonnegative_int("0") == 0
    assert _args.plain_text("``a`` :mod:`b.c` **d**") == "a b.c d"


def test_output_dir_accepts_new_and_existing_directories(tmp_path):
    assert _args.output_dir(str(tmp_path)) == tmp_path
    assert _args.output_dir(str(tmp_path / "x" / "y")) == tmp_path / "x" / "y"
    assert not (tmp_path / "x").exists()  # checked, not made


# ----------------------------------------------------------------------------- help


def _subparsers():
    parser = cli.build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return parser, sub.choices


def test_help_is_plain_text_with_defaults_and_descriptions():
    parser, commands = _subparsers()
    assert set(commands) == set(cli.DEMOS)
    for name, p in [("", parser), *commands.items()]:
        text = p.format_help()
        for markup in ("``", ":mod:", ":func:", "**"):
            assert markup not in text, (name, markup)
        assert p.description and len(p.description) > 40, name  # align had none
        if not name:
            continue
        for action in p._actions:
            if not action.option_strings or action.required or action.nargs == 0:
                continue  # -h, --out/--motion, flags
            help_line = p._get_formatter()._expand_help(action)
            assert "default" in help_line, (name, action.dest, help_line)


def test_docs_torchrun_line_is_the_help_one():
    guide = (Path(__file__).resolve().parents[2] / "docs" / "vo.md").read_text()
    line = "torchrun --standalone --nproc_per_node=2 -m gvnn_warp.cli.vo"
    assert line in guide
    _, commands = _subparsers()
    assert line in commands["vo"].format_help().replace("\n", " ")


def test_vo_loss_choices_match_the_losses():
    from gvnn_warp.cli.vo import _losses
    from gvnn_warp.vo.loss import LOSSES

    assert _losses() == LOSSES


# ----------------------------------------------------------------------------- Ctrl-C, missing packages


_VALID = {"align": ["--out", "{out}"], "flow": ["--out", "{out}"], "vo": ["--motion", "so3", "--out", "{out}"],
          "render": ["--out", "{out}"], "track": ["{out}/sequence", "--out", "{out}"],
          "depth": ["train", "--data", "{out}/sequence", "--out", "{out}"]}


def _requires(command):
    return cli.build_parser().parse_args([command, *(a.format(out="o") for a in _VALID[command])])._requires


@pytest.mark.parametrize("command", cli.DEMOS)
def test_keyboard_interrupt_anywhere_in_a_command(command, tmp_path, capsys, monkeypatch):
    """The handling is cli's, so every command (new ones too) gets it."""
    import importlib

    module = importlib.import_module(f"gvnn_warp.cli.{command}")

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(module, "run", interrupted)
    argv = [command, *(a.format(out=tmp_path / "o") for a in _VALID[command])]
    assert cli.main(argv) == 130
    assert capsys.readouterr().err == f"gvnn-warp {' '.join(argv[:2] if command == 'depth' else argv[:1])}: " \
                                      "interrupted\n"  # (depth's subcommand named: depth train)


def test_a_file_the_command_cannot_write_is_one_line(tmp_path, capsys, monkeypatch):
    from gvnn_warp.cli import render

    def unwritable(args):
        raise PermissionError(13, "Permission denied", str(tmp_path / "o" / "rgb.txt"))

    monkeypatch.setattr(render, "run", unwritable)
    argv = ["render", *(a.format(out=tmp_path / "o") for a in _VALID["render"])]
    assert cli.main(argv) == 1
    assert capsys.readouterr().err == f"gvnn-warp render: error: {tmp_path / 'o' / 'rgb.txt'}: Permission denied\n"

    def broken(args):  # an OSError about no file is not the user's: it keeps its traceback
        raise OSError("something else")

    monkeypatch.setattr(render, "run", broken)
    with pytest.raises(OSError, match="something else"):
        cli.main(argv)


def test_keyboard_interrupt_during_the_clean_up_still_exits_130(tmp_path, capsys, monkeypatch):
    """A second interrupt while run_command cleans up (after it reported the first) must not end the
    process as killed by SIGINT: one line, status 130."""
    import gvnn_warp._warp_setup as warp_setup
    from gvnn_warp.cli import align

    def interrupted(*args):
        raise KeyboardInterrupt

    monkeypatch.setattr(align, "run", interrupted)
    monkeypatch.setattr(warp_setup, "cancel_first_compile", interrupted)
    assert cli.main(["align", *(a.format(out=tmp_path / "o") for a in _VALID["align"])]) == 130
    assert capsys.readouterr().err == "gvnn-warp align: interrupted\n"


def _env():
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    return env


@pytest.mark.long
def test_ctrl_c_in_align_exits_130_with_one_line(tmp_path):
    cmd = [sys.executable, "-m", "gvnn_warp.cli", "align", "--out", str(tmp_path), "--size", "32x24",
           "--levels", "1", "--steps", "100000"]
    proc = subprocess.Popen(cmd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()  # printed once the views are rendered, as gradient descent starts
        assert line.startswith("rendered 2 views"), line + proc.stderr.read()
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise AssertionError(f"still running 60 s after Ctrl-C; stderr: {proc.communicate()[1][-3000:]}") from None
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "gvnn-warp align: interrupted", err
    assert "Traceback" not in err


SWALLOWS_CTRL_C = """
import argparse, sys, time
from gvnn_warp import cli
from gvnn_warp.cli import runner
runner.EXIT_GRACE_SECONDS = 1.0  # read by runner's Ctrl-C timer

def run(args):
    print("ready", flush=True)
    t = time.time()
    while time.time() - t < 60:
        try:
            time.sleep(0.05)
        except KeyboardInterrupt:
            pass  # as ctypes does with an exception raised in a callback from native code
    return 0

p = argparse.ArgumentParser(prog="gvnn-warp demo")
p.set_defaults(func=run)
sys.exit(cli.run_command(p, p.parse_args([])))
"""


def test_ctrl_c_ends_a_command_that_swallows_keyboard_interrupt():
    proc = subprocess.Popen([sys.executable, "-c", SWALLOWS_CTRL_C], env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        t0 = time.time()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130 and err == "gvnn-warp demo: interrupted\n", err
    assert time.time() - t0 < 20


def test_commands_without_torch_say_what_to_install(tmp_path):
    """Without torch, gvnn-warp still starts (help, argument errors) and a command that needs torch
    stops before any work with one line naming what to install."""
    code = f"""
import sys
sys.modules["torch"] = None  # as if torch were not installed
from gvnn_warp.cli import main
try:
    main(["--help"])
except SystemExit as e:
    assert e.code == 0, e.code
rc = main(["vo", "--motion", "so3", "--out", {str(tmp_path / "o")!r}])
assert rc == 1, rc
assert "torch" not in sys.modules or sys.modules["torch"] is None
print("ok")
"""
    res = run_python(code, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().endswith("ok")
    err = res.stderr.strip().splitlines()
    assert len(err) == 1, res.stderr
    assert err[0].startswith("gvnn-warp vo: error: this command needs PyTorch")
    assert "pip install -e '.[torch]'" in err[0] and "download.pytorch.org/whl/cpu" in err[0]
    assert not (tmp_path / "o").exists()


# ----------------------------------------------------------------------------- Warp's start-up


def test_a_command_run_as_a_program_freezes_its_objects_at_exit(monkeypatch):
    from gvnn_warp.cli import runner

    # the objects are frozen when the exit handlers run (a handler registered before runs after it)
    code = """import atexit, gc
atexit.register(lambda: print("frozen at exit:", gc.get_freeze_count() > 0))
from gvnn_warp.cli import runner
if {call}:
    runner.freeze_at_exit()
    runner.freeze_at_exit()
"""
    for call in (True, False):
        res = run_python(code.format(call=call), timeout=120)
        assert res.returncode == 0 and res.stdout.strip().splitlines()[-1] == f"frozen at exit: {call}", res
    # only as a program (argv from sys.argv), not when other code calls main with its arguments
    called = []
    monkeypatch.setattr(runner, "freeze_at_exit", lambda: called.append(sys.argv[0]))
    monkeypatch.setattr(runner, "run_command", lambda parser, args, requires: 0)
    assert cli.main(["render", "--out", "x"]) == 0 and called == []
    assert runner.command_main(lambda sub: sub.add_parser("x"), argv=[]) == 0 and called == []
    monkeypatch.setattr(sys, "argv", ["gvnn-warp", "render", "--out", "x"])
    assert cli.main() == 0 and called == ["gvnn-warp"]
    monkeypatch.setattr(sys, "argv", ["x.py"])
    assert runner.command_main(lambda sub: sub.add_parser("x")) == 0 and called == ["gvnn-warp", "x.py"]


def test_no_cuda_driver_warning():
    code = "import gvnn_warp, warp as wp; wp.zeros(1); print(wp.get_device())"
    res = run_python(code, timeout=120)
    assert res.returncode == 0, res.stderr
    assert "CUDA driver" not in res.stderr, res.stderr


def test_init_filter_keeps_other_stderr_lines(capfd):
    from gvnn_warp._warp_setup import init_warp_quietly

    def fake_init():
        os.write(2, b"Warp CUDA warning: Could not find or load the NVIDIA CUDA driver. GPU execution ...\n")
        os.write(2, b"another warning\n")

    init_warp_quietly(fake_init)
    assert capfd.readouterr().err == "another warning\n"


@pytest.mark.long
def test_cold_kernel_cache_is_announced_once(tmp_path):
    code = """
import sys
import warp as wp
from gvnn_warp.cli import announce_compiles

announce_compiles()
for scale in (1.0, 2.0):  # two kernel modules, compiled one after the other
    @wp.kernel(module="unique")
    def fill(a: wp.array(dtype=float), s: float):
        a[wp.tid()] = s

    a = wp.zeros(2)
    wp.launch(fill, 2, [a, scale])
    assert a.numpy()[0] == scale
print("done")
"""
    script = tmp_path / "kernels.py"  # Warp reads a kernel's source from its file
    script.write_text(code)
    env = dict(os.environ, WARP_CACHE_PATH=str(tmp_path / "cache"))
    runs = [subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True, timeout=300)
            for _ in range(2)]
    for r in runs:
        assert r.returncode == 0 and r.stdout.strip() == "done", r.stderr
    assert runs[0].stderr.count("compiling kernels, once") == 1, runs[0].stderr
    assert str(tmp_path / "cache") in runs[0].stderr
    assert "compiling" not in runs[1].stderr, runs[1].stderr  # warm cache: silent


# ----------------------------------------------------------------------------- figures


def _texts(fig):
    import matplotlib.text

    return [t for t in fig.findobj(matplotlib.text.Text) if t.get_text().strip()]


def _colorbar_labels(fig):
    return [ax.get_ylabel() for ax in fig.axes if ax.get_label() == "<colorbar>"]


def test_align_figure_has_a_labelled_colour_bar():
    import matplotlib.pyplot as plt

    from gvnn_warp.demos.align import figure

    g = torch.Generator().manual_seed(0)
    ref, live, before, after = (torch.rand(3, 24, 32, generator=g) for _ in range(4))
    valid = torch.ones(1, 24, 32, dtype=torch.bool)
    fig = figure(ref, live, before, after, valid, valid, errors=((4.0, 0.08), (0.1, 0.005)))
    try:
        labels = _colorbar_labels(fig)
        assert len(labels) == 1 and "intensity" in labels[0]
        assert min(t.get_fontsize() for t in _texts(fig)) >= 9
        assert any("pose error 0.10 deg, 0.50 cm" in t.get_text() for t in _texts(fig))
    finally:
        plt.close(fig)


def test_flow_figure_colour_bars_have_units():
    import matplotlib.pyplot as plt

    from gvnn_warp.demos.flow import figure

    g = torch.Generator().manual_seed(0)
    f1, f2, warped = (torch.rand(1, 3, 24, 32, generator=g) for _ in range(3))
    est, truth = (torch.randn(1, 2, 24, 32, generator=g) for _ in range(2))
    fig = figure(f1, f2, warped, est, truth, torch.rand(24, 32, generator=g).numpy(),
                 {"epe": 0.1, "epe_zero": 1.0, "steps": 3})
    try:
        labels = _colorbar_labels(fig)
        assert len(labels) == 3
        assert sum("px" in lab for lab in labels) == 1 and sum("intensity" in lab for lab in labels) == 2
        assert min(t.get_fontsize() for t in _texts(fig)) >= 9
    finally:
        plt.close(fig)


def test_commands_need_what_they_import():
    """render and track never import torch (the renderer, reader, aligner and tracking loop are
    numpy and Warp); track needs evo for its metrics and matplotlib for its figures."""
    assert set(_requires("align")) >= {"torch", "matplotlib"} and set(_requires("vo")) >= {"torch", "matplotlib"}
    assert "torch" not in _requires("render") and "matplotlib" not in _requires("render")
    assert {"evo", "matplotlib"} <= set(_requires("track")) and "torch" not in _requires("track")
    for name in {n for c in cli.DEMOS for n in _requires(c)}:
        assert name in cli.INSTALL_HINTS, name


@pytest.mark.parametrize("command", [c for c in cli.DEMOS if "matplotlib" in _requires(c)])
def test_missing_figure_library_is_reported_before_work(command, tmp_path, capsys, monkeypatch):
    """matplotlib is a dependency; in a broken installation without it a command stops at once
    (it used to train for minutes and then fail writing the figure)."""
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    argv = [command, *(a.format(out=tmp_path / "o") for a in _VALID[command])]
    assert cli.main(argv) == 1
    err = capsys.readouterr().err
    prog = " ".join(argv[:2] if command == "depth" else argv[:1])  # (depth's subcommand named: depth train)
    assert err == f"gvnn-warp {prog}: error: this command needs matplotlib, which is not installed: " \
                  "pip install matplotlib\n"
    assert not (tmp_path / "o").exists()


def test_track_without_evo_stops_before_work(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "evo", None)
    assert cli.main(["track", str(tmp_path / "seq"), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err
    assert err == "gvnn-warp track: error: this command needs evo (trajectory metrics), which is not installed: " \
                  "pip install evo\n"
    assert not (tmp_path / "o").exists()


@pytest.mark.long
def test_render_and_track_never_import_torch(tmp_path):
    """So they work without the torch extra: render and track end to end, and torch is never imported.
    (Not by blocking the import: scipy, which evo uses, looks torch up in sys.modules.)"""
    code = f"""
import sys
from gvnn_warp.cli import main
assert main(["render", "--out", {str(tmp_path / "seq")!r}, "--frames", "3", "--size", "32x24", "--no-progress"]) == 0
assert main(["track", {str(tmp_path / "seq")!r}, "--out", {str(tmp_path / "o")!r}, "--no-progress"]) == 0
assert "torch" not in sys.modules, "torch imported"
print("ok")
"""
    res = run_python(code, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.strip().endswith("ok") and "ATE RMSE" in res.stdout
    assert (tmp_path / "o" / "metrics.json").exists()


def test_render_refuses_a_folder_holding_a_sequence(tmp_path, capsys):
    out = tmp_path / "seq"
    argv = ["render", "--out", str(out), "--frames", "2", "--size", "16x16", "--no-progress"]
    assert cli.main(argv) == 0
    before = (out / "rgb.txt").read_text()
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        cli.main(argv[:4] + ["3"] + argv[5:])
    assert exc.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[0].startswith("usage: gvnn-warp render ")
    assert lines[-1] == f"gvnn-warp render: error: --out {out} already holds a sequence (rgb.txt); pass " \
                        "--overwrite or choose another folder"
    assert (out / "rgb.txt").read_text() == before
    assert cli.main(argv[:4] + ["3"] + argv[5:] + ["--overwrite"]) == 0
    assert len(list((out / "rgb").glob("*.png"))) == 3
