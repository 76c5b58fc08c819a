"""``nn.Module`` layers over :mod:`gvnn_warp.functional`; each ``forward`` is one functional call.

- :mod:`.layers`: the global transformations, the 3D grid generator, projection, the bilinear
  sampler and the 3D spatial transformer (gvnn's layers);
- :mod:`.perpixel`: per-pixel transformations, M-estimators, smoothness;
- :mod:`.photometric`: the fused photometric objective as a loss.
"""

from . import layers, perpixel, photometric
from .layers import *  # noqa: F403
from .perpixel import *  # noqa: F403
from .photometric import *  # noqa: F403

__all__ = [*layers.__all__, *perpixel.__all__, *photometric.__all__]
