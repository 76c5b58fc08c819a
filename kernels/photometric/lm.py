"""One Levenberg-Marquardt step for rigid-pose problems, as a Warp kernel (one thread per batch item).

A coarse-to-fine aligner (``gvnn_warp.odometry.DirectAligner``) evaluates the Gauss-Newton system
``(JtWJ, JtWr, cost, count)`` of a trial pose (``photometric_normal_equations``) and then runs
:data:`lm_step`, which, without a round trip through Python:

1. compares the trial with the best pose so far by the cost per valid pixel, ``cost / count``:
   the trial is accepted if it is lower and ``count >= min_count`` (always on the first call of a
   level, ``first = 1``, if ``count >= min_count``; otherwise the item skips the level);
   ``lambda`` shrinks by ``lam_down`` on acceptance and grows by ``lam_up`` on rejection;
2. stops the item (``active = 0``) when the trial's step moved the image by less than ``tol``
   pixels, ``lambda > lam_max``, an accepted trial lowered the cost per pixel by less than
   ``min_decrease`` of it, or the system could not be solved;
3. otherwise solves ``(JtWJ + lambda diag(JtWJ) + eps) delta = -JtWr`` of the best pose (a 6x6
   Cholesky factorisation in float64) and writes the next trial pose ``exp(delta) T`` (left
   multiplied, ``delta = [omega, t]``, ``se3_exp``) into ``pose``, the float32 pose the normal
   equations read, and the step length ``f (|omega| + |t| / z)`` in pixels (``f`` the level's
   focal length, ``z`` the item's typical depth). A step shorter than ``take`` pixels (the
   aligner passes ``max(tol, take_step / 2^level)``) is taken at once, without evaluating it, and
   stops the item (it cannot change the outcome, and the evaluation would cost a full pass over
   the level).

State arrays (length B): ``T`` and ``Tn`` (3x4 float64: best and trial pose), ``H`` (B * 36) and
``g`` (B * 6) float64 (the best pose's system), ``mean``, ``count``, ``lam``, ``step`` float64,
``trials``, ``active``, ``ok`` int32. No torch; no gradients.
"""

from __future__ import annotations

import warp as wp

from ..core.launch import mat34d, mat34f
from ..geometry import lie

wp.set_module_options({"enable_backward": False})

__all__ = ["lm_step", "lm_step_rows", "solve_spd6"]

vec6d = wp.types.vector(length=6, dtype=wp.float64)
mat66d = wp.types.matrix(shape=(6, 6), dtype=wp.float64)
vec29d = wp.types.vector(length=29, dtype=wp.float64)


@wp.func
def solve_spd6(A: mat66d, b: vec6d):
    """x with A x = b for a symmetric positive definite 6x6 A (Cholesky); returns (x, ok), ok False
    (and x = 0) if A is not positive definite or not finite."""
    L = mat66d()
    ok = bool(True)  # noqa: UP018 - a typed variable Warp may reassign inside the loops
    for j in range(6):
        s = A[j, j]
        for k in range(j):
            s = s - L[j, k] * L[j, k]
        if not (s > wp.float64(0.0)) or not wp.isfinite(s):
            ok = False
            s = wp.float64(1.0)
        d = wp.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, 6):
            t = A[i, j]
            for k in range(j):
                t = t - L[i, k] * L[j, k]
            L[i, j] = t / d
    y = vec6d()
    for i in range(6):
        t = b[i]
        for k in range(i):
            t = t - L[i, k] * y[k]
        y[i] = t / L[i, i]
    x = vec6d()
    for ii in range(6):
        i = 5 - ii
        t = y[i]
        for k in range(i + 1, 6):
            t = t - L[k, i] * x[k]
        x[i] = t / L[i, i]
    if not ok:
        x = vec6d()
    return x, ok


@wp.func
def _lm_update(
    b: int,
    JtWJ: mat66d,
    JtWr: vec6d,
    cost_in: wp.float64,
    n: wp.float64,
    zmean: wp.array(dtype=wp.float64),
    first: int,
    min_count: wp.float64,
    f: wp.float64,
    tol: wp.float64,
    take: wp.float64,
    lam0: wp.float64,
    lam_up: wp.float64,
    lam_down: wp.float64,
    lam_max: wp.float64,
    min_decrease: wp.float64,
    T: wp.array(dtype=mat34d),
    Tn: wp.array(dtype=mat34d),
    pose: wp.array(dtype=mat34f),
    H: wp.array(dtype=wp.float64),
    g: wp.array(dtype=wp.float64),
    mean: wp.array(dtype=wp.float64),
    count: wp.array(dtype=wp.float64),
    lam: wp.array(dtype=wp.float64),
    step: wp.array(dtype=wp.float64),
    trials: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    ok: wp.array(dtype=wp.int32),
):
    """The step of batch item b given its trial's system (see the module docstring)."""
    m = cost_in / wp.max(n, wp.float64(1.0))
    accept = bool(False)  # noqa: UP018
    go = bool(True)  # noqa: UP018 (Warp funcs return once: a flag instead of early returns)
    if first != 0:
        lam[b] = lam0
        trials[b] = 0
        step[b] = wp.float64(1.0e30)
        good = n >= min_count and wp.isfinite(m)
        ok[b] = wp.where(good, 1, 0)
        active[b] = wp.where(good, 1, 0)
        accept = good
    else:
        if active[b] == 0:
            go = False
        else:
            trials[b] = trials[b] + 1
            accept = n >= min_count and m < mean[b]
            small = False
            if accept:
                lam[b] = lam[b] * lam_down
                small = mean[b] - m < min_decrease * mean[b]
            else:
                lam[b] = lam[b] * lam_up
            if step[b] < tol or lam[b] > lam_max or small:
                active[b] = 0
    if go and accept:
        for i in range(6):
            for j in range(6):
                H[b * 36 + i * 6 + j] = JtWJ[i, j]
            g[b * 6 + i] = JtWr[i]
        mean[b] = m
        count[b] = n
        if first == 0:
            T[b] = Tn[b]
    if go and active[b] != 0:
        A = mat66d()
        r = vec6d()
        trace = wp.float64(0.0)
        for i in range(6):
            trace = trace + H[b * 36 + i * 7]
        eps = wp.float64(1.0e-9) * (wp.float64(1.0) + trace)
        for i in range(6):
            for j in range(6):
                A[i, j] = H[b * 36 + i * 6 + j]
            A[i, i] = A[i, i] * (wp.float64(1.0) + lam[b]) + eps
            r[i] = -g[b * 6 + i]
        delta, solved = solve_spd6(A, r)
        if not solved:
            active[b] = 0
        else:
            w = wp.vec3d(delta[0], delta[1], delta[2])
            t = wp.vec3d(delta[3], delta[4], delta[5])
            E = lie.se3_exp(w, t)
            Re = lie.pose_rotation(E)
            Tb = T[b]
            P = lie.pose_from_rt(Re * lie.pose_rotation(Tb), Re * lie.pose_translation(Tb) + lie.pose_translation(E))
            Tn[b] = P
            pose[b] = mat34f(
                wp.float32(P[0, 0]), wp.float32(P[0, 1]), wp.float32(P[0, 2]), wp.float32(P[0, 3]),
                wp.float32(P[1, 0]), wp.float32(P[1, 1]), wp.float32(P[1, 2]), wp.float32(P[1, 3]),
                wp.float32(P[2, 0]), wp.float32(P[2, 1]), wp.float32(P[2, 2]), wp.float32(P[2, 3]),
            )
            step[b] = f * (wp.length(w) + wp.length(t) / zmean[b])
            if step[b] < take:
                # a step this small cannot change the outcome: taken without another evaluation
                T[b] = P
                active[b] = 0


@wp.kernel
def _lm_step(
    JtWJ: wp.array(dtype=wp.float32),
    JtWr: wp.array(dtype=wp.float32),
    cost_in: wp.array(dtype=wp.float32),
    count_in: wp.array(dtype=wp.float32),
    zmean: wp.array(dtype=wp.float64),
    first: int,
    min_count: wp.float64,
    f: wp.float64,
    tol: wp.float64,
    take: wp.float64,
    lam0: wp.float64,
    lam_up: wp.float64,
    lam_down: wp.float64,
    lam_max: wp.float64,
    min_decrease: wp.float64,
    T: wp.array(dtype=mat34d),
    Tn: wp.array(dtype=mat34d),
    pose: wp.array(dtype=mat34f),
    H: wp.array(dtype=wp.float64),
    g: wp.array(dtype=wp.float64),
    mean: wp.array(dtype=wp.float64),
    count: wp.array(dtype=wp.float64),
    lam: wp.array(dtype=wp.float64),
    step: wp.array(dtype=wp.float64),
    trials: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    ok: wp.array(dtype=wp.int32),
):
    b = wp.tid()
    A = mat66d()
    r = vec6d()
    for i in range(6):
        for j in range(6):
            A[i, j] = wp.float64(JtWJ[b * 36 + i * 6 + j])
        r[i] = wp.float64(JtWr[b * 6 + i])
    _lm_update(b, A, r, wp.float64(cost_in[b]), wp.float64(count_in[b]), zmean, first, min_count, f, tol, take,
               lam0, lam_up, lam_down, lam_max, min_decrease, T, Tn, pose, H, g, mean, count, lam, step, trials,
               active, ok)


@wp.kernel
def _lm_step_rows(
    rows: wp.array(dtype=wp.float64),
    n_rows: int,
    row_stride: int,
    zmean: wp.array(dtype=wp.float64),
    first: int,
    min_count: wp.float64,
    f: wp.float64,
    tol: wp.float64,
    take: wp.float64,
    lam0: wp.float64,
    lam_up: wp.float64,
    lam_down: wp.float64,
    lam_max: wp.float64,
    min_decrease: wp.float64,
    T: wp.array(dtype=mat34d),
    Tn: wp.array(dtype=mat34d),
    pose: wp.array(dtype=mat34f),
    H: wp.array(dtype=wp.float64),
    g: wp.array(dtype=wp.float64),
    mean: wp.array(dtype=wp.float64),
    count: wp.array(dtype=wp.float64),
    lam: wp.array(dtype=wp.float64),
    step: wp.array(dtype=wp.float64),
    trials: wp.array(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    ok: wp.array(dtype=wp.int32),
):
    # _lm_step reading the normal equations' per-row sums (``rows``: n_rows rows of row_stride
    # slots per batch item; slots 0-20 the upper triangle of JtWJ row by row, 21-26 JtWr, 27 cost,
    # 28 count) and reducing them itself, in row order and rounded to float32 as the normal
    # equations' own reduction does: the same values, one launch fewer per trial
    b = wp.tid()
    if first == 0 and active[b] == 0:
        return
    o = b * n_rows * row_stride
    sums = vec29d()
    for h in range(n_rows):
        for k in range(29):
            sums[k] = sums[k] + rows[o + h * row_stride + k]
    A = mat66d()
    k = int(0)  # noqa: UP018
    for i in range(6):
        for j in range(i, 6):
            v = wp.float64(wp.float32(sums[k]))
            A[i, j] = v
            A[j, i] = v
            k += 1
    r = vec6d()
    for i in range(6):
        r[i] = wp.float64(wp.float32(sums[21 + i]))
    _lm_update(b, A, r, wp.float64(wp.float32(sums[27])), wp.float64(wp.float32(sums[28])), zmean, first, min_count,
               f, tol, take, lam0, lam_up, lam_down, lam_max, min_decrease, T, Tn, pose, H, g, mean, count, lam, step,
               trials, active, ok)


#: the kernel (launch with dim = B on the CPU); arguments as in the module docstring
lm_step = _lm_step
#: the same step on the normal equations' per-row sums (``NormalEquations._rows``), reduced in the kernel
lm_step_rows = _lm_step_rows
