"""The factor of safety's search and answer (dolfinx_granular.slope.safety, safety_strength):
bisection on a slope whose verdict is known, the verdict of a run's summary, phi from a curve;
and the command line's one-line refusals (bad options, an --out that holds a run)."""

import math

from dolfinx_granular.slope.safety import (
    COLLAPSE_GROWTH,
    DOUBLINGS,
    HALVINGS,
    JUMP_GROWTH,
    Trial,
    bracket,
    continuation_stop,
    continuation_trials,
    next_friction,
    outcome,
    search,
    settlement_growth,
    trial_of,
)
from dolfinx_granular.slope.safety_strength import Strength

import numpy as np
import pytest

P = 1e-2  # p / k_n


def phi_of(mu):
    """A saturating phi (degrees) in mu, as the RVEs' (about 6 degrees at mu = 0)."""
    return 6.0 + 26.0 * (1.0 - math.exp(-4.0 * mu))


def curve(mus, phi=phi_of, peak=2.0):
    return [
        dict(
            law="relaxed",
            mu=m,
            p_over_kn=P,
            phi_cs_deg_mean=phi(m),
            phi_peak_deg_mean=phi(m) + peak,
        )
        for m in mus
    ]


def grid(mu):
    """Frictions from mu / 2^HALVINGS to 2^DOUBLINGS mu: powers of 2 and 1.5 x each."""
    powers = [mu * 2.0**k for k in range(-HALVINGS, DOUBLINGS + 1)]
    return sorted(powers + [1.5 * m for m in powers[:-1]])


def fake_trial(mu_f, limit):
    """A trial of a slope that carries its load where mu_f >= limit."""
    passed = mu_f >= limit
    carried = 1.0 if passed else mu_f / limit
    why = "carried the whole load" if passed else "limit point before the whole load"
    return Trial(mu_f, passed, "gravity", carried, carried, 0.0, 1.0, why, "converged", "x")


def run_search(mu, limit, tolerance=0.01, mus=None):
    strength = Strength(curve(mus or grid(mu)), P, mu)
    trials, done = search(
        lambda m: fake_trial(m, limit), mu, strength.factor_of_safety, tolerance, strength.mu_range
    )
    return strength, trials, done


@pytest.mark.parametrize("limit", [0.013, 0.07, 0.2, 0.37, 0.49])
def test_bisection_brackets_the_limit_to_the_tolerance(limit):
    mu = 0.5
    strength, trials, done = run_search(mu, limit)
    assert done and trials[0].mu_f == mu and trials[0].passed
    failing, passing = bracket(trials)
    assert failing.mu_f < limit <= passing.mu_f
    fs = strength.factor_of_safety
    assert fs(failing.mu_f) / fs(passing.mu_f) - 1.0 <= 0.01
    answer = outcome(trials, mu, fs, lambda m: strength.factor_of_safety(m, "peak"))
    assert answer["converged"] and answer["bound"] is None
    lo, hi = answer["factor_of_safety_bracket"]
    assert lo <= answer["factor_of_safety"] <= hi and hi / lo - 1.0 <= 0.01
    assert failing.mu_f < answer["mu_f"] < passing.mu_f
    assert answer["mu_ratio"] == pytest.approx(mu / answer["mu_f"], rel=1e-14)
    # FS from tan phi, not mu / mu_f: phi saturates, so FS < mu / mu_f here
    exact = math.tan(math.radians(phi_of(mu))) / math.tan(math.radians(phi_of(limit)))
    assert answer["factor_of_safety"] == pytest.approx(exact, rel=0.01)
    assert answer["factor_of_safety"] < answer["mu_ratio"]


def test_the_bracket_is_found_by_halving_from_mu():
    _, trials, _ = run_search(0.5, 0.07)
    assert [t.mu_f for t in trials[:4]] == [0.5, 0.25, 0.125, 0.0625]
    assert [t.passed for t in trials[:4]] == [True, True, True, False]
    assert all(0.0625 < t.mu_f < 0.125 for t in trials[4:])


def test_a_slope_that_fails_at_mu_doubles_it():
    mu = 0.1
    strength, trials, done = run_search(mu, 0.23)
    assert [t.mu_f for t in trials[:3]] == [0.1, 0.2, 0.4] and done
    answer = outcome(trials, mu, strength.factor_of_safety, strength.factor_of_safety)
    assert answer["factor_of_safety"] < 1.0 and answer["mu_ratio"] < 1.0


def test_without_a_failure_the_answer_is_a_lower_bound():
    mu = 0.5
    strength, trials, done = run_search(mu, 0.0)
    assert done and len(trials) == HALVINGS + 1 and all(t.passed for t in trials)
    assert trials[-1].mu_f == mu / 2**HALVINGS
    answer = outcome(trials, mu, strength.factor_of_safety, strength.factor_of_safety)
    assert answer["bound"] == "lower" and not answer["converged"]
    assert answer["factor_of_safety"] == strength.factor_of_safety(mu / 2**HALVINGS)


def test_without_a_pass_the_answer_is_an_upper_bound():
    mu = 0.5
    strength, trials, done = run_search(mu, 10.0)
    assert len(trials) == DOUBLINGS + 1 and not any(t.passed for t in trials)
    answer = outcome(trials, mu, strength.factor_of_safety, strength.factor_of_safety)
    assert answer["bound"] == "upper" and answer["factor_of_safety"] < 1.0


def test_angles_missing_away_from_mu_narrow_the_search():
    rows = curve([0.1, 0.2, 0.3, 0.5, 1.0], phi=lambda m: math.nan if m in (0.1, 1.0) else 30.0)
    assert Strength(rows, P, 0.3).mu_range == (0.2, 0.5)


def test_a_curve_that_falls_is_read_on_its_nondecreasing_fit():
    """Three packings' means can fall from one mu to the next (here phi_cs 30 -> 26 degrees
    from mu = 0.25 to 0.5); read as measured, the slope that stands at mu would have FS < 1
    at every mu_f in between. On the fit FS is 1 there and falls nowhere as mu_f rises."""
    rows = curve([0.0, 0.25, 0.5], phi=lambda m: {0.0: 10.0, 0.25: 30.0, 0.5: 26.0}[m])
    strength = Strength(rows, P, 0.5)
    assert strength.falls("cs") == [(0.25, 0.5, 30.0, 26.0)] and strength.falls("peak") == [
        (0.25, 0.5, 32.0, 28.0)
    ]
    assert strength.phi(0.5, monotone=False) == 26.0 and strength.phi(0.5) == 28.0
    assert strength.factor_of_safety(0.3) == pytest.approx(1.0, rel=1e-15)
    fs = [strength.factor_of_safety(m) for m in np.linspace(0.01, 0.5, 50)]
    assert all(f >= 1.0 - 1e-15 for f in fs) and np.all(np.diff(fs) <= 1e-15)
    assert Strength(curve(grid(0.5)), P, 0.5).falls("cs") == []


def test_the_search_stays_inside_the_curve():
    """A curve from 0.2 to 0.5: no halving below 0.2 (a lower bound there)."""
    mu = 0.5
    _, trials, done = run_search(mu, 0.01, mus=[0.2, 0.3, 0.5])
    assert done and [t.mu_f for t in trials] == [0.5, 0.25]


def test_an_interrupted_trial_ends_the_search_unfinished():
    strength = Strength(curve(grid(0.5)), P, 0.5)
    trials, done = search(
        lambda m: None if m < 0.3 else fake_trial(m, 0.1), 0.5, strength.factor_of_safety
    )
    assert not done and [t.mu_f for t in trials] == [0.5]
    # started again with the finished trials, it goes on where it stopped
    more, done = search(lambda m: fake_trial(m, 0.1), 0.5, strength.factor_of_safety, trials=trials)
    assert done and more[0] == trials[0] and more[1].mu_f == 0.25


def test_next_friction_starts_at_mu():
    assert next_friction([], 0.3, lambda m: 1.0) == 0.3


def test_a_scattered_flat_curve_ends_the_bisection_on_the_frictions():
    """Where phi is flat in mu and scattered (packings measured at each mu_f), FS at the two
    ends of a narrow bracket can differ by more than the tolerance however narrow it is (here
    phi steps by half a degree at the limit): the search stops once the frictions differ by at
    most the tolerance, and says that the curve, not the search, limits FS (as on the 380-cell
    slope: phi_cs 7.33, 7.32 and 7.88 degrees at mu_f = 0.031, 0.047 and 0.0625)."""
    mu, limit = 0.5, 0.05

    def fs(m):  # tan phi(mu) / tan phi(m)
        phi = 28.0 if m >= 0.5 else (7.0 if m >= limit else 6.5)
        return math.tan(math.radians(28.0)) / math.tan(math.radians(phi))

    trials, done = search(lambda m: fake_trial(m, limit), mu, fs, 0.01)
    failing, passing = bracket(trials)
    assert done and failing.mu_f < limit <= passing.mu_f
    assert passing.mu_f / failing.mu_f - 1.0 <= 0.01 < fs(failing.mu_f) / fs(passing.mu_f) - 1
    assert len(trials) == 4 + 7  # 0.5 .. 0.03125, then 7 bisections of [0.03125, 0.0625]
    answer = outcome(trials, mu, fs, fs, 0.01)
    assert answer["converged"] and answer["curve_limited"]


def test_a_curve_that_falls_across_the_bracket_ends_the_search_curve_limited():
    """phi at the failing end above phi at the passing one (FS falling as mu_f rises): no
    bisection can order them; the search ends there, and says so."""
    mu, limit = 0.5, 0.05

    def fs(m):
        phi = 28.0 if m >= 0.5 else (7.0 if m >= limit else 7.5)
        return math.tan(math.radians(28.0)) / math.tan(math.radians(phi))

    trials, done = search(lambda m: fake_trial(m, limit), mu, fs, 0.01)
    assert done and [t.mu_f for t in trials] == [0.5, 0.25, 0.125, 0.0625, 0.03125]
    answer = outcome(trials, mu, fs, fs, 0.01)
    assert answer["converged"] and answer["curve_limited"]


def test_a_smooth_curve_is_not_curve_limited():
    strength, trials, _ = run_search(0.5, 0.07)
    fs = strength.factor_of_safety
    answer = outcome(trials, 0.5, fs, fs)
    assert answer["converged"] and not answer["curve_limited"]


def test_measured_strength_is_measured_at_each_trial_friction():
    asked = []

    def measure(mus):
        asked.append(list(mus))
        return curve(mus)

    mu = 0.5
    strength = Strength([], P, mu, measure)
    assert asked == [[mu]] and strength.mu_range == (0.0, math.inf)

    def run_trial(m):
        strength.cover([m])  # (as SafetyRun does before a trial)
        return fake_trial(m, 0.2)

    trials, done = search(run_trial, mu, strength.factor_of_safety, 0.01, strength.mu_range)
    assert done and asked[1:] == [[t.mu_f] for t in trials[1:]]  # (mu: measured once)
    assert sorted(float(r["mu"]) for r in strength.curve) == sorted(t.mu_f for t in trials)
    for t in trials:  # a trial's FS is that of its own friction, not an interpolation
        assert strength.phi(t.mu_f) == pytest.approx(phi_of(t.mu_f), rel=1e-14)


def test_a_measured_angle_outside_0_90_is_named():
    strength = Strength([], P, 0.5, lambda mus: curve(mus, phi=lambda m: 30.0 if m > 0.3 else -1))
    with pytest.raises(ValueError, match="strength tests at mu = 0.25 gave no friction angle"):
        strength.cover([0.25])


def summary(status="converged", steps=(), failed=None, stopped=None):
    return {
        "status": status,
        "step_info": list(steps),
        "failed": failed,
        "path_following": {"stopped": stopped},
        "interrupted_by": None,
    }


def step(phase, gravity, footing_load=0.0):
    return {"phase": phase, "gravity": gravity, "footing_load": footing_load}


def test_a_run_that_carries_its_weight_passes():
    s = summary(steps=[step("gravity", 0.5), step("gravity", 1.02)])
    t = trial_of(s, 0.3, 0.0, -4e7, "trials/mu_0.3", 12.5)
    assert t.passed and t.carried == 1.02 and t.phase == "gravity" and t.seconds == 12.5


def test_a_limit_point_below_the_weight_fails():
    stopped = "past the peak lam = 0.43 (increment 12) the load fell to 0.884 of it"
    s = summary(
        steps=[step("gravity", 0.3), step("gravity", 0.43), step("gravity", 0.38)], stopped=stopped
    )
    t = trial_of(s, 0.03, 0.0, -4e7, "x", 1.0)
    assert not t.passed and t.carried == 0.43 and "limit point" in t.why and stopped in t.why


def test_a_path_out_of_increments_fails_without_a_limit_point():
    s = summary(steps=[step("gravity", 0.3)], stopped="100 increments")
    t = trial_of(s, 0.3, 0.0, -4e7, "x", 1.0)
    assert not t.passed and t.why == "stopped before the whole load: 100 increments"


def test_a_run_with_no_equilibrium_fails_and_says_where():
    failed = {"phase": "gravity", "reason": "the corrector stagnates"}
    t = trial_of(summary("failed", [step("gravity", 0.2)], failed), 0.1, 0.0, -4e7, "x", 1.0)
    assert not t.passed and t.carried == 0.2 and "no equilibrium in the gravity" in t.why


def test_with_a_footing_the_footing_share_decides():
    weight = [step("gravity", 0.5), step("gravity", 1.0)]
    whole = summary(steps=[*weight, step("footing", 1.0, 0.2 * -4e7)])
    assert trial_of(whole, 0.3, 0.2, -4e7, "x", 1.0).passed
    part = summary(steps=[*weight, step("footing", 1.0, 0.15 * -4e7)], stopped="past the peak")
    t = trial_of(part, 0.3, 0.2, -4e7, "x", 1.0)
    assert not t.passed and t.phase == "footing" and t.carried == pytest.approx(0.75)
    assert t.gravity == 1.0
    short = trial_of(
        summary("failed", weight[:1], {"phase": "gravity", "reason": "r"}), 0.3, 0.2, -4e7, "x", 1.0
    )
    assert not short.passed and short.phase == "gravity" and short.carried == 0.5


def reduced(t, mu=0.5):
    """The continuation's mu_f at t: mu to mu / 64 geometrically."""
    return mu * (1.0 / 64.0) ** t


def continued(status="failed", ts=(0.25, 0.5, 0.53), failed_at=0.54, load_failed=False):
    """The summary of a continuation run: the weight in two steps, reduction steps at ``ts``;
    ``status`` failed: the reduction (or with ``load_failed`` the weight) found no
    equilibrium from t = ts[-1] to ``failed_at``."""
    weight = [dict(step("gravity", g), friction=0.5) for g in (0.5, 1.0)]
    steps = [dict(step("reduction", 1.0), friction=reduced(t)) for t in ts]
    cut = dict(phase="reduction", step=9, t_from=ts[-1], t_to=failed_at, reason="r")
    cuts = [dict(cut, iterations=4)]
    failed = {"phase": "reduction", "reason": "stagnation"} if status == "failed" else None
    if load_failed:
        weight, steps = weight[:1], []
        failed = {"phase": "gravity", "reason": "stagnation"}
    return {**summary(status, [*weight, *steps], failed), "wall_time": 42.0, "cutbacks": cuts}


def test_a_continuation_that_fails_in_its_reduction_brackets_mu_f():
    """The last friction carried passes, the one whose step failed after every cut-back fails;
    the outcome lies between."""
    rows = continuation_trials(continued(), 0.5, reduced, 0.0, -4e7, "trials/reduction")
    ok, bad = rows
    assert ok.passed and ok.mu_f == reduced(0.53) and ok.phase == "reduction"
    assert not bad.passed and bad.mu_f == reduced(0.54) and "no equilibrium" in bad.why
    assert ok.seconds == bad.seconds == 42.0 and ok.folder == "trials/reduction"
    strength = Strength(curve(grid(0.5)), P, 0.5)
    answer = outcome(rows, 0.5, strength.factor_of_safety, strength.factor_of_safety)
    assert answer["mu_f_bracket"] == [reduced(0.54), reduced(0.53)] and answer["bound"] is None
    assert reduced(0.54) < answer["mu_f"] < reduced(0.53)


def settling(rates, mu=0.5, dlog=0.1):
    """Reduction steps lowering ln(mu) by ``dlog`` each, the slope settling by rate x dlog."""
    u, rows = 0.0, []
    for k, rate in enumerate(rates):
        u -= rate * dlog
        rows.append(
            {"phase": "reduction", "friction": mu * math.exp(-dlog * (k + 1)), "settlement": u}
        )
    return rows


def test_the_settlement_growth_tells_a_collapse_from_a_stall():
    """A steady rate with one jump (an RVE's rearrangement) stays near 1 at its end; a rate
    that grows at the end, as near a collapse, gives its growth; too few steps give None."""
    steady = [0.25] * 12 + [7.7, 0.3, 0.25, 0.24]
    assert settlement_growth(settling(steady)) == pytest.approx((0.3 + 0.25 + 0.24) / 3 / 0.25)
    collapse = [0.6] * 12 + [0.9, 3.0, 6.0, 9.0]
    assert settlement_growth(settling(collapse)) == pytest.approx(6.0 / 0.6)
    assert settlement_growth(settling([0.6] * 4)) is None
    steps = settling([0.6] * 10)
    del steps[3]["settlement"]
    assert settlement_growth(steps) is None
    # and the failed row of a continuation says it
    run = continued(ts=(0.1, 0.2, 0.3, 0.4, 0.5, 0.53))
    for s, rate in zip([s for s in run["step_info"] if s["phase"] == "reduction"], range(6)):
        s["settlement"] = -0.1 * 2.0**rate
    _, bad = continuation_trials(run, 0.5, reduced, 0.0, -4e7, "trials/reduction")
    assert "the settlement per unit ln(mu) over the last 3 steps" in bad.why, bad.why


def test_a_continuations_stop_is_read_from_the_settlements_growth():
    """Below JUMP_GROWTH a stress jump, from COLLAPSE_GROWTH on a collapse, unclear between
    and without a growth; nothing for a continuation whose reduction did not fail."""

    def stopped_with(rates):
        run = continued()
        weight = [s for s in run["step_info"] if s["phase"] != "reduction"]
        return continuation_stop({**run, "step_info": weight + settling(rates)})

    jump = stopped_with([0.25] * 12 + [0.3, 0.25, 0.24])
    growth = (0.3 + 0.25 + 0.24) / 3 / 0.25
    assert jump == {"settlement_growth": pytest.approx(growth), "stopped_on": "stress jump"}
    assert JUMP_GROWTH <= 3.0 < COLLAPSE_GROWTH <= 10.0
    assert stopped_with([0.6] * 12 + [3.0, 6.0, 9.0])["stopped_on"] == "collapse"
    assert stopped_with([0.6] * 12 + [1.2, 1.8, 2.4])["stopped_on"] == "unclear"
    assert stopped_with([0.6] * 4) == {"settlement_growth": None, "stopped_on": "unclear"}
    assert continuation_stop(continued("converged", ts=(0.5, 1.0))) is None
    assert continuation_stop(continued(load_failed=True)) is None


def test_a_continuation_to_its_end_is_a_lower_bound():
    rows = continuation_trials(
        continued("converged", ts=(0.5, 1.0)), 0.5, reduced, 0.0, -4e7, "trials/reduction"
    )
    assert len(rows) == 1 and rows[0].passed and rows[0].mu_f == reduced(1.0)
    strength = Strength(curve(grid(0.5)), P, 0.5)
    answer = outcome(rows, 0.5, strength.factor_of_safety, strength.factor_of_safety)
    assert answer["bound"] == "lower" and answer["mu_f"] == pytest.approx(0.5 / 64)


def test_a_continuation_whose_load_fails_fails_at_mu():
    rows = continuation_trials(
        continued(load_failed=True), 0.5, reduced, 0.0, -4e7, "trials/reduction"
    )
    assert len(rows) == 1 and not rows[0].passed and rows[0].mu_f == 0.5
    assert rows[0].phase == "gravity" and rows[0].carried == 0.5
    assert "no equilibrium in the gravity" in rows[0].why


def test_strength_reads_phi_linear_in_mu():
    s = Strength(curve([0.25, 0.5]), P, 0.5)
    assert s.phi(0.375) == pytest.approx(0.5 * (phi_of(0.25) + phi_of(0.5)), rel=1e-14)
    assert s.phi(0.5, "peak") == phi_of(0.5) + 2.0 and s.mu_range == (0.25, 0.5)
    assert s.factor_of_safety(0.5) == 1.0


@pytest.mark.parametrize(
    "rows, mu, words",
    [
        (curve([0.25, 0.5]), 0.6, "mu = 0.6 lies outside"),
        ([dict(r, p_over_kn=1e-3) for r in curve([0.25, 0.5])], 0.5, "give one of 0.001"),
        (curve([0.25, 0.5], phi=lambda m: math.nan if m > 0.3 else 30.0), 0.4, "next to mu"),
        (curve([0.25, 0.5], phi=lambda m: -1.0 if m > 0.3 else 30.0), 0.5, "next to mu = 0.5"),
        ([dict(r, law="taylor") for r in curve([0.25, 0.5])], 0.5, "relaxed RVE alone"),
    ],
)
def test_strength_names_what_the_curve_lacks(rows, mu, words):
    with pytest.raises(ValueError, match=words):
        Strength(rows, P, mu)


def test_with_rolling_friction_strength_follows_its_line():
    """mu_r = 0.2 mu: phi is read on the curve's rows with mu_r = 0.2 mu (others ignored), and
    measured there (each mu with its own mu_r)."""
    on_line = [dict(r, mu_r=0.2 * r["mu"], phi_cs_deg_mean=r["phi_cs_deg_mean"] + 5.0)
               for r in curve([0.25, 0.5])]  # fmt: skip
    rows = [dict(r, mu_r=0.0) for r in curve([0.25, 0.5])] + on_line
    s = Strength(rows, P, 0.5, rolling_ratio=0.2)
    assert s.phi(0.5) == phi_of(0.5) + 5.0 and s.mu_range == (0.25, 0.5)
    assert Strength(rows, P, 0.5).phi(0.5) == phi_of(0.5)
    asked = []

    def measure(mus):
        asked.extend(mus)
        return [dict(r, mu_r=0.2 * r["mu"]) for r in curve(mus)]

    s = Strength([], P, 0.5, measure, rolling_ratio=0.2)
    s.cover([0.3])
    assert asked == [0.5, 0.3] and s.phi(0.3) == pytest.approx(phi_of(0.3), rel=1e-14)
