"""Importing this module defines, now, the torch ops through lens models (``lazy=True`` in their
registrations: the camera objects' projections, the pixel rays, the 3D spatial transformer and
the photometric objective through a distorted camera), which are otherwise defined on their first
use: a program that loads a saved graph holding them (``torch.export.load``) imports it first
(as ``gvnn_warp._lens_ops``, its path in earlier releases, or ``gvnn_warp.ops.lens``). Their
kernels are still made on their first launch.
"""

from __future__ import annotations

import sys

from . import geometry, photometric, sampling
from .registry import OPS

LENS_OPS = tuple(sorted(name for name, spec in OPS.items() if spec.lazy))
for _name in LENS_OPS:
    getattr(sys.modules[OPS[_name].module], _name)  # (the module's __getattr__ defines it)

__all__ = ["LENS_OPS", "geometry", "photometric", "sampling"]
