"""NewtonSolver: energy-norm logging, quadratic convergence, tangent consistency under line search,
failure reporting, and quadratic convergence of a small slope run."""

import csv
import importlib.util
import os

import numpy as np
import pytest

dolfinx = pytest.importorskip("dolfinx")
import ufl  # noqa: E402
from dolfinx import fem, mesh  # noqa: E402
from mpi4py import MPI  # noqa: E402

from dolfinx_granular import TaylorRVE, generate_packing  # noqa: E402
from dolfinx_granular.material import GranularMaterial  # noqa: E402
from dolfinx_granular.solver import NewtonSolver  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def column(pressure, petsc_options=None, prefix="col_", n=6):
    """A 10 m x 10 m column on rollers with a fixed base under a top pressure (Pa)."""
    msh = mesh.create_rectangle(MPI.COMM_WORLD, [[0, 0], [10, 10]], [n, n], mesh.CellType.quadrilateral)
    V = fem.VectorFunctionSpace(msh, ("Lagrange", 1))
    u, v, du = fem.Function(V), ufl.TestFunction(V), ufl.TrialFunction(V)
    material = GranularMaterial(TaylorRVE(generate_packing(70, seed=4), 2.8e7), u)
    top = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 10))
    bottom = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 0))
    walls = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[0], 0) | np.isclose(x[0], 10))
    ds = ufl.Measure("ds", msh, subdomain_data=mesh.meshtags(msh, 1, top, np.full_like(top, 1)))
    x = ufl.SpatialCoordinate(msh)
    # A pressure varying along the top so that the solution is not homogeneous.
    residual = material.residual_form(v) + pressure * (1 + 0.05 * x[0]) * v[1] * ds(1)
    bcs = [fem.dirichletbc(np.zeros(2), fem.locate_dofs_topological(V, 1, bottom), V),
           fem.dirichletbc(0.0, fem.locate_dofs_topological(V.sub(0), 1, walls), V.sub(0))]
    solver = NewtonSolver(residual, material.jacobian_form(du, v), u, bcs, material,
                          prefix=prefix, petsc_options=petsc_options)
    return solver, material, u


def energies(result):
    return np.array([e for _, _, e in result.history])


@pytest.mark.mpi
def test_energy_norm_history_is_quadratic():
    solver, _, _ = column(2e5)
    result = solver.solve()
    assert result.converged
    e = energies(result)
    assert [it for it, _, _ in result.history] == list(range(1, len(e) + 1))
    assert e[0] == 1.0 and 3 <= len(e) <= 7
    assert e[-1] <= 1e-20 or result.reason_name == "CONVERGED_FNORM_ABS"
    # quadratic: once in the asymptotic range, log e_{k+1} ~ 2 log e_k
    pairs = [(a, b) for a, b in zip(e[:-1], e[1:]) if a < 1e-3 and b > 1e-28]
    assert pairs, e
    assert all(np.log(b) / np.log(a) > 1.8 for a, b in pairs), e
    # residual norms fall as well
    r = np.array([rn for _, rn, _ in result.history])
    assert r[-1] < 1e-6 * r[0]
    solver.destroy()


@pytest.mark.mpi
@pytest.mark.parametrize("linesearch", ["bt", "l2", "cp"])
def test_tangent_consistent_under_line_search(linesearch):
    """Line searches evaluate trial states; the tangent must still belong to the iterate, so the
    solution and quadratic convergence are those of plain Newton."""
    ref_solver, _, u_ref = column(2e5, prefix="ref_")
    ref = ref_solver.solve()
    solver, material, u = column(2e5, {"snes_linesearch_type": linesearch}, prefix=f"ls{linesearch}_")
    result = solver.solve()
    assert ref.converged and result.converged, (ref, result)
    if linesearch != "bt":  # bt takes full Newton steps here; l2 and cp evaluate trial points
        assert material.n_updates > result.iterations + 1
    assert result.iterations <= ref.iterations + 2
    e = energies(result)
    assert e[-1] <= 1e-20 or result.reason_name == "CONVERGED_FNORM_ABS"
    diff = np.abs(u.x.array - u_ref.x.array).max()
    assert MPI.COMM_WORLD.allreduce(diff, op=MPI.MAX) <= 1e-10 * np.abs(u_ref.x.array).max()
    # material data belong to the returned state
    F_now = material.deformation_gradient()
    assert np.array_equal(F_now, material.F)
    ref_solver.destroy()
    solver.destroy()


@pytest.mark.mpi
def test_failure_is_reported_not_raised():
    solver, _, _ = column(3e7)  # crushes the column far below min_stretch
    result = solver.solve()
    assert not result.converged
    assert result.reason < 0
    assert result.reason_name == "DIVERGED_FNORM_NAN", result
    assert "outside the Taylor RVE's range" in result.error and "Affected cells" in result.error
    solver.destroy()


def _slope_module():
    spec = importlib.util.spec_from_file_location("slope_demo", os.path.join(ROOT, "demos", "slope.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_small_slope_run_converges_quadratically(tmp_path):
    """All 21 load steps of the slope with a 70-particle RVE, no figure."""
    slope = _slope_module()
    summary = slope.run(generate_packing(70, seed=2), steps=20, out=str(tmp_path),
                        comm=MPI.COMM_SELF, figure=False, verbose=False)
    assert summary["converged"], summary["failed"]
    assert len(summary["iterations"]) == 21
    with open(tmp_path / "convergence.csv") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["step", "iteration", "residual_norm", "energy_norm_rel"]
    by_step = {}
    for r in rows:
        by_step.setdefault(int(r["step"]), []).append(float(r["energy_norm_rel"]))
    assert sorted(by_step) == list(range(1, 22))
    for step, e in by_step.items():
        assert e[0] == 1.0
        assert len(e) <= 8, (step, e)
        if step > 1:  # footing steps: small increments, Newton's quadratic range from the start
            assert len(e) <= 6, (step, e)
            assert e[2] <= e[1] ** 1.5, (step, e)
