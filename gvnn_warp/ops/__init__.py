"""The torch side under the front: every Warp kernel registered as a ``gvnn_warp::*`` torch custom
op whose backward is the same kernel's Warp adjoint.

- :mod:`.bridge`: :func:`~.bridge.warp_op` (the declarative registration) and the registry
  :data:`~.bridge.OPS`;
- :mod:`.checks`: :class:`~.checks.ArgCheck`, the argument checks of the public functions;
- :mod:`.compat`: the torch internals gvnn_warp uses, one adapter each;
- the registrations, by concept: :mod:`.geometry`, :mod:`.lens`, :mod:`.perpixel`,
  :mod:`.photometric`.

The ops take validated, flattened, contiguous tensors; the documented entry points are in
:mod:`gvnn_warp.functional`.
"""
