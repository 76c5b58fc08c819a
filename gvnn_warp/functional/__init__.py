"""The functional torch API: every op of gvnn_warp as a function on tensors.

Every function takes float32 or float64 CPU tensors (all floating arguments of one call in the
same dtype), returns gradients for every floating argument through Warp's adjoints, validates its
arguments with a clear error naming the function and the argument, and never modifies its inputs.
Conventions (pixel centres, (x, y) order, ``[omega, t]`` order, units, valid masks):
``docs/conventions.md``.

- :mod:`.geometry`: global transformations (so3, SE3, Sim3, quaternions, Euler angles), the 3D
  grid generator, projection, the bilinear sampler and the 3D spatial transformer;
- :mod:`.perpixel`: per-pixel transformations, M-estimators, smoothness;
- :mod:`.photometric`: the fused photometric objective of direct alignment.
"""

from . import geometry, perpixel, photometric
from .geometry import *  # noqa: F403
from .perpixel import *  # noqa: F403
from .photometric import *  # noqa: F403

__all__ = [*geometry.__all__, *perpixel.__all__, *photometric.__all__]
