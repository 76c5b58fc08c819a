"""Data-parallel training under ``torchrun`` (gvnn_warp.vo.distributed), both trainers in one launch of
two ranks (each rank pays torch's and the package's imports once): ``gvnn-warp vo`` makes its own
process group and tears it down, as when it is the script torchrun runs; ``gvnn-warp depth train`` then
joins a group the calling script made and leaves it up. Each checks that the ranks' weights agree."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from processes import FAST_EXIT

from gvnn_warp.cli import main
from gvnn_warp.depth.checkpoint import load_checkpoint

TORCHRUN = shutil.which("torchrun", path=str(Path(sys.executable).parent))

RANKS = """if True:
    import os, sys
    import torch.distributed as dist
    from gvnn_warp.cli import main

    vo_out, depth_out, store, *folders = sys.argv[1:]
    assert main(["vo", "--motion", "se3", "--out", vo_out, "--size", "64x48", "--batch-size", "8",
                 "--frames", "12", "--trajectories", "1", "--steps", "6", "--no-progress", "--stages", "1",
                 "--refine", "0", "--gaps", "1"]) == 0
    assert not dist.is_initialized()  # (made and torn down by the command)
    # the caller's own group (its own store: a second group on torchrun's store would wait forever)
    dist.init_process_group("gloo", init_method="file://" + store, rank=int(os.environ["RANK"]),
                            world_size=int(os.environ["WORLD_SIZE"]))
    assert main(["depth", "train", "--data", *folders, "--out", depth_out, "--size", "64x64", "--steps", "2",
                 "--batch-size", "4", "--gap", "1", "--no-progress", "--supervised"]) == 0
    assert dist.is_initialized()  # (left up for the caller)
    dist.barrier()
    dist.destroy_process_group()
    print("rank done")
"""


@pytest.mark.long
@pytest.mark.skipif(TORCHRUN is None, reason="torchrun not installed")
def test_two_ranks_train_vo_and_depth_the_same_on_each_rank(tmp_path):
    folders = []
    for s in (5, 6):
        folders.append(tmp_path / f"seq{s}")
        assert main(["render", "--out", str(folders[-1]), "--frames", "5", "--size", "96x64", "--seed", str(s),
                     "--no-progress"]) == 0
    script = tmp_path / "ranks.py"
    script.write_text(FAST_EXIT + RANKS)
    vo_out, depth_out = tmp_path / "vo", tmp_path / "depth"
    cmd = [TORCHRUN, "--standalone", "--nproc_per_node=2", str(script), str(vo_out), str(depth_out),
           str(tmp_path / "store"), *map(str, folders)]
    # (depth train --supervised: the same data-parallel loop, no Warp kernels to load)
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    assert res.returncode == 0, res.stderr[-3000:]
    assert res.stdout.count("rank done") == 2

    vo = json.loads((vo_out / "metrics.json").read_text())
    assert vo["distributed"] == {"world_size": 2, "max_param_diff_between_ranks": 0.0}
    assert vo["steps"] == 6 and len(vo["train_loss"]) == 6

    assert res.stdout.count("depth train:") == 1  # (rank 0 reports)
    depth = json.loads((depth_out / "metrics.json").read_text())
    assert depth["distributed"] == {"world_size": 2, "max_param_diff_between_ranks": 0.0}
    assert depth["steps"] == 2 and len(depth["train_loss"]) == 2
    assert load_checkpoint(depth_out / "checkpoint.pt")["step"] == 2
