"""The 3-D scene as a DOLFINx model: hexahedral mesh, displacement, the sphere RVEs at the 2x2x2
Gauss points, gravity and the footing pressure (dead loads on the reference configuration),
supports and a Newton solver.

Supports: the base is fixed, the sides x = 0 and x = width and the planes z = 0 and z = depth
roll (the normal displacement is zero), as the 2-D slope's sides do.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import dolfinx.fem.petsc  # noqa: F401  (fem.petsc)
import numpy as np
import ufl
from dolfinx import fem
from petsc4py import PETSc

from ..drivers.newton import NewtonSolver
from ..fem import compat as dfx
from ..fem.material import GranularMaterial
from ..gathers import global_extremum
from ..io.postprocess import von_mises
from .geometry import BACK, BOTTOM, FOOTING, FRONT, LEFT, RIGHT, FootingGeometry, create_mesh

if TYPE_CHECKING:
    from mpi4py.MPI import Comm

    from ..laws.protocol import MaterialLaw


class FootingModel:
    """The scene of :class:`~dolfinx_granular.footing3d.geometry.FootingGeometry` under its
    own weight and the footing pressure.

    Args:
        comm: MPI communicator.
        law: a 3-D material-point law (a TaylorRVE of spheres).
        geometry: dimensions and loads.
        solver_options: keyword arguments of :class:`~dolfinx_granular.NewtonSolver`
            (``linear_solver``, ``petsc_options``, ``max_it``, ...).

    Attributes:
        mesh, facets, V, u, material, solver, bcs: the model's DOLFINx objects.
        gravity, footing: Constants multiplying the weight and the footing pressure.
        edge: (3,) the node of the footing's loaded edge nearest its middle (m), where the
            settlement is read.
    """

    def __init__(
        self,
        comm: Comm,
        law: MaterialLaw,
        geometry: FootingGeometry | None = None,
        solver_options: dict[str, Any] | None = None,
    ) -> None:
        self.comm, self.law = comm, law
        self.geometry = g = geometry or FootingGeometry()
        sec = g.section
        self.mesh, _, self.facets = create_mesh(comm, g)
        self.V = dfx.vector_space(self.mesh)
        self.u = fem.Function(self.V, name="displacement")
        self.material = GranularMaterial(law, self.u, quadrature_degree=2)
        v, du = ufl.TestFunction(self.V), ufl.TrialFunction(self.V)
        self.gravity = fem.Constant(self.mesh, PETSc.ScalarType(0.0))
        self.footing = fem.Constant(self.mesh, PETSc.ScalarType(0.0))
        q = sec.footing_pressure_on_strip(ufl.SpatialCoordinate(self.mesh)[0])  # Pa, < 0: down
        ds = ufl.Measure("ds", domain=self.mesh, subdomain_data=self.facets)
        f_ext = self.gravity * (-sec.density * sec.gravity) * v[1] * ufl.dx + self.footing * q * v[
            1
        ] * ds(FOOTING)
        residual = self.material.residual_form(v) - f_ext
        self.bcs = self._supports()
        options = {"max_it": 15, "prefix": "footing3d_", **(solver_options or {})}
        self.solver = NewtonSolver(
            residual, self.material.jacobian_form(du, v), self.u, self.bcs, self.material, **options
        )
        self.edge = np.array(
            [sec.loaded_edge, float(sec.surface_height(sec.loaded_edge)), g.middle_z]
        )
        n_owned = self.V.dofmap.index_map.size_local
        x = self.V.tabulate_dof_coordinates()[:n_owned]
        self._edge_node = np.flatnonzero(np.linalg.norm(x - self.edge, axis=1) < 1e-6 * sec.width)

    def _supports(self):
        """Fixed base; rollers on x = 0, x = width (u_x = 0) and z = 0, z = depth (u_z = 0)."""
        fdim = self.mesh.topology.dim - 1
        V = self.V
        zero = np.zeros(3, dtype=PETSc.ScalarType)
        base = fem.locate_dofs_topological(V, fdim, self.facets.find(BOTTOM))
        bcs = [fem.dirichletbc(zero, base, V)]
        for axis, tags in ((0, (LEFT, RIGHT)), (2, (FRONT, BACK))):
            facets = np.concatenate([self.facets.find(t) for t in tags])
            dofs = fem.locate_dofs_topological(V.sub(axis), fdim, facets)
            bcs.append(fem.dirichletbc(PETSc.ScalarType(0.0), dofs, V.sub(axis)))
        return bcs

    def set_gravity(self, t: float) -> None:
        """Gravity phase: weight x t, no footing load."""
        self.gravity.value, self.footing.value = t, 0.0

    def set_footing(self, t: float) -> None:
        """Footing phase: full weight, footing pressure x t."""
        self.gravity.value, self.footing.value = 1.0, t

    def footing_load(self) -> float:
        """The footing load now applied (N, negative = down)."""
        return float(self.footing.value) * self.geometry.footing_load

    def settlement(self) -> float:
        """Vertical displacement (m) at :attr:`edge`, the same on every rank."""
        local = [float(self.u.x.array[3 * d + 1]) for d in self._edge_node]
        return [s for part in self.comm.allgather(local) for s in part][0]

    def von_mises(self) -> np.ndarray:
        """(n_cells,) von Mises stress (Pa) of the cell means of the Cauchy stress on this
        rank's cells (at the last update)."""
        sigma = self.material.cell_average(self.material.cauchy())
        return von_mises(sigma)

    def max_von_mises(self) -> float:
        """The largest cell von Mises stress (Pa) over all ranks."""
        vm = self.von_mises()
        return global_extremum(self.comm, vm, np.zeros((vm.size, 3)))[0]
