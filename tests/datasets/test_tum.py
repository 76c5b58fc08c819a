"""gvnn_warp.datasets.tum: TUM RGB-D folders and trajectory files, and `gvnn-warp render`.

References: evo's own TUM file reader/writer and its trajectory interpolation, scipy's rotations,
a direct O(n^2) transcription of TUM associate.py's rules, and the renderer's arrays.
"""

import itertools

import numpy as np
import pytest
from PIL import Image
from processes import run_python
from scipy.spatial.transform import Rotation

from gvnn_warp.datasets import tum
from gvnn_warp.datasets.tum import (
    DISTORTION_PRESETS,
    DatasetError,
    TUMWriter,
    associate,
    intrinsics_preset,
    matrix_to_quaternion_xyzw,
    quaternion_xyzw_to_matrix,
    read_trajectory,
    read_tum,
    write_trajectory,
)


def _poses(n, seed=0, angles=None):
    rng = np.random.default_rng(seed)
    R = Rotation.random(n, random_state=seed).as_matrix() if angles is None else angles
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = rng.uniform(-3, 3, (n, 3))
    return T


# ------------------------------------------------------------------------------------------------
# quaternions and trajectory files


def test_quaternions_match_scipy_including_half_turns():
    axes = np.eye(3)
    hard = [Rotation.identity(), Rotation.from_rotvec([1e-9, 0, 0])]
    hard += [Rotation.from_rotvec(np.pi * a) for a in axes]  # qw = 0
    hard += [Rotation.from_rotvec((np.pi - 1e-7) * np.array([1.0, -2.0, 0.5]) / np.sqrt(5.25))]
    rots = [*hard, *Rotation.random(50, random_state=1)]
    R = np.stack([r.as_matrix() for r in rots])
    q = matrix_to_quaternion_xyzw(R)
    q_ref = np.stack([r.as_quat() for r in rots])  # scipy: (x, y, z, w)
    same = np.minimum(np.abs(q - q_ref).max(1), np.abs(q + q_ref).max(1))
    assert same.max() < 1e-7
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(quaternion_xyzw_to_matrix(q_ref * 3.0), R, atol=1e-12)  # any norm


def test_trajectory_round_trip_and_evo_reads_what_we_write(tmp_path):
    from evo.tools import file_interface

    T = _poses(20)
    T[3, :3, :3] = Rotation.from_rotvec([0, np.pi, 0]).as_matrix()
    stamps = 1305031102.175304 + np.arange(20) / 30.0
    path = tmp_path / "traj.txt"
    write_trajectory(path, stamps, T, comment="two\nlines")
    t2, T2 = read_trajectory(path)
    np.testing.assert_allclose(t2, stamps, atol=1.5e-6, rtol=0)  # written to 1 us
    np.testing.assert_allclose(T2, T, atol=5e-9)
    evo_traj = file_interface.read_tum_trajectory_file(str(path))
    np.testing.assert_allclose(np.stack(evo_traj.poses_se3), T, atol=5e-9)
    np.testing.assert_allclose(evo_traj.timestamps, t2, atol=1e-9, rtol=0)


def test_we_read_what_evo_writes(tmp_path):
    from evo.core.trajectory import PoseTrajectory3D
    from evo.tools import file_interface

    T = _poses(7, seed=3)
    stamps = np.array([5.0, 1.0, 2.0, 3.5, 4.25, 6.0, 7.125])  # unsorted: read back sorted by time
    path = tmp_path / "evo.txt"
    file_interface.write_tum_trajectory_file(str(path), PoseTrajectory3D(poses_se3=list(T), timestamps=stamps))
    t2, T2 = read_trajectory(path)
    order = np.argsort(stamps)
    np.testing.assert_allclose(t2, stamps[order])
    np.testing.assert_allclose(T2, T[order], atol=1e-12)


def test_write_trajectory_refuses_bad_poses(tmp_path):
    with pytest.raises(ValueError, match="write_trajectory: poses must be"):
        write_trajectory(tmp_path / "t.txt", np.zeros(3), np.zeros((2, 4, 4)))
    T = _poses(2)
    T[1, 0, 3] = np.nan
    with pytest.raises(ValueError, match="finite"):
        write_trajectory(tmp_path / "t.txt", np.zeros(2), T)


# ------------------------------------------------------------------------------------------------
# association


def _associate_reference(first, second, max_difference, offset=0.0):
    """TUM associate.py's rules, transcribed literally (all pairs, sort, greedy)."""
    cands = sorted((abs(a - (b + offset)), a, b) for a, b in itertools.product(first, second)
                   if abs(a - (b + offset)) < max_difference)
    used_a, used_b, out = set(), set(), []
    for _, a, b in cands:
        if a not in used_a and b not in used_b:
            used_a.add(a)
            used_b.add(b)
            out.append((a, b))
    return sorted(out)


def test_associate_corner_cases():
    rgb = np.array([1.000, 1.030, 1.070, 1.100, 2.000])
    depth = np.array([1.012, 1.019, 1.081, 1.0799, 1.5])
    pairs = associate(rgb, depth, 0.02)
    got = [(rgb[i], depth[j]) for i, j in pairs]
    assert got == _associate_reference(rgb, depth, 0.02)
    assert all(abs(a - b) < 0.02 for a, b in got)
    assert len({b for _, b in got}) == len(got)  # each depth used once
    assert 2.0 not in [a for a, _ in got]  # no depth near it
    # exactly max_difference apart: not associated (strict, as associate.py)
    assert associate(np.array([0.0]), np.array([0.5]), 0.5).shape == (0, 2)
    assert associate(np.array([]), np.array([1.0])).shape == (0, 2)
    np.testing.assert_array_equal(associate(np.array([1.0]), np.array([0.9]), 0.02, offset=0.1), [[0, 0]])


@pytest.mark.parametrize("seed", range(5))
def test_associate_matches_associate_py_rules_on_jittered_stamps(seed):
    rng = np.random.default_rng(seed)
    rgb = np.sort(rng.uniform(0, 2, 60))
    near = rgb[rng.random(60) < 0.8]  # most colour images have a depth image close by (jittered)
    depth = rng.permutation(np.concatenate([near + rng.uniform(-0.025, 0.025, near.size), rng.uniform(0, 2, 30)]))
    pairs = associate(rgb, depth, 0.02)
    assert [(rgb[i], depth[j]) for i, j in pairs] == _associate_reference(rgb, depth, 0.02)


# ------------------------------------------------------------------------------------------------
# hand-made folders


def _png_rgb(path, h=4, w=5, value=0):
    path.parent.mkdir(parents=True, exist_ok=True)
    rgb = np.zeros((h, w, 3), np.uint8)
    rgb[..., 0] = value
    rgb[..., 1] = np.arange(w, dtype=np.uint8)[None] * 50
    rgb[..., 2] = 255
    Image.fromarray(rgb).save(path)
    return rgb


def _png_depth(path, raw):
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.asarray(raw, dtype=np.uint16)).save(path)


def _three_frame_folder(root, gt=None, intrinsics="500 501 2.0 1.5\n"):
    """Colour at odd times with comments, blank lines, a tab and commas; depth slightly off; one depth
    that two colour images compete for, and one colour image with no depth near it."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "rgb.txt").write_text(
        "# colour images\n# file: 'x.bag'\n# timestamp filename\n\n"
        "10.000000 rgb/a.png\n"
        "10.0300\trgb/b.png\n"
        "10.060000,rgb/c.png\n"
        "10.500000 rgb/lonely.png\n"
        "10.090000 rgb/d.png\n"
    )
    (root / "depth.txt").write_text(
        "# depth maps\n10.011 depth/a.png\n10.045 depth/bc.png\n10.101 depth/d.png\n"
    )
    for k, name in enumerate(["a", "b", "c", "lonely", "d"]):
        _png_rgb(root / "rgb" / f"{name}.png", value=40 * k)
    for k, name in enumerate(["a", "bc", "d"]):
        _png_depth(root / "depth" / f"{name}.png", np.full((4, 5), 5000 * (k + 1)))
    if intrinsics is not None:
        (root / "intrinsics.txt").write_text("# fx fy cx cy\n" + intrinsics)
    if gt is not None:
        (root / "groundtruth.txt").write_text(gt)


def test_hand_made_folder_association_and_missing_groundtruth(tmp_path):
    _three_frame_folder(tmp_path)
    seq = read_tum(tmp_path)
    # 10.045 is 0.015 from 10.030 and 0.015 from 10.060: the tie goes to the earlier colour stamp;
    # 10.060 then has no depth within 0.02 s and is dropped, as is 10.5
    np.testing.assert_allclose(seq.timestamps, [10.0, 10.03, 10.09])
    np.testing.assert_allclose(seq.depth_timestamps, [10.011, 10.045, 10.101])
    assert [p.name for p in seq.rgb_files] == ["a.png", "b.png", "d.png"]
    assert len(seq) == 3 and seq.gt_poses is None and seq.pose(0) is None and seq[1].pose is None
    np.testing.assert_allclose(seq.K, [[500, 0, 2.0], [0, 501, 1.5], [0, 0, 1]])
    assert (seq.width, seq.height) == (5, 4)
    f = seq[2]
    assert f.image.shape == (3, 4, 5) and f.image.dtype == np.float32
    np.testing.assert_allclose(f.image[0], 160 / 255, atol=1e-7)  # "d" is the 5th colour image (value 4 * 40)
    np.testing.assert_allclose(f.image[2], 1.0)
    gray = seq.image(2, gray=True)
    np.testing.assert_allclose(gray[0], 0.299 * f.image[0] + 0.587 * f.image[1] + 0.114 * f.image[2], atol=1e-6)
    np.testing.assert_allclose(f.depth, 3.0)  # raw 15000 / 5000


def test_groundtruth_is_interpolated_like_evo(tmp_path):
    from evo.core.trajectory import PoseTrajectory3D

    rng = np.random.default_rng(0)
    gt_t = np.sort(np.concatenate([[9.95, 10.2], rng.uniform(9.95, 10.2, 18)]))
    gt_T = _poses(gt_t.size, seed=5)
    # keep consecutive rotations close (as a 100 Hz mocap would), so the slerp arc is unambiguous
    gt_T[:, :3, :3] = Rotation.from_rotvec(np.linspace([0, 0, 0], [0.4, -0.2, 0.3], gt_t.size)).as_matrix()
    write_trajectory(tmp_path / "gt.txt", gt_t, gt_T)
    (tmp_path / "gt.txt").rename(tmp_path / "groundtruth.txt")
    _three_frame_folder(tmp_path)
    seq = read_tum(tmp_path)
    t_file, T_file = read_trajectory(tmp_path / "groundtruth.txt")
    ref = PoseTrajectory3D(poses_se3=list(T_file), timestamps=t_file).interpolate(seq.timestamps)
    assert seq.gt_valid.all()
    np.testing.assert_allclose(seq.gt_poses, np.stack(ref.poses_se3), atol=1e-9)

    # a frame beyond the ground truth's end by more than max_difference has none
    write_trajectory(tmp_path / "groundtruth.txt", gt_t[gt_t < 10.06], gt_T[gt_t < 10.06])
    seq = read_tum(tmp_path)
    late = seq.timestamps > 10.06 + 0.02
    assert late.any() and not seq.gt_valid[late].any() and np.isnan(seq.gt_poses[late]).all()
    assert seq.pose(int(np.flatnonzero(late)[0])) is None


def test_intrinsics_file_presets_and_explicit(tmp_path):
    _three_frame_folder(tmp_path)
    assert read_tum(tmp_path).intrinsics_source.endswith("intrinsics.txt")
    assert read_tum(tmp_path).intrinsics_override is None
    seq = read_tum(tmp_path, intrinsics="fr1")  # explicit beats the file, and says so: they differ
    assert "replace" in seq.intrinsics_override and "which differs (fx 500 fy 501 cx 2 cy 1.5)" in (
        seq.intrinsics_override) and "radial-tangential" in seq.intrinsics_override
    same = read_tum(tmp_path, intrinsics=(500, 501, 2.0, 1.5)).intrinsics_override
    assert "which has the same values" in same
    # fr1 is 517.3 516.5 318.6 255.3 at 640x480; these images are 5x4
    sx, sy = 5 / 640, 4 / 480
    np.testing.assert_allclose(seq.K, [[517.3 * sx, 0, 319.1 * sx - 0.5], [0, 516.5 * sy, 255.8 * sy - 0.5], [0, 0, 1]])
    np.testing.assert_allclose(intrinsics_preset("fr3"), [[535.4, 0, 320.1], [0, 539.2, 247.6], [0, 0, 1]])
    np.testing.assert_allclose(intrinsics_preset("icl")[0, 0], 481.2)
    np.testing.assert_allclose(read_tum(tmp_path, intrinsics=(1, 2, 3, 4)).K, [[1, 0, 3], [0, 2, 4], [0, 0, 1]])
    with pytest.raises(ValueError, match="unknown intrinsics preset 'fr9'"):
        read_tum(tmp_path, intrinsics="fr9")

    named = tmp_path / "rgbd_dataset_freiburg2_xyz"
    _three_frame_folder(named, intrinsics=None)
    seq = read_tum(named)
    assert seq.intrinsics_source == "preset fr2 (from the folder name, scaled from 640x480 to 5x4)"
    np.testing.assert_allclose(seq.K, intrinsics_preset("fr2", 5, 4))
    assert read_tum(named, intrinsics="fr1").intrinsics_source == "preset fr1, scaled from 640x480 to 5x4"

    bare = tmp_path / "bare"
    _three_frame_folder(bare, intrinsics=None)
    with pytest.raises(DatasetError, match=r"bare/intrinsics.txt: missing"):
        read_tum(bare)
    (bare / "intrinsics.txt").write_text("500 500 2\n")
    with pytest.raises(DatasetError, match=r"intrinsics.txt:1: expected 'fx fy cx cy'"):
        read_tum(bare)


def test_depth_scaling(tmp_path):
    _three_frame_folder(tmp_path)
    raw = np.array([[0, 1, 5000, 65535, 2500]] * 4)
    _png_depth(tmp_path / "depth" / "a.png", raw)
    np.testing.assert_allclose(read_tum(tmp_path).depth(0)[0], raw / 5000.0, rtol=1e-7)
    np.testing.assert_allclose(read_tum(tmp_path, depth_scale=1000).depth(0)[0], raw / 1000.0, rtol=1e-7)
    assert read_tum(tmp_path).depth(0)[0, 0, 0] == 0.0  # 0 = no depth


# ------------------------------------------------------------------------------------------------
# errors name the file


def _one_line(excinfo):
    msg = str(excinfo.value)
    assert "\n" not in msg
    return msg


def test_errors_name_the_file(tmp_path):
    _three_frame_folder(tmp_path)
    seq = read_tum(tmp_path)

    (tmp_path / "depth" / "d.png").unlink()
    with pytest.raises(DatasetError) as e:
        seq.depth(2)
    assert "depth/d.png: missing depth image" in _one_line(e)

    (tmp_path / "rgb" / "b.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not a png")
    with pytest.raises(DatasetError) as e:
        seq.image(1)
    assert "rgb/b.png: cannot read colour image" in _one_line(e)

    Image.fromarray(np.full((4, 5), 7, np.uint8)).save(tmp_path / "depth" / "a.png")
    with pytest.raises(DatasetError) as e:
        seq.depth(0)
    assert "depth/a.png: depth image is 8-bit" in _one_line(e)

    Image.fromarray(np.zeros((4, 5, 3), np.uint8)).save(tmp_path / "depth" / "bc.png")
    with pytest.raises(DatasetError) as e:
        seq.depth(1)
    assert "depth/bc.png: depth image has colour channels" in _one_line(e)

    _png_depth(tmp_path / "depth" / "bc.png", np.zeros((3, 5)))
    with pytest.raises(DatasetError) as e:
        seq.depth(1)
    assert "depth/bc.png: depth image is 5x3, the colour images are 5x4" in _one_line(e)

    (tmp_path / "groundtruth.txt").write_text("# gt\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n")
    with pytest.raises(DatasetError) as e:
        read_tum(tmp_path)
    assert "groundtruth.txt:3: expected 8 fields per line, got 7" in _one_line(e)

    # line numbers in the file, not in time order
    (tmp_path / "groundtruth.txt").write_text("# gt\n2.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 0\n")
    with pytest.raises(DatasetError, match=r"groundtruth.txt:3: the quaternion \(qx qy qz qw\) has zero norm"):
        read_tum(tmp_path)
    (tmp_path / "groundtruth.txt").write_text("1.0 0 0 0 0 0 0 1\n2.0 0 0 x 0 0 0 1\n")
    with pytest.raises(DatasetError, match="groundtruth.txt:2: pose entries must be numbers"):
        read_tum(tmp_path)
    (tmp_path / "groundtruth.txt").unlink()

    (tmp_path / "depth.txt").write_text("10.0 depth/a.png\nnot-a-time depth/x.png\n")
    with pytest.raises(DatasetError) as e:
        read_tum(tmp_path)
    assert "depth.txt:2: timestamp 'not-a-time' is not a number" in _one_line(e)

    (tmp_path / "depth.txt").write_text("# nothing\n")
    with pytest.raises(DatasetError, match="depth.txt: no entries in depth list file"):
        read_tum(tmp_path)

    (tmp_path / "depth.txt").write_text("99.0 depth/a.png\n")
    with pytest.raises(DatasetError, match="depth.txt: no depth timestamp within 0.02 s"):
        read_tum(tmp_path)

    (tmp_path / "rgb.txt").unlink()
    with pytest.raises(DatasetError) as e:
        read_tum(tmp_path)
    assert "rgb.txt: missing colour list file" in _one_line(e)
    # the parent of TUM folders: its subfolders named
    (tmp_path / "seq_b").mkdir()
    (tmp_path / "seq_b" / "rgb.txt").write_text("")
    with pytest.raises(DatasetError) as e:
        read_tum(tmp_path)
    assert "rgb.txt and depth.txt; its subfolder seq_b is one)" in _one_line(e)

    with pytest.raises(DatasetError, match="nowhere: no such directory"):
        read_tum(tmp_path / "nowhere")


def test_errors_give_the_first_bad_line_in_the_file(tmp_path):
    _three_frame_folder(tmp_path)
    (tmp_path / "rgb.txt").write_text("# list\n10.0 rgb/a.png\n11.0 rgb/b.png\n10.0 rgb/c.png\n")
    with pytest.raises(DatasetError) as e:
        read_tum(tmp_path)
    assert "rgb.txt:4: timestamp 10.000000 appears more than once (also on line 2)" in _one_line(e)
    # two bad poses: the one on the earlier line is reported, though its timestamp is later
    path = tmp_path / "trajectory.txt"
    path.write_text("1.0 0 0 0 0 0 0 1\n5.0 0 0 0 0 0 0 0\n2.0 0 0 0 0 0 0 0\n")
    with pytest.raises(DatasetError, match=r"trajectory.txt:2: the quaternion"):
        read_trajectory(path)


def test_check_files_finds_a_bad_file_before_any_is_decoded(tmp_path):
    _three_frame_folder(tmp_path)
    seq = read_tum(tmp_path)
    seq.check_files()  # all good
    _png_depth(tmp_path / "depth" / "bc.png", np.zeros((3, 5)))
    seq.check_files(1)  # only the first frame
    with pytest.raises(DatasetError) as e:
        seq.check_files()
    assert "depth/bc.png: depth image is 5x3, the sequence's first image is 5x4" in _one_line(e)
    Image.fromarray(np.zeros((4, 5, 3), np.uint8)).save(tmp_path / "depth" / "bc.png")
    with pytest.raises(DatasetError) as e:
        seq.check_files()
    assert "depth/bc.png: depth image has colour channels" in _one_line(e)
    (tmp_path / "rgb" / "b.png").unlink()
    with pytest.raises(DatasetError) as e:
        seq.check_files()
    assert "rgb/b.png: missing colour image" in _one_line(e)


def test_lists_with_a_byte_order_mark_are_read(tmp_path):
    _three_frame_folder(tmp_path)
    plain = read_tum(tmp_path)
    for name in ("rgb.txt", "depth.txt", "intrinsics.txt"):
        (tmp_path / name).write_bytes(b"\xef\xbb\xbf" + (tmp_path / name).read_bytes())
    seq = read_tum(tmp_path)
    assert seq.rgb_files == plain.rgb_files and np.array_equal(seq.timestamps, plain.timestamps)
    assert np.array_equal(seq.K, plain.K)


def test_writer_quantises_and_drops_out_of_range_depth(tmp_path):
    rng = np.random.default_rng(0)
    image = rng.random((3, 6, 7)).astype(np.float32)
    depth = rng.uniform(0.5, 9.0, (1, 6, 7))
    depth[0, 0, :4] = [np.nan, -1.0, 0.0, 14.0]  # beyond 65535 / 5000 = 13.1 m
    T = _poses(1)[0]
    K = np.array([[10.0, 0, 3], [0, 11, 2.5], [0, 0, 1]])
    with TUMWriter(tmp_path, K) as w:
        w.add(3.25, image, depth, T)
    seq = read_tum(tmp_path)
    np.testing.assert_allclose(seq.image(0), image, atol=0.5 / 255 + 1e-7)
    d = seq.depth(0)[0]
    assert np.all(d[0, :4] == 0)
    np.testing.assert_allclose(d[1:], depth[0, 1:], atol=0.5 / 5000 + 1e-6)
    np.testing.assert_allclose(seq.gt_poses[0], T, atol=5e-9)
    np.testing.assert_allclose(seq.K, K)


# ------------------------------------------------------------------------------------------------
# gvnn-warp render


def test_render_writes_a_sequence_the_reader_reads_back(tmp_path, capsys):
    from gvnn_warp.cli import main
    from gvnn_warp.synthetic import default_intrinsics, make_room_scene, render_rgbd, smooth_se3_trajectory

    out = tmp_path / "seq"
    assert main(["render", "--out", str(out), "--frames", "4", "--size", "40x30", "--seed", "3", "--no-progress"]) == 0
    assert "render se3: 4 frames 40x30" in capsys.readouterr().out
    seq = read_tum(out)
    assert len(seq) == 4 and seq.gt_valid.all()
    T = smooth_se3_trajectory(4, 3)
    np.testing.assert_allclose(seq.gt_poses, T, atol=5e-9)
    np.testing.assert_allclose(seq.K, default_intrinsics(40, 30))
    np.testing.assert_allclose(np.diff(seq.timestamps), 1 / 30, atol=2e-6)
    image, depth = render_rgbd(make_room_scene(3), T, default_intrinsics(40, 30), 40, 30)
    np.testing.assert_allclose(seq.image(2), image[2], atol=0.5 / 255 + 1e-6)
    np.testing.assert_allclose(seq.depth(2), depth[2], atol=0.5 / 5000 + 1e-6)

    # so3: rotation only
    out3 = tmp_path / "so3"
    assert main(["render", "--out", str(out3), "--motion", "so3", "--frames", "3", "--size", "16x16",
                 "--no-progress"]) == 0
    centres = read_tum(out3).gt_poses[:, :3, 3]
    np.testing.assert_allclose(centres, centres[:1].repeat(3, 0), atol=1e-8)


def test_render_refuses_to_overwrite_and_bad_arguments(tmp_path, capsys):
    from gvnn_warp.cli import main

    out = tmp_path / "seq"
    assert main(["render", "--out", str(out), "--frames", "2", "--size", "16x16", "--no-progress"]) == 0
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main(["render", "--out", str(out), "--frames", "2", "--size", "16x16"])
    assert e.value.code == 2 and "already holds a sequence (rgb.txt); pass --overwrite" in capsys.readouterr().err
    (out / "rgb" / "stale.png").write_bytes(b"")
    assert main(["render", "--out", str(out), "--frames", "3", "--size", "16x16", "--overwrite", "--no-progress"]) == 0
    assert len(read_tum(out)) == 3 and not (out / "rgb" / "stale.png").exists()
    (tmp_path / "file").write_text("")
    with pytest.raises(SystemExit) as e:
        main(["render", "--out", str(tmp_path / "file")])
    assert e.value.code == 2 and "exists and is not a directory" in capsys.readouterr().err
    for bad in (["--size", "10x5"], ["--frames", "0"], ["--motion", "sim3"], ["--seed", "-1"]):
        with pytest.raises(SystemExit) as e:
            main(["render", "--out", str(tmp_path / "x"), *bad])
        assert e.value.code == 2
    assert not (tmp_path / "x").exists()


def test_module_is_free_of_torch():
    code = "import sys, gvnn_warp.datasets; assert 'torch' not in sys.modules, 'torch imported'"
    run_python(code, check=True, capture_output=False)
    assert tum.DEFAULT_DEPTH_SCALE == 5000.0


def test_radtan_distortion_from_presets_intrinsics_file_and_explicit(tmp_path):
    _three_frame_folder(tmp_path)  # a pinhole intrinsics.txt: no distortion
    assert read_tum(tmp_path).dist is None
    fr1, fr2 = read_tum(tmp_path, intrinsics="fr1").dist, read_tum(tmp_path, intrinsics="fr2").dist
    np.testing.assert_array_equal(fr1, [0.2624, -0.9531, -0.0054, 0.0026, 1.1633])  # TUM's published values
    np.testing.assert_array_equal(fr2, [0.2312, -0.7849, -0.0033, -0.0001, 0.9172])
    assert read_tum(tmp_path, intrinsics="fr3").dist is None and read_tum(tmp_path, intrinsics="icl").dist is None
    seq = read_tum(tmp_path, intrinsics=(1, 2, 3, 4, 0.1, -0.2, 0.01, 0.02, 0.3))
    np.testing.assert_allclose(seq.K, [[1, 0, 3], [0, 2, 4], [0, 0, 1]])
    np.testing.assert_array_equal(seq.dist, [0.1, -0.2, 0.01, 0.02, 0.3])
    (tmp_path / "intrinsics.txt").write_text("# fx fy cx cy k1 k2 p1 p2 k3\n500 501 2 1.5 0.1 -0.2 0.01 0.02 0.3\n")
    seq = read_tum(tmp_path)
    np.testing.assert_allclose(seq.K, [[500, 0, 2], [0, 501, 1.5], [0, 0, 1]])
    np.testing.assert_array_equal(seq.dist, [0.1, -0.2, 0.01, 0.02, 0.3])
    (tmp_path / "intrinsics.txt").write_text("500 501 2 1.5 0.1 -0.2 0.01 nan 0.3\n")
    with pytest.raises(DatasetError, match="distortion coefficients must be finite"):
        read_tum(tmp_path)
    (tmp_path / "intrinsics.txt").write_text("500 501 2 1.5 0.1 -0.2\n")
    with pytest.raises(DatasetError, match=r"intrinsics.txt:1: expected 'fx fy cx cy' \(four numbers\) or"):
        read_tum(tmp_path)
    named = tmp_path / "rgbd_dataset_freiburg1_desk"  # no intrinsics.txt: the folder's preset, distortion too
    _three_frame_folder(named, intrinsics=None)
    np.testing.assert_array_equal(read_tum(named).dist, DISTORTION_PRESETS["fr1"])


def test_writer_round_trips_the_distortion(tmp_path):
    K = np.array([[50.0, 0, 2.5], [0, 51.0, 1.5], [0, 0, 1]])
    d = [0.2624, -0.9531, -0.0054, 0.0026, 1.1633]
    with TUMWriter(tmp_path, K, dist=d) as w:
        for t in (1.0, 2.0):
            w.add(t, np.zeros((3, 4, 5)), np.ones((1, 4, 5)))
    seq = read_tum(tmp_path)
    np.testing.assert_allclose(seq.K, K)
    np.testing.assert_array_equal(seq.dist, d)
