"""Small-strain isotropic linear elasticity written in UFL: a sibling of the RVE material.

``sigma = lam tr(eps) I + 2 mu eps`` with ``eps = sym(grad u)`` (plane strain on a 2-D mesh; the
mesh's dimension d sets the shapes). Nothing is
evaluated per quadrature point: the forms carry the whole law, :meth:`update` does nothing. Use it
for the parts of a model that are not granular (a linear elastic base under a granular layer) or
as a yardstick of cost (the same mesh and solver with the cheapest law).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import ufl

from ..laws.levels import isotropic_lame
from . import compat as dfx
from .quadrature import QuadratureMaterial

if TYPE_CHECKING:
    from dolfinx import fem
    from numpy.typing import ArrayLike
    from ufl.core.expr import Expr

    from ..laws.protocol import HistoryLaw, MaterialLaw


def lame_from_young(E: float, nu: float) -> tuple[float, float]:
    """Lamé constants ``(lam, mu)`` in Pa of Young's modulus E (Pa) and Poisson's ratio nu."""
    E, nu = float(E), float(nu)
    if not (np.isfinite(E) and E > 0 and -1.0 < nu < 0.5):
        raise ValueError(f"need E > 0 and -1 < nu < 0.5, got E = {E!r}, nu = {nu!r}")
    return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


class LinearElasticMaterial(QuadratureMaterial):
    """Isotropic linear elasticity in UFL on the material's cells (all, or ``cells=``).

    Args:
        u: displacement Function (vector Lagrange space of a d-dimensional mesh), in m.
        lam, mu: Lamé constants in Pa (mu > 0, lam + mu > 0).
        quadrature_degree: degree of the "default" scheme of ``dx`` (an integer >= 1).
        cells: local indices of the cells the material occupies (None: all).

    Attributes:
        lam, mu: the constants; and those of
        :class:`~dolfinx_granular.QuadratureMaterial`.
    """

    def __init__(
        self,
        u: fem.Function,
        lam: float,
        mu: float,
        quadrature_degree: int = 2,
        cells: ArrayLike | None = None,
    ) -> None:
        lam, mu = float(lam), float(mu)
        if not (np.isfinite(lam) and np.isfinite(mu) and mu > 0 and lam + mu > 0):
            raise ValueError(f"need mu > 0 and lam + mu > 0 (Pa), got lam = {lam!r}, mu = {mu!r}")
        super().__init__(u, quadrature_degree, cells)
        self.lam, self.mu = lam, mu
        self._sigma_expr = dfx.expression(self.sigma(u), self.reference_points)

    @classmethod
    def isotropic_part(
        cls, rve: MaterialLaw | HistoryLaw, u: fem.Function, **kwargs: Any
    ) -> LinearElasticMaterial:
        """The isotropic projection of a law's small-strain modulus (e.g. the RVE's eq. 15
        modulus, :func:`~dolfinx_granular.laws.levels.isotropic_lame`) as a UFL material."""
        lam, mu = isotropic_lame(rve.small_strain_modulus())
        return cls(u, lam, mu, **kwargs)

    def sigma(self, w: Expr) -> Expr:
        """Stress of a displacement w (UFL), in Pa, on the whole mesh (no indicator)."""
        eps = ufl.sym(ufl.grad(w))
        return self.lam * ufl.tr(eps) * ufl.Identity(self.dim) + 2.0 * self.mu * eps

    def stress(self) -> Expr:
        sigma = self.sigma(self.u)
        return sigma if self.indicator is None else self.indicator * sigma

    def update(self, tangent: bool = True) -> None:
        """Nothing to evaluate: the forms carry the law."""

    @property
    def F(self) -> np.ndarray:
        """F = I + grad u (n_points, d, d) at the points for the current u."""
        return self.deformation_gradient()

    def cauchy(self) -> np.ndarray:
        """Stress (n_points, d, d) in Pa at the points for the current u (linear theory does
        not distinguish stress measures)."""
        d = self.dim
        return dfx.evaluate(self._sigma_expr, self.mesh, self.cells).reshape(-1, d, d)
