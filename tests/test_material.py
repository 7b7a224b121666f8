"""GranularMaterial in DOLFINx: pointwise agreement with the kernel, reactions, Taylor test.

Marked ``mpi`` so that ``mpirun -n 2 pytest -m mpi`` runs them on a distributed mesh as well.
"""

import numpy as np
import pytest

dolfinx = pytest.importorskip("dolfinx")
from dolfinx_granular import TaylorRVE, generate_packing  # noqa: E402
from dolfinx_granular.drivers.newton import NewtonSolver  # noqa: E402
from dolfinx_granular.fem.compat import function_space, vector_space  # noqa: E402
from dolfinx_granular.fem.material import GranularMaterial  # noqa: E402

import ufl  # noqa: E402
from dolfinx import fem, mesh  # noqa: E402
from dolfinx.fem.petsc import assemble_vector  # noqa: E402
from mpi4py import MPI  # noqa: E402
from petsc4py import PETSc  # noqa: E402

from helpers import taylor_remainders  # noqa: E402

K_N = 2.8e7
F0 = np.array([[0.975, 0.012], [-0.008, 0.962]])  # compressive, slightly sheared


def small_rve(n=70, seed=3):
    return TaylorRVE(generate_packing(n, seed=seed), K_N)


def unit_square(n=3, cell=mesh.CellType.quadrilateral):
    return mesh.create_unit_square(MPI.COMM_WORLD, n, n, cell)


def affine(F):
    return lambda x: np.stack(
        [(F[0, 0] - 1) * x[0] + F[0, 1] * x[1], F[1, 0] * x[0] + (F[1, 1] - 1) * x[1]]
    )


@pytest.mark.mpi
@pytest.mark.parametrize("cell", [mesh.CellType.quadrilateral, mesh.CellType.triangle])
def test_homogeneous_square_matches_kernel_and_reactions(cell):
    """Displacements (F0 - I) X prescribed on the boundary: P equals the kernel's P(F0) at every
    Gauss point and the reaction on each edge equals P(F0) n x edge length."""
    rve = small_rve()
    msh = unit_square(3, cell)
    V = vector_space(msh)
    u = fem.Function(V)
    material = GranularMaterial(rve, u)
    v, du = ufl.TestFunction(V), ufl.TrialFunction(V)
    boundary = fem.locate_dofs_geometrical(
        V,
        lambda x: (
            np.isclose(x[0], 0) | np.isclose(x[0], 1) | np.isclose(x[1], 0) | np.isclose(x[1], 1)
        ),
    )
    g = fem.Function(V)
    g.interpolate(affine(F0))
    solver = NewtonSolver(
        material.residual_form(v),
        material.jacobian_form(du, v),
        u,
        [fem.dirichletbc(g, boundary)],
        material,
        prefix="homog_",
    )
    result = solver.solve()
    assert result.converged, result
    _, P_ref, A_ref = rve.evaluate(F0[None])
    n = material.n_points
    P = material.P.x.array[: 4 * n].reshape(n, 2, 2)
    A = material.A.x.array[: 16 * n].reshape(n, 4, 4)
    scale = np.abs(P_ref).max()
    assert np.abs(P - P_ref).max() <= 1e-10 * scale
    assert np.abs(A - A_ref.reshape(1, 4, 4)).max() <= 1e-10 * np.abs(A_ref).max()
    assert np.allclose(material.F, F0, rtol=0, atol=1e-13)

    # Reactions: the internal force vector summed over the nodes of one edge (corners included).
    R = assemble_vector(fem.form(material.residual_form(v)))
    R.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    x = V.tabulate_dof_coordinates()[: V.dofmap.index_map.size_local]
    r = R.array_r.reshape(-1, 2)
    for axis, side, normal in [
        (0, 1.0, (1, 0)),
        (0, 0.0, (-1, 0)),
        (1, 1.0, (0, 1)),
        (1, 0.0, (0, -1)),
    ]:
        on = np.isclose(x[:, axis], side)
        reaction = msh.comm.allreduce(r[on].sum(axis=0), op=MPI.SUM)
        expected = P_ref[0] @ np.array(normal, dtype=float) * 1.0  # edge length 1 m
        assert np.allclose(reaction, expected, rtol=1e-10, atol=1e-10 * scale), (
            normal,
            reaction,
            expected,
        )
    solver.destroy()


@pytest.mark.mpi
def test_update_writes_owned_points_only_and_names_bad_cells():
    rve = small_rve()
    msh = unit_square(2)
    V = vector_space(msh)
    u = fem.Function(V)
    material = GranularMaterial(rve, u)
    n_owned = msh.topology.index_map(2).size_local
    assert material.n_points == 4 * n_owned
    # partitioned with the mesh: every cell's RVEs live on exactly one rank
    assert msh.comm.allreduce(material.n_points) == 4 * msh.topology.index_map(2).size_global
    material.P.x.array[:] = np.nan
    material.update()
    assert np.isfinite(material.P.x.array[: 4 * material.n_points]).all()
    assert np.isnan(material.P.x.array[4 * material.n_points :]).all()  # ghosts untouched
    u.interpolate(lambda x: np.stack([-0.9 * x[0], 0 * x[1]]))  # F00 = 0.1 < min_stretch
    if material.n_points:
        with pytest.raises(ValueError, match="min_stretch.*Affected cells"):
            material.update()


def test_rejects_bad_input():
    msh = unit_square(1)
    V = vector_space(msh)
    with pytest.raises(TypeError, match="TaylorRVE"):
        GranularMaterial("not an rve", fem.Function(V))
    S = function_space(msh, "Lagrange", 1)
    with pytest.raises(ValueError, match="vector displacement"):
        GranularMaterial(small_rve(), fem.Function(S))


@pytest.mark.mpi
def test_taylor_jacobian_against_residual():
    """|R(u + h du) - R(u) - h J(u) du| = O(h^2), while dropping J leaves O(h)."""
    rve = small_rve(seed=5)
    msh = unit_square(4)
    V = vector_space(msh)
    u = fem.Function(V)
    u.interpolate(
        lambda x: np.stack(
            [-0.02 * x[0] + 0.01 * np.sin(3 * x[1]), -0.03 * x[1] + 0.01 * x[0] * x[1]]
        )
    )
    d = fem.Function(V)
    d.interpolate(lambda x: np.stack([0.01 * np.cos(2 * x[0] + x[1]), -0.01 * x[0] * x[1] ** 2]))
    material = GranularMaterial(rve, u)
    v, du = ufl.TestFunction(V), ufl.TrialFunction(V)
    L, a = fem.form(material.residual_form(v)), fem.form(material.jacobian_form(du, v))
    rate1, rate2, r1, r2 = taylor_remainders(L, a, u, d, material.update, h0=1e-1)
    assert np.all(np.abs(rate1 - 1.0) < 0.1), rate1
    assert np.all(rate2 > 1.9), rate2
    assert r2[-1] < 1e-3 * r1[-1]


@pytest.mark.mpi
def test_stress_floor_is_the_reference_stress_of_a_stress_free_law():
    """A generated packing's P(I) (~1e-11 of the modulus) is the floor, and its forces are those
    of the material at u = 0, on a subdomain too; an exactly stress-free lattice and a
    prestressed packing (a real stress to balance) have none. A law with history: the same."""
    from dolfinx_granular import FrictionalRVE
    from dolfinx_granular.laws.taylor import PrestressWarning

    from helpers import random_packing, square_lattice

    msh = unit_square(4)
    V = vector_space(msh)
    u, v = fem.Function(V), ufl.TestFunction(V)
    packing = generate_packing(70, seed=1)
    lower = mesh.locate_entities(msh, 2, lambda x: x[1] <= 0.5 + 1e-12)
    for law, cells in [
        (TaylorRVE(packing, K_N), None),
        (TaylorRVE(packing, K_N), lower),
        (FrictionalRVE(packing, K_N, 0.5 * K_N, 0.5), None),
    ]:
        material = GranularMaterial(law, u, cells=cells)
        ratio = np.linalg.norm(material.reference_stress()) / K_N
        assert 1e-13 < ratio < 1e-9, ratio
        material.update()
        f_int = assemble_vector(fem.form(material.residual_form(v)))
        floor = assemble_vector(fem.form(material.stress_floor_form(v)))
        for b in (f_int, floor):
            b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        assert f_int.norm() > 0.0
        floor.axpy(-1.0, f_int)
        assert floor.norm() <= 1e-12 * f_int.norm()
    assert GranularMaterial(TaylorRVE(square_lattice(6), K_N), u).stress_floor_form(v) is None
    with pytest.warns(PrestressWarning):
        overlapping = TaylorRVE(random_packing(40, seed=3), K_N, allow_overlaps=True)
    assert GranularMaterial(overlapping, u).stress_floor_form(v) is None
