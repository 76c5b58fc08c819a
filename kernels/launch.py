"""Typed kernel overloads and the one launch helper every op goes through.

Kernels in this package are generic (``typing.Any`` arrays) and declare, through
:class:`FloatKernel`, the *kind* of each array argument (``"scalar"``, ``"vec3"``, ``"mat34"``...).
That one declaration gives both the concrete float32/float64 overloads (compiled together, so a
module loads once) and the element types the torch bridge needs to wrap tensors zero-copy.

Every per-element kernel takes ``offset: int`` as its first argument and handles element
``wp.tid() + offset``, so a launch range can be split into chunks.
"""

from __future__ import annotations

from collections.abc import Sequence

import warp as wp

mat34f = wp.types.matrix(shape=(3, 4), dtype=wp.float32)
mat34d = wp.types.matrix(shape=(3, 4), dtype=wp.float64)

# kind -> (element shape, {float type: Warp element type})
KINDS: dict[str, tuple[tuple[int, ...], dict]] = {
    "scalar": ((), {wp.float32: wp.float32, wp.float64: wp.float64}),
    "vec2": ((2,), {wp.float32: wp.vec2f, wp.float64: wp.vec2d}),
    "vec3": ((3,), {wp.float32: wp.vec3f, wp.float64: wp.vec3d}),
    "vec4": ((4,), {wp.float32: wp.vec4f, wp.float64: wp.vec4d}),
    "mat33": ((3, 3), {wp.float32: wp.mat33f, wp.float64: wp.mat33d}),
    "mat34": ((3, 4), {wp.float32: mat34f, wp.float64: mat34d}),
    "bool": ((), {wp.float32: wp.bool, wp.float64: wp.bool}),
}
FLOAT_TYPES = (wp.float32, wp.float64)


def element_type(kind: str, float_type) -> type:
    """The Warp element type of an array of ``kind`` for ``float_type``."""
    return KINDS[kind][1][float_type]


def element_shape(kind: str) -> tuple[int, ...]:
    """The trailing shape one element of ``kind`` occupies in a tensor, e.g. (3, 4) for mat34."""
    return KINDS[kind][0]


class FloatKernel:
    """A generic kernel with explicit float32 and float64 overloads.

    ``FloatKernel(kernel, image="scalar", pose="mat34", ...)`` names the kind of every generic
    array argument; ``fk[wp.float64]`` is the concrete float64 kernel.
    """

    def __init__(self, kernel: wp.Kernel, **array_kinds: str):
        self.kernel = kernel
        self.array_kinds = dict(array_kinds)
        self._overloads = {
            ft: wp.overload(
                kernel, {name: wp.array(dtype=element_type(kind, ft)) for name, kind in array_kinds.items()}
            )
            for ft in FLOAT_TYPES
        }

    def __getitem__(self, float_type) -> wp.Kernel:
        return self._overloads[float_type]


def launch(
    kernel: wp.Kernel,
    n: int,
    inputs: Sequence,
    outputs: Sequence,
    *,
    adjoint: bool = False,
    adj_inputs: Sequence | None = None,
    adj_outputs: Sequence | None = None,
) -> None:
    """Launch ``kernel`` over elements [0, n) on the CPU (forward, or its adjoint).

    ``inputs``/``outputs`` exclude the leading ``offset`` argument, which this helper supplies.
    For an adjoint launch, ``adj_inputs`` holds one gradient array (or a placeholder for scalar
    arguments) per input, accumulated into (callers zero them), and ``adj_outputs`` the incoming
    gradient of each output (``None`` for non-differentiable ones).
    """
    if n == 0:
        return
    if adjoint:
        wp.launch(
            kernel,
            dim=n,
            inputs=[0, *inputs],
            outputs=list(outputs),
            adj_inputs=[0, *adj_inputs],
            adj_outputs=list(adj_outputs),
            adjoint=True,
            device="cpu",
        )
    else:
        wp.launch(kernel, dim=n, inputs=[0, *inputs], outputs=list(outputs), device="cpu")
