"""The quadrature-material base: derivative() is the consistent Jacobian of any residual with P in
it, materials on subdomains add up, and a granular layer on a linear elastic base solves."""

from dolfinx_granular import TaylorRVE, generate_packing
from dolfinx_granular.drivers.loading import LoadStepper
from dolfinx_granular.drivers.newton import NewtonSolver
from dolfinx_granular.fem.compat import vector_space
from dolfinx_granular.fem.linear import LinearElasticMaterial, lame_from_young
from dolfinx_granular.fem.material import GranularMaterial
from dolfinx_granular.fem.quadrature import check_quadrature_degree, derivative

import numpy as np
import pytest
import ufl
from dolfinx import fem, mesh
from dolfinx.fem.petsc import assemble_matrix
from mpi4py import MPI

from helpers import taylor_remainders

K_N = 2.8e7


@pytest.fixture(scope="module")
def rve():
    return TaylorRVE(generate_packing(40, seed=5), K_N)


def square(n=4):
    return mesh.create_rectangle(
        MPI.COMM_WORLD, [[0, 0], [2, 2]], [n, n], mesh.CellType.quadrilateral
    )


def lower_cells(msh, y=1.0):
    """Cells below y (local indices, ghosts included)."""
    return mesh.locate_entities(msh, 2, lambda x: x[1] <= y + 1e-12)


def taylor_rates(materials, residual, u, direction, in_jacobian=None):
    """Convergence rates and remainders |R(u + h d) - R(u)| and |R(u + h d) - R(u) - h J d| for
    halving h (tests/helpers.py), J the Jacobian of derivative(residual, u, du, in_jacobian or
    materials)."""
    du = ufl.TrialFunction(u.function_space)
    in_jacobian = materials if in_jacobian is None else in_jacobian
    L, a = fem.form(residual), fem.form(derivative(residual, u, du, in_jacobian))

    def update():
        for m in materials:
            m.update()

    return taylor_remainders(L, a, u, direction, update, h0=4e-2)


def deformed(V):
    u, d = fem.Function(V), fem.Function(V)
    u.interpolate(
        lambda x: np.stack(
            [-0.015 * x[0] + 0.004 * np.sin(2 * x[1]), -0.02 * x[1] + 0.003 * x[0] * x[1]]
        )
    )
    d.interpolate(lambda x: np.stack([0.01 * np.cos(x[0] + 2 * x[1]), -0.01 * x[0] * x[1] ** 2]))
    return u, d


@pytest.mark.mpi
def test_derivative_is_the_consistent_jacobian_of_a_general_residual(rve):
    """Residual: a scaled RVE stress on the lower half, a linear elastic law on the upper half
    and a u-dependent spring term; the Jacobian from derivative() passes the Taylor test (second
    order), and leaving out the materials' stress derivative fails it."""
    msh = square()
    V = vector_space(msh)
    u, d = deformed(V)
    v = ufl.TestFunction(V)
    lower = lower_cells(msh)
    upper = mesh.locate_entities(msh, 2, lambda x: x[1] >= 1.0 - 1e-12)
    granular = GranularMaterial(rve, u, cells=lower)
    elastic = LinearElasticMaterial(u, *lame_from_young(5e6, 0.3), cells=upper)
    residual = (
        2.5 * ufl.inner(granular.P, ufl.grad(v)) * granular.dx
        + elastic.residual_form(v)
        + 1e5 * ufl.inner(u, u) * u[1] * v[1] * ufl.ds
    )
    rate1, rate2, r1, r2 = taylor_rates([granular, elastic], residual, u, d)
    assert np.all(np.abs(rate1 - 1.0) < 0.1), rate1
    assert np.all(rate2 > 1.9), rate2
    # without the stress derivative the Jacobian misses the RVE: first order only
    *_, r2_wrong = taylor_rates([granular, elastic], residual, u, d, in_jacobian=[elastic])
    assert r2_wrong[-1] > 100 * r2[-1]


@pytest.mark.mpi
def test_jacobian_form_equals_derivative_of_residual_form(rve):
    msh = square(3)
    V = vector_space(msh)
    u, _ = deformed(V)
    material = GranularMaterial(rve, u)
    material.update()
    v, du = ufl.TestFunction(V), ufl.TrialFunction(V)
    mats = [
        assemble_matrix(fem.form(f))
        for f in (
            material.jacobian_form(du, v),
            material.derivative(material.residual_form(v), u, du),
        )
    ]
    for A in mats:
        A.assemble()
    mats[0].axpy(-1.0, mats[1])
    assert mats[0].norm() <= 1e-12 * mats[1].norm()


@pytest.mark.mpi
def test_material_on_a_subdomain_has_zero_stress_elsewhere(rve):
    msh = square()
    V = vector_space(msh)
    u, _ = deformed(V)
    lower = lower_cells(msh)
    whole, part = GranularMaterial(rve, u), GranularMaterial(rve, u, cells=lower)
    whole.update()
    part.update()
    n_owned = msh.topology.index_map(2).size_local
    owned_lower = lower[lower < n_owned]
    assert np.array_equal(part.cells, np.sort(owned_lower)) and part.n_points == 4 * part.cells.size
    P_whole = whole.P.x.array.reshape(-1, 4, 4)[:n_owned]
    P_part = part.P.x.array.reshape(-1, 4, 4)[:n_owned]
    inside = np.isin(np.arange(n_owned), owned_lower)
    assert np.array_equal(P_part[inside], P_whole[inside])
    assert not P_part[~inside].any()
    assert np.array_equal(part.F, whole.F.reshape(n_owned, 4, 2, 2)[inside].reshape(-1, 2, 2))
    assert np.allclose(part.points[:, 1], part.points[:, 1].clip(max=1.0))


def layered_column(rve, n=6):
    """A 2 m x 2 m column: granular layer (y > 1) on a linear elastic base (y < 1), fixed
    bottom, rollers on the sides, top pressure p (a Constant, Pa)."""
    msh = square(n)
    V = vector_space(msh)
    u, v = fem.Function(V), ufl.TestFunction(V)
    base = mesh.locate_entities(msh, 2, lambda x: x[1] <= 1.0 + 1e-12)
    layer = mesh.locate_entities(msh, 2, lambda x: x[1] >= 1.0 - 1e-12)
    soil = GranularMaterial(rve, u, cells=layer)
    rock = LinearElasticMaterial(u, *lame_from_young(2e8, 0.25), cells=base)
    top = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 2))
    ds = ufl.Measure("ds", msh, subdomain_data=mesh.meshtags(msh, 1, top, np.full_like(top, 1)))
    p = fem.Constant(msh, 0.0)
    residual = soil.residual_form(v) + rock.residual_form(v) + p * v[1] * ds(1)
    bottom = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 0))
    walls = mesh.locate_entities_boundary(
        msh, 1, lambda x: np.isclose(x[0], 0) | np.isclose(x[0], 2)
    )
    bcs = [
        fem.dirichletbc(np.zeros(2), fem.locate_dofs_topological(V, 1, bottom), V),
        fem.dirichletbc(0.0, fem.locate_dofs_topological(V.sub(0), 1, walls), V.sub(0)),
    ]
    solver = NewtonSolver(residual, None, u, bcs, [soil, rock], prefix="layered_")
    return solver, soil, rock, u, p


@pytest.mark.mpi
def test_granular_layer_on_a_linear_elastic_base(rve):
    """Confined compression: both parts carry the vertical stress -p on average (the RVE's
    anisotropy makes it vary about that in the layer), the stepper drives both materials, and
    the stiff base settles far less than the layer."""
    solver, soil, rock, u, p = layered_column(rve)
    stepper = LoadStepper(solver)
    assert stepper.run("press", lambda t: setattr(p, "value", 3e5 * t), 0.5)
    assert stepper.failed is None and stepper.step == 2
    s_soil, s_rock = soil.cauchy(), rock.cauchy()
    comm = MPI.COMM_WORLD
    for sigma in (s_soil, s_rock):  # the mean of sigma_yy over whole rows of cells is -p
        mean = comm.allreduce(float(sigma[:, 1, 1].sum())) / comm.allreduce(len(sigma))
        lo = comm.allreduce(float(sigma[:, 1, 1].min()) if len(sigma) else np.inf, op=MPI.MIN)
        hi = comm.allreduce(float(sigma[:, 1, 1].max()) if len(sigma) else -np.inf, op=MPI.MAX)
        assert abs(mean + 3e5) < 1e-4 * 3e5 and -1.1 * 3e5 < lo <= hi < -0.9 * 3e5, (mean, lo, hi)
    x = V_coords(u)
    uy = u.x.array[1::2][: len(x)]

    def at(y):
        top = float(np.abs(uy[np.isclose(x[:, 1], y)]).max(initial=0.0))
        return comm.allreduce(top, op=MPI.MAX)

    assert at(2.0) - at(1.0) > 5 * at(1.0)  # the layer compresses more than the base
    solver.destroy()


def V_coords(u):
    return u.function_space.tabulate_dof_coordinates()[:, :2]


def test_quadrature_degree_must_be_an_integer():
    assert check_quadrature_degree(2) == 2 and check_quadrature_degree(3.0) == 3
    for bad in (2.7, 0, -1, "2", True, float("nan")):
        with pytest.raises(ValueError, match="quadrature_degree must be an integer >= 1"):
            check_quadrature_degree(bad)


def test_granular_material_rejects_a_fractional_degree(rve):
    V = vector_space(square(1))
    with pytest.raises(ValueError, match="got 2.7"):
        GranularMaterial(rve, fem.Function(V), quadrature_degree=2.7)
    with pytest.raises(ValueError, match="cells"):
        GranularMaterial(rve, fem.Function(V), cells=[10**6])
