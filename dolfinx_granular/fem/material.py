"""A material-point law on DOLFINx quadrature points: the RVE at every Gauss point.

Every quadrature point of the material's owned cells carries the same law (a
:class:`~dolfinx_granular.MaterialLaw` such as :class:`~dolfinx_granular.TaylorRVE`, or a
:class:`~dolfinx_granular.HistoryLaw` such as the frictional RVE).
:meth:`GranularMaterial.update` evaluates F = I + grad u at those points, calls the law and writes
the first Piola stress P and the tangent dP/dF into quadrature Functions, which the UFL forms read.
Ghost cells are skipped: cell integrals never read their quadrature values, so no RVE is evaluated
twice across ranks.

A law with history is always evaluated from the committed state (a
:class:`~dolfinx_granular.HistoryState`); :meth:`GranularMaterial.commit` (called by
:class:`~dolfinx_granular.NewtonSolver` when a solve converges) makes the state of the last
update the committed one. Restarts move the committed state through
:meth:`~GranularMaterial.export_state` and :meth:`~GranularMaterial.restore_state` only.

The dimension d (2 or 3) comes from the mesh; the law must take F of the same shape (d, d)
(:func:`~dolfinx_granular.law_dimension`). Flattening convention: see
:mod:`~dolfinx_granular.fem.quadrature`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import ufl
from dolfinx import fem

from ..laws.protocol import check_state, has_history, law_dimension
from ..laws.taylor import PRESTRESS_WARNING, UnsupportedDeformationError
from . import compat as dfx
from .quadrature import QuadratureMaterial, flatten, unflatten

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from ..laws.protocol import HistoryLaw, MaterialLaw


class GranularMaterial(QuadratureMaterial):
    """A material-point law (the Taylor RVE) on the quadrature points of a DOLFINx mesh.

    Args:
        rve: the material-point law (:class:`~dolfinx_granular.MaterialLaw` or
            :class:`~dolfinx_granular.HistoryLaw`).
        u: displacement Function on a vector Lagrange space (Q1/P1 or higher) of a d-dimensional
            mesh, in m; d must be the law's dimension (ValueError otherwise).
        quadrature_degree: degree k of the "default" quadrature scheme (2: 2x2 Gauss points on
            quadrilaterals, 3 points on triangles, 2x2x2 on hexahedra); an integer >= 1.
        stabilise: alpha >= 0. Where an RVE has lost all its load-carrying contacts (W = 0: every
            contact open, P = 0 and a zero tangent, so the global matrix can become singular), add
            the linear stress ``alpha C : (F - I)`` and tangent ``alpha C``, C the law's small-
            strain modulus. Points with a contact under load are untouched; 0 (default) disables
            it. The stabilising stress is fictitious: W, :meth:`cauchy` and the von Mises output
            leave it out; :attr:`P_stab` holds it alone, so that its nodal forces can be measured.
        cells: local indices of the cells the material occupies (None: all); elsewhere its P and
            A are zero.

    Attributes:
        P: quadrature Function (d, d), first Piola stress in Pa (the material's owned cells).
        A: quadrature Function (d*d, d*d), dP/dF on flattened F, in Pa.
        W: (n_points,) energy density in Pa at the points.
        has_state: the law carries a state (a HistoryLaw); ``history`` is its older name.
        state: committed state of a law with history (None without history); read-only: use
            :meth:`restore_state`.
        trial_state: state at the last ``update`` (committed by :meth:`commit`); read-only.
        n_open: points at the last ``update`` whose RVE had no loaded contact.
        update_seconds: (of :class:`QuadratureMaterial`) failed updates included: ranks wait
            for the slowest at every update.
        P_stab: quadrature Function with the stabilising stress of the last ``update`` (None
            without a stabiliser).
        (and those of :class:`~dolfinx_granular.QuadratureMaterial`: dx, F, points,
        cells, n_qp, timings)
    """

    def __init__(
        self,
        rve: MaterialLaw | HistoryLaw,
        u: fem.Function,
        quadrature_degree: int = 2,
        stabilise: float = 0.0,
        cells: ArrayLike | None = None,
    ) -> None:
        self.has_state = has_history(rve)
        super().__init__(u, quadrature_degree, cells)
        self.rve = rve
        msh, k, n, d = self.mesh, self.quadrature_degree, self.n_points, self.dim
        _check_law_dimension(rve, d)
        self.P = fem.Function(dfx.quadrature_space(msh, k, (d, d)), name="P")
        self.A = fem.Function(dfx.quadrature_space(msh, k, (d * d, d * d)), name="A")
        imap = msh.topology.index_map(msh.topology.dim)
        n_all = imap.size_local + imap.num_ghosts
        for f in (self.P, self.A):
            Q = f.function_space
            # Writing P and A by position needs dof = cell * n_qp + q with owned cells first.
            if Q.dofmap.index_map.size_local != imap.size_local * self.n_qp or not np.array_equal(
                dfx.cell_dofs(Q.dofmap).ravel(), np.arange(n_all * self.n_qp)
            ):
                raise RuntimeError(
                    "the quadrature dofmap is not cell-major (dof = cell * n_qp + q); this DOLFINx "
                    "version lays out quadrature spaces differently and is not supported"
                )
        self._hold_as_data(self.P, self.A)
        self._slots = _point_slots(self.cells, self.n_qp, imap.size_local)
        self.W = np.zeros(n)
        self.F = np.tile(np.eye(d), (n, 1, 1))
        self._P_data = _PointData(self.P, self._slots, (d, d))
        self._A_data = _PointData(self.A, self._slots, (d, d, d, d))
        self.n_updates = 0
        self.n_open = 0
        self._scalar = None
        self._state = check_state(rve.initial_state(n)) if self.has_state else None
        self._trial_state = self._state
        alpha = float(stabilise)
        if not (np.isfinite(alpha) and alpha >= 0.0):
            raise ValueError(f"stabilise must be a finite number >= 0, got {stabilise!r}")
        self.stabilise = alpha
        self._C_stab = alpha * rve.small_strain_modulus() if alpha > 0.0 else None
        self.P_stab = None  # the stabilising part of P alone, to measure its effect
        if alpha > 0.0:
            self.P_stab = fem.Function(self.P.function_space, name="P_stab")
            self._P_stab_data = _PointData(self.P_stab, self._slots, (d, d))

    @property
    def state(self):
        """The committed :class:`~dolfinx_granular.HistoryState` (None without history)."""
        return self._state

    @property
    def trial_state(self):
        """The state at the last ``update`` (becomes :attr:`state` on :meth:`commit`)."""
        return self._trial_state

    def export_state(self):
        """The committed state of this rank's points, ordered like :attr:`points` (a
        :class:`~dolfinx_granular.HistoryState`; None for a law without history). States
        are immutable: the object may be kept, gathered or saved as it is."""
        return self._state

    def restore_state(self, state) -> None:
        """Make ``state`` (a HistoryState of this rank's ``n_points`` points, ordered like
        :attr:`points`, e.g. from :meth:`export_state` or a restart file) the committed and the
        trial state; the next :meth:`update` evaluates from it."""
        if not self.has_state:
            if state is None:
                return
            raise ValueError(
                f"restore_state: {type(self.rve).__name__} has no history; pass None (or "
                "nothing to restore)"
            )
        state = check_state(state)
        if state.n_points != self.n_points or not isinstance(state, type(self._state)):
            raise ValueError(
                f"restore_state needs a {type(self._state).__name__} of {self.n_points} points "
                f"(this rank's), got a {type(state).__name__} of {state.n_points}; restore the "
                "state exported by a material on the same cells"
            )
        self._state = self._trial_state = state

    @property
    def tangent(self) -> np.ndarray:
        """(n_points, d, d, d, d) dP/dF in Pa at the last ``update(tangent=True)``,
        ``[q, a, b, c, d] = dP_ab / dF_cd`` (stabiliser included)."""
        return self._A_data.values

    def update(self, tangent: bool = True) -> None:
        """Evaluate the law at the current u (from the committed state) and write P (and A if
        ``tangent``).

        Raises:
            UnsupportedDeformationError: F at some point is outside the law's range; the message
                names the cells and their coordinates.
        """
        F = self.deformation_gradient()
        start = self.clock.wall["rve"]
        try:
            with self.clock("rve"):
                self._evaluate(F, tangent)
        except UnsupportedDeformationError as err:
            cells = np.unique(self.cells[err.points // self.n_qp])
            xy = self.points[err.points[0]]
            raise UnsupportedDeformationError(
                f"{err}. Affected cells (local) {cells[:10].tolist()}, first point at x = "
                f"{xy.tolist()} m. Reduce the load step or check the boundary conditions.",
                err.points,
                err.status,
            ) from None
        finally:
            self.update_seconds.append(self.clock.wall["rve"] - start)
        opened = np.flatnonzero(self.W == 0.0)
        self.n_open = opened.size
        if self._C_stab is not None:
            self._add_stabiliser(F, opened, tangent)
        self._P_data.write()
        if tangent:
            self._A_data.write()
        self.F[...] = F
        self.n_updates += 1

    def _evaluate(self, F, tangent):
        P, A = self._P_data.values, self._A_data.values
        if self.has_state:
            if tangent:
                *_, self._trial_state = self.rve.evaluate(F, self._state, out=(self.W, P, A))
            else:
                *_, self._trial_state = self.rve.stress(F, self._state, out=(self.W, P, None))
        elif tangent:
            self.rve.evaluate(F, out=(self.W, P, A))
        else:
            self.rve.stress(F, out=(self.W, P, None))

    def _add_stabiliser(self, F, opened, tangent):
        P_stab = self._P_stab_data.values
        P_stab[...] = 0.0
        if opened.size:
            E = F[opened] - np.eye(self.dim)
            P_stab[opened] = np.einsum("abcd,qcd->qab", self._C_stab, E)
            self._P_data.values[opened] += P_stab[opened]
            if tangent:
                self._A_data.values[opened] += self._C_stab
        self._P_stab_data.write()

    def integrate(self, values: ArrayLike) -> float:
        """∫ values dx over the material's cells (every rank gets the sum) of a per-point array
        (n_points,), e.g. an energy density in Pa -> J per unit thickness."""
        if self._scalar is None:
            self._scalar = fem.Function(dfx.quadrature_space(self.mesh, self.quadrature_degree, ()))
            self._scalar_form = fem.form(self._scalar * self.dx)
        self._scalar.x.array[self._slots] = np.asarray(values, dtype=float)
        local = fem.assemble_scalar(self._scalar_form)
        return float(self.mesh.comm.allreduce(local))

    def dissipated_energy(self) -> float:
        """Energy dissipated so far in the committed state, ∫ D dx in J per unit thickness (0 for
        a law without dissipation)."""
        D = getattr(self._state, "dissipation", None)
        return self.integrate(D) if D is not None else 0.0

    def commit(self) -> None:
        """Make the state of the last ``update`` the committed one (no-op without history)."""
        if self.has_state:
            self._state = self._trial_state

    def stress(self) -> fem.Function:
        return self.P

    def stress_derivative(self, residual: ufl.Form, du: ufl.Argument) -> ufl.Form:
        """``dR/dP [A : grad du]``: how the residual changes through P (held as data)."""
        dP = unflatten(ufl.dot(self.A, flatten(ufl.grad(du))))
        return ufl.derivative(residual, self.P, dP)

    def jacobian_form(self, du: ufl.Argument, v: ufl.Argument) -> ufl.Form:
        """Its linearisation ``∫ grad v : A : grad du dx`` (UFL bilinear form)."""
        return ufl.inner(ufl.dot(self.A, flatten(ufl.grad(du))), flatten(ufl.grad(v))) * self.dx

    def reference_stress(self) -> np.ndarray:
        """The law's P(I) (d, d) in Pa, from the initial state of a law with history."""
        I = np.eye(self.dim)[None]
        if self.has_state:
            return self.rve.stress(I, self.rve.initial_state(1))[1][0]
        return self.rve.stress(I)[1][0]

    def stress_floor_form(self, v: ufl.Argument) -> ufl.Form | None:
        """``∫ P(I) : grad v dx`` over the material's cells when the law counts as stress-free:
        |P(I)| at most ``PRESTRESS_WARNING`` (1e-6) of its modulus, e.g. ~1e-11 for a generated
        packing, whose contacts overlap by 1e-11 of the mean diameter. None when P(I) = 0, or when
        the reference state is prestressed (then P(I) is a real stress to balance)."""
        P0 = self.reference_stress()
        modulus = np.linalg.norm(self.rve.small_strain_modulus())
        if not 0.0 < np.linalg.norm(P0) <= PRESTRESS_WARNING * modulus:
            return None
        P0 = fem.Constant(self.mesh, np.asarray(P0, dtype=float))
        stress = P0 if self.indicator is None else self.indicator * P0
        return ufl.inner(stress, ufl.grad(v)) * self.dx

    def cauchy(self) -> np.ndarray:
        """Cauchy stress sigma (n_points, d, d) in Pa at the F of the last ``update``."""
        if self.has_state:
            return self.rve.cauchy(self.F, self._state)
        return self.rve.cauchy(self.F)


def _check_law_dimension(law, d):
    """ValueError unless the law takes F of shape (n, d, d), d the mesh's dimension."""
    d_law = law_dimension(law)
    if d_law != d:
        raise ValueError(
            f"GranularMaterial: {type(law).__name__} is a {d_law}-D law (F of shape (n, {d_law}, "
            f"{d_law})) and the mesh is {d}-D; give a {d}-D law or a {d_law}-D mesh"
        )


def _point_slots(cells, n_qp, n_owned):
    """Positions of the material's points in the quadrature arrays: a slice when the material
    covers every owned cell (data written in place), else an index array."""
    if cells.size == n_owned and (n_owned == 0 or cells[-1] == n_owned - 1):
        return slice(0, n_owned * n_qp)
    return (cells[:, None] * n_qp + np.arange(n_qp)).ravel()


class _PointData:
    """Per-point values (n_points, *shape) of a quadrature Function: a view of its array when the
    slots are a slice, else an array of its own that :meth:`write` copies in."""

    def __init__(self, f, slots, shape):
        size = int(np.prod(shape))
        self._target = f.x.array.reshape(-1, *shape)
        if isinstance(slots, slice):
            self.values = self._target[slots]
            self._slots = None
        else:
            self.values = np.zeros((slots.size, *shape))
            self._slots = slots
        assert self.values.flags.c_contiguous and size > 0

    def write(self):
        if self._slots is not None:
            self._target[self._slots] = self.values
