"""The registry of every torch op of gvnn_warp: :data:`OPS`, one :class:`OpSpec` per op (its
arguments, kernels, the public function and layer it serves, the tests that do not apply to it),
filled by the declarative registrations: :func:`.bridge.warp_op` (an op whose forward and backward
are a Warp kernel and its adjoint) and :func:`custom_op` (an op whose code is written by hand).
An op registered ``lazy`` is defined in torch on first use (:func:`lazy_ops`).
"""

from __future__ import annotations

import inspect
import sys
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import torch

from ..kernels.core.launch import FloatKernel
from . import compat as _compat


def skip_lazy_dynamo_import(op) -> None:
    """Spare the first call of ``op`` the import of ``torch._dynamo`` (~2 s; see
    :func:`.compat.defer_dynamo_disable`)."""
    for impl in _compat.custom_op_implementations(op):
        _compat.defer_dynamo_disable(impl)


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


def rows(t, *_) -> int:
    """Launch size (or shape function) of a per-row op: the first argument's length."""
    return t.shape[0]


def per_row(*inner: int) -> Callable[..., tuple[int, ...]]:
    """Output shape (n, *inner) for a first argument of length n."""
    return lambda t, *_: (t.shape[0], *inner)


# (two threads' first calls of a lazy op would define it twice; reentrant: a definition may need another op's)
_DEFINE_LOCK = threading.RLock()


@dataclass(eq=False)
class OpSpec:
    """One registered op (see :data:`OPS`): its arguments, kernels, the public function and layer
    it serves, and the tests that do not apply to it (``untested``: test -> why)."""

    name: str
    inputs: tuple[str, ...]  # its tensor arguments, in order
    params: tuple[Param, ...]  # its scalar arguments (after the tensors)
    outputs: tuple[Output, ...]  # its kernel's outputs (a hand-written op: none listed)
    function: str  # the public function in gvnn_warp it serves
    layer: str  # its nn.Module layer in gvnn_warp, or "no layer: <why>"
    differentiable: bool
    kernel: FloatKernel | Callable[[], FloatKernel] | None = None  # or a maker, called on first launch
    array_kinds: dict[str, str] = field(default_factory=dict)  # the inputs' kinds
    select: Callable[..., FloatKernel] | None = None
    backward_from: str | None = None  # the op whose backward (kernel adjoint) this one uses
    backward_select: Callable[..., FloatKernel] | None = None  # (needs, *params) -> the backward's kernel
    lazy: bool = False  # the torch op is defined on first use (see .bridge.warp_op)
    untested: dict[str, str] = field(default_factory=dict)
    module: str = ""  # the registration's module, whose attribute ``name`` is the op
    define: Callable[[OpSpec], Callable] | None = field(default=None, repr=False)
    _op: Callable | None = field(default=None, repr=False)
    _fk: FloatKernel | None = field(default=None, repr=False)

    @property
    def op(self) -> Callable:
        """The torch custom op (``torch.ops.gvnn_warp.<name>``), defined now if it was not yet."""
        if self._op is None:
            with _DEFINE_LOCK:
                if self._op is None:
                    self._op = self.define(self)
        return self._op

    @property
    def fk(self) -> FloatKernel | None:
        """The forward kernel (made now if the registration gave its maker); None with ``select``."""
        if self._fk is None and self.kernel is not None:
            fk = self.kernel if isinstance(self.kernel, FloatKernel) else self.kernel()
            wrong = {n: (k, fk.array_kinds.get(n)) for n, k in self.array_kinds.items() if fk.array_kinds.get(n) != k}
            if wrong:
                raise TypeError(f"gvnn_warp::{self.name}: kernel {fk} has array kinds other than registered: {wrong}")
            self._fk = fk
        return self._fk

    def kernel_for(self, params) -> FloatKernel | None:
        """The kernel a launch with these scalar arguments runs: ``select``'s variant for them, else
        :attr:`fk` (None: a hand-written op)."""
        return self.select(*params) if self.select is not None else self.fk

    def backward_kernel_for(self, params, needs: int = -1) -> FloatKernel | None:
        """The kernel whose Warp adjoint the backward launches with these scalar arguments and these
        wanted gradients (bit k of ``needs``: input k's; all by default): ``backward_select``'s, else
        its own or ``backward_from``'s op's kernel (None: a hand-written op)."""
        if self.backward_select is not None:
            return self.backward_select(needs, *params)
        return (OPS[self.backward_from] if self.backward_from is not None else self).kernel_for(params)


OPS: dict[str, OpSpec] = {}  # every registered op, by name (tests walk it)


def register(spec: OpSpec) -> Callable | OpSpec:
    """Put ``spec`` in :data:`OPS`; returns its op (defined now), or the spec itself if it is lazy.
    For :func:`custom_op` and :func:`.bridge.warp_op`, whose caller's module is the op's."""
    spec.module = sys._getframe(2).f_globals["__name__"]  # the module of the warp_op / custom_op call
    OPS[spec.name] = spec
    return spec if spec.lazy else spec.op


def lazy_ops(module: str) -> Callable[[str], Callable]:
    """The ``__getattr__`` of a registration module (``__getattr__ = lazy_ops(__name__)``): each of
    its lazy ops (``lazy=True``) becomes its attribute when first read, defined in torch then.
    Dynamo reads a module attribute it does not find with ``getattr`` rather than tracing it, so
    a first call inside ``torch.compile(fullgraph=True)`` works too."""

    def __getattr__(name: str) -> Callable:
        spec = OPS.get(name)
        if spec is None or not spec.lazy or spec.module != module:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        op = spec.op
        setattr(sys.modules[module], name, op)
        return op

    return __getattr__


def custom_op(
    name: str,
    impl: Callable,
    fake: Callable,
    *,
    function: str,
    layer: str,
    autograd: tuple[Callable, Callable] | None = None,
    lazy: bool = False,
    untested: dict[str, str] | None = None,
) -> Callable | OpSpec:
    """Register ``gvnn_warp::<name>``, an op whose forward ``impl`` (its schema from its type
    annotations, as ``torch.library.custom_op`` reads them) is written by hand; ``fake`` gives its
    outputs' shapes, ``autograd`` is ``(backward, setup_context)`` as ``register_autograd`` takes
    them (None: not differentiable). ``function``, ``layer``, ``lazy`` and ``untested`` as in
    :func:`.bridge.warp_op`. Returns the op (``lazy``: its :class:`OpSpec`)."""
    sig = inspect.signature(impl, eval_str=True)
    inputs = tuple(n for n, p in sig.parameters.items() if p.annotation is torch.Tensor)
    params = tuple(Param(n, p.annotation.__name__) for n, p in sig.parameters.items() if n not in inputs)
    spec = OpSpec(name, inputs, params, (), function, layer, differentiable=autograd is not None, lazy=lazy,
                  untested=dict(untested or {}), define=lambda s: define_op(s.name, impl, fake, autograd))
    return register(spec)


def define_op(name: str, impl: Callable, fake: Callable, autograd: tuple[Callable, Callable] | None = None):
    """The torch part of :func:`custom_op` (also for a hand-written op's backward op, which is not
    registered on its own): ``gvnn_warp::<name>`` with its fake and autograd implementations."""
    op = torch.library.custom_op(f"gvnn_warp::{name}", impl, mutates_args=())
    op.register_fake(fake)
    if autograd is not None:
        op.register_autograd(autograd[0], setup_context=autograd[1])
    skip_lazy_dynamo_import(op)
    return op
