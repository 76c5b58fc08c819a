"""The multi-core launch path (gvnn_warp.kernels.core.launch): results are bitwise identical for every
thread count, forward and all gradients, including odd sizes and batch size 1 (where backward
reductions are cut into fixed pieces with partial buffers). No timing assertions here; see
benchmarks/ for speed."""

import os
from typing import Any

import pytest
import torch
import warp as wp
from gvnn_warp.kernels.core import launch as L
from gvnn_warp.kernels.core import threads
from gvnn_warp.kernels.geometry import kernels as geometry_kernels
from gvnn_warp.kernels.sampling import kernels as sampling_kernels
from processes import run_python
from refs import gradients_of, weighted_backward

import gvnn_warp as G

THREADS = (2, 3, 4)


# where threaded launches run: torch's OpenMP team (the default with torch) or gvnn_warp's Python threads
G.so3_exp(torch.zeros(1, 3))  # loads the torch bridge, which picks the backend
DEFAULT_BACKEND = L.thread_backend()
BACKENDS = [DEFAULT_BACKEND, "python"] if DEFAULT_BACKEND != "python" else ["python"]


# Tests whose result cannot depend on the backend set in this process (they run their own
# subprocess, or go through every backend themselves) run once: a direct parametrization of
# "backend" overrides the autouse fixture's parameters.
once = pytest.mark.parametrize("backend", [DEFAULT_BACKEND])


def use_backend(name):
    L.use_openmp(name.removeprefix("openmp:") if name.startswith("openmp:") else None)


@pytest.fixture(autouse=True, params=BACKENDS)
def backend(request):
    """Every test here runs on each backend; results must not depend on it."""
    use_backend(request.param)
    yield request.param
    use_backend(DEFAULT_BACKEND)
    L.set_num_threads(None)


@pytest.fixture
def count_chunks(monkeypatch):
    """Counts the kernel launches (chunks) each op call makes."""
    calls = []
    real = L._launch_one

    def counting(*args, **kwargs):
        calls.append(args[0].key)
        return real(*args, **kwargs)

    monkeypatch.setattr(L, "_launch_one", counting)
    return calls


def run_with_threads(n, fn, *inputs):
    """fn(*leaves) -> tensors; returns the outputs and the gradients of every leaf, with n threads."""
    L.set_num_threads(n)
    leaves = [t.detach().clone().requires_grad_(t.is_floating_point()) for t in inputs]
    outs = weighted_backward(fn(*leaves), seed=123)
    return [o.detach() for o in outs], [t.grad for t in leaves if t.requires_grad]


def assert_bitwise_equal_across_threads(fn, *inputs):
    ref_out, ref_grads = run_with_threads(1, fn, *inputs)
    assert all(torch.isfinite(g).all() for g in ref_grads)
    for n in THREADS:
        out, grads = run_with_threads(n, fn, *inputs)
        for a, b in zip(out, ref_out):
            assert torch.equal(a, b), f"output differs with {n} threads"
        for k, (a, b) in enumerate(zip(grads, ref_grads)):
            assert torch.equal(a, b), f"gradient {k} differs with {n} threads (max {(a - b).abs().max()})"


def wfd_inputs(B, C, H, W, dtype, seed=0, motion=0.05):
    g = torch.Generator().manual_seed(seed)
    image = torch.rand(B, C, H, W, generator=g, dtype=dtype)
    depth = torch.rand(B, 1, H, W, generator=g, dtype=dtype) * 2 + 1
    depth[:, :, 0, :3] = torch.tensor([0.0, float("nan"), -1.0], dtype=dtype)  # some invalid depths
    pose = G.se3_to_matrix(torch.randn(B, 6, generator=g, dtype=dtype) * motion)
    K = torch.tensor([[0.9 * W, 0.0, (W - 1) / 2], [0.0, 0.9 * W, (H - 1) / 2], [0.0, 0.0, 1.0]], dtype=dtype)
    return image, depth, pose, K.expand(B, 3, 3).contiguous()


# B=1 and 3 cut batch items into pieces with partial gradient buffers; B=5 splits by batch item
@pytest.mark.parametrize("B,C,H,W", [(1, 3, 193, 257), (3, 2, 61, 77), (5, 1, 53, 91), (1, 5, 9, 11)])
@pytest.mark.parametrize("padding_mode", ["zeros", "border"])
def test_warp_frame_depth_bitwise_equal(B, C, H, W, padding_mode, dtype):
    def fn(image, depth, pose, K):
        return G.warp_frame_depth(image, depth, pose, K, padding_mode=padding_mode)

    assert_bitwise_equal_across_threads(fn, *wfd_inputs(B, C, H, W, dtype))


@pytest.mark.parametrize("B", [1, 3])
@pytest.mark.parametrize("wanted", [{1, 2}, {0}, {2}])
def test_wanted_gradients_bitwise_equal(B, wanted, dtype):
    """Gradients not asked for are not computed (null adjoint arrays, no partial buffers for them):
    the wanted ones equal those of a single-threaded call that wants all three."""
    image, depth, pose, K = wfd_inputs(B, 3, 97, 131, dtype, seed=4)

    def op(image, depth, pose):
        return G.warp_frame_depth(image, depth, pose, K)[0]

    L.set_num_threads(1)
    ref = gradients_of(op, (image, depth, pose), {0, 1, 2})
    for n in THREADS:
        L.set_num_threads(n)
        got = gradients_of(op, (image, depth, pose), wanted)
        for k in range(3):
            assert (got[k] is None) if k not in wanted else torch.equal(got[k], ref[k]), (n, k)


# the last two have h w % 8 == 0: the 8-lane forward kernel
@pytest.mark.parametrize(
    "B,C,H,W,h,w",
    [(1, 3, 67, 89, 131, 151), (3, 2, 40, 50, 97, 101), (6, 1, 17, 19, 13, 29), (1, 5, 61, 83, 96, 152),
     (3, 3, 40, 50, 88, 104)],
)
@pytest.mark.parametrize("align_corners", [False, True])
@pytest.mark.parametrize("padding_mode", ["zeros", "border"])
def test_bilinear_sample_bitwise_equal(B, C, H, W, h, w, align_corners, padding_mode, dtype):
    g = torch.Generator().manual_seed(1)
    image = torch.rand(B, C, H, W, generator=g, dtype=dtype)
    grid = torch.rand(B, h, w, 2, generator=g, dtype=dtype) * 2.4 - 1.2

    def fn(image, grid):
        return G.bilinear_sample(image, grid, align_corners=align_corners, padding_mode=padding_mode)

    assert_bitwise_equal_across_threads(fn, image, grid)


@pytest.mark.parametrize("n", [1, 7, 40_001, 100_003])
def test_so3_exp_bitwise_equal(n, dtype):
    g = torch.Generator().manual_seed(2)
    omega = torch.randn(n, 3, generator=g, dtype=dtype)
    omega[: min(n, 3)] *= 1e-3  # small-angle branch too
    assert_bitwise_equal_across_threads(G.so3_exp, omega)


@pytest.mark.parametrize("B", [1, 3])
def test_camera_layers_bitwise_equal(B, dtype):
    # depth_to_points / project_points accumulate K gradients ("any" scope: partial buffers)
    image, depth, pose, K = wfd_inputs(B, 1, 256, 256, dtype, seed=3)
    depth = depth.nan_to_num(1.0).clamp(min=1.0)

    def fn(depth, pose, K):
        points = G.transform_points(pose, G.depth_to_points(depth, K))
        return G.project_points(points, K)

    assert_bitwise_equal_across_threads(fn, depth, pose, K)


def test_large_launches_are_split(count_chunks):
    L.set_num_threads(2)
    image, depth, pose, K = wfd_inputs(1, 3, 193, 257, torch.float32)
    leaves = [t.requires_grad_() for t in (image, depth, pose, K)]
    out, _ = G.warp_frame_depth(*leaves)
    assert len(count_chunks) > 1  # forward split over rows
    count_chunks.clear()
    out.sum().backward()
    assert len(count_chunks) > 1  # backward cut into pieces (B = 1)
    count_chunks.clear()
    G.so3_exp(torch.randn(100_000, 3))
    assert len(count_chunks) > 1
    # small launches stay on one chunk
    small = wfd_inputs(1, 1, 8, 8, torch.float32)
    count_chunks.clear()
    G.warp_frame_depth(*small)
    assert len(count_chunks) == 1


@wp.kernel
def _scale(offset: int, x: wp.array(dtype=Any), L: int, out: wp.array(dtype=Any)):
    i = wp.tid() + offset
    out[i] = x[i] * x.dtype(2.0)


@wp.kernel
def _scale_blocks(offset: int, x: wp.array(dtype=Any), L: int, out: wp.array(dtype=Any)):
    k = wp.tid() + offset  # elements [k L, (k + 1) L) of _scale
    for j in range(L):
        i = k * L + j
        out[i] = x[i] * x.dtype(2.0)


def test_blocked_variant_is_used(count_chunks):
    """A kernel declaring a blocked twin (set_parallel(blocked=(fk, L))) is launched as the twin
    over n / L elements where L divides n, as itself otherwise; same results."""
    blocks = L.FloatKernel(_scale_blocks, x="scalar", out="scalar").set_parallel(scopes={"x": "element"})
    fk = L.FloatKernel(_scale, x="scalar", out="scalar").set_parallel(
        scopes={"x": "element"}, blocked=(blocks, lambda a: a["L"])
    )
    L.set_num_threads(1)
    x = torch.rand(60, dtype=torch.float64)
    for block, expect in ((6, "_scale_blocks"), (7, "_scale")):
        out = torch.empty_like(x)
        count_chunks.clear()
        L.launch(fk[wp.float64], 60, [wp.from_torch(x), block], [wp.from_torch(out)])
        assert len(count_chunks) == 1 and ("blocks" in count_chunks[0]) == (expect == "_scale_blocks")
        assert torch.equal(out, x * 2)


def test_thread_count_precedence(monkeypatch):
    monkeypatch.delenv(L.ENV_NUM_THREADS, raising=False)
    L.set_num_threads(None)
    torch.set_num_threads(1)
    try:
        assert L.get_num_threads() == 1  # follows torch once the bridge is loaded
        torch.set_num_threads(2)
        assert L.get_num_threads() == 2
        monkeypatch.setenv(L.ENV_NUM_THREADS, "3")
        assert L.get_num_threads() == 3
        L.set_num_threads(5)
        assert L.get_num_threads() == 5
        with pytest.raises(ValueError):
            L.set_num_threads(0)
    finally:
        torch.set_num_threads(2)


def test_adjoint_scopes():
    so3 = L.declaration(geometry_kernels.so3_exp[wp.float32])
    assert so3.scopes == {"omega": "element"} and so3.forward
    wfd = L.declaration(sampling_kernels.warp_frame_depth[wp.float64])
    assert wfd.scopes["image"] == "segment" and wfd.scopes["depth"] == "element" and wfd.segment({"H": 7}) == 7


@wp.kernel
def _splat(offset: int, x: wp.array(dtype=Any), out: wp.array(dtype=Any)):
    i = wp.tid() + offset
    wp.atomic_add(out, 0, x[i])


@wp.kernel
def _gather(offset: int, x: wp.array(dtype=Any), idx: wp.array(dtype=wp.int32), out: wp.array(dtype=Any)):
    i = wp.tid() + offset
    out[i] = x[idx[i]] * x[i]


def test_undeclared_kernels_are_refused():
    """A kernel that did not declare how it may be split is refused by name, never guessed at."""
    bare = L.FloatKernel(_gather, x="scalar", out="scalar")[wp.float64]
    x = wp.zeros(4, dtype=wp.float64)
    idx = wp.zeros(4, dtype=wp.int32)
    with pytest.raises(ValueError, match="_gather.*no declaration.*set_parallel"):
        L.launch(bare, 4, [x, idx], [wp.zeros(4, dtype=wp.float64)])
    with pytest.raises(ValueError, match="has no array argument 'y'"):
        L.FloatKernel(_gather, x="scalar", out="scalar").set_parallel(scopes={"y": "element"})


def test_declared_atomics_and_gathers_are_safe():
    """forward=False keeps an atomic forward on one thread; an "any" scope (the default for an
    input not named) cuts a gathering adjoint into fixed pieces with partial buffers."""
    splat = L.FloatKernel(_splat, x="scalar", out="scalar").set_parallel(forward=False, scopes={"x": "element"})
    splat = splat[wp.float64]
    gather = L.FloatKernel(_gather, x="scalar", out="scalar").set_parallel()[wp.float64]
    assert L.declaration(gather).scope("x") == "any"

    n = 50_000
    rng = torch.Generator().manual_seed(4)
    x = torch.rand(n, dtype=torch.float64, generator=rng)
    idx = torch.randint(0, n, (n,), generator=rng, dtype=torch.int32)
    results = []
    for n_threads in (1, 2, 4):
        L.set_num_threads(n_threads)
        total = torch.zeros(1, dtype=torch.float64)
        L.launch(splat, n, [wp.from_torch(x)], [wp.from_torch(total)])
        gx = torch.zeros(n, dtype=torch.float64)
        out = torch.empty(n, dtype=torch.float64)
        L.launch(
            gather, n, [wp.from_torch(x), wp.from_torch(idx)], [wp.from_torch(out)], adjoint=True,
            adj_inputs=[wp.from_torch(gx), None], adj_outputs=[wp.from_torch(torch.ones(n, dtype=torch.float64))],
        )
        results.append((total, gx))
    assert torch.allclose(results[0][0], x.sum())
    expected = x[idx.long()].clone()  # d out_i / d x_i = x[idx_i]; d out_i / d x[idx_i] = x_i
    expected.index_add_(0, idx.long(), x)
    assert torch.allclose(results[0][1], expected)
    for total, gx in results[1:]:
        assert torch.equal(total, results[0][0]) and torch.equal(gx, results[0][1])


@once
def test_env_var_in_subprocess(tmp_path, backend):
    code = "import gvnn_warp.kernels.core.launch as L; print(L.get_num_threads())"
    env = dict(os.environ, **{L.ENV_NUM_THREADS: "3"})
    out = run_python(code, env=env, check=True)
    assert out.stdout.strip().splitlines()[-1] == "3"


def test_torch_openmp_team_is_the_default():
    from gvnn_warp.ops.compat import torch_openmp_library

    if torch_openmp_library()[0] is None or os.environ.get("GVNN_WARP_OPENMP") == "0":
        pytest.skip("torch does not run on OpenMP here, or it was turned off")
    assert DEFAULT_BACKEND.startswith("openmp:")


def test_pool_runs_on_several_threads(backend):
    """The chunks really are spread over threads (the calling one included)."""
    import threading
    import time

    ids = set()

    def fn(k):
        ids.add(threading.get_native_id())
        time.sleep(0.005)  # long enough for every thread to get chunks

    threads.pool().run(fn, 16, 2)
    assert len(ids) == 2 and threading.get_native_id() in ids


@once
def test_backends_give_bitwise_equal_results(backend):
    image, depth, pose, K = wfd_inputs(1, 3, 97, 131, torch.float32, seed=5)
    L.set_num_threads(2)
    results = {}
    for name in BACKENDS:
        use_backend(name)
        results[name] = gradients_of(lambda i, d, p: G.warp_frame_depth(i, d, p, K)[0], (image, depth, pose), {0, 1, 2})
    for name in BACKENDS[1:]:
        assert all(torch.equal(a, b) for a, b in zip(results[name], results[BACKENDS[0]]))


def test_pool_errors_are_raised(backend):
    done = []

    def fn(k):
        if k == 5:
            raise RuntimeError("chunk 5 failed")
        done.append(k)

    with pytest.raises(RuntimeError, match="chunk 5 failed"):
        threads.pool().run(fn, 12, 3)
    assert sorted(done) == [k for k in range(12) if k != 5]  # the other chunks still ran


def _run(code, **env):
    out = run_python(code, env=dict(os.environ, **env), timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip().splitlines()[-1]


@pytest.mark.long
@once
def test_openmp_can_be_turned_off_by_env_var(backend):
    code = "import torch, gvnn_warp as G; G.so3_exp(torch.zeros(1, 3)); print(G.kernels.core.launch.thread_backend())"
    assert _run(code, GVNN_WARP_OPENMP="0") == "python"


def _child_status(pid: int, seconds: float) -> int | None:
    """The exit status of forked child ``pid``, or None (the child killed) if it has not ended within
    ``seconds`` (a hang)."""
    import time

    deadline = time.monotonic() + seconds
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return os.waitstatus_to_exitcode(status)
        if time.monotonic() > deadline:
            os.kill(pid, 9)
            os.waitpid(pid, 0)
            return None
        time.sleep(0.02)


@once
@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_forked_child_runs_threaded_launches(backend):
    """libgomp's team does not survive a fork: a child's launches fall back to Python threads and
    give the parent's results. (torch's own parallel ops hang in such a child unless it sets
    torch.set_num_threads(1) first, as DataLoader workers do; so does this child.) Forked from the
    test's process, whose OpenMP team has run launches before (here, the parent's)."""
    L.set_num_threads(2)
    omega = torch.randn(200_000, 3, generator=torch.Generator().manual_seed(0))
    parent = G.so3_exp(omega)
    pid = os.fork()
    if pid == 0:  # the child: never returns into pytest
        code = 3
        try:
            torch.set_num_threads(1)
            code = 0 if torch.equal(G.so3_exp(omega), parent) and L.get_num_threads() == 2 else 3
        finally:
            os._exit(code)
    assert _child_status(pid, 60) == 0


@wp.kernel
def _affine(offset: int, x: wp.array(dtype=float), a: float, y: wp.array(dtype=float)):
    i = wp.tid() + offset
    y[i] = x[i] * a + float(i)


@once
@pytest.mark.parametrize("n_threads", [1, 2])
def test_recorded_launch_pieces_and_set_arg(n_threads, monkeypatch):
    # RecordedLaunch packs the arguments once and runs one replay function per piece (each piece
    # its own offset and size), built on the first call; a set_arg (a scalar, an array, an array
    # descriptor) takes effect on the next call, updating the replays in place; and the same
    # results through Warp's Launch.launch where the fast replay does not apply (recorded again
    # after each set_arg)
    import numpy as np
    from gvnn_warp.kernels.core import compat as _compat

    monkeypatch.setattr(threads, "get_num_threads", lambda: n_threads)
    built = []
    real = _compat.replay_pieces
    n = 1001  # unequal pieces on 2 threads
    x = wp.array(np.arange(n, dtype=np.float32))
    x2 = wp.array(np.arange(n, dtype=np.float32)[::-1].copy())
    y = wp.zeros(n, dtype=float)
    y2 = wp.zeros(n, dtype=float)
    for fast in (True, False):
        def counted(cmd, pieces, fast=fast):
            built.append(pieces)
            return real(cmd, pieces) if fast else None

        monkeypatch.setattr(_compat, "replay_pieces", counted)
        for first in (2.0, 3.0):
            rec = L.RecordedLaunch(_affine, n, [x, 2.0], [y], grain=100)
            assert len(rec._pieces) == n_threads and not built  # nothing built when recording
            if first != 2.0:
                rec.set_arg(1, first)  # before the first call
            steps = [(1, first), (1, 5.0), (0, x2), (2, y2), (2, _compat.array_descriptor(y.ptr, n, 4)),
                     (0, x), (1, 7.0)]
            a, src, dst = first, x, y
            for k, (index, value) in enumerate(steps):
                if k:
                    rec.set_arg(index, value)
                    if index == 1:
                        a = value
                    elif index == 0:
                        src = value
                    else:
                        dst = y if value is not y2 else y2
                for _ in range(2):
                    dst.fill_(-1.0)
                    rec()
                    expect = src.numpy() * np.float32(a) + np.arange(n, dtype=np.float32)
                    np.testing.assert_array_equal(dst.numpy(), expect)
                    assert len(built) == (1 if fast else k + 1)  # fallback: recorded again after each set_arg
            assert [p[1] for p in built[0]] == [n * (k + 1) // n_threads - n * k // n_threads for k in range(n_threads)]
            with pytest.raises(RuntimeError):  # Warp refuses the value: the launch is left as it was
                rec.set_arg(0, wp.zeros(4, dtype=wp.vec2))
            dst.fill_(-1.0)
            rec()
            np.testing.assert_array_equal(dst.numpy(), expect)
            with pytest.raises(IndexError, match="set_arg"):
                rec.set_arg(-1, 1.0)
            with pytest.raises(IndexError, match="set_arg"):
                rec.set_arg(3, 1.0)
            built.clear()


@once
def test_recorded_launch_of_no_elements_does_nothing():
    import numpy as np

    y = wp.array(np.full(4, 7.0, np.float32))
    rec = L.RecordedLaunch(_affine, 0, [y, 2.0], [y])
    rec.set_arg(1, 3.0)
    rec()
    assert y.numpy().tolist() == [7.0] * 4


_FIRST_USES = """if True:
    import random, sys, threading
    sys.path.insert(0, sys.argv[1])
    import torch, warp as wp
    import gvnn_warp as G
    from gvnn_warp.cameras import FisheyeCamera, RadTanCamera
    from gvnn_warp.kernels import launch as L
    from warp._src import context  # Warp's CPU JIT entry points (pinned: warp-lang 1.19.x)

    # every module load and entry-point lookup of Warp's CPU JIT, counted, and those made by a thread
    # that does not hold kernels.core.launch's lock
    wp.init()
    llvm = context.runtime.llvm
    calls, unlocked = [], []
    for name in ("wp_load_obj", "wp_lookup"):
        def wrapped(*args, _real=getattr(llvm, name), _name=name):
            calls.append(_name)
            if not L._FIRST_LAUNCH_LOCK._is_owned():
                unlocked.append(_name)
            return _real(*args)
        setattr(llvm, name, wrapped)

    # 1. first uses of many kernels from six threads at once, in random orders
    def jobs(dtype):
        g = torch.Generator().manual_seed(0)
        B, C, H, W = 2, 3, 12, 16
        img = torch.rand(B, C, H, W, generator=g, dtype=dtype)
        dep = 1 + torch.rand(B, 1, H, W, generator=g, dtype=dtype)
        pose = torch.eye(4, dtype=dtype)[:3].expand(B, 3, 4).contiguous()
        K = torch.tensor([[20.0, 0, 8], [0, 20, 6], [0, 0, 1]], dtype=dtype)
        rt = RadTanCamera(K, torch.tensor([0.01, 0, 0, 0, 0], dtype=dtype))
        fe = FisheyeCamera(K, torch.tensor([0.01, 0, 0, 0], dtype=dtype))
        v = torch.rand(B, 3, generator=g, dtype=dtype)
        return [
            lambda: G.photometric_normal_equations(img, dep, img, pose, K),
            lambda: G.photometric_normal_equations(img[:, :1], dep, img[:, :1], pose, rt),
            lambda: G.photometric_normal_equations(img, dep, img, pose, fe, live_depth=dep, depth_weight=1.0),
            lambda: G.photometric_error(img, dep, img, pose, K),
            lambda: G.photometric_error(img, dep, img, pose, rt),
            lambda: G.warp_frame_depth(img, dep, pose, K),
            lambda: G.warp_frame_depth(img, dep, pose, fe),
            lambda: G.so3_exp(v),
            lambda: G.se3_exp(torch.cat([v, v], 1)),
        ]

    every = jobs(torch.float32) + jobs(torch.float64)

    def run(seed):
        order = list(range(len(every)))
        random.Random(seed).shuffle(order)
        for k in order:
            every[k]()

    workers = [threading.Thread(target=run, args=(s,)) for s in range(6)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    print("threads ok")

    # 2. then, one after the other: backward passes, the aligner and its pyramids, the renderer
    from gvnn_warp.odometry import DirectAligner
    from odometry_refs import motion, rendered_pair  # renders with gvnn_warp.synthetic

    g = torch.Generator().manual_seed(0)
    img = torch.rand(2, 3, 12, 16, generator=g, dtype=torch.float64, requires_grad=True)
    dep = (1 + torch.rand(2, 1, 12, 16, generator=g, dtype=torch.float64)).requires_grad_()
    pose = torch.eye(4, dtype=torch.float64)[:3].expand(2, 3, 4).contiguous().requires_grad_()
    K = torch.tensor([[20.0, 0, 8], [0, 20, 6], [0, 0, 1]], dtype=torch.float64)
    rt = RadTanCamera(K, torch.tensor([0.01, 0, 0, 0, 0], dtype=torch.float64))
    G.photometric_error(img, dep, img, pose, K)[0].sum().backward()
    G.photometric_error(img, dep, img, pose, rt)[0].sum().backward()
    G.photometric_normal_equations(img.detach(), dep.detach(), img.detach(), pose.detach(), rt)
    G.warp_frame_depth(img, dep, pose, K)[0].sum().backward()
    G.so3_exp(torch.rand(2, 3, dtype=torch.float64, requires_grad=True)).sum().backward()
    G.flow_warp(img, torch.rand(2, 2, 12, 16, generator=g, dtype=torch.float64)).sum().backward()
    ri, rd, li, ld, Kk, T = rendered_pair(motion((1, 0, 0), (0.01, 0, 0)), width=64, height=48)
    DirectAligner(Kk).align(ri, rd, li, ld)
    DirectAligner(Kk, color=True).align(ri, rd, li, ld)
    print(len(calls), len(unlocked))
"""


@pytest.mark.long
@once
def test_first_uses_of_many_kernels_from_several_threads_at_once_load_under_the_lock():
    # the first launch of a kernel loads its module and looks its entry points up in Warp's CPU
    # JIT; done by several threads at once this crashed the process (a segmentation fault: 3 runs
    # of 4 before kernels.core.launch.wp_launch serialised first launches). In a fresh process, so
    # every kernel's first launch happens here: many from six threads at once, then more one after
    # the other (torch ops forward and backward, lens cameras, the aligner and its pyramids, the
    # synthetic renderer); every module load and entry-point lookup must happen with
    # kernels.core.launch's lock held (the deterministic check: a crash needs an unlucky schedule)
    from pathlib import Path

    out = run_python(_FIRST_USES, Path(__file__).parents[1], timeout=300)
    assert out.returncode == 0 and "threads ok" in out.stdout, (out.returncode, out.stderr[-3000:])
    calls, unlocked = map(int, out.stdout.split()[-2:])
    assert calls > 20 and unlocked == 0, out.stdout


@once
@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_a_fork_while_another_thread_loads_a_kernel_does_not_hang_the_child():
    # the child of a fork made while another thread held the first-launch lock gets a new lock
    import threading

    holding, release = threading.Event(), threading.Event()

    def loader():
        with L._FIRST_LAUNCH_LOCK:
            holding.set()
            release.wait(10)

    t = threading.Thread(target=loader)
    t.start()
    holding.wait(10)
    try:
        pid = os.fork()
        if pid == 0:  # the child: the lock must be free
            ok = L._FIRST_LAUNCH_LOCK.acquire(timeout=5)
            os._exit(0 if ok else 1)
        status = _child_status(pid, 30)
    finally:
        release.set()
        t.join()
    assert status == 0
