"""Every kernel's declared adjoint scopes (FloatKernel.set_parallel) are checked by running it cut
into many pieces, in reverse order, against one piece: forward outputs and gradients must be
bitwise equal. A kernel whose adjoint writes outside its declared scope (e.g. a pose gradient
declared "element" while every pixel adds to it) sums in another order and fails."""

import math

import pytest
import torch
from gvnn_warp.kernels.core import kinds
from gvnn_warp.kernels.core import launch as L
from op_samples import OPS, op_samples
from refs import gradients_of

MAX_PIECES = 256


def one_piece(n, adjoint, info, names, shared, n_threads, grain):
    return [(0, n, 0)]


def many_pieces(seen):
    """A planner that cuts wherever the declaration allows (every element, or every segment when a
    wanted gradient is "segment"), in reverse order; no partial buffers, so equal to one piece
    exactly when the declaration is right."""

    def plan(n, adjoint, info, names, shared, n_threads, grain):
        seen.add((info.owner.kernel.key, adjoint))
        if (not adjoint and not info.forward) or "any" in shared or (shared and info.segment is None):
            return [(0, n, 0)]
        unit = max(1, min(n, int(info.segment(names)))) if shared else 1
        step = unit * max(1, math.ceil(n / unit / MAX_PIECES))
        return [(s, min(step, n - s), 0) for s in range(0, n, step)][::-1]

    return plan


def wanted_inputs(spec, params):
    """Positions (among the float tensor inputs) of the gradients the declaration lets be cut:
    all but the "any" ones (those are always cut into fixed pieces with partial buffers). A
    hand-written op (no one kernel whose adjoint is its backward): all of its tensor inputs, the
    planner cutting each of its launches as that kernel's declaration allows."""
    if not spec.differentiable:
        return set()
    fk = spec.backward_kernel_for(params)
    if fk is None:
        return set(range(len(spec.inputs)))
    info = kinds.declaration(fk[L.FLOAT_TYPES[1]])
    return {k for k, name in enumerate(spec.inputs) if info.scope(name) != "any"}


def scope_of(spec, params, k):
    fk = spec.backward_kernel_for(params)
    if fk is None:  # a hand-written op
        return "in the declarations of the kernels it launches"
    return repr(kinds.declaration(fk[L.FLOAT_TYPES[1]]).scope(spec.inputs[k]))


def run(spec, args, planner, monkeypatch, wanted):
    monkeypatch.setattr(L, "_planner", planner)
    out = spec.op(*args)
    outs = [o.detach() for o in (out if isinstance(out, tuple) else (out,))]
    return outs, gradients_of(spec.op, args, wanted) if wanted else []


@pytest.fixture
def one_thread():
    L.set_num_threads(1)  # pieces run one after the other, in the plan's order
    yield
    L.set_num_threads(None)


def test_declared_scopes_hold_for_every_kernel(monkeypatch, one_thread):
    samples = op_samples(B=3, C=2, H=9, W=10, seed=1)
    seen = set()
    for name, spec in sorted(OPS.items()):
        if "scopes" in spec.untested:
            continue  # (the registration says why)
        args = samples[name]
        params = args[len(spec.inputs):]
        wanted = wanted_inputs(spec, params)
        ref_out, ref_grads = run(spec, args, one_piece, monkeypatch, wanted)
        # all cuttable gradients at once, then each alone (an "element" one is then cut per element)
        for subset in [wanted, *({k} for k in sorted(wanted))]:
            out, grads = run(spec, args, many_pieces(seen), monkeypatch, subset)
            for a, b in zip(out, ref_out):
                assert torch.equal(a, b), f"{name}: forward differs when cut into pieces (declared forward=True?)"
            for k in subset:
                assert torch.equal(grads[k], ref_grads[k]), (
                    f"{name}: gradient of {spec.inputs[k]!r} differs when cut into pieces: its declared scope "
                    f"({scope_of(spec, params, k)}) is wrong"
                )
    # every kernel an op launches was cut, forward and (if it has one) adjoint. Kernels that no op
    # launches through launch() (the pure-Warp normal equations and the aligner's kernels replay
    # their own recorded splits) have their own any-thread-count tests.
    op_kernels = set()
    for name, spec in OPS.items():
        params = samples[name][len(spec.inputs):]
        for fk in (spec.kernel_for(params), spec.backward_kernel_for(params)):
            if fk is not None and fk in kinds.registered():
                op_kernels.add(fk)
    missing = []
    for fk in op_kernels:
        info = kinds.declaration(fk[L.FLOAT_TYPES[0]])
        if info.blocked is not None:  # launches run its blocked variant
            fk = kinds.declaration(info.blocked[0]).owner
        forward_only = not fk.kernel.options.get("enable_backward", True)
        for adjoint in (False,) if forward_only else (False, True):
            if (fk.kernel.key, adjoint) not in seen:
                missing.append(f"{fk.kernel.key} ({'adjoint' if adjoint else 'forward'})")
    assert not missing, f"kernels no op sample reaches (add to tests/op_samples.py): {missing}"
