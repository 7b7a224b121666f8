"""NewtonSolver: energy-norm logging, quadratic convergence, tangent consistency under line search,
failure reporting, and quadratic convergence of a small slope run."""

import csv
import warnings

import numpy as np
import pytest

dolfinx = pytest.importorskip("dolfinx")
from dolfinx_granular import SolveFailedWarning, TaylorRVE, generate_packing  # noqa: E402
from dolfinx_granular.fem.compat import SNES_NAN_REASON  # noqa: E402
from dolfinx_granular.slope import SlopeOptions, run_slope  # noqa: E402

from mpi4py import MPI  # noqa: E402

from helpers import granular_column  # noqa: E402


def column(pressure, petsc_options=None, prefix="col_", n=6, **solver_kwargs):
    """The shared column (tests/helpers.py) of a 70-particle RVE under a top pressure (Pa)."""
    return granular_column(
        TaylorRVE(generate_packing(70, seed=4), 2.8e7),
        prefix,
        n=n,
        pressure=pressure,
        petsc_options=petsc_options,
        **solver_kwargs,
    )[:3]


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
    # stopped by the paper's energy norm, or with the residual at round-off of the forces
    assert (e[-1] <= 1e-20 and result.stopped_by == "energy norm") or (
        result.stopped_by == "round-off" and result.residual_norm <= 1e-12 * result.force_scale
    )
    # quadratic: once in the asymptotic range, log e_{k+1} ~ 2 log e_k
    pairs = [(a, b) for a, b in zip(e[:-1], e[1:]) if a < 1e-3 and b > 1e-28]
    assert pairs, e
    assert all(np.log(b) / np.log(a) > 1.8 for a, b in pairs), e
    # residual norms fall as well
    r = np.array([rn for _, rn, _ in result.history] + [result.residual_norm])
    assert np.all(r[2:] < r[1:-1]) and r[-1] < 1e-12 * r[0]
    solver.destroy()


@pytest.mark.mpi
@pytest.mark.parametrize("linesearch", ["bt", "l2", "cp"])
def test_tangent_consistent_under_line_search(linesearch):
    """Line searches evaluate trial states; the tangent must still belong to the iterate, so the
    solution and quadratic convergence are those of plain Newton."""
    ref_solver, _, u_ref = column(2e5, prefix="ref_")
    ref = ref_solver.solve()
    solver, material, u = column(
        2e5, {"snes_linesearch_type": linesearch}, prefix=f"ls{linesearch}_"
    )
    result = solver.solve()
    assert ref.converged and result.converged, (ref, result)
    if linesearch != "bt":  # bt takes full Newton steps here; l2 and cp evaluate trial points
        assert material.n_updates > result.iterations + 1
    assert result.iterations <= ref.iterations + 2
    e = energies(result)
    assert e[-1] <= 1e-20 or result.reason_name == "CONVERGED_FNORM_ABS"
    # both collective: every rank compares the same numbers (a rank's own |u| differs)
    comm = MPI.COMM_WORLD
    diff = comm.allreduce(np.abs(u.x.array - u_ref.x.array).max(initial=0.0), op=MPI.MAX)
    scale = comm.allreduce(np.abs(u_ref.x.array).max(initial=0.0), op=MPI.MAX)
    assert scale > 0.0 and diff <= 1e-10 * scale, (diff, scale)
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
    assert result.reason == SNES_NAN_REASON and result.why.startswith("NaN residual"), result
    assert "outside the Taylor RVE's range" in result.error and "Affected cells" in result.error
    solver.destroy()


def test_small_slope_run_converges_quadratically(tmp_path, capsys):
    """All 21 load steps of the slope with a 70-particle RVE, no figure; the console numbers
    the Newton iterates as convergence.csv does."""
    summary = run_slope(
        generate_packing(70, seed=2),
        SlopeOptions(steps=20),
        out=str(tmp_path),
        comm=MPI.COMM_SELF,
        figure=False,
        verbose=True,
    )
    console = [line.strip() for line in capsys.readouterr().out.splitlines() if "Newton" in line]
    assert summary["converged"], summary["failed"]
    assert len(summary["iterations"]) == 21
    with open(tmp_path / "convergence.csv") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["step", "iterate", "residual_norm", "energy_norm_rel", "converged_by"]
    assert console == [
        f"Newton {int(r['iterate']):2d}: |R| = {float(r['residual_norm']):.3e} N"
        + (r["energy_norm_rel"] and f", energy norm (rel) = {float(r['energy_norm_rel']):.3e}")
        for r in rows
    ]
    by_step = {}
    for r in rows:
        by_step.setdefault(int(r["step"]), []).append(r)
    assert sorted(by_step) == list(range(1, 22))
    for step, its in by_step.items():
        assert [int(r["iterate"]) for r in its] == list(range(len(its)))
        assert its[0]["energy_norm_rel"] == "" and float(its[1]["energy_norm_rel"]) == 1.0
        e = [float(r["energy_norm_rel"]) for r in its[1:]]
        residuals = [float(r["residual_norm"]) for r in its]
        # every step ends where the table says why: the energy norm or round-off residual
        assert [r["converged_by"] for r in its[:-1]] == [""] * (len(its) - 1)
        last = its[-1]["converged_by"]
        assert last in ("energy norm", "round-off"), its[-1]
        assert (last == "energy norm" and e[-1] <= 1e-20) or residuals[-1] <= 1e-11 * residuals[0]
        assert residuals[-1] == summary["step_info"][step - 1]["residual_norm"]
        assert len(e) <= 8, (step, e)
        if step > 1:  # footing steps: small increments, Newton's quadratic range from the start
            assert len(e) <= 6, (step, e)
            assert e[2] <= e[1] ** 1.5, (step, e)


@pytest.mark.mpi
def caught(call, category):
    """``call()``'s result and the warnings of ``category`` it issued (every one recorded)."""
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        result = call()
    return result, [w for w in record if issubclass(w.category, category)]


@pytest.mark.mpi
def test_a_failed_solve_warns_once_with_the_reason_and_a_remedy():
    """A failed solve used to return silently, the reason only in result.error. It warns once,
    at the user's call, naming the reason and what to do; a driver's solve(warn=False) does
    not, nor does a converged solve."""
    solver, _, _ = column(3e7, prefix="warn_")
    result, record = caught(solver.solve, SolveFailedWarning)
    assert not result.converged and len(record) == 1
    message = str(record[0].message)
    assert message.startswith("Newton solve failed after") and result.why.rstrip(".") in message
    assert "Remedy: take the load in smaller steps: LoadStepper(solver)" in message, message
    assert record[0].filename == __file__  # attributed to the line that called solve()
    quiet, record = caught(lambda: solver.solve(warn=False), SolveFailedWarning)
    assert not quiet.converged and not record
    solver.destroy()
    solver, _, _ = column(2e5, prefix="nowarn_")
    result, record = caught(solver.solve, UserWarning)
    assert result.converged and not record
    solver.destroy()


@pytest.mark.mpi
def test_the_iteration_limit_names_max_it():
    solver, _, _ = column(2e5, prefix="maxit_", max_it=1)
    result, (record,) = caught(solver.solve, SolveFailedWarning)
    assert result.reason_name == "DIVERGED_MAX_IT", result
    assert "Remedy: allow more Newton steps (max_it, now 1)" in str(record.message)
    solver.destroy()


def test_a_converged_state_returns_at_once():
    """The same load twice: the second solve starts converged (residual at round-off of the
    forces) and returns with 0 iterations, not a stagnation from round-off / round-off."""
    solver, _, u = column(2e5)
    first = solver.solve()
    u_first = u.x.array.copy()
    again = solver.solve()
    assert first.converged and again.converged and again.iterations == 0
    assert again.stopped_by == "round-off" and again.residual_norm <= 1e-12 * again.force_scale
    assert np.array_equal(u.x.array, u_first)
    solver.destroy()


@pytest.mark.mpi
def test_a_tolerated_residual_ends_the_solve_at_the_first_iterate_within_it():
    """A residual_rtol above round-off is an out-of-balance force tolerated: the solve takes
    the round-off solve's iterates and stops at the first whose |R| lies within it."""
    exact, _, u_exact = column(2e5, prefix="exact_")
    full = exact.solve()
    scale = full.force_scale
    starts = [r for _, r, _ in full.history] + [full.residual_norm]  # |R| at iterate 0, 1, ...
    tolerance = 1e-5
    first = next(k for k, r in enumerate(starts) if r <= tolerance * scale)
    assert 0 < first < full.iterations, (starts, scale)  # (the test needs one in between)
    loose, _, u_loose = column(2e5, prefix="loose_", residual_rtol=tolerance)
    result = loose.solve()
    assert result.converged and result.stopped_by == "tolerance", result
    assert result.iterations == first and result.force_scale == pytest.approx(scale)
    assert result.residual_norm == pytest.approx(starts[first], rel=1e-6)
    assert [r for _, r, _ in result.history] == pytest.approx(starts[:first], rel=1e-6)
    # the iterate it stopped at is within the tolerance of the exact solution's displacement
    err = np.linalg.norm(u_loose.x.array - u_exact.x.array)
    assert 0.0 < err <= 1e-3 * np.linalg.norm(u_exact.x.array)
    exact.destroy()
    loose.destroy()


@pytest.mark.mpi
@pytest.mark.parametrize("stall_rtol, accepted", [(1e-2, True), (1e-3, False)])
def test_a_newton_cut_off_goes_back_to_its_best_iterate_within_the_stall_tolerance(
    stall_rtol, accepted
):
    """max_it 2 ends the column's Newton at |R| about 2e-3 of the force scale (quadratic, not
    stalled): with stall_rtol 1e-2 the solve takes its best iterate, evaluated again, and
    converges by 'tolerance' with the materials at that state; with 1e-3 it fails as before."""
    exact, _, _ = column(2e5, prefix="bestx_")
    full = exact.solve()
    starts = [r for _, r, _ in full.history]
    assert 1e-3 < starts[2] / full.force_scale < 1e-2, starts  # (what the test needs)
    cut, _, u = column(2e5, prefix=f"best{accepted}_", max_it=2, stall_rtol=stall_rtol)
    result = cut.solve(warn=False)
    assert result.converged is accepted, result
    if accepted:
        assert result.stopped_by == "tolerance" and result.iterations == 2
        assert result.residual_norm == pytest.approx(starts[2], rel=1e-6)
        # u and the materials are that iterate's: a solve from it starts at its residual
        again = cut.solve()
        assert again.history[0][1] == pytest.approx(starts[2], rel=1e-6)
        assert again.converged and again.stopped_by in ("round-off", "energy norm"), again
    else:
        assert result.reason_name == "DIVERGED_MAX_IT" and not u.x.array.any()
    exact.destroy()
    cut.destroy()


@pytest.mark.mpi
def test_readme_loop_from_zero_load_and_after_a_failure():
    """The README's loop with the loads 0, 1e5, 2e5 Pa: at zero load the reference state's
    overlaps (P(I) ~ 1e-11 of the modulus) are all there is to balance: converged at once. A
    failed solve leaves u where it started, so that the next loads converge: a crushing load
    fails, and the next solve converges."""
    solver, material, u, p = granular_column(
        TaylorRVE(generate_packing(70, seed=4), 2.8e7), "readme_loop_", n=6
    )
    p.value = 0.0
    at_rest = solver.solve()
    assert at_rest.converged and at_rest.iterations == 0 and not u.x.array.any()
    for pressure in [1e5, 2e5]:
        p.value = pressure
        assert solver.solve().converged, pressure
    u_good = u.x.array.copy()
    p.value = 3e7  # far beyond what the column carries
    crushed = solver.solve()
    assert not crushed.converged and np.array_equal(u.x.array, u_good)
    assert np.array_equal(material.F, material.deformation_gradient())  # data belong to u
    p.value = 2.5e5
    assert solver.solve().converged
    solver.destroy()


@pytest.mark.mpi
def test_zero_load_on_a_generated_packing_converges_at_once():
    """The README column (8 x 8 cells, generate_packing(70, seed=1): P(I) ~ 3e-4 Pa) at 0 Pa from
    u = 0. R is the forces of the reference stress (contacts overlapping by 1e-11 of the mean
    diameter), which Newton could only remove by opening those contacts: it used to move u by
    round-off and end with a singular Jacobian. A stress-free material under no load is in
    equilibrium: converged with 0 Newton steps, u untouched; the loads after it converge."""
    solver, _, u, p = granular_column(TaylorRVE(generate_packing(70, seed=1), 2.8e7), "zero_", n=8)
    result = solver.solve()
    assert result.converged and result.iterations == 0 and result.stopped_by == "no load"
    # not round-off: the residual is the reference stress's forces, the round-off scale as large
    assert result.residual_norm > 1e-12 * result.force_scale, result
    assert not u.x.array.any()
    for pressure in (1e5, 2e5):
        p.value = pressure
        loaded = solver.solve()
        assert loaded.converged and loaded.stopped_by != "no load", (pressure, loaded)
    solver.destroy()


def test_gravity_only_slope_converges(tmp_path):
    """No footing load (--load-factor 0): every footing step starts converged and takes 0
    Newton steps; the run succeeds."""
    summary = run_slope(
        generate_packing(70, seed=2),
        SlopeOptions(steps=2, load_factor=0.0),
        out=str(tmp_path),
        comm=MPI.COMM_SELF,
        figure=False,
        verbose=False,
    )
    assert summary["converged"] and summary["iterations"][1:] == [0, 0], summary["iterations"]


class _FailingLaw:
    """A Taylor RVE that raises ``error`` once F compresses beyond a stretch ``below``."""

    def __init__(self, rve, error, below):
        self.rve, self.error, self.below = rve, error, below

    def __getattr__(self, name):
        return getattr(self.rve, name)

    def _check(self, F):
        if np.asarray(F)[..., 1, 1].min() < self.below:
            raise self.error

    def evaluate(self, F, out=None):
        self._check(F)
        return self.rve.evaluate(F, out)

    def stress(self, F, out=None):
        self._check(F)
        return self.rve.stress(F, out)

    def cauchy(self, F):
        return self.rve.cauchy(F)

    def spatial_tangent(self, F):
        return self.rve.spatial_tangent(F)

    def small_strain_modulus(self):
        return self.rve.small_strain_modulus()


def test_only_law_evaluation_errors_become_failed_solves():
    """A LawEvaluationError (the law cannot answer there) is a failed, restored solve; any
    other exception inside a law (a bug: an IndexError, or a shape bug's plain ValueError)
    reaches the user as it is."""
    from dolfinx_granular import LawEvaluationError

    from helpers import granular_column

    class OutOfRange(LawEvaluationError):
        pass

    rve = TaylorRVE(generate_packing(70, seed=4), 2.8e7)
    cases = (
        (OutOfRange("too compressed", np.array([0])), True),
        (IndexError("a bug in the law"), False),
        (ValueError("operands could not be broadcast together"), False),
    )
    for error, fails in cases:
        solver, _, u, p = granular_column(_FailingLaw(rve, error, 0.999), "fail_", n=2)[:4]
        p.value = 3e5
        if fails:
            result = solver.solve()
            assert not result.converged and "too compressed" in result.error
            assert np.all(u.x.array == 0.0)  # restored
        else:
            with pytest.raises(type(error), match=str(error)):
                solver.solve()
        solver.destroy()
