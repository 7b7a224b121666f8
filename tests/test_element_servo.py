"""The element tests' servo: a step whose held stress jumps across -p beyond the driver's limits
is taken on its last halving at the jump's side (as a DEM cell's servo-controlled wall lags or
overshoots), the measures read only the steps that held p, and a test whose steps stop holding
p stops. Linear laws with a jump (helpers) and hand-made rows."""

import math

from dolfinx_granular.drivers import element_tests as et
from dolfinx_granular.drivers.material_point import ControlError, MaterialPoint

import numpy as np
import pytest

from helpers import CollapsingHistoryLaw, CollapsingLaw, JumpLaw

K = CollapsingLaw(0.0).lam + 2 * CollapsingLaw(0.0).mu  # P11 / H11 at F22 = 1 (Pa)


@pytest.mark.parametrize("hold", [2.5, 4.0])
def test_a_collapse_beyond_the_limits_is_taken_on_the_jammed_side_only_as_the_servo(hold):
    """Jammed, the cell holds hold x p (beyond ACCEPT_UNJAMMED's miss) and a round-off further
    it comes apart: no F holds p. Without the servo the step is refused; with it, it is taken
    at the jammed side and its row records the miss."""
    law, p = CollapsingLaw(-hold * 1e-3 * K), 1e-3 * K
    assert hold - 1.0 > et.ACCEPT_UNJAMMED
    point = MaterialPoint(law)
    F = np.diag([0.99, 1.0])
    with pytest.raises(ControlError, match="jumps"):
        et.hold_step(point, F, (0, 0), p, 1e-3)
    assert np.array_equal(point.F, np.eye(2))  # (nothing committed)
    # (the Cauchy stress: F22 = 1, so sigma11 = P11 F11 / det F = P11)
    r, collapses = et.hold_step(point, F, (0, 0), p, 1e-3, servo=True)
    assert collapses == 0  # (a law that gives no state does not collapse)
    assert r.F[0, 0] == pytest.approx(1.0, abs=1e-12)
    assert r.control_error == pytest.approx(-(hold - 1.0) * p, rel=1e-9)
    assert np.array_equal(point.F, r.F)  # (committed)


def test_a_cell_that_holds_too_much_collapses_and_jams_again_at_p():
    """Jammed, the cell holds 2.5 p, and a round-off further it comes apart with its state
    (CellFloats): the step commits that state and holds p again from it, in the same step,
    where the collapsed cell jams 2e-3 further in (F11 = 1 - 2e-3 - 1e-3); its iterations
    count both solves."""
    law, p = CollapsingHistoryLaw(-2.5e-3 * K), 1e-3 * K
    point = MaterialPoint(law)
    r, collapses = et.hold_step(point, np.diag([0.99, 1.0]), (0, 0), p, 1e-3)
    assert collapses == 1
    assert not r.floating and r.control_error == 0.0
    assert r.F[0, 0] == pytest.approx(1.0 - law.further - 1e-3, rel=1e-12)
    assert r.sigma[0, 0] == pytest.approx(-p, rel=1e-9)
    assert point.state[0] == law.further and np.array_equal(point.F, r.F)
    alone = MaterialPoint(law, state=np.array([law.further]))  # (from the collapsed state)
    again = alone.step(r.F, {(0, 0): -p}, max_increment=1e-3)
    assert r.iterations > again.iterations


def test_a_step_that_fails_after_a_collapse_takes_the_collapse_back():
    """The collapsed cell never jams again (its state comes apart everywhere): the step fails,
    and the point is as it was before the step, not in the collapsed state."""
    law, p = CollapsingHistoryLaw(-2.5e-3 * K, further=np.inf), 1e-3 * K
    point = MaterialPoint(law)
    with pytest.raises(ControlError):
        et.hold_step(point, np.diag([0.99, 1.0]), (0, 0), p, 1e-3)
    assert point.state[0] == 0.0 and np.array_equal(point.F, np.eye(2)) and point.last is None


def test_a_jump_between_two_jammed_states_is_taken_at_its_nearer_side_by_the_servo():
    law = JumpLaw(jump=0.5e-3 * K)  # (P11 rises by 0.5e-3 K as F11 passes 1.001)
    target = 1.3e-3 * K  # (in the gap: 0.3e-3 K above the lower branch, 0.2e-3 K below the upper)
    F = np.eye(2)
    with pytest.raises(ControlError, match="jumps"):  # (both sides miss by more than 10 %)
        et.hold_step(MaterialPoint(law), F, (0, 0), -target, 1e-3)
    r = et.hold_step(MaterialPoint(law), F, (0, 0), -target, 1e-3, servo=True)[0]
    assert r.control_error == pytest.approx(0.2e-3 * K, rel=1e-9)  # (the upper branch)
    assert r.F[0, 0] == pytest.approx(1.001, abs=1e-12)


def test_a_jump_far_from_the_guess_is_reached_and_shrunk_within_the_iterations():
    """30 moves of p / k_n from the guess to the jump, then about 33 bisections of its bracket
    to round-off: more than 50 iterations, fewer than MAX_ITERATIONS."""
    law = JumpLaw(jump=0.5e-3 * K)
    F = np.diag([1.001 - 30e-3, 1.0])
    r = et.hold_step(MaterialPoint(law), F, (0, 0), -1.3e-3 * K, 1e-3, servo=True)[0]
    assert 50 < r.iterations <= et.MAX_ITERATIONS
    assert r.F[0, 0] == pytest.approx(1.001, abs=1e-12)
    assert r.control_error == pytest.approx(0.2e-3 * K, rel=1e-9)


def _rows(misses, qp, p=1e4):
    """Hand-made biaxial rows: eps1 0, 1, 2, ... %, the misses (parts of p) and q/p given."""
    return [
        {"eps1": 0.01 * k, "q_over_p": q, "volumetric_strain": 0.0, "control_error_Pa": m * p,
         "p_Pa": p, "z": 4.0, "sliding_share": 0.1, "tau_over_p": q, "dissipation_Pa": 0.0}
        for k, (m, q) in enumerate(zip(misses, qp))
    ]  # fmt: skip


def test_the_measures_read_only_the_steps_that_held_p():
    misses = [0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0]
    qp = [0.0, 0.3, 0.9, 0.4, 0.3, 0.3, 0.2, 0.05, 0.25]
    m = et.measures(_rows(misses, qp), "", 0.08, et.BIAXIAL)
    assert m["qp_peak"] == 0.4 and m["eps1_peak"] == pytest.approx(0.03)  # (not the 0.9)
    # the last quarter: eps1 >= 6 %: 0.2, (0.05 missed p), 0.25
    assert m["qp_critical_last_quarter"] == pytest.approx(0.225, rel=1e-12)
    assert m["off_target_steps"] == 2 and m["collapses"] == 0  # (rows without the column)
    rows = _rows(misses, qp)
    for row, n in zip(rows, [0, 0, 0, 2, 0, 1, 0, 0, 0]):
        row["collapses"] = n
    assert et.measures(rows, "", 0.08, et.BIAXIAL)["collapses"] == 3
    # all held: every step counts
    m = et.measures(_rows([0.0] * 9, qp), "", 0.08, et.BIAXIAL)
    assert m["qp_peak"] == 0.9 and m["off_target_steps"] == 0
    assert m["qp_critical_last_quarter"] == pytest.approx((0.2 + 0.05 + 0.25) / 3, rel=1e-12)


def test_no_step_of_the_last_quarter_held_p_leaves_the_critical_state_unmeasured():
    m = et.measures(_rows([0.0, 0.0, 0.0, 0.5, 0.5], [0.0, 0.3, 0.4, 0.2, 0.1]), "", 0.04,
                    et.BIAXIAL)  # fmt: skip
    assert math.isnan(m["qp_critical_last_quarter"]) and m["qp_peak"] == 0.4


def test_a_test_whose_steps_stop_holding_p_stops():
    n = et.MAX_OFF_TARGET
    rows = _rows([0.0] + [0.0] + [0.3] * (n - 1), [0.1] * (n + 1))
    assert et.off_target(rows, 1e4) == ""  # (n - 1 steps in a row missed)
    rows = _rows([0.0] + [0.3, -0.2] + [0.5] * (n - 2), [0.1] * (n + 1))
    stop = et.off_target(rows, 1e4)
    assert stop.startswith(f"stopped: {n} steps in a row missed p") and "+0.30, -0.20" in stop
    rows = _rows([0.0] + [0.3] * (n - 1) + [0.05], [0.1] * (n + 1))
    assert et.off_target(rows, 1e4) == ""  # (the last one held p again)


def test_the_held_strain_is_extrapolated_only_along_a_step_that_held_p_and_did_not_collapse():
    """The next step's guess of e11 follows the last step's slope where both held p; after a
    step that missed p or collapsed (its cell jammed again further in) it is the last e11."""
    p = 1e4

    def row(eps1, e11, miss=0.0, collapses=0):
        return dict(eps1=eps1, e11=e11, control_error_Pa=miss, collapses=collapses)

    held = [row(0.01, 0.002), row(0.02, 0.005)]
    assert et.held_guess(held, et.BIAXIAL, 0.03, p) == pytest.approx(0.008, rel=1e-12)
    for last in (row(0.02, -0.045, miss=-5 * p), row(0.02, -0.045, collapses=1)):
        assert et.held_guess([held[0], last], et.BIAXIAL, 0.03, p) == -0.045
    missed_before = [row(0.01, 0.002, miss=2 * p), row(0.02, 0.005)]
    assert et.held_guess(missed_before, et.BIAXIAL, 0.03, p) == 0.005
