"""``nn.Module`` layers over :mod:`gvnn_warp.functional`; each ``forward`` is one functional call.

Mirrors :mod:`gvnn_warp.functional`:

- :mod:`.lie`: the global transformations (gvnn's SO3, SE3, Sim3 layers);
- :mod:`.camera`: the 3D grid generator and the projection layer;
- :mod:`.sampling`: the bilinear sampler and the 3D spatial transformer;
- :mod:`.perpixel`: per-pixel transformations, M-estimators, smoothness;
- :mod:`.photometric`: the fused photometric objective as a loss.
"""

from .._exports import lazy_exports

# the public names are those of the modules (their __all__), each loaded on first use
__getattr__, __dir__ = lazy_exports(__name__, ('lie', 'camera', 'sampling', 'perpixel', 'photometric', 'reprojection'))
