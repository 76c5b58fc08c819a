"""The lens models' ids, the layout of ``dist`` and the constants of the numerics (the contract is
the docstring of :mod:`gvnn_warp.kernels.geometry.lens`, which exports these names)."""

import warp as wp

PINHOLE = wp.constant(0)
RADTAN = wp.constant(1)
FISHEYE = wp.constant(2)
MODEL_IDS = {"pinhole": 0, "radtan": 1, "fisheye": 2}
N_COEFFS = {0: 0, 1: 5, 2: 4}  # coefficients each model reads from dist[0:5]
DIST_SIZE = 8
LIMIT = wp.constant(5)  # dist[LIMIT] = the domain's bound on r^2

NEWTON_ITERS = wp.constant(20)
NEWTON_STEP_TOL = wp.constant(1.0e-13)
UNDISTORT_TOL = wp.constant(1.0e-10)

mat22d = wp.types.matrix((2, 2), wp.float64)

__all__ = [
    "DIST_SIZE", "FISHEYE", "LIMIT", "MODEL_IDS", "NEWTON_ITERS", "NEWTON_STEP_TOL", "N_COEFFS", "PINHOLE", "RADTAN",
    "UNDISTORT_TOL", "mat22d",
]
