"""What every quadrature-point material shares: points, F, forms, the consistent Jacobian.

A quadrature material lives on the Gauss points of the owned cells of a d-dimensional mesh (d = 2 or
3; or of a subset of them, ``cells=``) and provides the UFL terms of its internal virtual work.
Subclasses are
:class:`~dolfinx_granular.GranularMaterial` (a material-point law evaluated pointwise into
quadrature Functions) and :class:`~dolfinx_granular.LinearElasticMaterial` (a law written
in UFL). :func:`derivative` gives the consistent Jacobian of any residual built from them.

Flattening convention, one rule for any dimension d (DOLFINx 0.5 cannot hold rank-4 quadrature
tensors; one layout on every release): F, P and grad v are flattened row-major to d*d values,
``T[a, b] -> t[d*a + b]`` (``[F00, F01, F10, F11]`` in 2-D), and a tangent is the (d*d, d*d) matrix
``A[d*a + b, d*c + e] = dP_ab / dF_ce``. P itself is held as a (d, d) quadrature tensor (d*d values
per point, the same row-major layout).

A material on a subdomain (``cells=``) contributes nothing on the other cells: its stress and
tangent are zero there (quadrature data, or a cell indicator for UFL laws), so several materials
add up in one residual with the one measure ``dx`` and no subdomain data.
"""

from __future__ import annotations

import math
import numbers
import weakref
from typing import TYPE_CHECKING

import numpy as np
import ufl
from dolfinx import fem

from ..timing import Stopwatch
from . import compat as dfx

if TYPE_CHECKING:
    from collections.abc import Iterable

    from numpy.typing import ArrayLike
    from ufl.core.expr import Expr

#: the material that writes each quadrature data Function (``id`` -> material): names a material
#: whose data a residual reads but that was not handed to the solver (it would never be updated)
_DATA_OWNERS: weakref.WeakValueDictionary = weakref.WeakValueDictionary()


def data_owner(f: object) -> QuadratureMaterial | None:
    """The material whose :meth:`~QuadratureMaterial.data` includes the Function f, or None."""
    owner = _DATA_OWNERS.get(id(f))
    return owner if owner is not None and any(g is f for g in owner.data) else None


def flatten(T: Expr) -> Expr:
    """Row-major flattening of a (d, d) UFL tensor to a (d*d,) vector, ``t[d*a + b] = T[a, b]``
    (``[T00, T01, T10, T11]`` in 2-D)."""
    d = T.ufl_shape[0]
    return ufl.as_vector([T[a, b] for a in range(d) for b in range(d)])


def unflatten(t: Expr) -> Expr:
    """The (d, d) UFL tensor of a row-major (d*d,) vector (inverse of :func:`flatten`)."""
    d = math.isqrt(t.ufl_shape[0])
    if d * d != t.ufl_shape[0]:
        raise ValueError(f"unflatten needs a vector of d*d values, got shape {t.ufl_shape}")
    return ufl.as_matrix([[t[d * a + b] for b in range(d)] for a in range(d)])


def check_quadrature_degree(value: float) -> int:
    """``value`` as a quadrature degree: an integer >= 1 (2.0 is accepted, 2.7 is not)."""
    if (
        isinstance(value, bool)
        or not isinstance(value, numbers.Real)
        or not (np.isfinite(value) and value == int(value) and value >= 1)
    ):
        raise ValueError(f"quadrature_degree must be an integer >= 1, got {value!r}")
    return int(value)


def derivative(
    residual: ufl.Form,
    u: fem.Function,
    du: ufl.Argument,
    materials: Iterable[QuadratureMaterial] = (),
) -> ufl.Form:
    """The consistent Jacobian of ``residual`` (a UFL linear form in v) with respect to u.

    ``ufl.derivative`` sees the explicit u-dependence (UFL laws, follower loads, any term of the
    user's); the first Piola stress P of each quadrature material is data, and its dependence on
    u enters through its tangent: ``dP[du] = A : grad du``. Works for any residual that contains
    the materials' P (scaled, on subdomains, with extra u-dependent terms).

    Args:
        residual: UFL form, linear in a test function.
        u: the displacement Function.
        du: trial function (direction).
        materials: the quadrature materials whose P appears in ``residual``.
    """
    J = ufl.derivative(residual, u, du)
    for m in materials:
        term = m.stress_derivative(residual, du)
        if term is not None:
            J += term
    return J


class QuadratureMaterial:
    """Base of the materials on the quadrature points of the owned cells.

    Args:
        u: displacement Function on a vector Lagrange space (Q1/P1 or higher) of a mesh of
            dimension d (geometric = topological dimension, e.g. 2 or 3), with d components, in m.
        quadrature_degree: degree k of the "default" scheme (2: 2x2 Gauss points on
            quadrilaterals, 3 points on triangles, 2x2x2 on hexahedra); an integer >= 1.
        cells: local indices of the cells the material occupies (ghosts allowed, ignored for
            evaluation); None: every cell.

    Attributes:
        u, mesh, quadrature_degree: as given.
        dim: d, the dimension of the mesh (F, P are (d, d) at every point).
        dx: cell measure with the quadrature metadata; use it for every form that reads the
            material's quadrature data.
        cells: (n_cells,) the owned cells the material evaluates.
        n_qp: quadrature points per cell.
        reference_points: (n_qp, d) the quadrature points on the reference cell.
        F: (n_points, d, d) deformation gradient at the last ``update`` (point ``cell*n_qp+q``
            of ``cells``), set by the subclasses.
        clock: :class:`~dolfinx_granular.timing.Stopwatch` of ``"F"`` (evaluating grad u) and
            ``"rve"`` (the law); ``timings`` is its wall-time table.
        update_seconds: wall seconds of the law's evaluation in each update (this rank's
            points; empty for a material without a law to evaluate).
    """

    def __init__(
        self, u: fem.Function, quadrature_degree: int = 2, cells: ArrayLike | None = None
    ) -> None:
        msh = u.function_space.mesh
        self.dim = d = _mesh_dimension(type(self).__name__, msh, u)
        self.u = u
        self.mesh = msh
        self.quadrature_degree = k = check_quadrature_degree(quadrature_degree)
        self.dx = ufl.Measure(
            "dx", domain=msh, metadata={"quadrature_degree": k, "quadrature_scheme": "default"}
        )
        # the reference quadrature points (n_qp, d): expressions of subclasses use them too
        self.reference_points = X = dfx.quadrature_points(msh, k)
        self.n_qp = X.shape[0]
        self.cells, self.indicator = _material_cells(msh, cells)
        self._F_expr = dfx.expression(ufl.Identity(d) + ufl.grad(u), X)
        self._x_expr = dfx.expression(ufl.SpatialCoordinate(msh), X)
        self.clock = Stopwatch()
        self.update_seconds = []

    # -- points --------------------------------------------------------------------------------

    @property
    def n_points(self) -> int:
        """Number of quadrature points on this rank's cells of the material."""
        return self.cells.size * self.n_qp

    @property
    def points(self) -> np.ndarray:
        """(n_points, d) reference coordinates of the points (m), ordered like F."""
        if not hasattr(self, "_points"):
            values = dfx.evaluate(self._x_expr, self.mesh, self.cells)
            self._points = values.reshape(-1, self.dim)
        return self._points

    @property
    def timings(self) -> dict:
        """Wall seconds spent in ``"F"`` (evaluating grad u) and ``"rve"`` (the law)."""
        return {"F": self.clock.wall["F"], "rve": self.clock.wall["rve"]}

    def deformation_gradient(self) -> np.ndarray:
        """F = I + grad u (n_points, d, d) at the points for the current u."""
        d = self.dim
        with self.clock("F"):
            return dfx.evaluate(self._F_expr, self.mesh, self.cells).reshape(-1, d, d)

    def cell_average(self, values: ArrayLike) -> np.ndarray:
        """Mean of a per-point array (n_points, ...) over each cell's quadrature points
        -> (n_cells, ...) (unweighted: a display value, not an integral)."""
        values = np.asarray(values)
        return values.reshape(self.cells.size, self.n_qp, *values.shape[1:]).mean(axis=1)

    @property
    def data(self) -> tuple:
        """The quadrature Functions ``(stress, tangent)`` that :meth:`update` writes and the forms
        read (P and dP/dF), or ``()`` for a law written in UFL."""
        return getattr(self, "_data", ())

    def _hold_as_data(self, stress: fem.Function, tangent: fem.Function) -> None:
        """Declare the Functions of :attr:`data` (the solver checks its forms against them)."""
        self._data = (stress, tangent)
        for f in self._data:
            _DATA_OWNERS[id(f)] = self

    def stress_floor_form(self, v: ufl.Argument) -> ufl.Form | None:
        """``∫ P0 : grad v dx`` of the stress P0 (Pa) the material carries in its reference state
        while counting as stress-free (a solver treats residuals within its forces as zero under
        no load), or None: the material is exactly stress-free there."""
        return None

    # -- state (no history here; see GranularMaterial) -----------------------------------------

    #: the law carries a state (a HistoryState) that export_state/restore_state move
    has_state: bool = False

    @property
    def history(self) -> bool:
        """The older name of :attr:`has_state` (kept for existing callers)."""
        return self.has_state

    def export_state(self):
        """The committed law state of this rank's points (None: a law without history)."""
        return None

    def restore_state(self, state) -> None:
        """Make ``state`` (from :meth:`export_state`) the committed one; None here."""
        if state is not None:
            raise ValueError(f"{type(self).__name__} has no history state; pass None")

    def update(self, tangent: bool = True) -> None:
        """Evaluate the law at the current u (and the tangent if ``tangent``)."""
        raise NotImplementedError

    def commit(self) -> None:
        """Accept the state of the last ``update`` as converged (laws with history)."""

    def dissipated_energy(self) -> float:
        """Energy dissipated so far, J per unit thickness (0: an elastic law)."""
        return 0.0

    # -- forms ---------------------------------------------------------------------------------

    def stress(self) -> Expr:
        """P as UFL (d x d): the quadrature Function, or the UFL law."""
        raise NotImplementedError

    def residual_form(self, v: ufl.Argument) -> ufl.Form:
        """Internal virtual work ``∫ P : grad v dx`` over the material's cells (UFL, N·m per
        unit thickness)."""
        return ufl.inner(self.stress(), ufl.grad(v)) * self.dx

    def stress_derivative(self, residual: ufl.Form, du: ufl.Argument) -> ufl.Form | None:
        """The part of d(residual)/du that ``ufl.derivative`` does not see (P held as data), or
        None (a law written in UFL: ``ufl.derivative`` sees it all)."""
        return None

    def jacobian_form(self, du: ufl.Argument, v: ufl.Argument) -> ufl.Form:
        """The linearisation of :meth:`residual_form` (UFL bilinear form)."""
        return derivative(self.residual_form(v), self.u, du, [self])

    def derivative(self, residual: ufl.Form, u: fem.Function, du: ufl.Argument) -> ufl.Form:
        """The consistent Jacobian of ``residual`` (which may contain this material's P) with
        respect to u: :func:`derivative` with this material."""
        return derivative(residual, u, du, [self])


def _mesh_dimension(name: str, msh, u) -> int:
    """d of a mesh whose cells span its space (geometric = topological dimension) and whose
    displacement u has d components; ValueError naming the mismatch otherwise."""
    d, tdim = msh.geometry.dim, msh.topology.dim
    if d != tdim or u.ufl_shape != (d,):
        raise ValueError(
            f"{name} needs a mesh of cells that fill its space (2-D or 3-D) and a vector "
            f"displacement with one component per dimension; got geometric dimension {d}, "
            f"topological dimension {tdim} and value shape {u.ufl_shape} (use "
            "vector_space(mesh) on a triangle/quadrilateral or tetrahedron/hexahedron mesh)"
        )
    return d


def _material_cells(msh, cells):
    """The owned cells of the material (int32, ascending) and, on a subdomain, a DG0 indicator
    Function of its cells (1 on them, 0 elsewhere; None for the whole mesh)."""
    tdim = msh.topology.dim
    imap = msh.topology.index_map(tdim)
    n_owned, n_all = imap.size_local, imap.size_local + imap.num_ghosts
    if cells is None:
        return np.arange(n_owned, dtype=np.int32), None
    cells = np.asarray(cells)
    if cells.ndim != 1 or not np.issubdtype(cells.dtype, np.integer) and cells.size:
        raise ValueError(
            "cells must be a 1-D array of local cell indices (e.g. from "
            f"dolfinx.mesh.locate_entities(mesh, {tdim}, marker))"
        )
    cells = np.unique(cells.astype(np.int32))
    if cells.size and (cells[0] < 0 or cells[-1] >= n_all):
        raise ValueError(
            f"cells must be local cell indices in [0, {n_all}), got {cells[0]} .. {cells[-1]}"
        )
    chi = fem.Function(dfx.function_space(msh, "DG", 0), name="indicator")
    chi.x.array[dfx.cell_dofs(chi.function_space.dofmap)[cells].ravel()] = 1.0
    chi.x.scatter_forward()
    return cells[cells < n_owned], chi
