"""TUM RGB-D / ICL-NUIM sequence folders and TUM trajectory files (numpy + Pillow; no torch).

A sequence folder holds (the format of the TUM RGB-D benchmark, also used by ICL-NUIM's
"TUM-compatible" downloads)::

    rgb.txt           timestamp filename        (lines starting with # are comments)
    depth.txt         timestamp filename
    groundtruth.txt   timestamp tx ty tz qx qy qz qw    (optional; T_world_cam, metres)
    intrinsics.txt    fx fy cx cy [k1 k2 p1 p2 k3]      (optional; not part of TUM's own format;
                                                        the 5 radial-tangential coefficients of
                                                        OpenCV's model when the images are
                                                        distorted, none for a pinhole)
    rgb/*.png         8-bit colour images
    depth/*.png       16-bit single-channel depth, metres * depth_scale (5000), 0 = no depth

How frames are formed (the rules of TUM's ``associate.py`` and of ``evo``):

- Colour and depth images are associated by timestamp: every pair closer than ``max_difference``
  (0.02 s) is a candidate, candidates are taken greedily by smallest time difference (ties by the
  earlier stamps), and each stamp is used at most once. The frames are the associated pairs in
  colour-time order; a frame's timestamp is its colour image's.
- Read ``colour_only`` (monocular video: depth learnt from colour, or tracked with predicted
  depth), every colour image listed is a frame, and ``depth.txt`` need not exist.
- A frame's ground-truth pose is *interpolated* at its timestamp: a ground-truth stamp must lie
  closer than ``max_difference`` (otherwise the frame has no ground truth: NaN pose,
  ``gt_valid`` False), and the pose is interpolated between the two ground-truth samples that
  bracket the frame's time (translation linearly, rotation by slerp) - the way ``evo``'s
  ``SyncMethod.interpolation`` resamples a trajectory - or taken from the nearest sample when the
  frame lies before the first or after the last.

Poses follow the project's conventions (docs/conventions.md): ``T_world_cam`` (4, 4) float64 maps
camera points into the world; TUM's quaternions are (qx, qy, qz, qw) in the files, Hamilton,
the rotation of ``T_world_cam``.

Every problem with the files raises :class:`DatasetError` (a ``ValueError``) with a one-line
message that names the file.

This module holds the sequences (:class:`TUMSequence`, :func:`read_tum`, :class:`TUMWriter`) and
exports the names of the parts they are made of: trajectory files, quaternions, association and
interpolation (:mod:`.trajectory`), intrinsics presets and files (:mod:`.intrinsics`), image files
(:mod:`.images`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

# the readers' parts, each in its module; gvnn_warp.datasets.tum exports every name it always has
from .errors import DatasetError
from .images import (
    DEFAULT_DEPTH_SCALE,
    check_depth_mode,
    check_rgb_mode,
    open_image,
    read_depth,
    read_rgb,
    to_gray,
    write_depth,
    write_rgb,
)
from .intrinsics import DISTORTION_PRESETS, INTRINSICS_PRESETS, intrinsics_preset, resolve_intrinsics
from .trajectory import (
    DEFAULT_MAX_DIFFERENCE,
    associate,
    interpolate_poses,
    matrix_to_quaternion_xyzw,
    quaternion_xyzw_to_matrix,
    read_table,
    read_trajectory,
    write_trajectory,
)

__all__ = [
    "DEFAULT_DEPTH_SCALE",
    "DISTORTION_PRESETS",
    "INTRINSICS_PRESETS",
    "DatasetError",
    "TUMSequence",
    "TUMWriter",
    "associate",
    "intrinsics_preset",
    "matrix_to_quaternion_xyzw",
    "quaternion_xyzw_to_matrix",
    "read_depth",
    "read_rgb",
    "read_trajectory",
    "read_tum",
    "write_trajectory",
]


# ------------------------------------------------------------------------------------------------
# Sequences


@dataclass
class Frame:
    """One associated frame of a :class:`TUMSequence`."""

    index: int
    timestamp: float
    image: np.ndarray  #: float32 (3, H, W) in [0, 1], or (1, H, W) grey
    depth: np.ndarray  #: float32 (1, H, W) metres, 0 = no depth
    pose: np.ndarray | None  #: T_world_cam (4, 4) float64, None without ground truth


@dataclass
class TUMSequence:
    """A TUM-format RGB-D sequence (see the module docstring); made by :func:`read_tum`.

    ``len(seq)`` frames; ``seq[i]`` / :meth:`frame` read frame ``i`` (colour or grey image and
    depth); :meth:`image` and :meth:`depth` read one of them. Images are read from disk on every
    access (nothing is cached).

    Attributes:
        root: the folder.
        K: (3, 3) float64 intrinsics; ``intrinsics_source`` says where they came from, and
            ``intrinsics_override`` (None, or a sentence) that given intrinsics replaced the
            folder's ``intrinsics.txt`` and whether it differs.
        dist: (5,) float64 radial-tangential distortion (k1, k2, p1, p2, k3) of the images, or
            None (a pinhole: undistorted images); from the same source as K.
        width, height: image size (from the first colour image).
        timestamps: (N,) float64 colour timestamps of the frames.
        depth_timestamps: (N,) float64 timestamps of their depth images (empty when read
            ``colour_only``).
        rgb_files, depth_files: the N image paths (no depth files when read ``colour_only``).
        depth_scale: raw depth units per metre.
        gt_poses: (N, 4, 4) float64 ``T_world_cam`` interpolated at the frames' timestamps (NaN
            where ``gt_valid`` is False), or None without ``groundtruth.txt``.
        gt_valid: (N,) bool, or None.
        gt_timestamps, gt_raw_poses: the ground-truth file as read (for evaluation tools).
        listed: the numbers of colour and depth images ``rgb.txt`` and ``depth.txt`` list (those
            the association left without a partner are not frames); ``max_difference``: its seconds.
        colour_only: read without depth (:func:`read_tum`'s ``colour_only``): every colour image
            listed is a frame, and :meth:`depth` refuses.
    """

    root: Path
    K: np.ndarray
    intrinsics_source: str
    width: int
    height: int
    timestamps: np.ndarray
    depth_timestamps: np.ndarray
    rgb_files: list[Path]
    depth_files: list[Path]
    depth_scale: float
    gt_poses: np.ndarray | None = None
    gt_valid: np.ndarray | None = None
    gt_timestamps: np.ndarray | None = None
    gt_raw_poses: np.ndarray | None = field(default=None, repr=False)
    dist: np.ndarray | None = None
    intrinsics_override: str | None = None
    listed: tuple[int, int] = (0, 0)
    max_difference: float = DEFAULT_MAX_DIFFERENCE
    colour_only: bool = False

    def __len__(self) -> int:
        return len(self.rgb_files)

    def _check(self, i: int) -> int:
        if not -len(self) <= i < len(self):
            raise IndexError(f"frame {i} out of range for a sequence of {len(self)} frames")
        return i % len(self)

    def image(self, i: int, gray: bool = False) -> np.ndarray:
        """Frame ``i``'s colour image, float32 (3, H, W) in [0, 1], or its grey (BT.601 luma) image
        (1, H, W) when ``gray``."""
        path = self.rgb_files[self._check(i)]
        rgb = read_rgb(path)
        if rgb.shape[1:] != (self.height, self.width):
            raise DatasetError(f"{path}: image is {rgb.shape[2]}x{rgb.shape[1]}, "
                               f"the sequence's first image is {self.width}x{self.height}")
        return to_gray(rgb) if gray else rgb

    def depth(self, i: int) -> np.ndarray:
        """Frame ``i``'s depth, float32 (1, H, W) metres (0 = no depth)."""
        i = self._check(i)
        if self.colour_only:
            raise DatasetError(f"{self.root}: read without its depth (colour_only): frame {i} has no depth image")
        path = self.depth_files[i]
        d = read_depth(path, self.depth_scale)
        if d.shape[1:] != (self.height, self.width):
            raise DatasetError(f"{path}: depth image is {d.shape[2]}x{d.shape[1]}, "
                               f"the colour images are {self.width}x{self.height}")
        return d

    def check_files(self, n: int | None = None) -> None:
        """Check the first ``n`` frames' image files (default: all) without decoding them: each
        exists and can be opened, has a colour / 16-bit depth format and the sequence's size.
        Raises DatasetError naming the first bad file, so that a long run does not stop at it
        (Pillow reads only the headers: ~0.1 ms per file)."""
        for k in range(len(self) if n is None else min(n, len(self))):
            files = [(self.rgb_files[k], "colour", check_rgb_mode)]
            if not self.colour_only:
                files.append((self.depth_files[k], "depth", check_depth_mode))
            for path, what, check in files:
                with open_image(path, what, load=False) as im:
                    mode, size = im.mode, im.size
                check(path, mode)
                if size != (self.width, self.height):
                    raise DatasetError(f"{path}: {what} image is {size[0]}x{size[1]}, the sequence's first image is "
                                       f"{self.width}x{self.height}")

    def pose(self, i: int) -> np.ndarray | None:
        """Frame ``i``'s ground-truth ``T_world_cam`` (4, 4), or None if it has none."""
        i = self._check(i)
        if self.gt_poses is None or not self.gt_valid[i]:
            return None
        return self.gt_poses[i].copy()

    def frame(self, i: int, gray: bool = False) -> Frame:
        i = self._check(i)
        return Frame(i, float(self.timestamps[i]), self.image(i, gray), self.depth(i), self.pose(i))

    def __getitem__(self, i: int) -> Frame:
        return self.frame(i)


def read_tum(
    root: str | Path,
    *,
    intrinsics: str | np.ndarray | tuple | list | None = None,
    depth_scale: float = DEFAULT_DEPTH_SCALE,
    max_difference: float = DEFAULT_MAX_DIFFERENCE,
    colour_only: bool = False,
) -> TUMSequence:
    """Open a TUM RGB-D / ICL-NUIM style folder (see the module docstring for the rules).

    Args:
        root: the folder with ``rgb.txt`` and ``depth.txt`` (``rgb.txt`` alone with ``colour_only``).
        intrinsics: a preset name (``fr1``, ``fr2``, ``fr3``, ``icl``; fr1 and fr2 with their
            published distortion, :data:`DISTORTION_PRESETS`), ``(fx, fy, cx, cy)``, ``(fx, fy,
            cx, cy, k1, k2, p1, p2, k3)`` (with radial-tangential distortion) or a (3, 3) ``K``;
            overrides ``intrinsics.txt``. None: ``root/intrinsics.txt`` if present, else the
            Freiburg preset named by the folder (``rgbd_dataset_freiburg2_*`` -> fr2), else an
            error. The result's ``K`` and ``dist`` (None for a pinhole) come from it.
        depth_scale: raw depth units per metre (5000 for TUM and ICL-NUIM).
        max_difference: seconds; colour/depth association and ground-truth matching.
        colour_only: a video without depth (monocular depth and tracking): every colour image
            ``rgb.txt`` lists is a frame, ``depth.txt`` is not read (nor need it exist), and the
            sequence has no depth (:meth:`TUMSequence.depth` refuses).

    Only the first colour image is opened here (for the size); the others when read.
    """
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"{root}: not a directory" if root.exists() else f"{root}: no such directory")
    if not (math.isfinite(depth_scale) and depth_scale > 0):
        raise ValueError(f"read_tum: depth_scale must be a positive number, got {depth_scale}")
    if not (math.isfinite(max_difference) and max_difference > 0):
        raise ValueError(f"read_tum: max_difference must be a positive number, got {max_difference}")

    if not (root / "rgb.txt").exists():  # (the folder itself is likely not a TUM folder: say what one holds)
        inside = sorted(p.parent.name for p in root.glob("*/rgb.txt"))
        hint = ""
        if len(inside) == 1:
            hint = f"; its subfolder {inside[0]} is one"
        elif inside:
            hint = f"; its subfolders {', '.join(inside[:3])}{', ...' if len(inside) > 3 else ''} are"
        raise DatasetError(f"{root / 'rgb.txt'}: missing colour list file (a TUM RGB-D folder lists its images in "
                           f"rgb.txt and depth.txt{hint})")
    rgb_times, rgb_rows, _ = read_table(root / "rgb.txt", 2, "colour list")
    if colour_only:  # (every colour image a frame, in colour-time order as associated frames are)
        depth_rows, frames, depth_stamps, depth_files = [], np.argsort(rgb_times, kind="stable"), np.zeros(0), []
    else:
        depth_times, depth_rows, _ = read_table(root / "depth.txt", 2, "depth list")
        pairs = associate(rgb_times, depth_times, max_difference)
        if pairs.shape[0] == 0:
            raise DatasetError(f"{root / 'depth.txt'}: no depth timestamp within {max_difference} s "
                               f"of any colour timestamp in {root / 'rgb.txt'}")
        frames, depth_stamps = pairs[:, 0], depth_times[pairs[:, 1]]
        depth_files = [root / depth_rows[j][0] for j in pairs[:, 1]]
    rgb_files = [root / rgb_rows[i][0] for i in frames]
    first = read_rgb(rgb_files[0])
    height, width = first.shape[1:]

    K, source, dist, override = resolve_intrinsics(root, intrinsics, width, height)
    seq = TUMSequence(
        root=root, K=K, intrinsics_source=source, intrinsics_override=override, width=width, height=height,
        dist=dist,
        timestamps=rgb_times[frames], depth_timestamps=depth_stamps,
        rgb_files=rgb_files, depth_files=depth_files, depth_scale=float(depth_scale),
        listed=(len(rgb_rows), len(depth_rows)), max_difference=float(max_difference), colour_only=bool(colour_only),
    )
    gt_path = root / "groundtruth.txt"
    if gt_path.exists():
        seq.gt_timestamps, seq.gt_raw_poses = read_trajectory(gt_path)
        seq.gt_poses, seq.gt_valid = interpolate_poses(seq.gt_timestamps, seq.gt_raw_poses, seq.timestamps,
                                                       max_difference)
    return seq



# ------------------------------------------------------------------------------------------------
# Writing sequences


class TUMWriter:
    """Write an RGB-D sequence as a TUM folder, frame by frame.

    ``root/rgb/<stamp>.png`` (8-bit RGB), ``root/depth/<stamp>.png`` (16-bit, metres *
    ``depth_scale`` rounded; depths that are not finite, not positive, or beyond 65535 /
    ``depth_scale`` metres are written as 0 = no depth), and on :meth:`close` (or leaving a
    ``with`` block without an error) ``rgb.txt``, ``depth.txt``, ``groundtruth.txt`` (if poses
    were given) and ``intrinsics.txt`` (with ``dist``, the images' radial-tangential
    coefficients (k1, k2, p1, p2, k3), after fx fy cx cy).
    """

    def __init__(self, root: str | Path, K: np.ndarray, depth_scale: float = DEFAULT_DEPTH_SCALE,
                 comment: str = "written by gvnn_warp.datasets.tum.TUMWriter", dist=None):
        self.root = Path(root)
        self.K = np.asarray(K, dtype=np.float64)
        self.dist = None if dist is None else np.asarray(dist, dtype=np.float64).reshape(5)
        self.depth_scale = float(depth_scale)
        self.comment = comment
        self._stamps: list[float] = []
        self._poses: list[np.ndarray] = []
        (self.root / "rgb").mkdir(parents=True, exist_ok=True)
        (self.root / "depth").mkdir(parents=True, exist_ok=True)

    def add(self, timestamp: float, image: np.ndarray, depth: np.ndarray, pose: np.ndarray | None = None) -> None:
        """Write one frame: ``image`` float (3, H, W) in [0, 1], ``depth`` (1, H, W) or (H, W) metres,
        ``pose`` ``T_world_cam`` (4, 4) (give it for all frames or none)."""
        image = np.asarray(image)
        depth = np.asarray(depth, dtype=np.float64).reshape(image.shape[1:])
        name = f"{timestamp:.6f}.png"
        write_rgb(self.root / "rgb" / name, image)
        write_depth(self.root / "depth" / name, depth, self.depth_scale)
        self._stamps.append(float(timestamp))
        if pose is not None:
            self._poses.append(np.asarray(pose, dtype=np.float64))

    def close(self) -> None:
        if self._poses and len(self._poses) != len(self._stamps):
            raise ValueError("TUMWriter: give a pose for every frame or for none")
        names = [f"{t:.6f}" for t in self._stamps]
        for kind in ("rgb", "depth"):
            lines = [f"# {self.comment}", f"# {kind} images", "# timestamp filename"]
            lines += [f"{n} {kind}/{n}.png" for n in names]
            (self.root / f"{kind}.txt").write_text("\n".join(lines) + "\n")
        if self._poses:
            write_trajectory(self.root / "groundtruth.txt", np.array(self._stamps), np.stack(self._poses),
                             comment=f"{self.comment}\nground-truth trajectory T_world_cam")
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        if self.dist is None:
            (self.root / "intrinsics.txt").write_text(f"# fx fy cx cy (pixel centres at integer coordinates)\n"
                                                      f"{fx:.9g} {fy:.9g} {cx:.9g} {cy:.9g}\n")
        else:
            k = " ".join(f"{v:.9g}" for v in self.dist)
            (self.root / "intrinsics.txt").write_text(
                "# fx fy cx cy k1 k2 p1 p2 k3 (pixel centres at integer coordinates; radial-tangential distortion)\n"
                f"{fx:.9g} {fy:.9g} {cx:.9g} {cy:.9g} {k}\n")

    def __enter__(self) -> TUMWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
