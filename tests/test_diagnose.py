"""Wiring mistakes with several materials are refused when the solver is built, with the fix in the
message; a singular Jacobian names its cause (cells with no material, RVEs in tension)."""

import numpy as np
import pytest

dolfinx = pytest.importorskip("dolfinx")
from dolfinx_granular import TaylorRVE, generate_packing  # noqa: E402
from dolfinx_granular.drivers.newton import NewtonSolver  # noqa: E402
from dolfinx_granular.fem.compat import vector_space  # noqa: E402
from dolfinx_granular.fem.linear import LinearElasticMaterial, lame_from_young  # noqa: E402
from dolfinx_granular.fem.material import GranularMaterial  # noqa: E402

import ufl  # noqa: E402
from dolfinx import fem, mesh  # noqa: E402
from mpi4py import MPI  # noqa: E402


@pytest.fixture(scope="module")
def rve():
    return TaylorRVE(generate_packing(40, seed=5), 2.8e7)


class Layered:
    """A 2 m x 2 m square of 4 x 4 cells: granular layer above y = 1, linear elastic base below,
    fixed bottom, rollers on the sides, a top pressure p (Pa, a Constant)."""

    def __init__(self, rve):
        msh = mesh.create_rectangle(
            MPI.COMM_WORLD, [[0, 0], [2, 2]], [4, 4], mesh.CellType.quadrilateral
        )
        self.V = V = vector_space(msh)
        self.u, self.v, self.du = fem.Function(V), ufl.TestFunction(V), ufl.TrialFunction(V)
        self.layer = mesh.locate_entities(msh, 2, lambda x: x[1] >= 1.0 - 1e-12)
        base = mesh.locate_entities(msh, 2, lambda x: x[1] <= 1.0 + 1e-12)
        self.soil = GranularMaterial(rve, self.u, cells=self.layer)
        self.rock = LinearElasticMaterial(self.u, *lame_from_young(2e8, 0.25), cells=base)
        top = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 2))
        tags = mesh.meshtags(msh, 1, top, np.full_like(top, 1))
        self.ds = ufl.Measure("ds", msh, subdomain_data=tags)
        self.p = fem.Constant(msh, 1e5)
        self.load = self.p * self.v[1] * self.ds(1)
        bottom = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 0))
        walls = mesh.locate_entities_boundary(
            msh, 1, lambda x: np.isclose(x[0], 0) | np.isclose(x[0], 2)
        )
        self.bcs = [
            fem.dirichletbc(np.zeros(2), fem.locate_dofs_topological(V, 1, bottom), V),
            fem.dirichletbc(0.0, fem.locate_dofs_topological(V.sub(0), 1, walls), V.sub(0)),
        ]

    def residual(self, *materials):
        return sum((m.residual_form(self.v) for m in materials), self.load)

    def solver(self, residual, jacobian, materials, prefix):
        return NewtonSolver(residual, jacobian, self.u, self.bcs, materials, prefix=prefix)


@pytest.mark.mpi
def test_a_material_left_out_of_the_solver_is_refused(rve):
    """The residual reads the soil's P, the solver gets only the rock: the soil would never be
    evaluated (P = 0, no tangent) and the Jacobian is singular."""
    s = Layered(rve)
    with pytest.raises(ValueError, match=r"reads the stress of a GranularMaterial on 8 cells"):
        s.solver(s.residual(s.soil, s.rock), None, [s.rock], "unlisted_")


@pytest.mark.mpi
@pytest.mark.parametrize("layered", [True, False])
def test_ufl_derivative_as_jacobian_is_refused(rve, layered):
    """``ufl.derivative(residual, u)`` differentiates through P as data: zero for the RVE. With
    one material the form is empty, with two only the rock's part is left."""
    s = Layered(rve)
    if layered:
        materials = [s.soil, s.rock]
    else:
        materials = [GranularMaterial(rve, s.u)]
    residual = s.residual(*materials)
    with pytest.raises(ValueError, match=r"Jacobian does not contain the tangent A of materials"):
        s.solver(residual, ufl.derivative(residual, s.u, s.du), materials, "uflder_")
    # the consistent Jacobian of the same residual is accepted, and solves
    solver = s.solver(residual, None, materials, "uflok_")
    assert solver.solve().converged
    solver.destroy()


@pytest.mark.mpi
def test_cells_without_a_material_are_refused(rve):
    """Only the granular layer: the 8 base cells have no stiffness at all."""
    s = Layered(rve)
    with pytest.raises(ValueError, match=r"^8 cells of the mesh belong to no material"):
        s.solver(s.residual(s.soil), None, [s.soil], "uncovered_")


@pytest.mark.mpi
def test_materials_sharing_cells_are_refused(rve):
    """A granular material on every cell plus the rock on the base: the base would carry both."""
    s = Layered(rve)
    whole = GranularMaterial(rve, s.u)
    with pytest.raises(ValueError, match=r"materials\[0\] .* and materials\[1\] .* share 8 cells"):
        s.solver(s.residual(whole, s.rock), None, [whole, s.rock], "shared_")


@pytest.mark.mpi
def test_cells_without_a_material_are_named_when_the_jacobian_is_singular(rve):
    """A u-dependent term of the user's (a spring on the top edge) might give the base cells
    stiffness, so the solver is built; the factorisation fails and the result says why."""
    s = Layered(rve)
    spring = 1e6 * ufl.inner(s.u, s.v) * s.ds(1)
    solver = s.solver(s.residual(s.soil) + spring, None, [s.soil], "spring_")
    result = solver.solve()
    assert not result.converged
    assert "8 cells belong to no material" in result.why, result.why
    assert not s.u.x.array.any()  # restored
    solver.destroy()
