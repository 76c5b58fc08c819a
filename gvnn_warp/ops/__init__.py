"""The torch side under the front: every Warp kernel registered as a ``gvnn_warp::*`` torch custom
op whose backward is the same kernel's Warp adjoint.

- :mod:`.registry`: :data:`~.registry.OPS`, every op with its arguments, kernels, and the public
  function and layer it serves, and :func:`~.registry.custom_op`, the registration of an op
  written by hand;
- :mod:`.bridge`: :func:`~.bridge.warp_op`, the registration of a Warp kernel as an op (its
  backward the kernel's adjoint), and the tensor-to-Warp descriptors;
- :mod:`.checks`: :class:`~.checks.ArgCheck`, the argument checks of the public functions;
- :mod:`.compat`: the torch internals gvnn_warp uses, one adapter each;
- the registrations, by concept (importing them fills :data:`~.registry.OPS`): :mod:`.geometry`
  (rotations, cameras, lens models), :mod:`.sampling` (the bilinear sampler, the 3D spatial
  transformer), :mod:`.perpixel`, :mod:`.photometric`; the ops through lens models are defined in
  torch on first use, or all at once by importing :mod:`.lens`.

The ops take validated, flattened, contiguous tensors; the documented entry points are in
:mod:`gvnn_warp.functional`.
"""
