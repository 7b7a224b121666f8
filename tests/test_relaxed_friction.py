"""FrictionalRelaxedRVE: frictional disks with rotations in static equilibrium, the consistent
condensed tangent.

Each test checks one property against something computed another way: the contact law's
derivatives and the tangent by central differences, the equilibrium by a brute-force loop over
pairs and images, mu = 0 against the frictionless RelaxedRVE, a superposed rotation, a lattice."""

import os

from dolfinx_granular import (
    FrictionalRelaxedRVE,
    FrictionalRelaxedState,
    HistoryLaw,
    HistoryState,
    Packing,
    RelaxedRVE,
    generate_packing,
)
from dolfinx_granular.laws.relaxed.errors import CellFloats
from dolfinx_granular.laws.relaxed.path import stretch, stretches_between
from dolfinx_granular.laws.relaxed_friction import contact_law, point, system
from dolfinx_granular.laws.relaxed_friction.cell_state import Increment
from dolfinx_granular.laws.relaxed_friction.path_tangent import stretch_derivative
from dolfinx_granular.laws.relaxed_friction.tangent import condensation

import numpy as np
import pytest
import scipy.sparse as sp

from helpers import frictional_balance, hex_lattice

K_N = 1e8
#: a compression, then a shear under it (p / k_n ~ 1e-3 on the 70-disk packing)
F_ONE = np.array([[0.99, 0.0], [0.0, 0.99]])
F_TWO = np.array([[0.99, 0.004], [0.001, 0.992]])


@pytest.fixture(scope="module")
def packing():
    return generate_packing(70, seed=1)


@pytest.fixture(scope="module", params=[0.0, 0.1], ids=["sliding", "rolling"])
def rve(packing, request):
    """Sliding friction, without and with rolling resistance (mu_r = 0.1: about a third of the
    rolling springs slip at F_TWO)."""
    return FrictionalRelaxedRVE(
        packing, K_N, K_N, friction=0.3, force_tol=1e-12, rolling_friction=request.param
    )


def _rolling_caps(rve, c):
    """(m,) the rolling moments' caps mu_r r_eff f_n of a ContactSet."""
    r = rve.packing.radii
    ri, rj = r[c.pairs[:, 0]], r[c.pairs[:, 1]]
    return rve.rolling_friction * ri * rj / (ri + rj) * c.force


@pytest.fixture(scope="module")
def sheared(rve):
    """(W, P, A, state) at F_TWO from the committed state at F_ONE, and that state."""
    committed = rve.evaluate(F_ONE, rve.initial_state(1))[3]
    return rve.evaluate(F_TWO, committed), committed


def test_it_is_a_history_law_with_a_history_state(rve):
    assert isinstance(rve, HistoryLaw)
    state = rve.initial_state(3)
    assert isinstance(state, HistoryState) and state.n_points == 3


# -- the contact law's derivatives ---------------------------------------------------------------


def _equations(cell, F, w, th, inc, mu, kt, jacobian=False, mu_r=0.0):
    m = cell.pi.shape[0]
    kr = kt  # (rolling stiffness 1: k_r = k_t r_eff^2)
    c = contact_law.return_map(
        F, w, th, *inc.arrays(m), cell.pi, cell.pj, cell.X, cell.Y, cell.R, cell.radii, m, K_N,
        kt, mu, kr, mu_r,
    )  # fmt: skip
    size = 36 * m
    rows, cols, vals = np.empty(size, np.int64), np.empty(size, np.int64), np.empty(size)
    mode = np.full(m, 2, np.int8)
    r, P, nnz = system.equations(
        F, *c, cell.pi, cell.pj, cell.R, cell.radii, K_N, kt, mu, kr, mu_r, 1.0, cell.n_disks,
        mode, jacobian, rows, cols, vals,
    )  # fmt: skip
    _, krs = system.rolling_springs(cell.pi, cell.pj, cell.radii, c[5], K_N, kr, mu_r)
    W = system.energy(c[5], c[6], c[8], K_N, kt, 1.0, c[9], c[11], krs)
    J = sp.coo_matrix((vals[:nnz], (rows[:nnz], cols[:nnz])), (r.size, r.size)).toarray()
    return W, r.ravel(), P.ravel(), J, c


@pytest.fixture(scope="module")
def increment(rve):
    """A cell and an increment to a random (w, theta) at F, with random committed forces and
    rolling moments."""
    rng = np.random.default_rng(0)
    cell, N, M = rve.cell, rve.cell.n_disks, rve.cell.pi.shape[0]
    F0 = np.array([[0.99, 0.003], [-0.002, 0.995]])
    w0, th0 = 1e-3 * rng.standard_normal((N, 2)), 1e-2 * rng.standard_normal(N)
    reff = cell.radii[cell.pi] * cell.radii[cell.pj] / cell.R
    mr0 = 1e3 * reff * rng.standard_normal(M)
    inc = Increment(F0, w0, th0, 1e3 * rng.standard_normal(M), None, mr0)
    F = F0 + np.array([[-0.006, 0.004], [0.001, -0.005]])
    w, th = w0 + 1e-4 * rng.standard_normal((N, 2)), th0 + 1e-3 * rng.standard_normal(N)
    return cell, F, w, th, inc


def _unknowns(N, k):
    """(dw, dth) of unit size in unknown k (numbered 3 i + a)."""
    dw, dth = np.zeros((N, 2)), np.zeros(N)
    if k % 3 < 2:
        dw[k // 3, k % 3] = 1.0
    else:
        dth[k // 3] = 1.0
    return dw, dth


@pytest.mark.parametrize("mu, mu_r", [(1e3, 0.0), (0.3, 0.0), (1e3, 1e3), (0.3, 0.1)])
def test_the_jacobian_and_mixed_terms_are_derivatives(increment, mu, mu_r):
    """dr/dq, dP/dF, dP/dq and dr/dF against central differences, no status changed (mu = 1e3:
    all stick, then r = dW/dq and P = dW/dF too; mu = 0.3: some slip, non-symmetric), without
    and with rolling resistance (mu_r = 1e3: every rolling spring sticks; 0.1: some slip)."""
    cell, F, w, th, inc = increment
    N, h = cell.n_disks, 1e-7
    _, r, P, J, c = _equations(cell, F, w, th, inc, mu, 0.7 * K_N, True, mu_r)
    status, rolling = c[8], c[11]
    assert (status == contact_law.STICK).any()
    assert (status == contact_law.SLIP).any() == (mu < 1)
    on = status != contact_law.OPEN
    if mu_r == 0.0:
        assert (rolling == contact_law.OPEN).all()
    else:
        assert (rolling[on] == contact_law.STICK).any()
        assert (rolling[on] == contact_law.SLIP).any() == (mu_r < 1)
    dr, dW, dP = np.zeros((3 * N, 3 * N)), np.zeros(3 * N), np.zeros((4, 3 * N))
    for k in range(3 * N):
        dw, dth = _unknowns(N, k)
        p = _equations(cell, F, w + h * dw, th + h * dth, inc, mu, 0.7 * K_N, mu_r=mu_r)
        m = _equations(cell, F, w - h * dw, th - h * dth, inc, mu, 0.7 * K_N, mu_r=mu_r)
        for side in (p, m):
            assert np.array_equal(side[4][8], status) and np.array_equal(side[4][11], rolling)
        dW[k], dr[:, k], dP[:, k] = (
            (p[0] - m[0]) / (2 * h),
            (p[1] - m[1]) / (2 * h),
            (p[2] - m[2]) / (2 * h),
        )
    assert np.abs(dr - J).max() <= 1e-7 * np.abs(J).max()
    KFF, KFq, KqF = system.mixed(
        F, *c, cell.pi, cell.pj, cell.R, cell.radii, K_N, 0.7 * K_N, mu, 0.7 * K_N, mu_r, 1.0,
        N, np.ones(len(c[0]), bool),
    )  # fmt: skip
    assert np.abs(dP - KFq).max() <= 1e-7 * np.abs(KFq).max()
    dPdF, drdF, dWdF = np.zeros((4, 4)), np.zeros((3 * N, 4)), np.zeros(4)
    for k in range(4):
        dF = np.zeros(4)
        dF[k] = h
        p = _equations(cell, F + dF.reshape(2, 2), w, th, inc, mu, 0.7 * K_N, mu_r=mu_r)
        m = _equations(cell, F - dF.reshape(2, 2), w, th, inc, mu, 0.7 * K_N, mu_r=mu_r)
        dWdF[k], drdF[:, k], dPdF[:, k] = (
            (p[0] - m[0]) / (2 * h),
            (p[1] - m[1]) / (2 * h),
            (p[2] - m[2]) / (2 * h),
        )
    assert np.abs(dPdF - KFF).max() <= 1e-7 * np.abs(KFF).max()
    assert np.abs(drdF - KqF).max() <= 1e-7 * np.abs(KqF).max()
    asym = np.abs(J - J.T).max() / np.abs(J).max()
    if mu > 1 and (mu_r == 0.0 or mu_r > 1):  # all stick: hyperelastic
        assert np.abs(dW - r).max() <= 1e-7 * np.abs(r).max()
        assert np.abs(dWdF - P).max() <= 1e-7 * np.abs(P).max()
        assert asym <= 1e-14
    else:
        assert asym > 1e-3


# -- the law --------------------------------------------------------------------------------------


@pytest.mark.parametrize("mu, mu_r", [(0.3, 0.0), (0.3, 0.1)])
def test_the_newton_loops_sums_are_the_equations_bit_for_bit(increment, mu, mu_r):
    """forces (the residual and stress of every iterate) and jacobian_blocks (the blocks the
    block LU assembles) are system.equations' sums, in the same order: equal bit for bit."""
    cell, F, w, th, inc = increment
    kt, kr = 0.7 * K_N, 0.7 * K_N
    _, r, P, J, c = _equations(cell, F, w, th, inc, mu, kt, True, mu_r)
    args = (cell.pi, cell.pj, cell.R, cell.radii, K_N)
    r2, P2 = system.forces(F, *c[:7], c[8], c[9], c[11], *args, 1.0, cell.n_disks)
    assert np.array_equal(r2.ravel(), r) and np.array_equal(P2.ravel(), P)
    contacts = np.flatnonzero(c[8] != contact_law.OPEN)
    K = system.jacobian_blocks(F, *c[2:7], c[8], c[9], c[11], *args, kt, mu, kr, mu_r, 1.0,
                               contacts)  # fmt: skip
    dofs = 3 * np.c_[cell.pi[contacts], cell.pj[contacts]]
    dofs = (dofs[:, :, None] + np.arange(3)).reshape(-1, 6)
    rows = np.broadcast_to(dofs[:, :, None], K.shape).ravel()
    cols = np.broadcast_to(dofs[:, None, :], K.shape).ravel()
    J2 = sp.coo_matrix((K.ravel(), (rows, cols)), J.shape).toarray()
    assert np.array_equal(J2, J)


def test_without_friction_it_is_the_frictionless_relaxed_rve(packing):
    frictional = FrictionalRelaxedRVE(packing, K_N, K_N, friction=0.0)
    frictionless = RelaxedRVE(packing, K_N)
    F = np.stack([F_ONE, F_TWO])
    W, P, A, state = frictional.evaluate(F, frictional.initial_state(2))
    W0, P0, A0, state0 = frictionless.evaluate(F, frictionless.initial_state(2))
    for a, b in ((W, W0), (P, P0), (A, A0), (state.w, state0.w)):
        assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max()
    assert not state.theta.any() and state.keys.size == 0 and not state.dissipation.any()
    c = frictional.contacts(F_TWO, state.take([1]))
    assert not c.tangential.any() and not c.sliding.any()
    # a cell come apart floats as the frictionless one's: the same outputs, in its own state
    apart = 1.03 * F_ONE
    with pytest.raises(CellFloats) as mine:
        frictional.evaluate(apart, state.take([0]))
    with pytest.raises(CellFloats) as theirs:
        frictionless.evaluate(apart, state0.take([0]))
    (W, P, A, floating), (W0, P0, A0, floating0) = mine.value.outputs, theirs.value.outputs
    assert W == W0 and np.array_equal(P, P0) and not A.any() and not A0.any()
    assert isinstance(floating, type(state)) and np.array_equal(floating.w, floating0.w)


def test_every_disk_is_in_equilibrium_of_forces_and_moments(packing, rve, sheared):
    (_, P, _, state), _ = sheared
    f, M, mean = frictional_balance(packing, F_TWO, state.w[0], rve.contacts(F_TWO, state))
    assert np.abs(f).max() <= 1e-9 * mean
    assert np.abs(M).max() <= 1e-9 * mean * packing.radii.mean()
    sigma = P @ F_TWO.T / np.linalg.det(F_TWO)
    assert abs(sigma[0, 1] - sigma[1, 0]) <= 1e-9 * np.abs(sigma).max()  # moments balance


def test_every_contact_obeys_coulomb(rve, sheared):
    (_, _, _, state), _ = sheared
    c = rve.contacts(F_TWO, state)
    cap = rve.friction * c.force
    assert np.all(np.abs(c.tangential) <= cap * (1 + 1e-12))
    assert c.sliding.any() and (~c.sliding).any()
    assert np.allclose(np.abs(c.tangential[c.sliding]), cap[c.sliding], rtol=1e-12)
    # the rolling moments within their caps, some on them (rolling), some inside
    cap = _rolling_caps(rve, c)
    assert np.all(np.abs(c.rolling) <= cap * (1 + 1e-12))
    if rve.rolling_friction == 0.0:
        assert not c.rolling.any()
    else:
        on_cap = np.abs(c.rolling) >= cap * (1 - 1e-12)
        carry = c.force > 1e-12 * c.force.mean()
        assert on_cap[carry].any() and (~on_cap[carry]).any()


def test_the_dissipation_of_every_increment_is_not_negative(rve):
    state = rve.initial_state(1)
    for k in range(1, 6):
        F = np.array([[0.99, 0.002 * k], [0.0, 0.99 - 0.001 * k]])
        new = rve.stress(F, state)[2]
        assert new.dissipation[0] >= state.dissipation[0]
        state = new
    assert state.dissipation[0] > 0.0


def _differences(rve, F, committed, h=1e-7):
    """Central differences dP/dF (2, 2, 2, 2) at F from the 1-point ``committed`` state, and
    the perturbed F + h e_ab it evaluated (4 of them)."""
    dP, moved = np.zeros((2, 2, 2, 2)), []
    for a in range(2):
        for b in range(2):
            dF = np.zeros((2, 2))
            dF[a, b] = h
            Pp = rve.stress(F + dF, committed)[1]
            Pm = rve.stress(F - dF, committed)[1]
            dP[:, :, a, b] = (Pp - Pm) / (2 * h)
            moved.append(F + dF)
    return dP, moved


def _sliding(rve, F, committed):
    """{(i, j, image): (sliding, rolling on its cap)} of the contacts at F that carry a force
    (a rattler's last contact relaxes to a round-off overlap, on either side of touching)."""
    c = rve.contacts(F, committed)
    carry = c.force > 1e-12 * c.force.mean()
    rolls = np.abs(c.rolling) >= _rolling_caps(rve, c) * (1 - 1e-12)
    return {
        (int(i), int(j), int(s0), int(s1)): (bool(slide), bool(roll))
        for (i, j), (s0, s1), slide, roll in zip(
            c.pairs[carry], c.shift[carry], c.sliding[carry], rolls[carry]
        )
    }


def test_the_tangent_is_the_derivative_of_the_stress_within_a_substep(rve, sheared):
    """A at F against central differences of P from the same committed state: F within one
    substep of it, no contact changes status."""
    _, committed = sheared
    F = F_ONE + np.array([[2e-4, 3e-4], [-1e-4, -2e-4]])
    _, P, A, new = rve.evaluate(F, committed)
    status = _sliding(rve, F, committed)
    dP, moved = _differences(rve, F, committed)
    assert all(_sliding(rve, G, committed) == status for G in moved)
    assert any(slide for slide, _ in status.values())
    if rve.rolling_friction > 0.0:
        assert any(roll for _, roll in status.values())
    assert np.abs(dP - A).max() <= 1e-5 * np.abs(A).max()
    A4 = A.reshape(4, 4)
    assert np.abs(A4 - A4.T).max() > 1e-4 * np.abs(A4).max()  # slip: not symmetric


def test_the_tangent_is_the_derivative_of_the_stress_through_the_path(rve, sheared):
    """From the committed state at F_ONE to F_TWO the path takes several substeps, each
    committing its forces: A at F_TWO is still the derivative of P(F_TWO) (central
    differences), the history's dependence on F included."""
    (_, _, A, _), committed = sheared
    dP, _ = _differences(rve, F_TWO, committed)
    inc = rve.increment(committed, 0)
    h_path = point.substep(rve.cell, rve.springs, inc, F_TWO, rve.settings)
    assert len(stretches_between(F_ONE, F_TWO, h_path)) >= 3
    assert np.abs(dP - A).max() <= 1e-6 * np.abs(A).max()


def test_the_stretchs_derivative_is_its_difference_quotient():
    """dU/dF of the path's right stretch (compiled, :func:`stretch_derivative`) against
    central differences of :func:`stretch`, at an F with rotation and shear."""
    F = np.array([[0.97, 0.04], [-0.11, 1.02]])
    h = 1e-6
    dU = np.empty((4, 4))
    for p in range(4):
        dF = np.zeros(4)
        dF[p] = h
        dU[:, p] = (stretch(F + dF.reshape(2, 2)) - stretch(F - dF.reshape(2, 2))).ravel() / (2 * h)
    assert np.abs(stretch_derivative(F) - dU).max() <= 1e-8


def test_a_superposed_rotation_rotates_everything(rve, sheared):
    (W, P, A, state), committed = sheared
    for alpha in (0.3, -np.pi + 0.01):
        Q = np.array([[np.cos(alpha), -np.sin(alpha)], [np.sin(alpha), np.cos(alpha)]])
        Wr, Pr, Ar, rotated = rve.evaluate(Q @ F_TWO, committed)
        assert abs(Wr - W) <= 1e-9 * W
        assert np.abs(Pr - Q @ P).max() <= 1e-9 * np.abs(P).max()
        assert np.abs(Ar - np.einsum("ai,ck,ibkd->abcd", Q, Q, A)).max() <= 1e-8 * np.abs(A).max()
        turn = rotated.theta - state.theta
        assert np.abs(np.angle(np.exp(1j * (turn - alpha)))).max() <= 1e-9
        # the same forces by pair and image (a rattler's contact at zero overlap may be open
        # in one and closed in the other: its force is nil)
        for field in ("force", "rolling"):  # (and rolling moments)
            a = dict(zip(rotated.keys.tolist(), getattr(rotated, field)))
            b = dict(zip(state.keys.tolist(), getattr(state, field)))
            small = 1e-9 * np.abs(getattr(state, field)).max()
            for key in a.keys() | b.keys():
                assert abs(a.get(key, 0.0) - b.get(key, 0.0)) <= 1e-8 * abs(b.get(key, 0.0)) + small


def test_a_triangular_lattice_does_not_move():
    """No fluctuation; every disk turns alike, with the lattice's mean branch rotation (F's
    polar rotation to first order)."""
    lattice = hex_lattice(6, 6, overlap=1e-3)
    rve = FrictionalRelaxedRVE(lattice, K_N, K_N, friction=0.5)
    F = np.array([[0.999, 0.0005], [0.0002, 0.998]])
    _, P, _, state = rve.evaluate(F, rve.initial_state(1))
    assert np.abs(state.w).max() <= 1e-12
    polar = np.arctan2(F[1, 0] - F[0, 1], F[0, 0] + F[1, 1])
    assert np.ptp(state.theta) <= 1e-14
    assert abs(state.theta[0, 0] - polar) <= 1e-3 * abs(polar)


def test_the_state_round_trips_and_selects_points(rve, sheared):
    (_, _, _, state), committed = sheared
    both = FrictionalRelaxedState.concatenate([committed, state])
    assert both.take([1]).equals(state) and both.take([0]).equals(committed)
    assert FrictionalRelaxedState.from_arrays(both.to_arrays()).equals(both)
    bad = both.to_arrays()
    bad["offsets"] = bad["offsets"][:-1]
    with pytest.raises(ValueError, match="offsets"):
        FrictionalRelaxedState.from_arrays(bad)


def test_a_rotation_nothing_resists_does_not_change_the_tangent(rve, sheared):
    """The diagonal of a rotation no sticking contact holds (a rattler's, a disk whose contacts
    all slip) is arbitrary: scaled by 1e3, P and A stay to round-off."""
    _, committed = sheared
    eq, _ = rve.equilibrium(F_TWO, committed, 0)
    A1, dq1 = condensation(rve.cell, rve.springs, F_TWO, eq.state)
    A2, dq2 = condensation(rve.cell, rve.springs, F_TWO, eq.state, free_rotation=1e3)
    assert np.abs(A2 - A1).max() <= 1e-10 * np.abs(A1).max()
    assert np.abs(dq2 - dq1).max() <= 1e-8 * np.abs(dq1).max()


# -- rolling resistance ---------------------------------------------------------------------------


def test_without_rolling_friction_the_law_is_the_one_without_it(packing):
    """mu_r = 0: the rolling stiffness changes nothing, bit for bit, and no moment is stored;
    a small mu_r moves P by about its own size (the law is continuous in mu_r)."""
    answers = []
    for mu_r, beta in ((0.0, 1.0), (0.0, 7.0), (1e-6, 1.0)):
        rve = FrictionalRelaxedRVE(packing, K_N, K_N, friction=0.3, rolling_friction=mu_r,
                                   rolling_stiffness=beta)  # fmt: skip
        committed = rve.evaluate(F_ONE, rve.initial_state(1))[3]
        answers.append(rve.evaluate(F_TWO, committed))
    (W0, P0, A0, s0), (W1, P1, A1, s1), (_, P2, _, s2) = answers
    assert W0 == W1 and np.array_equal(P0, P1) and np.array_equal(A0, A1) and s0.equals(s1)
    assert not s0.rolling.any() and s2.rolling.any()
    assert 0.0 < np.abs(P2 - P0).max() <= 1e-4 * np.abs(P0).max()


def test_rolling_resistance_without_sliding_friction_changes_nothing(packing):
    """mu = 0, mu_r > 0: normal forces pass through the centres, so nothing turns a disk
    against another and no rolling spring is loaded: P and A are the frictionless relaxed
    RVE's (computed here by the frictional solver, every rotation held by its sticking rolling
    springs)."""
    rve = FrictionalRelaxedRVE(packing, K_N, K_N, friction=0.0, rolling_friction=0.2,
                               force_tol=1e-12)  # fmt: skip
    committed = rve.evaluate(F_ONE, rve.initial_state(1))[3]
    _, P, A, state = rve.evaluate(F_TWO, committed)
    c = rve.contacts(F_TWO, state)
    assert not c.tangential.any() and not c.rolling.any()
    assert np.ptp(state.theta) <= 1e-15  # (all turn alike: with F's polar rotation)
    frictionless = RelaxedRVE(packing, K_N, force_tol=1e-12)
    before = frictionless.evaluate(F_ONE, frictionless.initial_state(1))[3]
    _, P0, A0, _ = frictionless.evaluate(F_TWO, before)
    assert np.abs(P - P0).max() <= 1e-9 * np.abs(P0).max()
    assert np.abs(A - A0).max() <= 1e-7 * np.abs(A0).max()


def test_rolling_resistance_needs_its_springs(packing):
    with pytest.raises(ValueError, match="tangential_stiffness must be > 0"):
        FrictionalRelaxedRVE(packing, K_N, 0.0, friction=0.0, rolling_friction=0.1)
    with pytest.raises(ValueError, match="rolling_stiffness must be > 0"):
        FrictionalRelaxedRVE(packing, K_N, K_N, friction=0.3, rolling_friction=0.1,
                             rolling_stiffness=0.0)  # fmt: skip


def test_a_state_without_rolling_moments_loads_with_none(rve, sheared):
    """A state written before rolling resistance existed (no ``rolling`` array) loads, with
    zero moments."""
    (_, _, _, state), _ = sheared
    arrays = state.to_arrays()
    del arrays["rolling"]
    old = FrictionalRelaxedState.from_arrays(arrays)
    assert old.rolling.shape == state.force.shape and not old.rolling.any()


# -- strength reduction: the friction lowered at a fixed F ---------------------------------------


@pytest.fixture(scope="module", params=[0.0, 0.1], ids=["sliding", "rolling"])
def reduced(packing, request):
    """(law, committed state at F_TWO under mu = 0.3, the state after lowering mu (and mu_r)
    to half at the same F, its (W, P, A))."""
    mu_r = request.param
    rve = FrictionalRelaxedRVE(
        packing, K_N, K_N, friction=0.3, force_tol=1e-12, rolling_friction=mu_r
    )
    committed = rve.evaluate(F_ONE, rve.initial_state(1))[3]
    committed = rve.evaluate(F_TWO, committed)[3]
    rve.set_friction(0.15, mu_r / 2)
    W, P, A, state = rve.evaluate(F_TWO, committed)
    return rve, committed, state, (W, P, A)


def _unmoved(a, b):
    """True where two one-point states hold the same positions, rotations, contacts, forces
    and dissipation, bit for bit (the sensitivities of a state at rest are its own)."""
    fields = ("w", "theta", "F", "dissipation", "keys", "force", "sliding", "rolling")
    return all(np.array_equal(getattr(a, f), getattr(b, f)) for f in fields)


def test_the_same_friction_leaves_a_committed_state_at_rest(rve, sheared):
    """set_friction with the law's own coefficients: the committed state at its F does not
    move, bit for bit, and dissipates nothing."""
    (_, P, _, state), _ = sheared
    law = FrictionalRelaxedRVE(
        rve.packing, K_N, K_N, friction=0.3, force_tol=1e-12,
        rolling_friction=rve.rolling_friction,
    )  # fmt: skip
    law.set_friction(0.3)
    _, P1, _, again = law.evaluate(F_TWO, state)
    assert np.array_equal(P1, P) and _unmoved(again, state)


def test_a_lowered_friction_relaxes_the_point_at_its_f(packing, reduced):
    """Half the friction at the committed F: every force and moment back in its (smaller)
    cone, some on it, every disk in equilibrium (brute force), energy dissipated, the shear
    stress lower; the new state is at rest under the new law."""
    rve, committed, state, (_, P, _) = reduced
    c = rve.contacts(F_TWO, state)
    cap = rve.friction * c.force
    assert np.all(np.abs(c.tangential) <= cap * (1 + 1e-12))
    assert np.allclose(np.abs(c.tangential[c.sliding]), cap[c.sliding], rtol=1e-12)
    assert c.sliding.any()
    assert np.all(np.abs(c.rolling) <= _rolling_caps(rve, c) * (1 + 1e-12))
    f, M, mean = frictional_balance(packing, F_TWO, state.w[0], rve.contacts(F_TWO, state))
    assert np.abs(f).max() <= 1e-9 * mean
    assert np.abs(M).max() <= 1e-9 * mean * packing.radii.mean()
    assert state.dissipation[0] > committed.dissipation[0]
    P0 = rve.stress(F_TWO, committed)[1]  # (the same answer: the relaxation is deterministic)
    assert np.array_equal(P0, P)
    before = FrictionalRelaxedRVE(packing, K_N, K_N, friction=0.3, force_tol=1e-12,
                                  rolling_friction=2 * rve.rolling_friction)  # fmt: skip
    P_before = before.stress(F_TWO, committed)[1]
    assert abs(P[0, 1]) < 0.9 * abs(P_before[0, 1])
    _, P2, _, again = rve.evaluate(F_TWO, state)
    assert np.array_equal(P2, P) and _unmoved(again, state)


def test_the_tangent_after_a_lowered_friction_is_the_derivative_of_the_stress(reduced):
    """A at the committed F under the lowered friction against central differences of P from
    the same committed state and law."""
    rve, committed, _, (_, _, A) = reduced
    dP, _ = _differences(rve, F_TWO, committed)
    assert np.abs(dP - A).max() <= 1e-5 * np.abs(A).max()


def test_a_lowered_friction_relaxes_a_point_whose_committed_state_has_no_tangent():
    """A point of the 160-cell slope's strength reduction (tests/data): its committed state,
    at mu = 0.12246, lies outside the cones of mu = 0.12240, and the network's stiffness at
    it (the return map's statuses under the lowered friction) is singular. The law relaxes
    the point at its F without asking for that tangent: forces in the new cones, every disk
    in equilibrium, and a tangent at the relaxed state (the slope's continuation stopped
    here on RigidityLostError before)."""
    data = np.load(os.path.join(os.path.dirname(__file__), "data", "lowered_friction_point.npz"))
    packing = Packing(data["centers"], data["radii"], data["box"])
    kn, kt = float(data["normal_stiffness"]), float(data["tangential_stiffness"])
    rve = FrictionalRelaxedRVE(packing, kn, kt, float(data["friction"]))
    committed = FrictionalRelaxedState.from_arrays(
        {k[len("state_") :]: data[k] for k in data.files if k.startswith("state_")}
    )
    F = committed.F[0]
    _, P0, _, again = rve.evaluate(F, committed)  # (at rest under its own friction)
    assert _unmoved(again, committed)
    rve.set_friction(float(data["lowered"]))
    _, P, A, state = rve.evaluate(F, committed)
    c = rve.contacts(F, state)
    assert np.all(np.abs(c.tangential) <= rve.friction * c.force * (1 + 1e-12))
    f, M, mean = frictional_balance(packing, F, state.w[0], c)
    assert np.abs(f).max() <= 1e-9 * mean
    assert np.abs(M).max() <= 1e-9 * mean * packing.radii.mean()
    assert state.dissipation[0] > committed.dissipation[0]
    assert np.isfinite(A).all() and np.abs(A).max() > 0.0
    assert not np.array_equal(P, P0)


def test_friction_cannot_be_switched_off_or_rolling_on_without_springs(packing):
    rve = FrictionalRelaxedRVE(packing, K_N, K_N, friction=0.3, rolling_stiffness=0.0)
    with pytest.raises(ValueError, match="cannot be switched on or off"):
        rve.set_friction(0.0)
    with pytest.raises(ValueError, match="needs rolling springs"):
        rve.set_friction(0.2, 0.1)
    with pytest.raises(ValueError, match="friction"):
        rve.set_friction(-0.1)
    assert rve.friction == 0.3 and rve.springs.mu == 0.3
