"""Pseudo-transient continuation, the frictional relaxed RVE's first fallback
(laws/relaxed_friction/pseudo_time.py): its potential is the residual's, its shift is the
documented diagonal, it reaches the increment's equilibrium where Newton fails (the same one
where both do), and the point's relaxation takes it before FIRE."""

from dolfinx_granular import FrictionalRelaxedRVE, generate_packing
from dolfinx_granular.laws.relaxed.errors import RelaxationError
from dolfinx_granular.laws.relaxed_friction import newton_kernel as nk
from dolfinx_granular.laws.relaxed_friction import pseudo_time as pt
from dolfinx_granular.laws.relaxed_friction import system
from dolfinx_granular.laws.relaxed_friction.block_lu import BlockLU
from dolfinx_granular.laws.relaxed_friction.contact_law import SLIP
from dolfinx_granular.laws.relaxed_friction.newton import Counts, solve
from dolfinx_granular.laws.relaxed_friction.point import predicted, relax

import numpy as np
import pytest

F1 = np.diag([0.99, 0.99])
# one increment from F1 of 3e-3 in F: Newton stalls (statuses cycling), the continuation
# converges; the second, Newton converges too (from a random batch of such increments)
HARD = np.array([[0.9890745152008461, 0.0006247337322891522],
                 [0.0022529423564802325, 0.9916362873796044]])  # fmt: skip
EASY = np.array([[0.9905595506291848, -0.00058792038008198],
                 [0.002850141309570654, 0.9904668481932514]])  # fmt: skip


@pytest.fixture(scope="module")
def committed():
    """A frictional relaxed cell committed at F1: ``(rve, state, inc)``."""
    rve = FrictionalRelaxedRVE(generate_packing(70, seed=1), 1e8, 1e8, friction=0.3)
    state = rve.evaluate(F1, rve.initial_state(1))[3]
    return rve, state, rve.increment(state, 0)


def _start(committed, F):
    _, state, inc = committed
    return predicted(inc.w0, inc.th0, state.sensitivity[0], inc.F0, F)


def _state(rve, inc, F, w, th):
    cell = rve.cell
    arrays = inc.arrays(cell.pi.shape[0])
    return nk.cell_state(F, w, th, arrays, nk.cell_arrays(cell), nk.spring_arrays(rve.springs),
                         cell.visited(F, w))  # fmt: skip


@pytest.fixture(scope="module")
def rolling():
    """As ``committed``, with rolling resistance (mu_r = 0.1)."""
    rve = FrictionalRelaxedRVE(generate_packing(70, seed=1), 1e8, 1e8, friction=0.3,
                               rolling_friction=0.1)  # fmt: skip
    state = rve.evaluate(F1, rve.initial_state(1))[3]
    return rve, state, rve.increment(state, 0)


@pytest.mark.parametrize("case", ["committed", "rolling"])
def test_the_residual_is_the_gradient_of_the_potential_with_frozen_caps(case, request):
    """Central differences of the frozen-cap potential (sliding and, with rolling resistance,
    rolling springs) along a random direction: the residual's slope, slipping springs in the
    sum."""
    committed = request.getfixturevalue(case)
    rve, _, inc = committed
    w, th = _start(committed, HARD)
    s = _state(rve, inc, HARD, w, th)
    sp, cell = rve.springs, rve.cell
    caps = sp.mu * sp.kn * np.maximum(s[5], 0.0)
    rcaps, kr = system.rolling_springs(cell.pi, cell.pj, cell.radii, s[5], sp.kn, sp.kr, sp.mu_r)
    d = np.random.default_rng(3).normal(size=(rve.cell.n_disks, 3))
    d[:, :2] *= 1e-3 * rve.cell.R.min()
    d[:, 2] *= 1e-3
    h = 1e-4

    def potential(t):
        k = _state(rve, inc, HARD, w + t * d[:, :2], th + t * d[:, 2])
        return system.potential(k[5], k[7], caps, sp.kn, sp.kt, k[16], rcaps, kr)

    slope = (potential(h) - potential(-h)) / (2 * h)
    assert slope == pytest.approx((s[14] * d).sum() / sp.inv_area, rel=1e-6)
    assert (s[8] == SLIP).any()  # (the Huber branch beyond the cap is in the sum)
    assert (s[17] == SLIP).any() == (sp.mu_r > 0.0)


def test_the_shift_adds_k_n_per_translation_and_k_n_r2_per_rotation(committed):
    rve, _, inc = committed
    w, th = _start(committed, HARD)
    s = _state(rve, inc, HARD, w, th)
    cell, sp = rve.cell, rve.springs
    p, lu, cover = cell.block_pattern(-1, s[5].shape[0], d=3, new_factor=BlockLU.on)
    matrices = []
    for shift in (0.0, 0.7):
        code, _, _ = nk.factorise(HARD, s, nk.cell_arrays(cell), nk.spring_arrays(sp),
                                  nk.pattern_arrays(p, cover), lu.arrays(), 0.0, False, 1.0,
                                  shift)  # fmt: skip
        assert code == 0
        matrices.append(lu.to_csc().toarray())
    K = sp.kn * sp.inv_area
    expected = 0.7 * K * np.column_stack([np.ones(cell.n_disks)] * 2 + [cell.radii**2]).ravel()
    assert np.allclose(matrices[1] - matrices[0], np.diag(expected), rtol=1e-13, atol=0.0)


def test_where_newton_stalls_the_continuation_reaches_the_equilibrium(committed):
    rve, _, inc = committed
    w, th = _start(committed, HARD)
    with pytest.raises(RelaxationError):
        solve(rve.cell, rve.springs, HARD, w, th, inc, rve.settings, Counts())
    counts = Counts()
    _, _, s, residual = solve(rve.cell, rve.springs, HARD, w, th, inc, rve.settings, counts,
                              pseudo=True)  # fmt: skip
    assert residual <= rve.settings.force_tol
    assert counts.pseudo_steps == counts.steps > 0 and counts.factorisations >= counts.steps
    cap = rve.springs.mu * rve.springs.kn * s.e
    on = s.status != 0
    assert (np.abs(s.ft[on]) <= cap[on] * (1 + 1e-12)).all()
    assert np.allclose(np.abs(s.ft[s.status == SLIP]), cap[s.status == SLIP], rtol=1e-12)


def test_where_both_converge_they_find_the_same_equilibrium(committed):
    rve, _, inc = committed
    w, th = _start(committed, EASY)
    P = []
    for pseudo in (False, True):
        counts = Counts()
        s = solve(rve.cell, rve.springs, EASY, w, th, inc, rve.settings, counts, pseudo)[2]
        assert (counts.pseudo_steps > 0) == pseudo
        P.append(s.P)
    assert np.allclose(P[1], P[0], rtol=0, atol=1e-11 * abs(P[0]).max())


def test_the_relaxation_takes_the_continuation_before_fire(committed):
    rve, state, inc = committed
    eq = relax(rve.cell, rve.springs, HARD, np.eye(4), inc, state.sensitivity[0], rve.settings,
               True)  # fmt: skip
    assert eq.counts.pseudo_steps > 0 and eq.counts.fire_steps == 0
    assert eq.residual <= rve.settings.force_tol and eq.A is not None


def test_a_start_of_no_contact_has_lost_rigidity(committed):
    rve, _, inc = committed
    w, th = _start(committed, HARD)
    F = 1.5 * np.eye(2)  # (every contact open)
    code, _, _, _ = nk.run(rve.cell, rve.springs, F, w, th, inc, rve.settings, Counts(),
                           pt.transient_entry, 10, (np.array([pt.SIGMA_START]),))  # fmt: skip
    assert code == nk.RIGIDITY_LOST
