"""The torch and Warp internals gvnn_warp relies on, each behind one adapter (gvnn_warp/ops/compat.py,
gvnn_warp/kernels/core/compat.py): these tests fail loudly if an upgrade changes one. Also the thread
backend's visibility (info(), the debug log) and the free-threaded fallback."""

import ctypes
import json
import logging
import sys
import threading
import warnings
from typing import Any

import numpy as np
import pytest
import torch
import warp as wp
from gvnn_warp.kernels.core import compat as wcompat
from gvnn_warp.kernels.core import launch as L
from gvnn_warp.kernels.core import threads
from gvnn_warp.kernels.geometry import kernels as geometry_kernels
from processes import run_python

import gvnn_warp as G
from gvnn_warp.ops import bridge as _bridge
from gvnn_warp.ops import compat as _compat
from gvnn_warp.ops import geometry as _geometry_ops  # noqa: F401  (its registrations fill OPS)
from gvnn_warp.ops.registry import OPS


@wp.kernel
def _probe(offset: int, x: wp.array(dtype=Any), n: int, y: wp.array(dtype=Any)):
    i = wp.tid() + offset
    y[i] = x[i] * type(x[i])(n)


def test_warp_kernel_arguments():
    fk = L.FloatKernel(_probe, x="scalar", y="vec3")
    assert wcompat.kernel_arguments(fk[wp.float64]) == [("offset", False), ("x", True), ("n", False), ("y", True)]
    assert wcompat.kernel_argument_dtype(fk[wp.float64], 1) is wp.float64
    assert wcompat.kernel_argument_dtype(fk[wp.float32], 3) is wp.vec3f


def test_warp_array_descriptor():
    t = torch.arange(6, dtype=torch.float64).reshape(2, 3)
    d = wcompat.array_descriptor(t.data_ptr(), 2, 3 * 8)
    assert type(d) is type(wp.from_torch(t, dtype=wp.vec3d, return_ctype=True))
    assert wcompat.is_array_descriptor(d) and not wcompat.is_array_descriptor(wp.from_torch(t))
    assert wcompat.array_length(d) == 2 and wcompat.array_pointer(d) == t.data_ptr()
    a = wp.from_torch(t, dtype=wp.vec3d)
    assert wcompat.array_length(a) == 2 and wcompat.array_pointer(a) == t.data_ptr()
    # a kernel launched on descriptors reads and writes the tensors' memory
    omega = torch.tensor([[0.0, 0.0, torch.pi / 2]], dtype=torch.float64)
    R = torch.zeros(1, 3, 3, dtype=torch.float64)
    k = geometry_kernels.so3_exp[wp.float64]
    wp.launch(k, dim=1, inputs=[0, wcompat.array_descriptor(omega.data_ptr(), 1, 24)],
              outputs=[wcompat.array_descriptor(R.data_ptr(), 1, 72)], device="cpu")
    torch.testing.assert_close(R[0], torch.tensor([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=torch.float64))
    null = wcompat.array_descriptor(0, 0, 8)  # a null array: no elements
    assert wcompat.array_length(null) == 0 and wcompat.array_pointer(null) == 0


@wp.kernel(module="unique")
def _scale(offset: int, x: wp.array(dtype=wp.float64), n: int, y: wp.array(dtype=wp.float64)):
    i = wp.tid() + offset
    y[i] = x[i] * wp.float64(n)


def test_replay_function_runs_the_recorded_launch():
    # the recorded launch's arguments packed once: same results as Launch.launch(), reads the
    # arrays' current contents, a scalar argument replaced through set_param_at_index after a rebuild
    import numpy as np

    x = wp.array(np.arange(8.0), dtype=wp.float64, device="cpu")
    y = wp.zeros(8, dtype=wp.float64, device="cpu")
    cmd = wp.launch(_scale, dim=6, inputs=[1, x, 3], outputs=[y], device="cpu", record_cmd=True)
    run = wcompat.replay_function(cmd)
    assert run is not cmd.launch  # the fast path, not the fallback
    run()
    assert y.numpy().tolist() == [0, 3, 6, 9, 12, 15, 18, 0]
    x.assign(np.arange(8.0) + 1)
    run()
    assert y.numpy().tolist() == [0, 6, 9, 12, 15, 18, 21, 0]
    cmd.set_param_at_index(2, 2)
    wcompat.replay_function(cmd)()
    assert y.numpy().tolist() == [0, 4, 6, 8, 10, 12, 14, 0]
    # a recorded launch of the normal equations replays to the same bits either way
    from gvnn_warp.kernels.photometric.pipeline import photometric_normal_equations

    img = wp.array(np.random.default_rng(0).random((1, 1, 8, 16)), dtype=wp.float64, device="cpu")
    depth = wp.array(np.full((1, 1, 8, 16), 2.0), dtype=wp.float64, device="cpu")
    pose = wp.array([np.eye(3, 4) + 0.01], dtype=L.mat34d, device="cpu")
    K = wp.array([[[10.0, 0, 7.5], [0, 10.0, 3.5], [0, 0, 1]]], dtype=wp.mat33d, device="cpu")
    ne = photometric_normal_equations(img, depth, img, pose, K)
    want = [a.copy() for a in ne.numpy()]
    for c in ne._cmds:
        assert len(c._pieces) == 1  # 8 rows: one piece, which the recorded launch covers
        c._cmd.launch()
    assert all(np.array_equal(a, b) for a, b in zip(ne.numpy(), want))


def test_replay_pieces_sets_each_pieces_offset_and_size():
    # one recorded launch replayed as pieces: each piece covers [start, start + size) and only that
    import numpy as np

    x = wp.array(np.arange(10.0), dtype=wp.float64, device="cpu")
    y = wp.array(np.full(10, -1.0), dtype=wp.float64, device="cpu")
    cmd = wp.launch(_scale, dim=4, inputs=[0, x, 2], outputs=[y], device="cpu", record_cmd=True)
    runs = wcompat.replay_pieces(cmd, [(1, 3), (6, 2)])
    assert len(runs) == 2
    runs[1]()
    assert y.numpy().tolist() == [-1] * 6 + [12, 14, -1, -1]
    runs[0]()
    assert y.numpy().tolist() == [-1, 2, 4, 6, -1, -1, 12, 14, -1, -1]
    adjoint = wp.launch(_scale, dim=4, inputs=[0, x, 2], outputs=[y], adj_inputs=[0, x, 0], adj_outputs=[y],
                        adjoint=True, device="cpu", record_cmd=True)
    assert wcompat.replay_pieces(adjoint, [(0, 4)]) is None  # not a forward launch: the caller's fallback


def test_set_replay_arg_updates_the_replays_in_place():
    # an argument set on the recorded launch (Warp's public set_param_at_index) and copied into the
    # replays' structs: scalars and arrays; the offset and non-replays are refused (False)
    import numpy as np

    x = wp.array(np.arange(10.0), dtype=wp.float64, device="cpu")
    x2 = wp.array(np.arange(10.0) + 100, dtype=wp.float64, device="cpu")
    y = wp.array(np.full(10, -1.0), dtype=wp.float64, device="cpu")
    cmd = wp.launch(_scale, dim=4, inputs=[0, x, 2], outputs=[y], device="cpu", record_cmd=True)
    runs = wcompat.replay_pieces(cmd, [(0, 5), (5, 5)])
    cmd.set_param_at_index(2, 3)
    assert wcompat.set_replay_arg(cmd, runs, 2)
    cmd.set_param_at_index(1, x2)
    assert wcompat.set_replay_arg(cmd, runs, 1)
    for run in runs:
        run()
    assert y.numpy().tolist() == [3.0 * (k + 100) for k in range(10)]
    assert not wcompat.set_replay_arg(cmd, runs, 0)  # each piece's own offset
    assert not wcompat.set_replay_arg(cmd, [cmd.launch], 1)  # not replay_pieces' replays


def test_alias_keeps_its_source_alive():
    # a view from a bare pointer does not hold its array: alias must (Warp's _ref), or a tape's replay
    # reads freed memory
    import gc
    import weakref

    src = wp.array(np.arange(16, dtype=np.float32), dtype=wp.float32)
    alive = weakref.ref(src)
    view = wcompat.alias(src, wp.types.vector(8, wp.float32), (2,))
    del src
    gc.collect()
    assert alive() is not None
    np.testing.assert_array_equal(view.numpy().reshape(-1), np.arange(16, dtype=np.float32))
    del view
    gc.collect()
    assert alive() is None  # (and nothing else holds it)


def test_warp_type_attributes():
    assert wcompat.scalar_type(wp.vec3f) is wp.float32 and wcompat.scalar_type(wp.float64) is wp.float64
    assert wcompat.scalar_type(L.mat34d) is wp.float64
    assert wcompat.scalars_per_element(L.mat34f) == 12 and wcompat.scalars_per_element(wp.float32) == 1
    assert wcompat.matrix_shape(L.mat34f) == (3, 4) and wcompat.matrix_shape(wp.vec2d) == (2,)
    assert wcompat.matrix_shape(wp.float32) is None


def _twice(T):
    @wp.func
    def twice(x: T):
        return x + x

    return twice


def test_add_function_overload():
    # two wp.Functions of one name and module (defined by the same maker for two types): after the
    # call, the first holds both signatures and Warp's module resolves the name to it
    first, other = _twice(wp.float32), _twice(wp.float64)
    wcompat.add_function_overload(first, other)
    assert first.module.functions[first.key] is first
    types = {tuple(f.input_types.values()) for f in first.user_overloads.values()}
    assert {(wp.float32,), (wp.float64,)} <= types


def _square(register, adjoint_scale: float):
    """A float32 square with a custom adjoint ``adjoint_scale * adj_ret`` (not the true derivative:
    which adjoint ran shows in the gradient), registered by ``register`` (wp.func_grad or ours)."""

    @wp.func
    def square(x: wp.float32):
        return x * x

    @register(square)
    def adj_square(x: wp.float32, adj_ret: wp.float32):
        wp.adjoint[x] += wp.float32(adjoint_scale) * adj_ret

    return square


def _square_adjoint_of_another_type(register):
    """As :func:`_square`, with an adjoint whose argument is not of the function's type."""

    @wp.func
    def square(x: wp.float32):
        return x * x

    @register(square)
    def adj_square(x: wp.float64, adj_ret: wp.float32):
        wp.adjoint[x] += wp.float64(adj_ret)

    return square


@wp.func
def _generic_identity(x: Any):
    return x


_IDENTITIES = {"adj", "func", "initializer_list_func", "native_func", "user_overloads", "module"}  # (per function)
_ADJOINT_FLAGS = ("custom_reverse_mode", "custom_reverse_num_input_args", "skip_forward_codegen",
                  "skip_reverse_codegen")


def test_func_grad_registers_the_adjoint_as_warp_does():
    # Warp's decorator and ours leave the same custom adjoint on the forward function; ours skips
    # only Warp's check of the signature, which builds the forward function first
    theirs, ours = _square(wp.func_grad, 3.0), _square(wcompat.func_grad, 3.0)
    assert not hasattr(ours.adj, "return_var") and hasattr(theirs.adj, "return_var")  # (no build)
    a, b = theirs.custom_grad_func, ours.custom_grad_func
    assert type(a) is type(b) and set(vars(a)) == set(vars(b))
    for field in set(vars(a)) - _IDENTITIES:
        assert getattr(a, field) == getattr(b, field), field
    for field in _ADJOINT_FLAGS:
        assert getattr(a.adj, field) == getattr(b.adj, field), field
    assert a.native_func == theirs.native_func and b.native_func == ours.native_func
    assert a.module is theirs.module and b.module is ours.module
    assert ours.adj.skip_reverse_codegen and theirs.adj.skip_reverse_codegen
    with pytest.raises(TypeError, match="func_grad.*concrete argument types"):
        wcompat.func_grad(_generic_identity)  # (generic: no overload to attach an adjoint to)


def test_func_grad_adjoint_runs_and_a_wrong_signature_is_refused():
    square = _square(wcompat.func_grad, 3.0)

    @wp.kernel(module="unique")
    def apply(x: wp.array(dtype=wp.float32), y: wp.array(dtype=wp.float32)):
        i = wp.tid()
        y[i] = square(x[i])

    x = wp.array([2.0, -1.0], dtype=wp.float32, device="cpu", requires_grad=True)
    y = wp.zeros(2, dtype=wp.float32, device="cpu", requires_grad=True)
    tape = wp.Tape()
    with tape:
        wp.launch(apply, dim=2, inputs=[x], outputs=[y], device="cpu")
    tape.backward(grads={y: wp.array([1.0, 0.5], dtype=wp.float32, device="cpu")})
    np.testing.assert_array_equal(y.numpy(), [4.0, 1.0])
    np.testing.assert_array_equal(x.grad.numpy(), [3.0, 1.5])  # the custom adjoint's, not 2x

    # an adjoint of other argument types: refused at once, by Warp's decorator and by ours
    with pytest.raises(RuntimeError, match="adj_square"):
        _square_adjoint_of_another_type(wp.func_grad)
    with pytest.raises(TypeError, match="func_grad.*the adjoint .*adj_square must take the function's arguments"):
        _square_adjoint_of_another_type(wcompat.func_grad)


def test_gil_enabled(monkeypatch):
    assert wcompat.gil_enabled() == (getattr(sys, "_is_gil_enabled", lambda: True)())
    monkeypatch.setattr(sys, "_is_gil_enabled", lambda: False, raising=False)
    assert not wcompat.gil_enabled()


def test_torch_custom_op_implementations():
    impls = _compat.custom_op_implementations(OPS["so3_exp"].op)
    assert impls, "torch.library.custom_op no longer keeps its implementations in op._backend_fns"
    assert any(getattr(f, "__dynamo_disable", None) is not None for f in impls)


FRESH_PROCESS = """if True:
    import json, sys, numpy as np, torch, gvnn_warp as G
    from gvnn_warp.odometry import DirectAligner
    from gvnn_warp.kernels import lens
    from gvnn_warp.kernels.core import cache
    facts = {}
    G.so3_exp(torch.zeros(2, 3))
    facts["dynamo after the first call"] = 'torch._dynamo' in sys.modules
    img = torch.rand(1, 1, 16, 16, requires_grad=True)
    depth = torch.full((1, 1, 16, 16), 2.0, requires_grad=True)
    K = torch.tensor([[20.0, 0, 7.5], [0, 20.0, 7.5], [0, 0, 1]])
    G.warp_frame_depth(img, depth, torch.eye(4)[None], K)[0].sum().backward()
    G.photometric_error(img, depth, img, torch.eye(4)[None], K)[0].backward()
    DirectAligner(K.numpy()).align(img[0].detach().numpy(), depth[0].detach().numpy(), img[0].detach().numpy())
    facts["lens after pinhole work"] = [any('lens' in e for e in cache.entries()), 'gvnn_warp.ops.lens' in sys.modules,
                                        'project' in vars(lens)]
    G.warp_frame_depth(img, depth, torch.eye(4)[None], G.RadTanCamera(K, torch.tensor([0.1, 0, 0, 0, 0])))
    facts["lens after a distorted camera"] = 'geometry.lens_fronts()' in cache.entries()
    print(json.dumps(facts))
"""


@pytest.fixture(scope="module")
def fresh_process_facts():
    """What a fresh process has imported and defined after a first op call, then pinhole work (a
    pinhole warp_frame_depth fwd+bwd, photometric_error, a pinhole DirectAligner), then one distorted
    camera (one process for the tests below: each pays torch's and the package's imports)."""
    out = run_python(FRESH_PROCESS, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_first_call_does_not_import_dynamo(fresh_process_facts):
    """The lazy __dynamo_disable is what torch calls: the first op call imports no torch._dynamo."""
    assert fresh_process_facts["dynamo after the first call"] is False


def test_pinhole_work_does_not_define_the_lens_models(fresh_process_facts):
    """The lens models' kernels cost seconds to define (Warp builds every custom adjoint's function
    then): import gvnn_warp, a pinhole warp_frame_depth fwd+bwd and a pinhole DirectAligner never
    define them; the first distorted camera does."""
    assert fresh_process_facts["lens after pinhole work"] == [False, False, False]
    assert fresh_process_facts["lens after a distorted camera"] is True


def test_torch_openmp_library():
    library, reason = _compat.torch_openmp_library()
    assert "parallel backend:" in torch.__config__.parallel_info(), "parallel_info() text changed"
    if not sys.platform.startswith("linux") or "parallel backend: OpenMP" not in torch.__config__.parallel_info():
        assert library is None and reason
        return
    assert library is not None, reason
    assert ctypes.CDLL(library).GOMP_parallel  # resolves through libtorch_cpu's dependencies


def test_other_platforms_use_python_threads(monkeypatch):
    monkeypatch.setattr(sys, "platform", "darwin")
    library, reason = _compat.torch_openmp_library()
    assert library is None and "darwin" in reason and "Python threads" in reason


def test_info():
    info = G.info()
    assert info["gvnn_warp"] == G.__version__ and info["warp"] == wp.config.version
    assert info["torch"] == torch.__version__ and info["num_threads"] == G.get_num_threads()
    assert info["thread_backend"] == L.thread_backend() and info["thread_backend_reason"]


def test_backend_choice_is_logged_not_warned(caplog):
    before = L.thread_backend()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with caplog.at_level(logging.DEBUG, logger="gvnn_warp"):
                L.use_openmp(None, "because a test said so")
        assert L.thread_backend() == "python" and L.backend_reason() == "because a test said so"
        assert any("because a test said so" in r.getMessage() and r.levelno == logging.DEBUG for r in caplog.records)
    finally:
        _bridge._use_torch_openmp()
    assert L.thread_backend() == before


def test_free_threaded_interpreter_runs_launches_on_one_thread(monkeypatch):
    monkeypatch.setattr(wcompat, "gil_enabled", lambda: False)
    assert L.thread_backend() == "serial" and "free-threaded" in L.backend_reason()
    ids = []
    threads.pool().run(lambda k: ids.append((k, threading.get_native_id())), 8, 4)
    assert ids == [(k, threading.get_native_id()) for k in range(8)]  # in order, on this thread
    omega = torch.randn(100_000, 3, generator=torch.Generator().manual_seed(0))
    L.set_num_threads(1)
    try:
        one = G.so3_exp(omega)
        L.set_num_threads(4)
        assert torch.equal(G.so3_exp(omega), one)
    finally:
        L.set_num_threads(None)


def test_lanes_compiler_flags_lift_warps_slp_depth_cap():
    from gvnn_warp.kernels import pyramid
    from gvnn_warp.kernels.core.kinds import LANES_MODULE_OPTIONS
    from gvnn_warp.kernels.photometric import error as pek
    from gvnn_warp.kernels.photometric import normal_equations_lanes as nel
    from gvnn_warp.kernels.sampling import kernels as sk

    # the Warp default this works around: a cap on the SLP vectoriser's depth (if an upgrade drops
    # it, lanes_compiler_flags has nothing left to do)
    assert "-mllvm=-slp-recursion-max-depth=4" in wp.config.cpu_compiler_flags.split()
    assert wcompat.lanes_compiler_flags("-O2 -march=native") == "-O2 -march=native"
    both = "-march=native -mllvm=-slp-recursion-max-depth=4 -O3 -mllvm -slp-recursion-max-depth=2 -mllvm -foo=1"
    assert wcompat.lanes_compiler_flags(both) == "-march=native -O3 -mllvm -foo=1"
    dashes = "-mllvm=--slp-recursion-max-depth=4 -mllvm --slp-recursion-max-depth=3 -mllvm=-slp-threshold=1"
    assert wcompat.lanes_compiler_flags(dashes) == "-mllvm=-slp-threshold=1"
    flags = LANES_MODULE_OPTIONS["cpu_compiler_flags"]
    assert "slp-recursion-max-depth" not in flags and "-march=native" in flags.split()
    # every 8-lane kernel family compiles with them
    for fk in (pek.error_lanes(0, 3, 320), nel.normal_equations_lanes(False, False, 1, 2, 320),
               nel.normal_equations_lanes_kernel(True, True, None, None, None),
               sk.bilinear_sample_lanes(3, 0, 0), sk.warp_frame_depth_lanes(3, 0), pyramid.level0_lanes_kernel(3),
               pyramid.downsample_lanes_kernel(1)):
        assert fk.kernel.module.options["cpu_compiler_flags"] == flags, fk
