"""Rearrangements of the frictional relaxed RVE (laws/relaxed_friction/fire.py ``settle``,
point.py ``rearranged``): where an increment has no equilibrium that Newton, the continuation
and FIRE find, the cell rearranges with the friction law step by step and comes to rest in an
equilibrium (brute force), its forces in their cones, having dissipated; Newton finishes
there and its tangent is the derivative of P at the rearranged history. A cell that comes
apart floats: no stress, and the path goes on from where its disks are."""

from dataclasses import replace

from dolfinx_granular import ContactSet, FrictionalRelaxedRVE, generate_packing
from dolfinx_granular.drivers import element_tests as et
from dolfinx_granular.laws.relaxed.errors import CameApart, CellFloats, RigidityLostError
from dolfinx_granular.laws.relaxed_friction.cell_state import CellState
from dolfinx_granular.laws.relaxed_friction.contact_law import OPEN, SLIP
from dolfinx_granular.laws.relaxed_friction.fire import fire, settle
from dolfinx_granular.laws.relaxed_friction.point import follow, predicted, relax

import numpy as np
import pytest

from helpers import frictional_balance

F1 = np.diag([0.99, 0.99])
#: an increment of 3e-3 in F from F1 on which Newton stalls
#: (tests/test_relaxed_friction_pseudo_time.py)
HARD = np.array([[0.9890745152008461, 0.0006247337322891522],
                 [0.0022529423564802325, 0.9916362873796044]])  # fmt: skip
#: fallbacks cut to one step each: the increment's solvers fail, the cell rearranges
NO_FALLBACK = {"pseudo_steps": 1, "fire_steps": 1}


@pytest.fixture(scope="module", params=[0.0, 0.1], ids=["sliding", "rolling"])
def committed(request):
    """A frictional relaxed cell (mu = 0.3, and mu_r) committed at F1: ``(rve, state, inc)``."""
    rve = FrictionalRelaxedRVE(generate_packing(70, seed=1), 1e8, 1e8, friction=0.3,
                               rolling_friction=request.param)  # fmt: skip
    state = rve.evaluate(F1, rve.initial_state(1))[3]
    return rve, state, rve.increment(state, 0)


def balance(rve, F, w, s):
    """The largest net force over the mean normal force and net moment over it times the mean
    radius of the cell state s at (F, w), by brute force over every pair and image
    (``helpers.frictional_balance``; the contacts as ``FrictionalRelaxedRVE.contacts`` gives
    them)."""
    c, on = rve.cell, np.flatnonzero(s.on)
    contacts = ContactSet(
        pairs=np.stack([c.pi[on], c.pj[on]], axis=1).astype(np.int64),
        shift=np.asarray(c.shift)[on], branch=np.stack([s.lx[on], s.ly[on]], axis=1),
        overlap=s.e[on], force=rve.springs.kn * s.e[on], tangential=-s.ft[on],
        sliding=s.status[on] == SLIP, rolling=s.mr[on],
    )  # fmt: skip
    f, M, mean = frictional_balance(rve.packing, F, w, contacts)
    return max(np.linalg.norm(f, axis=1).max() / mean,
               np.abs(M).max() / (mean * rve.packing.radii.mean()))  # fmt: skip


def test_a_disturbed_cell_settles_into_an_equilibrium_having_dissipated(committed):
    """From the increment's start with every disk pushed by up to 3 % of the smallest radius
    sum: at rest (brute force, FIRE's tolerance), forces and moments in their cones, its stored
    energy below the energy it started with."""
    rve, state, inc = committed
    cell, sp, settings = rve.cell, rve.springs, rve.settings
    w, th = predicted(inc.w0, inc.th0, state.sensitivity[0], inc.F0, HARD)
    kick = np.random.default_rng(0).uniform(-1, 1, size=w.shape) * 0.03 * cell.R.min()
    w = w + kick @ np.linalg.inv(HARD).T
    base, available, steps = settle(cell, sp, HARD, w, th, inc, settings)
    assert steps > 0 and np.array_equal(base.F0, HARD) and base.chain is None
    s = CellState(cell, sp, HARD, base.w0, base.th0, base)
    assert s.residual(cell)[0] <= settings.fire_tol
    assert balance(rve, HARD, base.w0, s) <= 1.01 * settings.fire_tol
    on = s.status != OPEN
    assert (np.abs(s.ft[on]) <= sp.mu * sp.kn * s.e[on] * (1 + 1e-12)).all()
    if sp.mu_r > 0.0:
        assert np.any(s.mr[on] != 0.0)
    stored, _ = s.energies(cell, sp)
    assert available > stored > 0.0


def test_where_every_solver_fails_the_cell_rearranges(committed):
    """The hard increment with the fallbacks cut short: one rearrangement, then Newton's
    equilibrium (brute force), every force in its cone, energy dissipated."""
    rve, state, inc = committed
    settings = replace(rve.settings, **NO_FALLBACK)
    eq = relax(rve.cell, rve.springs, HARD, np.eye(4), inc, state.sensitivity[0], settings, True)
    assert eq.counts.rearrangements == 1
    assert eq.residual <= settings.force_tol
    s, sp = eq.state, rve.springs
    assert balance(rve, HARD, eq.w, s) <= 1e-8
    on = s.status != OPEN
    assert (np.abs(s.ft[on]) <= sp.mu * sp.kn * s.e[on] * (1 + 1e-12)).all()
    assert eq.dissipated > 0.0 and eq.W > 0.0
    # the default settings solve the same increment without rearranging
    default = relax(rve.cell, sp, HARD, np.eye(4), inc, state.sensitivity[0], rve.settings, True)
    assert default.counts.rearrangements == 0


def test_the_tangent_after_a_rearrangement_is_the_derivative_of_p_at_its_history(committed):
    """A of the equilibrium Newton finds from where the disturbed cell came to rest (as
    ``rearranged`` does) against central differences of P from that rest, the history fixed,
    where no contact changes status."""
    rve, state, inc = committed
    cell, sp = rve.cell, rve.springs
    w, th = predicted(inc.w0, inc.th0, state.sensitivity[0], inc.F0, HARD)
    kick = np.random.default_rng(0).uniform(-1, 1, size=w.shape) * 0.03 * cell.R.min()
    base = settle(cell, sp, HARD, w + kick @ np.linalg.inv(HARD).T, th, inc, rve.settings)[0]
    still = np.zeros((cell.n_disks, 3, 4))
    eq = relax(cell, sp, HARD, np.eye(4), base, still, rve.settings, True)
    h = 1e-9  # (at 1e-8 a rolling spring at its cap changes status)
    for k in range(4):
        dF = np.zeros(4)
        dF[k] = h
        P = []
        for sign in (1.0, -1.0):
            G = HARD + sign * dF.reshape(2, 2)
            other = relax(cell, sp, G, np.eye(4), base, still, rve.settings, False)
            assert np.array_equal(other.state.status, eq.state.status)
            assert np.array_equal(other.state.rstatus, eq.state.rstatus)
            P.append(other.P.ravel())
        fd = (P[0] - P[1]) / (2 * h)
        assert np.allclose(eq.A.reshape(4, 4)[:, k], fd, rtol=0, atol=1e-5 * np.abs(eq.A).max())


@pytest.mark.slow
def test_a_biaxial_test_goes_on_through_its_rearrangements():
    """70 disks (seed 2, p / k_n = 1e-2, mu = 0.5), eps1 in steps of 0.5 % to 13.5 %: without
    rearranging, its increment at 12.75 % had no equilibrium (after the continuation and
    100,000 FIRE steps), and at 12.8 % the lateral stress jumped 3.5 % of p across its target;
    now the test goes on, every step holding p to ACCEPT_JUMP."""
    law = et.make_law("relaxed", generate_packing(70, seed=2, pressure=1e-2), 0.5)
    targets = np.linspace(0.0, 0.135, 28)[1:]
    rows, stop = et.load_test(et.BIAXIAL, law, 1e-2, targets)
    assert stop == "" and rows[-1]["eps1"] == pytest.approx(0.135, rel=1e-12)
    p = 1e-2 * law.normal_stiffness
    misses = np.array([r["control_error_Pa"] for r in rows])
    assert np.abs(misses).max() <= et.ACCEPT_JUMP * p
    assert all(r["q_over_p"] > 0.0 for r in rows[1:])


#: F1 dilated by 3 %: past the packing's reference, every contact opens
APART = 1.03 * F1


def test_an_increment_that_takes_the_cell_apart_floats_without_stress(committed):
    """relax to a dilated F: the disks float (no disk keeps two contacts, no overlap beyond
    round-off by brute force), P of round-off against the committed state's, no tangent; the
    path to it (``follow``) ends so, and the law raises CellFloats (a RigidityLostError) with
    its outputs there: the state the disks float in, which floats at rest, and jams again
    compressed back to F1, in equilibrium (brute force)."""
    rve, state, inc = committed
    eq = relax(rve.cell, rve.springs, APART, np.eye(4), inc, state.sensitivity[0], rve.settings,
               True)  # fmt: skip
    assert eq.floating and eq.A is None and eq.state.keep.sum() < 2
    P1 = rve.evaluate(F1, rve.initial_state(1))[1]
    assert np.abs(eq.P).max() <= 1e-9 * np.abs(P1).max()
    assert np.abs(eq.sensitivity).max() == 0.0 and eq.chain is None
    x = (rve.packing.centers + eq.w) @ APART.T
    gap = np.inf
    for a in range(len(x)):
        for b in range(a + 1, len(x)):
            d = x[b] - x[a]
            box = APART @ np.diag(rve.packing.box)
            d -= box @ np.round(np.linalg.solve(box, d))  # (the nearest image)
            gap = min(gap, np.linalg.norm(d) - rve.packing.radii[a] - rve.packing.radii[b])
    assert gap >= -1e-12 * rve.packing.radii.mean()
    eq = follow(rve.cell, rve.springs, APART, inc, state.sensitivity[0], rve.settings, True)[0]
    assert eq.floating and np.abs(eq.P).max() <= 1e-9 * np.abs(P1).max()
    with pytest.raises(CellFloats, match="come apart") as floats:
        rve.evaluate(APART, state)
    assert isinstance(floats.value, RigidityLostError) and list(floats.value.points) == [0]
    W, P, A, floating = floats.value.outputs
    assert np.abs(P).max() <= 1e-9 * np.abs(P1).max() and not A.any()
    assert np.array_equal(floating.F[0], APART) and floating.w.shape == state.w.shape
    with pytest.raises(CellFloats):  # (at rest where it floats)
        rve.evaluate(APART, floating)
    P, jammed = rve.evaluate(F1, floating)[1::2]
    assert np.abs(P).max() > 0.5 * np.abs(P1).max()
    f, M, mean = frictional_balance(rve.packing, F1, jammed.w[0], rve.contacts(F1, jammed))
    assert np.abs(f).max() <= 1e-9 * mean
    assert np.abs(M).max() <= 1e-9 * mean * rve.packing.radii.mean()


def test_damped_motion_that_takes_the_cell_apart_says_where_the_disks_are(committed):
    rve, state, inc = committed
    w, th = predicted(inc.w0, inc.th0, state.sensitivity[0], inc.F0, APART)
    with pytest.raises(CameApart) as apart:
        fire(rve.cell, rve.springs, APART, w, th, inc, rve.settings)
    assert apart.value.w.shape == w.shape and apart.value.th.shape == th.shape
    s = CellState(rve.cell, rve.springs, APART, apart.value.w, apart.value.th, inc)
    assert not s.on.any()  # (no two disks touch there)
