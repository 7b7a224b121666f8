"""The material-point driver (dolfinx_granular.drivers.material_point): mixed control against the
hand-written confined-shear driver, pure stress control against a linear law's closed form,
biaxial compression, and a stress-controlled cycle of a hyperelastic law."""

from dolfinx_granular import FrictionalRVE, TaylorRVE, generate_packing
from dolfinx_granular.drivers.material_point import (
    ControlError,
    MaterialPoint,
    solve_point,
    solve_pressure,
    stress_tangent,
)
from dolfinx_granular.laws.relaxed.errors import RelaxationError, RigidityLostError

import numpy as np
import pytest

from helpers import (
    CollapsingHistoryLaw,
    CollapsingLaw,
    GivingWayLaw,
    JumpLaw,
    LinearLaw,
    UnjamLaw,
)

K_N, PRESSURE, RTOL = 2.8e7, 1e5, 1e-10


@pytest.fixture(scope="module")
def packing():
    return generate_packing(70, seed=0)


def hand_written_confined_shear(rve, gamma, state, pressure, e=0.0, max_iter=50, cap=0.02):
    """The confined shear step as demos/friction_study.py wrote it by hand before the driver:
    Newton on e22 (F = [[1, gamma], [0, 1 + e22]]) for sigma_22 = -pressure. Returns F."""
    lo, hi = -np.inf, np.inf
    for _ in range(max_iter + 1):
        F = np.array([[1.0, gamma], [0.0, 1.0 + e]])
        W, P, A, new = rve.evaluate(F, state)
        J = np.linalg.det(F)
        sigma = P @ F.T / J
        r = sigma[1, 1] + pressure
        if abs(r) <= RTOL * pressure:
            return F, new
        lo, hi = (e, hi) if r < 0.0 else (lo, e)
        k = (A[1, :, 1, 1] @ F[1] + P[1, 1]) / J - sigma[1, 1] * np.linalg.inv(F)[1, 1]
        step = -r / k if k > 0.0 else -np.sign(r) * cap
        e_new = e + float(np.clip(step, -cap, cap))
        e = e_new if lo < e_new < hi else 0.5 * (lo + hi)
    raise AssertionError("hand-written driver did not converge")


def test_mixed_control_matches_the_hand_written_confined_shear(packing):
    rve = FrictionalRVE(packing, normal_stiffness=K_N, tangential_stiffness=K_N, friction=0.5)
    point, ref_state, ref_F = MaterialPoint(rve), rve.initial_state(1), np.eye(2)
    path = [(0.0, p) for p in np.linspace(0.0, PRESSURE, 6)[1:]]
    path += [(g, PRESSURE) for g in (0.005, 0.01, 0.02, 0.01, -0.01, 0.0)]
    iterations = 0
    for gamma, p in path:
        ref_F, ref_state = hand_written_confined_shear(rve, gamma, ref_state, p, ref_F[1, 1] - 1)
        guess = np.array([[1.0, gamma], [0.0, point.F[1, 1]]])
        step = point.step(guess, {(1, 1): -p})
        # the same operations in the same order: the same floats, not only within 1e-10
        np.testing.assert_array_equal(step.F, ref_F)
        assert abs(step.sigma[1, 1] + p) <= RTOL * p
        iterations += step.iterations
    assert iterations > len(path)  # the path exercised Newton, not only converged guesses
    assert point.state.dissipation[0] > 0.0  # with friction the steps slid


def test_cauchy_tangent_is_the_derivative_of_the_cauchy_stress(packing):
    rve = TaylorRVE(packing, K_N)
    F = np.array([[0.97, 0.02], [-0.01, 0.98]])
    W, P, A = rve.evaluate(F)
    T = stress_tangent(F, P, A, "cauchy")
    h = 1e-7
    for k, l in np.ndindex(2, 2):
        dF = np.zeros((2, 2))
        dF[k, l] = h
        fd = (rve.cauchy(F + dF) - rve.cauchy(F - dF)) / (2 * h)
        np.testing.assert_allclose(T[:, :, k, l], fd, rtol=1e-5, atol=1e-5 * np.abs(T).max())


def test_pure_stress_control_of_a_linear_law_is_its_closed_form():
    law, (p11, p22, p21) = LinearLaw(), (-3e4, -1e5, 2e4)
    # F12 = 0 fixes the rotation; F11, F22, F21 are solved for P11, P22, P21
    step = solve_point(
        law, np.eye(2), {(0, 0): p11, (1, 1): p22, (1, 0): p21}, measure="piola", max_increment=1.0
    )
    lam, mu = law.lam, law.mu
    h11, h22 = np.linalg.solve([[lam + 2 * mu, lam], [lam, lam + 2 * mu]], [p11, p22])
    expected = np.array([[1 + h11, 0.0], [p21 / mu, 1 + h22]])
    np.testing.assert_allclose(step.F, expected, rtol=0, atol=1e-12)
    assert step.iterations == 1  # linear, no step cap: Newton is exact in one step
    assert step.P[0, 1] == pytest.approx(p21)


def test_isotropic_pressure_control_of_a_linear_law_is_its_closed_form():
    # F = (1 + h) I: P = 2 (lam + mu) h I, sigma = P / (1 + h), so -tr(sigma) / 2 = p at
    # h = -p / (2 (lam + mu) + p)
    law, p = LinearLaw(), 1e5
    step = solve_pressure(law, p, max_increment=1.0)
    h = -p / (2.0 * (law.lam + law.mu) + p)
    np.testing.assert_allclose(step.F, (1.0 + h) * np.eye(2), rtol=0, atol=1e-12)
    assert -np.trace(step.sigma) / 2 == pytest.approx(p, rel=1e-8)


def test_isotropic_pressure_control_of_taylor_commits_an_isotropic_f(packing):
    point = MaterialPoint(TaylorRVE(packing, K_N))
    for p in (2e4, PRESSURE):  # the second starts from the first's lam
        step = point.compress(p)
        assert step.F[0, 1] == step.F[1, 0] == 0.0 and step.F[0, 0] == step.F[1, 1] < 1.0
        assert -np.trace(step.sigma) / 2 == pytest.approx(p, rel=1e-8)
        np.testing.assert_array_equal(point.F, step.F)
    with pytest.raises(ValueError, match="pressure must be > 0"):
        point.compress(0.0)


def test_biaxial_compression_under_lateral_pressure(packing):
    """F22 prescribed (axial compression), F11 solved for sigma_11 = -p (lateral confinement)."""
    rve = TaylorRVE(packing, K_N)
    point = MaterialPoint(rve)
    point.step(np.eye(2), {(0, 0): -PRESSURE, (1, 1): -PRESSURE})  # isotropic confinement
    e0 = point.F.copy()
    axial = e0[1, 1] * (1.0 - np.linspace(0.0, 0.05, 6)[1:])
    Fs = np.array([[[1.0, 0.0], [0.0, a]] for a in axial])
    steps = point.path(Fs, {(0, 0): -PRESSURE})
    s11 = np.array([s.sigma[0, 0] for s in steps])
    s22 = np.array([s.sigma[1, 1] for s in steps])
    assert np.abs(s11 + PRESSURE).max() <= RTOL * PRESSURE
    assert np.all(np.diff(s22) < 0) and s22[-1] < 2 * s11[-1]  # the axial stress grows
    assert [s.F[1, 1] for s in steps] == list(axial)  # prescribed components stay as given


def test_stress_controlled_cycle_of_a_hyperelastic_law_returns_to_its_start(packing):
    """Shear stress 0 -> +t -> -t -> 0 under sigma_22 = -p, F11 = 1: every F12 and F22 is
    solved; a law without history returns to the start's F within the Newton tolerance."""
    rve = TaylorRVE(packing, K_N)
    point = MaterialPoint(rve)
    start = point.step(np.eye(2), {(0, 1): 0.0, (1, 1): -PRESSURE})
    taus = (
        0.3
        * PRESSURE
        * np.r_[np.linspace(0, 1, 5), np.linspace(1, -1, 9)[1:], -1 + np.linspace(0, 1, 5)[1:]]
    )
    steps = point.path(
        np.broadcast_to(np.eye(2), (taus.size, 2, 2)),
        {(0, 1): lambda k: taus[k], (1, 1): -PRESSURE},
    )
    assert max(abs(s.sigma[0, 1] - t) for s, t in zip(steps, taus)) <= RTOL * PRESSURE
    assert max(s.F[0, 1] for s in steps) > 0.002 and min(s.F[0, 1] for s in steps) < -0.002
    # both ends meet the stresses to RTOL p: their F differ by at most 2 RTOL p over the
    # smallest singular value of d(sigma_12, sigma_22) / d(F12, F22)
    T = stress_tangent(start.F, start.P, rve.evaluate(start.F)[2])
    rows, cols = np.array([0, 1]), np.array([1, 1])  # the unknowns F12, F22
    K = T[rows, cols][:, rows, cols]
    bound = 2 * RTOL * PRESSURE / np.linalg.svd(K, compute_uv=False).min()
    assert bound < 1e-10  # sharp against the shear of the cycle (> 2e-3)
    np.testing.assert_allclose(steps[-1].F, start.F, rtol=0, atol=bound)


def test_failure_raises_and_commits_nothing(packing):
    rve = FrictionalRVE(packing, normal_stiffness=K_N, tangential_stiffness=K_N, friction=0.5)
    point = MaterialPoint(rve)
    before = point.state.to_arrays()
    with pytest.raises(ControlError, match="not committed"):
        point.step(np.eye(2), {(1, 1): -PRESSURE}, max_iter=1)
    assert point.last is None and np.array_equal(point.F, np.eye(2))
    assert all(np.array_equal(v, getattr(point.state, k)) for k, v in before.items())


@pytest.mark.parametrize(
    "kwargs, words",
    [
        (dict(F=np.eye(3)[:2]), "(d, d)"),
        (dict(stress={(2, 0): 1.0}), "index pairs"),
        (dict(measure="kirchhoff"), "measure"),
        (dict(stress={(0, 0): 0.0}), "stress_scale"),
    ],
)
def test_bad_control_is_refused_in_one_line(kwargs, words):
    args = dict(F=np.eye(2), stress={(0, 0): 1.0}) | kwargs
    with pytest.raises(ValueError, match=None) as err:
        solve_point(LinearLaw(), **args)
    assert words in str(err.value) and "\n" not in str(err.value)


def test_a_stress_that_jumps_across_its_target_is_named_or_taken_at_the_nearer_side():
    law = JumpLaw(jump=3e3)  # (P11 rises by 3 kPa as F11 passes 1.001)
    below = (law.lam + 2 * law.mu) * 1e-3  # P11 just below the jump (F22 = 1, F12 = F21 = 0)
    target = below + 1e3  # (in the gap: below < target < below + 3e3, no F gives it)
    with pytest.raises(ControlError, match="jumps"):
        solve_point(law, np.eye(2), {(0, 0): target}, measure="piola")
    step = solve_point(law, np.eye(2), {(0, 0): target}, measure="piola", accept_jump=0.25)
    assert step.F[0, 0] == pytest.approx(1.001, abs=1e-12)
    assert step.control_error == pytest.approx(step.P[0, 0] - target)
    assert step.control_error == pytest.approx(-1e3, rel=1e-6)  # (the nearer side: below)
    with pytest.raises(ControlError, match="jumps"):  # (a miss beyond accept_jump)
        solve_point(law, np.eye(2), {(0, 0): target}, measure="piola", accept_jump=0.1)


def test_an_iterate_that_unjams_bounds_a_compressive_target_from_the_dilated_side():
    law = UnjamLaw()
    target = -(law.lam + 2 * law.mu) * 1e-3  # (its root F11 = 0.999; Newton from 0.99 leaps
    F = np.diag([0.99, 1.0])  # past 1, where the cell comes apart)
    step = solve_point(law, F, {(0, 0): target}, measure="piola")
    assert step.F[0, 0] == pytest.approx(0.999, rel=1e-12) and step.control_error == 0.0
    assert max(step.residuals) == pytest.approx(-target)  # (an unjammed iterate: sigma = 0)
    # a first iterate that unjams: the next lies max_increment more compressed
    step = solve_point(law, np.diag([1.01, 1.0]), {(0, 0): target}, measure="piola",
                       max_increment=0.005)  # fmt: skip
    assert step.F[0, 0] == pytest.approx(0.999, rel=1e-12)
    assert step.residuals[:2] == pytest.approx((-target, -target))  # (1.01, 1.005: apart)
    # a tensile target: an unjammed iterate tells nothing
    with pytest.raises(RigidityLostError):
        solve_point(UnjamLaw(), F, {(0, 0): 1e2}, measure="piola", stress_scale=1.0)


def test_iterates_that_keep_coming_apart_move_ever_further_into_compression():
    """A cell that holds only 5 % more compressed than the guess (a collapsed loose cell that
    re-jams further on): the moves double from max_increment (1e-3: 1.0, 0.999, 0.997, ...,
    0.937), so the root F11 = 0.94 is found in a score of iterations (Newton's steps capped at
    1e-3 too), not after 50 moves of 1e-3 that come apart."""
    law = UnjamLaw(stiff=1.0, edge=0.95)
    target = -(law.lam + 2 * law.mu) * 0.06
    step = solve_point(law, np.eye(2), {(0, 0): target}, measure="piola", max_increment=1e-3,
                       max_iter=30)  # fmt: skip
    assert step.F[0, 0] == pytest.approx(0.94, rel=1e-12) and step.control_error == 0.0
    assert step.residuals[:6] == pytest.approx((-target,) * 6)  # (1.0 ... 0.969: apart)
    assert step.residuals[6] == pytest.approx(target / 0.06 * 0.003)  # (0.937: holds)


def test_where_a_jammed_cell_collapses_beyond_a_round_off_the_jammed_side_is_taken():
    """Between F11 = 1 (P11 = hold) and F11 > 1 (apart) no F holds the target: the jammed end
    is taken where it misses by at most accept_unjammed, the miss in control_error."""
    k = CollapsingLaw(0.0).lam + 2 * CollapsingLaw(0.0).mu
    law = CollapsingLaw(-1.5e-3 * k)
    target = -1e-3 * k
    F = np.diag([0.99, 1.0])
    step = solve_point(law, F, {(0, 0): target}, measure="piola", accept_jump=0.1,
                       accept_unjammed=0.6)  # fmt: skip
    assert step.F[0, 0] == pytest.approx(1.0, abs=1e-12)
    assert step.control_error == pytest.approx(-0.5e-3 * k, rel=1e-9)
    for accept, unjammed in ((0.1, 0.0), (0.1, 0.4)):
        with pytest.raises(ControlError, match="jumps"):
            solve_point(law, F, {(0, 0): target}, measure="piola", accept_jump=accept,
                        accept_unjammed=unjammed)  # fmt: skip


def test_no_equilibrium_beside_a_cell_that_holds_too_much_counts_as_come_apart():
    """Jammed at 2 p up to F11 = 1, no equilibrium found in (1, 1.001], apart beyond: an
    iterate without equilibrium on the dilated side of one that held more than p counts as
    come apart, so the bracket shrinks onto F11 = 1 and the jammed end is taken (as
    CollapsingLaw's); where no iterate has held more than p yet, the error is the answer."""
    k = CollapsingLaw(0.0).lam + 2 * CollapsingLaw(0.0).mu
    target = -1e-3 * k
    for start in (0.99, 1.05):  # (Newton from 0.99 overshoots into the band; 1.05: apart)
        step = solve_point(GivingWayLaw(-2e-3 * k), np.diag([start, 1.0]), {(0, 0): target},
                           measure="piola", accept_unjammed=2.0)  # fmt: skip
        assert step.F[0, 0] == pytest.approx(1.0, abs=1e-12)
        assert step.control_error == pytest.approx(-1e-3 * k, rel=1e-9)
    with pytest.raises(RelaxationError, match="did not come to rest"):  # (nothing held yet)
        solve_point(GivingWayLaw(-2e-3 * k), np.diag([1.0005, 1.0]), {(0, 0): target},
                    measure="piola", accept_unjammed=2.0)  # fmt: skip


def test_with_collapse_the_state_the_cell_came_apart_in_is_taken_beyond_accept_jump():
    """Jammed at 2.5 p, apart a round-off further, the law giving that state (CellFloats):
    with ``collapse`` the end come apart is the answer (floating, stress-free, its miss the
    whole target); the jammed end only where it misses by at most accept_jump; without
    ``collapse`` accept_unjammed decides as before, and a law that gives no state (UnjamLaw's
    RigidityLostError) keeps to it too."""
    k = CollapsingHistoryLaw(0.0).lam + 2 * CollapsingHistoryLaw(0.0).mu
    law, target, F = CollapsingHistoryLaw(-2.5e-3 * k), -1e-3 * k, np.diag([0.99, 1.0])
    state = law.initial_state(1)
    step = solve_point(law, F, {(0, 0): target}, state, "piola", accept_jump=0.1,
                       accept_unjammed=1e3, collapse=True)  # fmt: skip
    assert step.floating and step.F[0, 0] == pytest.approx(1.0, abs=1e-12)
    assert step.control_error == -target and not step.P.any()
    assert step.state[0] == law.further  # (the state it came apart in)
    step = solve_point(law, F, {(0, 0): target}, state, "piola", accept_jump=2.0,
                       collapse=True)  # fmt: skip
    assert not step.floating and step.control_error == pytest.approx(-1.5e-3 * k, rel=1e-9)
    step = solve_point(law, F, {(0, 0): target}, state, "piola", accept_jump=0.1,
                       accept_unjammed=1e3)  # fmt: skip
    assert not step.floating and step.control_error == pytest.approx(-1.5e-3 * k, rel=1e-9)
    step = solve_point(CollapsingLaw(-2.5e-3 * k), F, {(0, 0): target}, measure="piola",
                       accept_jump=0.1, accept_unjammed=1e3, collapse=True)  # fmt: skip
    assert not step.floating and step.control_error == pytest.approx(-1.5e-3 * k, rel=1e-9)


def test_a_bracket_shrunk_by_an_iterate_that_came_apart_ends_the_search_there():
    """Bisecting onto the edge of jamming, the iterate that shrinks the bracket to round-off
    may be one that came apart: the jammed end is taken then (39 evaluations here), not after
    more bisections that cannot narrow it."""
    k = CollapsingLaw(0.0).lam + 2 * CollapsingLaw(0.0).mu
    law = CollapsingLaw(-2e-3 * k)
    step = solve_point(law, np.diag([0.99, 1.0]), {(0, 0): -1e-3 * k}, measure="piola",
                       accept_unjammed=2.0, max_iter=38)  # fmt: skip
    assert step.F[0, 0] == pytest.approx(1.0, abs=1e-12)
    assert step.control_error == pytest.approx(-1e-3 * k, rel=1e-9)


def test_a_crawling_newton_is_bisected_in_its_bracket():
    law = JumpLaw(stiff=1e3)  # (Newton's steps a thousandth of what they should be)
    target = -(law.lam + 2 * law.mu) * 2e-3
    step = solve_point(law, np.eye(2), {(0, 0): target}, measure="piola", max_increment=0.01,
                       max_iter=80)  # fmt: skip
    assert step.F[0, 0] == pytest.approx(0.998, rel=1e-12) and step.control_error == 0.0
    assert abs(step.P[0, 0] - target) <= RTOL * abs(target)
