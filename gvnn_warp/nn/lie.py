"""``nn.Module`` layers of the global transformations (gvnn's SO3, SE3 and Sim3 layers) over
:mod:`gvnn_warp.functional.lie`; each ``forward`` is one call. Shapes and conventions are those of
the functions (see ``docs/conventions.md``).
"""

from __future__ import annotations

from torch import Tensor, nn

from ..functional import lie as F

__all__ = ["SO3", "SE3", "Sim3"]


class SO3(nn.Module):
    """so(3) vector (..., 3) -> rotation matrix (..., 3, 3) by the exponential map."""

    def forward(self, omega: Tensor) -> Tensor:
        return F.so3_exp(omega)


class SE3(nn.Module):
    """[omega, t] (..., 6) -> [so3_exp(omega) | t] (..., 3, 4), the paper's SE3 layer."""

    def forward(self, xi: Tensor) -> Tensor:
        return F.se3_to_matrix(xi)


class Sim3(nn.Module):
    """[omega, t, sigma] (..., 7) -> [exp(sigma) so3_exp(omega) | t] (..., 3, 4)."""

    def forward(self, xi: Tensor) -> Tensor:
        return F.sim3_to_matrix(xi)
