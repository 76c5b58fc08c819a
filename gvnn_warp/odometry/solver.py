"""The Levenberg-Marquardt solver of :class:`gvnn_warp.odometry.DirectAligner`: its state per
(batch size, level shapes) and, per level and pair of frames, the recorded launches of one trial.

A trial is the fused normal equations of the level
(:func:`gvnn_warp.kernels.photometric_normal_equations`) then one LM step
(:mod:`gvnn_warp.kernels.photometric.lm`: accept or reject, damping, the 6x6 solve, the pose update
and the stop test, in a Warp kernel), each replayed from launches recorded once per (level, frame
pair).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import warp as wp

from ..kernels import pyramid as _pyramid
from ..kernels.core import compat as _compat
from ..kernels.core import launch as _launch
from ..kernels.photometric import lm as _lm
from ..kernels.photometric import normal_equations_reduce as _ne_reduce
from ..kernels.photometric.pipeline import photometric_normal_equations
from ..kernels.sampling.pipeline import pixel_rays
from .frame import Frame

__all__ = ["LMState"]

_MIN_VALID_PIXELS = 24  # below this a level's system is not trusted, whatever the fraction
_LAMBDA_MAX = 1e8
_SYSTEM_CACHE = 64  # normal-equation outputs (with recorded launches) kept per batch size and frame size


class LMState:
    """Per (batch size, level shapes): the Levenberg-Marquardt state of
    :mod:`gvnn_warp.kernels.photometric.lm` (with numpy views), the intrinsics of every level, and
    per (level, reference pyramid, live pyramid) the normal equations' outputs with the launches
    that fill them and the LM step launches, recorded once: in frame-to-frame tracking pyramids are
    pooled, so the same few combinations recur, and a trial costs a few recorded launches.

    ``aligner``: the :class:`~gvnn_warp.odometry.DirectAligner` whose settings the launches use;
    ``occlusion_levels``: the occlusion test runs at the finest this many levels."""

    def __init__(self, aligner, B: int, shapes, occlusion_levels: int):
        self.aligner = aligner
        self.occlusion_levels = occlusion_levels
        self.B = B
        Ks = [_pyramid.scale_intrinsics(aligner.K, level) for level in range(len(shapes))]
        self.K = [wp.array(np.broadcast_to(Kl.astype(np.float32), (B, 3, 3)).copy(), dtype=wp.mat33f, device="cpu")
                  for Kl in Ks]
        self.f = [math.sqrt(Kl[0, 0] * Kl[1, 1]) for Kl in Ks]
        # a distorted lens: its coefficients (the same at every level) and each level's pixel rays
        self.dist = None if aligner.dist is None else wp.array(
            np.broadcast_to(aligner.dist.astype(np.float32), (B, 8)).copy(), dtype=_launch.vec8f, device="cpu")
        self.shapes = list(shapes)
        self._rays: dict[int, wp.array] = {}
        self.min_count = [max(_MIN_VALID_PIXELS, aligner.min_valid_fraction * h * w) for h, w in shapes]

        def arr(dtype, n=B):
            a = wp.zeros(n, dtype=dtype, device="cpu")
            return a, a.numpy()

        self.pose, pose_np = arr(_launch.mat34f)
        self.pose_np = pose_np.reshape(B, 3, 4)
        self.T, T_np = arr(_launch.mat34d)
        self.T_np = T_np.reshape(B, 3, 4)
        self.Tn, _ = arr(_launch.mat34d)
        self.H, _ = arr(wp.float64, B * 36)
        self.g, _ = arr(wp.float64, B * 6)
        self.zmean, self.zmean_np = arr(wp.float64)
        self.mean, self.mean_np = arr(wp.float64)
        self.count, self.count_np = arr(wp.float64)
        self.lam, _ = arr(wp.float64)
        self.step, self.step_np = arr(wp.float64)
        self.trials, self.trials_np = arr(wp.int32)
        self.active, self.active_np = arr(wp.int32)
        self.ok, self.ok_np = arr(wp.int32)
        self._runners: dict[tuple, tuple] = {}

    def runner(self, ref: Frame, live: Frame, level: int):
        """(normal-equation launches, first LM step, next LM step) for this pair at ``level``."""
        al = self.aligner
        # the live depth serves the depth term and the occlusion test (the finest occlusion_levels
        # levels; skipped without live depths)
        occlusion = al.occlusion > 0 and level < self.occlusion_levels
        use_depth = live.depths is not None and (al.depth_weight > 0 or occlusion)
        key = (level, id(ref.images[level]), id(ref.depths[level]), id(live.images[level]),
               id(live.depths[level]) if use_depth else None)
        run = self._runners.get(key)
        if run is None:
            if len(self._runners) >= _SYSTEM_CACHE:
                self._runners.pop(next(iter(self._runners)))
            run = self._runners[key] = self._make_runner(ref, live, level, use_depth)
        return run[:3]

    def _make_runner(self, ref: Frame, live: Frame, level: int, use_depth: bool):
        al = self.aligner
        args = (ref.images[level], ref.depths[level], live.images[level], self.pose, self.K[level])
        kw = {"robust": al.robust, "scale": al.scale, "depth_weight": al.depth_weight, "min_depth": al.min_depth,
              "occlusion": al.occlusion if level < self.occlusion_levels else 0.0,
              "live_depth": live.depths[level] if use_depth else None}
        if self.dist is not None:  # the level's rays, computed once per aligner state
            if level not in self._rays:
                h, w = self.shapes[level]
                self._rays[level] = pixel_rays(self.K[level], self.dist, h, w, al.model)
            kw.update(dist=self.dist, model=al.model, rays=self._rays[level])
        ne = photometric_normal_equations(*args, **kw)
        cmds = getattr(ne, "_cmds", None)
        rows = getattr(ne, "_rows", None)
        if cmds and len(cmds) == 2 and rows is not None:
            # the row kernel only: the LM step reduces its per-row sums itself (one launch fewer per trial)
            cmds = cmds[:1]
            system = [rows, rows.shape[0] // (self.B * _ne_reduce.ROW_STRIDE), _ne_reduce.ROW_STRIDE]
            step_kernel = _lm.lm_step_rows
        else:
            if not cmds:  # no recorded launches to replay: the public call with out= each time
                cmds = [functools.partial(photometric_normal_equations, *args, out=ne, **kw)]
            system = [ne.JtWJ.flatten(), ne.JtWr.flatten(), ne.cost, ne.count]
            step_kernel = _lm.lm_step
        lm = []
        for first in (1, 0):
            lm.append(_launch.wp_launch(
                step_kernel, dim=self.B,
                inputs=[*system, self.zmean, first,
                        self.min_count[level], self.f[level], al.tolerance, max(al.tolerance, al.take_step / 2**level),
                        al.lm_lambda, al.lm_up, al.lm_down,
                        _LAMBDA_MAX, al.min_decrease],
                outputs=[self.T, self.Tn, self.pose, self.H, self.g, self.mean, self.count, self.lam, self.step,
                         self.trials, self.active, self.ok],
                device="cpu", record_cmd=True,
            ))
        # the arrays stay referenced with their recorded launches: their ids (the cache key) and
        # addresses cannot be reused by other arrays while the entry exists
        keep = (ref.images[level], ref.depths[level], live.images[level], kw["live_depth"], ne, lm)
        lm_first, lm_next = (_compat.replay_function(c) for c in lm)
        return tuple(cmds), lm_first, lm_next, keep
