"""Moved: the kernels through a lens model are made on first use beside their pinhole twins,
:func:`.error_rows.photometric_rows_lens` and :func:`.normal_equations.normal_equations_rows_lens`.
This module keeps the names of before for gvnn_warp/ops (the lead removes it)."""

from .error_rows import photometric_rows_lens as _photometric_rows_lens
from .normal_equations import normal_equations_rows_lens as _normal_equations_rows_lens

photometric_rows_lens = _photometric_rows_lens()  # (re-export for gvnn_warp/ops/; the lead removes it)
#: indexed by depth term (1) + 2 * occlusion test (1)  (re-export for gvnn_warp/ops/; the lead removes it)
normal_equations_rows_lens = tuple(_normal_equations_rows_lens(k & 1 == 1, k >= 2) for k in range(4))
