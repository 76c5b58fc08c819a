"""kernels/core/cache.py: one variant per normalised key, readable keys, float32/float64 overloads that
Warp resolves by argument type, and a loud error for a wrong call or a family named twice."""

import threading
from typing import Any

import numpy as np
import pytest
import warp as wp
from gvnn_warp.kernels.core import cache
from gvnn_warp.kernels.core.launch import wp_launch

made = []


@cache.specialise("tests.cache_demo", channels=(1, 3))
def _variant(channels, narrow: bool):
    made.append((channels, narrow))
    return object()


def test_policy_compiles_listed_values_and_reads_the_rest_at_run_time():
    a = _variant(3, False)
    assert _variant(3, False) is a and _variant(channels=3, narrow=False) is a
    # channel counts outside the policy share the run-time variant (channels=None), made once
    b = _variant(5, False)
    assert _variant(7, False) is b and b is not a
    assert made.count((None, False)) == 1 and made.count((3, False)) == 1
    assert _variant(1, True) is not _variant(1, False)  # narrow has no policy: every value compiled in
    entries = cache.entries()
    assert "tests.cache_demo(channels=3, narrow=False)" in entries
    assert "tests.cache_demo(channels=None, narrow=False)" in entries
    assert cache.POLICIES["tests.cache_demo"] == {"channels": (1, 3)}


@cache.specialise("tests.cache_default", channels=(1, 3))
def _with_default(channels, wide: bool = True):
    made.append(("default", channels, wide))
    return object()


def test_a_default_left_out_or_passed_is_one_variant():
    a = _with_default(3)
    assert _with_default(3, True) is a and _with_default(3, wide=True) is a and _with_default(channels=3) is a
    assert _with_default(3, False) is not a
    assert made.count(("default", 3, True)) == 1


def test_wrong_calls_and_reused_families_are_refused():
    with pytest.raises(TypeError, match="narrow"):
        _variant(3)
    with pytest.raises(TypeError):
        _variant(3, False, True)
    with pytest.raises(TypeError, match="'narrow'"):
        _variant(3, narow=False)  # misspelt: 'narrow' missing
    with pytest.raises(TypeError, match="unexpected keyword"):
        _variant(3, narrow=False, extra=1)
    with pytest.raises(ValueError, match="family already used"):
        cache.specialise("tests.cache_demo")(lambda x: x)
    with pytest.raises(ValueError, match="no argument named"):
        cache.specialise("tests.cache_other", width=(8,))(lambda x: x)


def test_threads_asking_at_once_get_one_variant():
    calls = []
    barrier = threading.Barrier(4)

    @cache.specialise("tests.cache_threads")
    def slow(k):
        calls.append(k)
        return object()

    out = []

    def ask():
        barrier.wait()
        out.append(slow(1))

    threads = [threading.Thread(target=ask) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert calls == [1] and all(o is out[0] for o in out)


def _scaled(T):
    @wp.func
    def scaled(x: T):
        return x * T(2.0)

    @wp.func_grad(scaled)
    def adj_scaled(x: T, adj_ret: T):
        wp.adjoint[x] += adj_ret * T(3.0)  # not the true derivative: shows this adjoint is the one used

    return scaled


scaled = cache.float_overloads(_scaled)


@wp.kernel
def _apply(x: wp.array(dtype=Any), y: wp.array(dtype=Any)):
    i = wp.tid()
    y[i] = scaled(x[i])


@pytest.mark.parametrize("dtype", [wp.float32, wp.float64])
def test_float_overloads_resolve_by_type_with_their_custom_adjoints(dtype):
    assert cache.float_overloads(_scaled) is scaled  # made once per maker
    assert f"float_overloads({__name__}._scaled)" in cache.entries()
    x = wp.array(np.array([1.0, -2.0]), dtype=dtype, requires_grad=True)
    y = wp.zeros(2, dtype=dtype, requires_grad=True)
    tape = wp.Tape()
    with tape:
        wp_launch(_apply, dim=2, inputs=[x], outputs=[y], device="cpu")
    tape.backward(grads={y: wp.array(np.ones(2), dtype=dtype)})
    assert np.array_equal(y.numpy(), [2.0, -4.0])
    assert np.array_equal(x.grad.numpy(), [3.0, 3.0])
