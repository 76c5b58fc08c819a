"""The functional torch API: every op of gvnn_warp as a function on tensors.

Every function takes float32 or float64 CPU tensors (all floating arguments of one call in the
same dtype), returns gradients for every floating argument through Warp's adjoints, validates its
arguments with a clear error naming the function and the argument, and never modifies its inputs.
Conventions (pixel centres, (x, y) order, ``[omega, t]`` order, units, valid masks):
``docs/conventions.md``.

- :mod:`.lie`: global transformations (so3, SE3, Sim3, quaternions, Euler angles);
- :mod:`.camera`: the 3D grid generator, points moved by poses, projection;
- :mod:`.sampling`: the bilinear sampler and the 3D spatial transformer;
- :mod:`.perpixel`: per-pixel transformations, M-estimators, smoothness;
- :mod:`.photometric`: the fused photometric objective of direct alignment;
- :mod:`.reprojection`: the self-supervised reprojection objective (Monodepth2) and smoothness.
"""

from .._exports import lazy_exports

# the public names are those of the modules (their __all__), each loaded on first use
__getattr__, __dir__ = lazy_exports(__name__, ('lie', 'camera', 'sampling', 'perpixel', 'photometric', 'reprojection'))
