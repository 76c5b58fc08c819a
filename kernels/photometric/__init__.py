"""The fused photometric objective of direct alignment, one module per kernel family:

- :mod:`.residual`: per-pixel residuals, penalties and their gradients (``@wp.func``), 8-lane penalties;
- :mod:`.error_rows`: the error row by row, differentiated by Warp (the reference; pinhole and
  through a lens); :mod:`.error`: the error and its gradients in one pass, 8 pixels at a time,
  reduced and scaled by :mod:`.error_reduce`;
- :mod:`.normal_equations`: the Gauss-Newton normal equations one pixel at a time (pinhole and
  through a lens), :mod:`.normal_equations_lanes`: 8 pixels at a time, both reduced by
  :mod:`.normal_equations_reduce`;
- :mod:`.lm`: the Levenberg-Marquardt step on the 6x6 systems;
- :mod:`.pipeline`: host functions on ``wp.array`` s (``photometric_error``,
  ``photometric_normal_equations``).

Variants (a penalty, a channel count, a lens) are made on first use through :mod:`..core.cache`.
"""

from ..core.moved import names_of

# the former module gvnn_warp.kernels.photometric is now this package: its names still resolve here
__getattr__ = names_of(__name__, ".residual", "..core.lanes")
