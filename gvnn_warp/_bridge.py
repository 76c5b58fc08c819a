"""The bridge from Warp kernels to PyTorch autograd.

:func:`warp_op` turns a :class:`gvnn_warp.kernels.launch.FloatKernel` into a
``torch.library.custom_op`` (so ``torch.compile(fullgraph=True)`` can trace it) whose backward is
a second custom op that runs the *same kernel's Warp adjoint*. Tensors are wrapped zero-copy with
``wp.from_torch`` on detached, contiguous views; nothing here computes the op itself.

Callers (``functional.py``) validate and flatten arguments first: every tensor handed to an op
is contiguous, on the CPU, float32 or float64 (all the same), with shape ``(n, *element_shape)``
for its kind.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
import warp as wp

from .kernels.launch import FloatKernel, element_shape, element_type, launch

wp.config.quiet = True
wp.init()

_FLOAT_TYPES = {torch.float32: wp.float32, torch.float64: wp.float64}


def to_warp(t: torch.Tensor, kind: str, float_type) -> wp.array:
    """Zero-copy 1-D Warp array of ``kind`` elements over a contiguous tensor (never its grad)."""
    n_inner = len(element_shape(kind))
    return wp.from_torch(
        t.detach().reshape((-1, *t.shape[t.dim() - n_inner :])) if n_inner else t.detach().reshape(-1),
        dtype=element_type(kind, float_type),
        requires_grad=False,
    )


@dataclass(frozen=True)
class Param:
    """A non-tensor kernel argument: its name and schema type (``int``, ``float`` or ``bool``)."""

    name: str
    type: str


@dataclass(frozen=True)
class Output:
    """A kernel output: its name, kind, and shape as a function of the op's arguments."""

    name: str
    kind: str
    shape: Callable[..., Sequence[int]]
    differentiable: bool = True


def warp_op(
    name: str,
    fk: FloatKernel,
    inputs: Sequence[str],
    params: Sequence[Param],
    outputs: Sequence[Output],
    n_threads: Callable[..., int],
) -> Callable:
    """Register ``gvnn_warp::<name>`` (forward) and ``gvnn_warp::<name>_backward``.

    ``inputs`` are the kernel's tensor arguments in order (their kinds come from ``fk``),
    ``params`` its scalar arguments (after the tensors), ``outputs`` its output arrays (last).
    ``n_threads(*tensors, *params)`` is the launch size. Returns the forward op.
    """
    in_kinds = [fk.array_kinds[n] for n in inputs]
    n_in = len(inputs)
    sig_in = ", ".join([f"Tensor {n}" for n in inputs] + [f"{p.type} {p.name}" for p in params])
    ret = "Tensor" if len(outputs) == 1 else "(" + ", ".join("Tensor" for _ in outputs) + ")"
    diff_outputs = [o for o in outputs if o.differentiable]

    def out_dtype(o: Output, ref: torch.Tensor) -> torch.dtype:
        return torch.bool if o.kind == "bool" else ref.dtype

    def alloc_outputs(args, empty=torch.empty):
        ref = args[0]
        return [empty(tuple(o.shape(*args)), dtype=out_dtype(o, ref), device=ref.device) for o in outputs]

    def wrap(args, outs):
        ft = _FLOAT_TYPES[args[0].dtype]
        arrays = [to_warp(t, k, ft) for t, k in zip(args[:n_in], in_kinds)]
        out_arrays = [to_warp(t, o.kind, ft) for t, o in zip(outs, outputs)]
        return ft, arrays, out_arrays

    def forward(*args):
        outs = alloc_outputs(args)
        n = n_threads(*args)
        if n > 0:
            ft, arrays, out_arrays = wrap(args, outs)
            launch(fk[ft], n, [*arrays, *args[n_in:]], out_arrays)
        return outs[0] if len(outs) == 1 else tuple(outs)

    def forward_fake(*args):
        outs = alloc_outputs(args, empty=torch.empty)
        return outs[0] if len(outs) == 1 else tuple(outs)

    fwd = torch.library.custom_op(
        f"gvnn_warp::{name}", forward, mutates_args=(), schema=f"({sig_in}) -> {ret}"
    )
    fwd.register_fake(forward_fake)

    # backward(*tensors, *params, *grads of differentiable outputs) -> grads of the tensors
    sig_grads = ", ".join(f"Tensor grad_{o.name}" for o in diff_outputs)

    def backward_impl(*args):
        fargs, grads = args[: n_in + len(params)], args[n_in + len(params) :]
        in_grads = [torch.zeros_like(t) for t in fargs[:n_in]]
        n = n_threads(*fargs)
        if n == 0:
            return in_grads
        scratch = alloc_outputs(fargs)  # the adjoint replays the forward's stores into these
        ft, arrays, out_arrays = wrap(fargs, scratch)
        adj_in = [to_warp(g, k, ft) for g, k in zip(in_grads, in_kinds)]
        g_iter = iter(grads)
        adj_out = [
            to_warp(next(g_iter).contiguous(), o.kind, ft) if o.differentiable else None for o in outputs
        ]
        launch(
            fk[ft],
            n,
            [*arrays, *fargs[n_in:]],
            out_arrays,
            adjoint=True,
            adj_inputs=[*adj_in, *fargs[n_in:]],
            adj_outputs=adj_out,
        )
        return in_grads

    def backward_fake(*args):
        return [torch.empty_like(t) for t in args[:n_in]]

    bwd = torch.library.custom_op(
        f"gvnn_warp::{name}_backward",
        backward_impl,
        mutates_args=(),
        schema=f"({sig_in}, {sig_grads}) -> Tensor[]",
    )
    bwd.register_fake(backward_fake)

    def setup_context(ctx, inputs, output):
        ctx.save_for_backward(*inputs[:n_in])
        ctx.params = inputs[n_in:]

    def autograd_backward(ctx, *grad_outs):
        tensors = ctx.saved_tensors
        grads = []
        for o, g in zip(outputs, grad_outs):
            if o.differentiable:
                grads.append(g if g is not None else tensors[0].new_zeros(tuple(o.shape(*tensors, *ctx.params))))
        in_grads = bwd(*tensors, *ctx.params, *grads)
        return (*in_grads, *([None] * len(params)))

    fwd.register_autograd(autograd_backward, setup_context=setup_context)
    return fwd
