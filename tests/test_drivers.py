"""The problem and its drivers: the one convergence test (SNES Newton's rule and the arc-length
corrector's, a parameter of it), load control as a driver of the protocol, the problem's public
methods (no import circle anywhere in the package: tests/test_imports.py)."""

from dolfinx_granular.drivers.convergence import CONVERGED, ITERATING, STAGNATION, ConvergenceTest

import numpy as np
import pytest


class _Forces:
    """A problem without forces: force scale 0, no reference stress."""

    floor, external = 0.0, 0.0

    def force_scale(self, R):
        return 0.0


def _verdicts(test, norms):
    """The verdicts at iterates 0, 1, ... of residual norms ``norms`` (every step's energy 1)."""
    test.reset()
    return [test.check(it, r, None, None if it == 0 else 1.0) for it, r in enumerate(norms)]


def test_snes_rule_counts_stagnation_from_iterate_1_the_corrector_from_iterate_0():
    """A first step that overshoots the start (|R| 1 -> 10) and then never gets below 1: SNES's
    rule takes iterate 1 as the best |R| so far (5 < 10 is progress), the corrector's keeps the
    start's (every iterate from 2 on counts as no progress)."""
    norms = [1.0, 10.0, 5.0, 6.0, 7.0, 8.0, 9.0]
    snes = _verdicts(ConvergenceTest(_Forces(), stagnation_it=4), norms)
    corrector = _verdicts(ConvergenceTest(_Forces(), stagnation_it=4, corrector=True), norms)
    assert snes == [ITERATING] * 6 + [STAGNATION]
    assert corrector == [ITERATING] * 5 + [STAGNATION, STAGNATION]


class _Scaled(_Forces):
    """A problem whose forces are 1e6 N."""

    def force_scale(self, R):
        return 1e6


@pytest.mark.parametrize("corrector", [False, True])
def test_a_stall_tolerance_accepts_a_stalled_residual_within_it_and_nothing_else(corrector):
    """stall_rtol 1e-4 (100 N of 1e6 N): a residual Newton still halves goes on to round-off
    however small it is; one that has stalled is accepted within the tolerance, not above it."""
    test = ConvergenceTest(_Scaled(), stall_rtol=1e-4, corrector=corrector, stagnation_it=4)
    # converging: 50 N and 1 N are within 100 N, but Newton halves them: it goes on
    assert _verdicts(test, [1e5, 5e2, 50.0, 1.0]) == [ITERATING] * 4
    # cycling at 150 N (above the tolerance) and then at 80 N (within it): accepted at 80 N
    assert _verdicts(test, [1e5, 150.0, 140.0, 80.0]) == [ITERATING] * 3 + [CONVERGED]
    assert test.stopped_by == "tolerance"
    # the best iterate within the tolerance, where a stagnating Newton may go back to: a
    # Newton iterate (30 N, reached by halving), never the start (80 N: the step's imbalance)
    test.reset()
    assert test.check(0, 80.0, None) == ITERATING and not test.best_within
    assert test.check(1, 30.0, None, 1.0) == ITERATING and test.best_within
    assert test.check(2, 120.0, None, 1.0) == ITERATING and not test.best_within
    # the same cycle without the tolerance goes on (and stagnates)
    plain = ConvergenceTest(_Scaled(), corrector=corrector, stagnation_it=4)
    assert CONVERGED not in _verdicts(plain, [1e5, 150.0, 140.0, 80.0, 90.0, 85.0, 88.0, 86.0])


def test_one_test_energy_norm_and_round_off_in_both_variants():
    """The energy norm relative to the first step's ends both; a stalled |R| with the energy at
    round-off is 'round-off' in both; only SNES's rule has the absolute test."""
    for corrector in (False, True):
        test = ConvergenceTest(_Forces(), energy_rtol=1e-20, corrector=corrector)
        assert test.check(0, 1.0, None) == ITERATING
        assert test.check(1, 1e-3, None, 2.0) == ITERATING
        assert test.check(2, 1e-9, None, 2e-21) == CONVERGED
        assert test.stopped_by == "energy norm" and test.history[-1] == (2, 1e-3, 1e-21)
        test.reset()
        test.check(0, 1.0, None)
        test.check(1, 1e-8, None, 1.0)
        assert test.check(2, 0.9e-8, None, 1e-15) == CONVERGED and test.stopped_by == "round-off"
    snes, corrector = ConvergenceTest(_Forces()), ConvergenceTest(_Forces(), corrector=True)
    assert snes.check(0, 0.0, None) == CONVERGED and snes.stopped_by == "residual_atol"
    assert corrector.check(0, 0.0, None) == CONVERGED and corrector.stopped_by == "round-off"


dolfinx = pytest.importorskip("dolfinx")


@pytest.mark.mpi
def test_load_phase_is_a_driver_with_one_record_per_increment():
    """LoadStepper.phase: run(on_converged) with a LoadIncrement per converged increment; a stop
    asked for is ``stopped`` (a str, as ArcLength's), run returns True unless it failed."""
    from dolfinx_granular import TaylorRVE, generate_packing
    from dolfinx_granular.drivers.loading import LoadIncrement, LoadStepper
    from dolfinx_granular.drivers.protocol import ASKED_TO_STOP, Driver, IncrementRecord

    from helpers import granular_column

    solver, _, u, p = granular_column(TaylorRVE(generate_packing(70, seed=4), 2.8e7), "drv_")[:4]
    stepper = LoadStepper(solver)
    phase = stepper.phase("press", lambda t: setattr(p, "value", 3e5 * t), 0.25)
    assert isinstance(phase, Driver)
    records = []
    assert phase.run(on_converged=lambda inc: records.append(inc) or len(records) < 2)
    assert phase.stopped == ASKED_TO_STOP and phase.failed is None
    assert [(r.step, r.t, r.phase) for r in records] == [(1, 0.25, "press"), (2, 0.5, "press")]
    r = records[-1]
    assert isinstance(r, LoadIncrement) and isinstance(r, IncrementRecord)
    assert r.iterations == r.result.iterations > 0 and r.converged_by == r.result.stopped_by
    assert r.history == r.result.history and r.reason_name.startswith("CONVERGED")
    rest = stepper.phase("press", lambda t: setattr(p, "value", 3e5 * t), 0.25, t=r.t)
    assert rest.run() and rest.stopped is None and stepper.step == 4
    solver.destroy()


def test_problem_evaluates_assembles_commits_and_restores():
    """GranularProblem's public methods: R and K at a state, the force scale, a restore to a
    saved state (u and the materials' stress), all without SNES."""
    from dolfinx_granular import TaylorRVE, generate_packing
    from dolfinx_granular.drivers.problem import GranularProblem

    from helpers import granular_column

    solver, material, u, p = granular_column(
        TaylorRVE(generate_packing(70, seed=4), 2.8e7), "prob_", n=2, pressure=2e5
    )[:4]
    problem = solver.problem
    assert isinstance(problem, GranularProblem) and problem.materials == (material,)
    u0 = u.x.array.copy()
    b = problem.u_vec.duplicate()
    assert problem.residual(problem.u_vec, b) is None
    assert problem.force_scale(b) > 0.0 and b.norm() > 0.0  # loaded, not in balance
    assert solver.solve().converged
    K = problem.assemble_jacobian(problem.u_vec)
    assert K.norm() > 0.0
    P = material.P.x.array.copy()
    problem.restore(u0)
    assert np.array_equal(u.x.array, u0) and not np.array_equal(material.P.x.array, P)
    solver.destroy()
