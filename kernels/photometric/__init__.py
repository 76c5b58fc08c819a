"""The fused photometric objective of direct alignment:

- :mod:`.residual`: per-pixel residuals, penalties and their gradients (``@wp.func``), 8-lane helpers;
- :mod:`.error`: the error and its gradients in one pass; :mod:`.normal_equations`: the
  Gauss-Newton normal equations (and the reference kernels the tests compare with), through a
  lens model in :mod:`.lens_kernels`;
- :mod:`.lm`: the Levenberg-Marquardt step on the 6x6 systems;
- :mod:`.pipeline`: host functions on ``wp.array`` s (``photometric_error``,
  ``photometric_normal_equations``).
"""

import importlib


def __getattr__(name: str):
    # the former module gvnn_warp.kernels.photometric is now .residual: its names still resolve here
    value = getattr(importlib.import_module(".residual", __name__), name)
    globals()[name] = value
    return value
