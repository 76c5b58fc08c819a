"""The bridge from Warp kernels to PyTorch autograd.

:func:`warp_op` turns a :class:`gvnn_warp.kernels.core.kinds.FloatKernel` into a
``torch.library.custom_op`` (so ``torch.compile(fullgraph=True)`` can trace it) whose backward is
a second custom op that runs the *same kernel's Warp adjoint*, and registers it in
:data:`.registry.OPS` with the public function and layer it serves (beside
:func:`.registry.custom_op`, for ops written by hand). Tensors are wrapped zero-copy with
:func:`descriptor` (or :func:`to_warp`) on detached, contiguous views; nothing here computes the
op itself.

Callers (``gvnn_warp.functional``) validate and flatten arguments first: every tensor handed to an
op is contiguous, on the CPU, float32 or float64 (all the same), with shape
``(n, *element_shape)`` for its kind.

Launches go through :func:`gvnn_warp.kernels.core.launch.launch`, which splits them over threads; the
thread count follows ``torch.get_num_threads()`` unless set with
``gvnn_warp.set_num_threads`` or ``GVNN_WARP_NUM_THREADS``.
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable, Sequence

import torch
import warp as wp

from ..kernels.core.compat import array_descriptor
from ..kernels.core.launch import FloatKernel, element_shape, element_type, launch, set_default_num_threads, use_openmp
from . import compat as _compat
from .registry import OPS, OpSpec, Output, Param, register, skip_lazy_dynamo_import

wp.init()
set_default_num_threads(torch.get_num_threads)


def _use_torch_openmp() -> None:
    """Run threaded launches on torch's OpenMP team, whose threads spin, waiting for work, after
    every parallel torch op (Python threads would share the cores with them), unless
    ``GVNN_WARP_OPENMP=0``; gvnn_warp's own Python threads otherwise, or if that fails. The choice
    and its reason: ``gvnn_warp.info()`` (and a DEBUG line on the ``gvnn_warp`` logger)."""
    if os.environ.get("GVNN_WARP_OPENMP", "1") == "0":
        use_openmp(None, "GVNN_WARP_OPENMP=0; using Python threads")
        return
    library, reason = _compat.torch_openmp_library()
    try:
        use_openmp(library, reason)
    except (OSError, AttributeError) as e:  # no such library or symbol: the Python threads stay
        use_openmp(None, f"torch's OpenMP runtime could not be used ({e}); using Python threads")


_use_torch_openmp()

WARP_FLOAT = {torch.float32: wp.float32, torch.float64: wp.float64}  # torch dtype -> Warp float type


# ----------------------------------------------------------------------------- tensors as Warp arrays


def to_warp(t: torch.Tensor, kind: str, float_type) -> wp.array:
    """Zero-copy 1-D Warp array of ``kind`` elements over a contiguous tensor (never its grad)."""
    n_inner = len(element_shape(kind))
    return wp.from_torch(
        t.detach().reshape((-1, *t.shape[t.dim() - n_inner :])) if n_inner else t.detach().reshape(-1),
        dtype=element_type(kind, float_type),
        requires_grad=False,
    )


@functools.cache
def null_array(kind: str, float_type):
    """A null array (no data, no elements) of ``kind``: the adjoint of an input whose gradient is
    not wanted, or of a non-differentiable output. Warp's adjoints skip writes to it; its stride
    is the element size, as a contiguous array's, so it keeps the kernel on Warp's faster
    contiguous-array path."""
    return array_descriptor(0, 0, wp.types.type_size_in_bytes(element_type(kind, float_type)))


def descriptor(t: torch.Tensor, kind: str, float_type):
    """Like :func:`to_warp` but returns a bare 1-D array descriptor (~1 us instead of ~9 us), which
    :func:`~gvnn_warp.kernels.core.launch.launch` accepts. It holds no reference to ``t``: keep ``t``
    alive while the descriptor is used."""
    if not t.is_contiguous():
        return to_warp(t, kind, float_type)  # a copy: the wp.array keeps it alive
    inner = 1
    for d in element_shape(kind):
        inner *= d
    n = t.numel() // inner
    return array_descriptor(t.data_ptr(), n, inner * t.element_size())




def warp_op(
    name: str,
    fk: FloatKernel | Callable[[], FloatKernel] | None,
    inputs: Sequence[str],
    params: Sequence[Param],
    outputs: Sequence[Output],
    n_threads: Callable[..., int],
    *,
    function: str,
    layer: str,
    backward_from: Callable | None = None,
    select: Callable[..., FloatKernel] | None = None,
    backward_select: Callable[..., FloatKernel] | None = None,
    array_kinds: dict[str, str] | None = None,
    lazy: bool = False,
    untested: dict[str, str] | None = None,
) -> Callable | OpSpec:
    """Register ``gvnn_warp::<name>`` (forward) and ``gvnn_warp::<name>_backward``.

    ``inputs`` are the kernel's tensor arguments in order (their kinds come from ``fk``),
    ``params`` its scalar arguments (after the tensors), ``outputs`` its output arrays (last).
    ``n_threads(*tensors, *params)`` is the launch size. ``function`` is the public function of
    gvnn_warp the op serves, ``layer`` its ``nn.Module`` layer or ``"no layer: <why>"``
    (``tests/ops/test_registry.py`` checks both exist and are documented); ``untested`` maps a
    test of every op (``"scopes"``, ``"gradients"``) that does not apply to this one to why.
    Returns the forward op.

    ``fk`` may be a maker, ``fk() -> FloatKernel``, called on the first launch (a kernel that
    takes seconds to define); ``array_kinds`` then names the inputs' kinds. ``lazy``: the torch op
    too is defined on first use, as the module's attribute ``name`` (the module sets
    ``__getattr__ = lazy_ops(__name__)``, see :func:`.registry.lazy_ops`; :mod:`.lens` defines
    them all): 5-15 ms per op, which a user who never calls it should not pay.
    ``torch.ops.gvnn_warp.<name>`` exists from then on, and the call returns the
    :class:`~.registry.OpSpec` (not to be bound to that name).

    ``backward_from``: an op made by this function with the same arguments and outputs whose
    kernel computes the same values; its backward (its kernel's Warp adjoint) is used, and none
    is registered for this one (whose kernel may then be forward-only).

    ``select(*params) -> FloatKernel``: the kernel for these scalar arguments (a variant compiled
    for them), instead of ``fk``; its adjoint is the backward unless ``backward_from`` gives one.
    With ``select``, ``fk`` may be None and ``array_kinds`` name the kinds of the kernels' arrays
    (none is built up front).

    ``backward_select(needs, *params) -> FloatKernel``: the kernel whose adjoint the backward
    launches when the gradients of bit set ``needs`` are wanted (bit k: input k), a variant that
    computes the same values but compiles only the gradients asked for; else ``select``'s.
    """
    # what an op that borrows another's backward must share with it (array kinds may differ: views)
    signature = (tuple(inputs), tuple(params), tuple((o.name, o.differentiable) for o in outputs))
    source = OPS.get(getattr(backward_from, "_gvnn_name", None)) if backward_from is not None else None
    if backward_from is not None and (source is None or _signature(source) != signature):
        raise ValueError(f"warp_op {name!r}: backward_from must be a warp_op with the same inputs, params, outputs")
    if backward_from is not None and backward_select is not None:
        raise ValueError(f"warp_op {name!r}: backward_from and backward_select exclude each other (the backward "
                         "is the other op's, or this op's kernels')")
    kinds = dict(array_kinds) if array_kinds is not None else {n: fk.array_kinds[n] for n in inputs}
    spec = OpSpec(
        name, tuple(inputs), tuple(params), tuple(outputs), function, layer,
        differentiable=any(o.differentiable for o in outputs), kernel=fk, array_kinds=kinds, select=select,
        backward_from=source.name if source is not None else None, backward_select=backward_select, lazy=lazy,
        untested=dict(untested or {}),
        define=functools.partial(_define_warp_op, n_threads=n_threads),
    )
    return register(spec)


def _signature(spec: OpSpec) -> tuple:
    return spec.inputs, spec.params, tuple((o.name, o.differentiable) for o in spec.outputs)


def _define_warp_op(spec: OpSpec, n_threads: Callable[..., int]) -> Callable:
    """The torch ops of a :func:`warp_op` registration (forward, and backward unless borrowed)."""
    name, inputs, params, outputs = spec.name, spec.inputs, spec.params, spec.outputs
    in_kinds = [spec.array_kinds[n] for n in inputs]
    n_in = len(inputs)
    sig_in = ", ".join([f"Tensor {n}" for n in inputs] + [f"{p.type} {p.name}" for p in params])
    ret = "Tensor" if len(outputs) == 1 else "(" + ", ".join("Tensor" for _ in outputs) + ")"
    diff_outputs = [o for o in outputs if o.differentiable]

    def out_dtype(o: Output, ref: torch.Tensor) -> torch.dtype:
        return {"bool": torch.bool, "int32": torch.int32}.get(o.kind, ref.dtype)

    def output_shapes(args) -> list[tuple]:
        return [tuple(o.shape(*args)) for o in outputs]

    def alloc_outputs(args, shapes=None):
        ref = args[0]
        shapes = output_shapes(args) if shapes is None else shapes
        return [torch.empty(s, dtype=out_dtype(o, ref), device=ref.device) for s, o in zip(shapes, outputs)]

    def wrap(args, outs):
        ft = WARP_FLOAT[args[0].dtype]
        arrays = [descriptor(t, k, ft) for t, k in zip(args[:n_in], in_kinds)]
        out_arrays = [descriptor(t, o.kind, ft) for t, o in zip(outs, outputs)]
        return ft, arrays, out_arrays

    def forward(*args):
        shapes = output_shapes(args)
        for shape in shapes:  # inputs are checked by ArgCheck; an output can be far larger (e.g. a big grid)
            if math.prod(shape) >= 2**31:
                raise ValueError(
                    f"gvnn_warp.{name}: the output would have shape {shape} ({math.prod(shape)} elements); "
                    "kernels index with int32 (< 2**31): split the batch"
                )
        outs = alloc_outputs(args, shapes)
        n = n_threads(*args)
        if n > 0:
            ft, arrays, out_arrays = wrap(args, outs)
            kernel = spec.kernel_for(args[n_in:])
            launch(kernel[ft], n, [*arrays, *args[n_in:]], out_arrays)
        return outs[0] if len(outs) == 1 else tuple(outs)

    def forward_fake(*args):
        outs = alloc_outputs(args)
        return outs[0] if len(outs) == 1 else tuple(outs)

    fwd = torch.library.custom_op(
        f"gvnn_warp::{name}", forward, mutates_args=(), schema=f"({sig_in}) -> {ret}"
    )
    fwd.register_fake(forward_fake)
    skip_lazy_dynamo_import(fwd)
    fwd._gvnn_name = name
    if spec.backward_from is not None:
        backward, setup_context = OPS[spec.backward_from].op._gvnn_autograd
        fwd.register_autograd(backward, setup_context=setup_context)
        return fwd

    # backward(*tensors, *params, needs, *grads of differentiable outputs) -> grads of the tensors;
    # bit k of ``needs`` asks for the gradient of tensor k (the others come back empty)
    sig_grads = ", ".join(["int needs"] + [f"Tensor grad_{o.name}" for o in diff_outputs])

    def backward_impl(*args):
        n_args = n_in + len(params)
        fargs, needs, grads = args[:n_args], args[n_args], args[n_args + 1 :]
        wanted = [bool(needs >> k & 1) for k in range(n_in)]
        n = n_threads(*fargs)
        # zeroed by torch (its OpenMP team, the one the launch below runs on)
        in_grads = [
            torch.zeros(t.shape, dtype=t.dtype) if w else t.new_empty(0) for t, w in zip(fargs[:n_in], wanted)
        ]
        if n == 0 or not any(wanted):
            return in_grads
        scratch = alloc_outputs(fargs)  # the adjoint replays the forward's stores into these
        ft, arrays, out_arrays = wrap(fargs, scratch)
        # a gradient nobody asked for gets a null array: Warp's adjoints skip writes to it, and the
        # hand-written ones check (see gvnn_warp.kernels.sampling.scalar.sample_channels_grad)
        adj_in = [descriptor(g, k, ft) if w else null_array(k, ft) for g, k, w in zip(in_grads, in_kinds, wanted)]
        g_iter = iter(grads)
        # incoming gradients made contiguous, broadcast ones too (e.g. from out.sum().backward()):
        # reading a stride-0 array in place would take the kernel off Warp's contiguous-array path,
        # which costs more than the copy (measured: bilinear_sample fwd+bwd ~5% slower)
        readable = [next(g_iter).contiguous() if o.differentiable else None for o in outputs]
        adj_out = [
            descriptor(g, o.kind, ft) if g is not None else null_array(o.kind, ft) for g, o in zip(readable, outputs)
        ]
        launch(
            spec.backward_kernel_for(fargs[n_in:], needs)[ft],
            n,
            [*arrays, *fargs[n_in:]],
            out_arrays,
            adjoint=True,
            adj_inputs=[*adj_in, *fargs[n_in:]],
            adj_outputs=adj_out,
        )
        return in_grads

    def backward_fake(*args):
        needs = args[n_in + len(params)]
        return [
            torch.empty(t.shape, dtype=t.dtype) if needs >> k & 1 else t.new_empty(0) for k, t in enumerate(args[:n_in])
        ]

    bwd = torch.library.custom_op(
        f"gvnn_warp::{name}_backward",
        backward_impl,
        mutates_args=(),
        schema=f"({sig_in}, {sig_grads}) -> Tensor[]",
    )
    bwd.register_fake(backward_fake)

    def no_second_order(ctx, *grads):
        raise NotImplementedError(
            f"gvnn_warp.{name}: second-order gradients are not supported (its backward is a Warp adjoint "
            "launch, which has no adjoint of its own); see docs/conventions.md"
        )

    # without this, create_graph=True would seem to work and the second backward would fail with a
    # torch-internal "no autograd formula" error
    bwd.register_autograd(no_second_order, setup_context=lambda ctx, inputs, output: None)
    skip_lazy_dynamo_import(bwd)

    def setup_context(ctx, inputs, output):
        ctx.save_for_backward(*inputs[:n_in])
        ctx.params = inputs[n_in:]

    def autograd_backward(ctx, *grad_outs):
        tensors = ctx.saved_tensors
        needs = sum(1 << k for k in range(n_in) if ctx.needs_input_grad[k])
        grads = []
        for o, g in zip(outputs, grad_outs):
            if o.differentiable:
                grads.append(g if g is not None else tensors[0].new_zeros(tuple(o.shape(*tensors, *ctx.params))))
        in_grads = bwd(*tensors, *ctx.params, needs, *grads)
        return (*(g if ctx.needs_input_grad[k] else None for k, g in enumerate(in_grads)), *([None] * len(params)))

    fwd.register_autograd(autograd_backward, setup_context=setup_context)
    fwd._gvnn_autograd = (autograd_backward, setup_context)
    return fwd
