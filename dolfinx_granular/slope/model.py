"""The slope benchmark as a DOLFINx model: mesh, displacement, material, dead loads, supports,
solver and the quantities a run reports (settlement, stresses, diagnostics).

The material and the solver come from factories, so that a study can swap the law (model levels,
friction, a UFL yardstick) or the solver settings without touching the model.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import dolfinx.fem.petsc  # noqa: F401  (fem.petsc)
import numpy as np
import ufl
from dolfinx import fem
from mpi4py import MPI
from petsc4py import PETSc

from ..drivers.newton import NewtonSolver
from ..fem import compat as dfx
from ..fem.material import GranularMaterial
from ..gathers import global_extremum, nearest_point
from ..io.postprocess import min_acoustic_eigenvalue, von_mises
from ..laws.validity import OVERLAP_THRESHOLD, OverlapSummary, validity_summary
from .geometry import BOTTOM, FOOTING, LEFT, RIGHT, SURFACE, SlopeGeometry, create_mesh

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from numpy.typing import ArrayLike

    from ..fem.quadrature import QuadratureMaterial
    from ..laws.protocol import HistoryLaw, MaterialLaw


def granular_material(
    law: MaterialLaw | HistoryLaw, u: fem.Function, stabilise: float = 0.0
) -> GranularMaterial:
    """The default material factory: the law at the 2x2 Gauss points of every cell."""
    return GranularMaterial(law, u, quadrature_degree=2, stabilise=stabilise)


def newton_solver(
    residual: ufl.Form,
    jacobian: ufl.Form | None,
    u: fem.Function,
    bcs: Sequence[Any],
    material: QuadratureMaterial,
    **options: Any,
) -> NewtonSolver:
    """The default solver factory: Newton with LU (MUMPS), at most 15 steps per load step;
    ``options`` (petsc_options, verbose, skip_final_tangent, ...) go to NewtonSolver."""
    options = {"max_it": 15, "prefix": "slope_", **options}
    return NewtonSolver(residual, jacobian, u, bcs, material, **options)


class SlopeModel:
    """The slope of :class:`~dolfinx_granular.slope.geometry.SlopeGeometry` under its own weight
    and an eccentric strip footing, plane strain, dead loads on the reference configuration.

    Args:
        comm: MPI communicator.
        law: the material-point law (e.g. a TaylorRVE).
        geometry: dimensions and loads (default: the reconstruction of the paper's figure 6).
        load_factor: multiplies the footing load (negative: uplift).
        material_factory: ``material_factory(law, u)`` -> a quadrature material.
        solver_factory: ``solver_factory(residual, jacobian, u, bcs, material)`` -> a solver
            with ``solve()``, ``materials``, ``u``, ``timings`` and ``destroy()``.
        confined: the law's reference stress P(I) (a confined packing) is held by the traction
            P(I) n on every boundary but the fixed base, so that u = 0 is in equilibrium.

    Attributes:
        mesh, facets, V, u, material, solver, bcs: the model's DOLFINx objects.
        gravity, footing: Constants multiplying the weight and the footing load.
        gravity_pattern, footing_pattern: the weight and the footing load per unit factor
            (linear forms).
        edge: (2,) the loaded footing edge (m), where the settlement is measured.
    """

    def __init__(
        self,
        comm: MPI.Comm,
        law: MaterialLaw | HistoryLaw,
        geometry: SlopeGeometry | None = None,
        load_factor: float = 1.0,
        material_factory: Callable[[Any, fem.Function], QuadratureMaterial] = granular_material,
        solver_factory: Callable[..., NewtonSolver] = newton_solver,
        confined: bool = False,
    ) -> None:
        self.comm, self.law = comm, law
        self.geometry = g = geometry or SlopeGeometry()
        self.load_factor = float(load_factor)
        self.mesh, _, self.facets = create_mesh(comm, g)
        self.V = dfx.vector_space(self.mesh)
        self.u = fem.Function(self.V, name="displacement")
        self.material = material_factory(law, self.u)
        v, du = ufl.TestFunction(self.V), ufl.TrialFunction(self.V)
        self.gravity = fem.Constant(self.mesh, PETSc.ScalarType(0.0))
        self.footing = fem.Constant(self.mesh, PETSc.ScalarType(0.0))
        q = g.footing_pressure_on_strip(ufl.SpatialCoordinate(self.mesh)[0])
        ds = ufl.Measure("ds", domain=self.mesh, subdomain_data=self.facets)
        self.footing_pattern = q * v[1] * ds(FOOTING)  # the footing load per unit factor
        self.gravity_pattern = (-g.density * g.gravity) * v[1] * ufl.dx  # the weight
        self.f_ext = self.gravity * self.gravity_pattern + self.footing * self.footing_pattern
        if confined:
            P0 = fem.Constant(self.mesh, PETSc.ScalarType(self.material.reference_stress()))
            traction = ufl.dot(P0, ufl.FacetNormal(self.mesh))
            self.f_ext += ufl.dot(traction, v) * ds((SURFACE, FOOTING, LEFT, RIGHT))
        residual = self.material.residual_form(v) - self.f_ext
        self.bcs = self._supports()
        self.solver = solver_factory(
            residual, self.material.jacobian_form(du, v), self.u, self.bcs, self.material
        )
        # the forms of stabiliser_share, compiled (FFCx JIT) only for a material with a
        # stabilising stress: without one the share is 0 and they are never assembled
        self._stab_form = self._f_ext_form = None
        if getattr(self.material, "P_stab", None) is not None:
            self._stab_form = fem.form(
                ufl.inner(self.material.P_stab, ufl.grad(v)) * self.material.dx
            )
            self._f_ext_form = fem.form(self.f_ext)
        self.edge = np.array([g.loaded_edge, float(g.surface_height(g.loaded_edge))])
        n_owned = self.V.dofmap.index_map.size_local
        dof_x = self.V.tabulate_dof_coordinates()[:n_owned, :2]
        self._edge_dofs = np.flatnonzero(np.linalg.norm(dof_x - self.edge, axis=1) < 1e-6 * g.width)
        self._von_mises = None  # (material updates, committed state, von Mises) of von_mises()

    def _supports(self):
        """Fixed base, rollers on the left and right sides."""
        fdim = self.mesh.topology.dim - 1
        V = self.V
        zero = np.zeros(2, dtype=PETSc.ScalarType)
        bcs = [
            fem.dirichletbc(zero, fem.locate_dofs_topological(V, fdim, self.facets.find(BOTTOM)), V)
        ]
        for tag in (LEFT, RIGHT):
            dofs = fem.locate_dofs_topological(V.sub(0), fdim, self.facets.find(tag))
            bcs.append(fem.dirichletbc(PETSc.ScalarType(0.0), dofs, V.sub(0)))
        return bcs

    # -- loads ---------------------------------------------------------------------------------

    def set_gravity(self, t: float) -> None:
        """Gravity phase: weight x t, no footing load."""
        self.gravity.value, self.footing.value = t, 0.0

    def set_footing(self, t: float) -> None:
        """Footing phase: full weight, footing load x ``load_factor * t``."""
        self.gravity.value, self.footing.value = 1.0, self.load_factor * t

    def footing_load(self) -> float:
        """The footing load now applied (N per metre, negative = down)."""
        return float(self.footing.value) * self.geometry.footing_load

    # -- what a run reports ----------------------------------------------------------------------

    def settlement(self) -> float:
        """Vertical displacement (m) of the loaded footing edge, the same on every rank."""
        local = [float(self.u.x.array[2 * d + 1]) for d in self._edge_dofs]
        return [s for part in self.comm.allgather(local) for s in part][0]

    def non_elliptic_points(self) -> int:
        """RVEs whose tangent has lost strong ellipticity (0 for a law without a tangent view)."""
        A = getattr(self.material, "tangent", None)
        if A is None:
            return 0
        lowest = min_acoustic_eigenvalue(A)
        scale = self.comm.allreduce(float(np.abs(A).max()) if len(A) else 0.0, op=MPI.MAX)
        return self.comm.allreduce(int(np.count_nonzero(lowest < -1e-12 * scale)))

    def stabiliser_share(self) -> float:
        """|nodal forces of the stabilising stress| / |external load| on the free dofs."""
        if self._stab_form is None:
            return 0.0
        norms = []
        for form in (self._stab_form, self._f_ext_form):
            b = fem.petsc.assemble_vector(form)
            b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            fem.petsc.set_bc(b, self.bcs, None, 0.0)  # reactions are not forces on the soil
            norms.append(b.norm())
            b.destroy()
        return norms[0] / norms[1] if norms[1] > 0 else 0.0

    def open_points(self) -> int:
        return self.comm.allreduce(getattr(self.material, "n_open", 0))

    def von_mises(self) -> np.ndarray:
        """Von Mises stress (n_points,) in Pa at this rank's Gauss points (read-only).

        Kept until the material changes: the stress depends on F of the last update and the
        committed state alone, and a run asks for it twice at its last state (the XDMF file of
        the step, then :meth:`extremes`), each time an RVE evaluation at every point. A material
        without an update count (``n_updates``) is evaluated at every call."""
        material = self.material
        updates, state = getattr(material, "n_updates", None), material.export_state()
        kept = self._von_mises
        if updates is not None and kept is not None and kept[0] == updates and kept[1] is state:
            return kept[2]
        vm = von_mises(material.cauchy())
        vm.flags.writeable = False  # shared by the callers until the material changes
        self._von_mises = (updates, state, vm)
        return vm

    def extremes(
        self,
    ) -> tuple[np.ndarray, tuple[float, list[float]], tuple[float, list[float]]]:
        """``(vm, (vmax, xmax), (vmin, xmin))``: von Mises at the points and its global extremes
        with their reference coordinates."""
        vm = self.von_mises()
        X = self.material.points
        return (
            vm,
            global_extremum(self.comm, vm, X, "max"),
            global_extremum(self.comm, vm, X, "min"),
        )

    def probes(self, xmax: ArrayLike) -> list[tuple[str, np.ndarray | None, np.ndarray, str, Any]]:
        """The four probe points of figure 7: ``(label, point, F, text, state)`` at the Gauss
        point nearest to each spot (``state``: the committed state of that point for a law with
        history, else None); the same on every rank."""
        g = self.geometry
        spots = [
            ("A", xmax, "max von Mises"),
            (
                "B",
                [g.loaded_edge - 0.5 * g.column_width, 0.75 * g.crest_height],
                "under the footing",
            ),
            ("C", [g.slope_end + 0.5 * g.column_width, 0.9 * g.toe_height], "at the toe"),
            ("D", [0.5 * g.footing_start + 0.5 * g.column_width, 0.1 * g.crest_height], "deep"),
        ]
        # B, C and D lie midway between Gauss points of a regular column: nudged off the tie,
        # which ranks and DOLFINx releases would break differently
        nudge = 0.05 * g.column_width
        probes = []
        for label, spot, text in spots:
            if label != "A":
                spot = np.asarray(spot, dtype=float) + nudge
            rank, i, xp = nearest_point(self.comm, self.material.points, spot)
            mine = self.comm.rank == rank
            F = self.comm.bcast(np.array(self.material.F[i]) if mine else None, root=rank)
            probes.append((label, xp, F, text, self._point_state(rank, i)))
        return probes

    def _point_state(self, rank: int, i: int) -> Any:
        """The committed law state of point i of ``rank`` (a one-point HistoryState), on every
        rank; None for a law without history."""
        committed = self.material.export_state()
        if committed is None:
            return None
        arrays = committed.take([i]).to_arrays() if self.comm.rank == rank else None
        return type(committed).from_arrays(self.comm.bcast(arrays, root=rank))

    def min_singular_value(self) -> float:
        F = self.material.F
        return self.comm.allreduce(
            float(np.linalg.svd(F, compute_uv=False).min()) if len(F) else np.inf, op=MPI.MIN
        )

    def overlap_summary(self, threshold: float = OVERLAP_THRESHOLD) -> OverlapSummary | None:
        """Where the contact law leaves its range, at the material's last update (the same on
        every rank; collective): the largest contact overlap over the smaller disk radius at any
        Gauss point, where, and the points beyond ``threshold`` (default 0.10). None for a
        material without a disk-packing law (a UFL yardstick)."""
        law = getattr(self.material, "rve", None)
        if not callable(getattr(law, "overlap_statistics", None)):
            return None
        return validity_summary(self.material, threshold)

    def overlap_validity(self, threshold: float = OVERLAP_THRESHOLD) -> dict | None:
        """:meth:`overlap_summary` for ``summary.json``: a dict with ``max_ratio``, ``at``
        (reference coordinates, m), ``points_above``, ``points``, ``fraction_above`` and
        ``threshold``; None without a disk-packing law."""
        summary = self.overlap_summary(threshold)
        return None if summary is None else summary.as_dict()
