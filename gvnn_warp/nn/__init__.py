"""``nn.Module`` layers over :mod:`gvnn_warp.functional`; each ``forward`` is one functional call.

Mirrors :mod:`gvnn_warp.functional`:

- :mod:`.lie`: the global transformations (gvnn's SO3, SE3, Sim3 layers);
- :mod:`.camera`: the 3D grid generator and the projection layer;
- :mod:`.sampling`: the bilinear sampler and the 3D spatial transformer;
- :mod:`.perpixel`: per-pixel transformations, M-estimators, smoothness;
- :mod:`.photometric`: the fused photometric objective as a loss.
"""

from . import camera, lie, perpixel, photometric, sampling
from .camera import *  # noqa: F403
from .lie import *  # noqa: F403
from .perpixel import *  # noqa: F403
from .photometric import *  # noqa: F403
from .sampling import *  # noqa: F403

__all__ = [*lie.__all__, *camera.__all__, *sampling.__all__, *perpixel.__all__, *photometric.__all__]
