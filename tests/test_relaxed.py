"""RelaxedRVE: disks in static equilibrium at every F, the exact condensed tangent.

Each test checks one property against something computed another way: the net forces by a
brute-force pair loop over the relaxed positions, P and A by central differences, the affine
modulus and W, P by a TaylorRVE of the relaxed positions, a lattice against TaylorRVE."""

import warnings
from dataclasses import replace

from dolfinx_granular import (
    HistoryLaw,
    HistoryState,
    LawEvaluationError,
    Packing,
    TaylorRVE,
    generate_packing,
)
from dolfinx_granular.laws.relaxed import (
    RelaxationError,
    RelaxedRVE,
    RelaxedState,
    RigidityLostError,
    relax,
)
from dolfinx_granular.laws.relaxed.contact_state import ContactState
from dolfinx_granular.laws.relaxed.errors import CellFloats
from dolfinx_granular.laws.relaxed.fire import FIRE_CHUNK
from dolfinx_granular.laws.relaxed.path import predicted, substeps
from dolfinx_granular.packings.reference_packing import reference_packing

import numpy as np
import pytest

from helpers import hex_lattice, net_forces

K_N = 1e8
#: an isotropic compression and a sheared one (p / k_n ~ 1e-3 on the 70-disk packing)
F_TEST = np.array([[[0.99, 0.0], [0.0, 0.99]], [[0.99, 0.004], [0.001, 0.992]]])


@pytest.fixture(scope="module")
def packing():
    return generate_packing(70, seed=1)


@pytest.fixture(scope="module")
def rve(packing):
    return RelaxedRVE(packing, K_N)


@pytest.fixture(scope="module")
def relaxed(rve):
    """(W, P, A, state) at F_TEST from the initial state."""
    return rve.evaluate(F_TEST, rve.initial_state(len(F_TEST)))


def test_it_is_a_history_law_with_a_history_state(rve):
    assert isinstance(rve, HistoryLaw)
    state = rve.initial_state(3)
    assert isinstance(state, HistoryState) and state.n_points == 3


def test_every_disk_is_in_equilibrium(packing, rve, relaxed):
    _, P, _, state = relaxed
    x = rve.positions(F_TEST, state)
    for q, F in enumerate(F_TEST):
        p = -np.trace(P[q] @ F.T) / (2 * np.linalg.det(F))
        assert p / K_N >= 1e-5
        f, mean = net_forces(packing, x[q], F)
        worst = np.linalg.norm(f, axis=1).max()
        assert worst <= 1e-9 * mean


def test_the_state_passed_in_is_left_untouched(rve):
    state = rve.initial_state(2)
    before = {k: v.copy() for k, v in state.to_arrays().items()}
    rve.evaluate(F_TEST, state)
    for k, v in state.to_arrays().items():
        np.testing.assert_array_equal(v, before[k])


def test_the_state_round_trips_through_arrays_and_selection(relaxed):
    state = relaxed[3]
    again = RelaxedState.from_arrays(state.to_arrays())
    np.testing.assert_array_equal(again.w, state.w)
    np.testing.assert_array_equal(again.sensitivity, state.sensitivity)
    # a state saved before the sensitivities were kept: no predictor
    old = RelaxedState.from_arrays(
        {k: v for k, v in state.to_arrays().items() if k != "sensitivity"}
    )
    assert old.sensitivity.shape == state.w.shape + (4,) and not old.sensitivity.any()
    both = RelaxedState.concatenate([state.take([1]), state.take([0])])
    np.testing.assert_array_equal(both.w[0], state.w[1])
    assert both.n_points == 2


def test_a_damaged_state_is_refused():
    with pytest.raises(ValueError, match="RelaxedState"):
        RelaxedState.from_arrays({"w": np.zeros((2, 3)), "F": np.zeros((2, 2, 2))})


def _step(rve, F, state, h, c, d):
    """W, P and the network fingerprint at F +- h e_cd, relaxed from ``state`` (at F)."""
    out = []
    for sign in (1.0, -1.0):
        dF = np.zeros_like(F)
        dF[:, c, d] = sign * h
        W, P, new = rve.stress(F + dF, state)
        out.append((W, P, new.network))
    return out


def test_P_is_the_derivative_of_the_relaxed_energy(rve, relaxed):
    W, P, _, state = relaxed
    h = 1e-7
    for c in range(2):
        for d in range(2):
            (Wp, _, _), (Wm, _, _) = _step(rve, F_TEST, state, h, c, d)
            np.testing.assert_allclose(
                (Wp - Wm) / (2 * h), P[:, c, d], rtol=1e-6, atol=1e-7 * np.abs(P).max()
            )


def test_A_is_the_derivative_of_P_where_the_contacts_stay(rve, relaxed):
    _, P, A, state = relaxed
    h = 1e-7  # (P is good to ~1e-10 of itself: the equilibrium tolerance)
    for c in range(2):
        for d in range(2):
            (_, Pp, netp), (_, Pm, netm) = _step(rve, F_TEST, state, h, c, d)
            assert np.array_equal(netp, state.network) and np.array_equal(netm, state.network)
            np.testing.assert_allclose(
                (Pp - Pm) / (2 * h), A[..., c, d], rtol=1e-5, atol=1e-6 * np.abs(A).max()
            )


def test_the_sensitivities_are_the_derivative_of_the_relaxed_positions(rve, relaxed):
    """dw/dF in the state (the warm start's predictor) against central differences of w,
    relaxed from the committed positions without it, over the non-rattlers (rattlers have
    none; the pinned disk stays put in both)."""
    _, _, _, state = relaxed
    h = 1e-6
    for q, F in enumerate(F_TEST):
        keep = ContactState(rve.cell, F, state.w[q]).keep
        dw = state.sensitivity[q]
        assert np.abs(dw[keep]).max() > 0 and np.abs(dw[~keep]).max() == 0
        for k in range(4):
            E = np.zeros(4)
            E[k] = h
            wp, wm = (
                relax(rve.cell, F + s * E.reshape(2, 2), state.w[q], False,
                                 rve.settings).w
                for s in (1.0, -1.0)
            )  # fmt: skip
            fd = (wp - wm)[keep] / (2 * h)
            np.testing.assert_allclose(fd, dw[keep][..., k], atol=1e-5 * np.abs(dw).max())


def test_a_rotation_predicts_no_move(rve, relaxed):
    """The warm start's predictor changes the positions with C = F^T F only, and the path is
    measured in the right stretch: a finite rotation of the committed F starts from the
    committed positions, in one step."""
    state = relaxed[3]
    t = 0.7
    Q = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    for q, F in enumerate(F_TEST):
        w, dw = state.w[q], state.sensitivity[q]
        np.testing.assert_allclose(predicted(w, dw, F, Q @ F), w, atol=1e-12 * np.abs(w).max())
        assert substeps(F, Q @ F) == []
    assert np.abs(predicted(state.w[0], state.sensitivity[0], F_TEST[0], 1.001 * F_TEST[0])
                  - state.w[0]).max() > 0  # fmt: skip
    # 1 % more stretch: |dU| = 0.01 |U| = 0.014, 15 steps of at most MAX_SUBSTEP = 1e-3
    path = substeps(F_TEST[0], 1.01 * F_TEST[0])
    assert len(path) == 14 and np.allclose(path[0], (1 + 0.01 / 15) * F_TEST[0])


def test_W_and_P_are_taylors_at_the_relaxed_positions_and_A_lies_below(packing, rve, relaxed):
    """The affine (Born) modulus of the relaxed positions bounds the relaxed one."""
    W, P, A, state = relaxed
    x = rve.positions(F_TEST, state)
    for q, F in enumerate(F_TEST):
        X = np.linalg.solve(F, x[q].T).T  # the relaxed centres pulled back to the reference
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the relaxed positions overlap at F = I
            taylor = TaylorRVE(Packing(X, packing.radii, packing.box), K_N, allow_overlaps=True)
        Wt, Pt, At = taylor.evaluate(F)
        np.testing.assert_allclose(Wt, W[q], rtol=1e-10)
        np.testing.assert_allclose(Pt, P[q], rtol=1e-9, atol=1e-9 * np.abs(P[q]).max())
        gap = np.linalg.eigvalsh(((At - A[q]).reshape(4, 4) + (At - A[q]).reshape(4, 4).T) / 2)
        assert gap.min() >= -1e-9 * np.abs(At).max()
        assert gap.max() > 1e-3 * np.abs(At).max()  # relaxation softens the packing


def test_objective_and_the_cauchy_stress_is_symmetric(rve, relaxed):
    W, P, A, state = relaxed
    t = 0.7
    Q = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    QF = np.einsum("ab,qbc->qac", Q, F_TEST)
    Wr, Pr, Ar, _ = rve.evaluate(QF, state)
    np.testing.assert_allclose(Wr, W, rtol=1e-9)
    np.testing.assert_allclose(Pr, np.einsum("ab,qbc->qac", Q, P), atol=1e-8 * np.abs(P).max())
    QAQ = np.einsum("ae,cf,qebfd->qabcd", Q, Q, A)
    np.testing.assert_allclose(Ar, QAQ, atol=1e-7 * np.abs(A).max())
    sigma = rve.cauchy(F_TEST, state)
    np.testing.assert_allclose(sigma, np.swapaxes(sigma, 1, 2), atol=1e-9 * np.abs(sigma).max())


def test_a_triangular_lattice_does_not_relax():
    """Every disk is a centre of symmetry: no force moves it, so relaxed = Taylor."""
    lattice = hex_lattice(6, 6)
    F = np.array([[[0.995, 0.002], [0.0, 0.996]]])
    relaxed = RelaxedRVE(lattice, K_N)
    W, P, A, state = relaxed.evaluate(F, relaxed.initial_state(1))
    Wt, Pt, At = TaylorRVE(lattice, K_N).evaluate(F)
    assert np.abs(state.w).max() <= 1e-12
    np.testing.assert_allclose(W, Wt, rtol=1e-12)
    np.testing.assert_allclose(P, Pt, rtol=1e-12, atol=1e-12 * np.abs(Pt).max())
    np.testing.assert_allclose(A, At, rtol=1e-10, atol=1e-10 * np.abs(At).max())


def test_tension_loses_rigidity_and_names_the_point(rve):
    F = np.array([np.diag([0.99, 0.99]), np.diag([1.01, 1.01])])
    with pytest.raises(RigidityLostError, match="point 1") as err:
        rve.evaluate(F, rve.initial_state(2))
    assert isinstance(err.value, LawEvaluationError)
    np.testing.assert_array_equal(err.value.points, [1])


def test_a_cell_dilated_past_jamming_floats_and_jams_again(packing, rve, relaxed):
    """Point 0 (confined at F_TEST[0]) dilated by 3 %: its path ends in a cell come apart, and
    the law raises CellFloats (a RigidityLostError) with its outputs there: no stress, A zero,
    the disks where they float (no two overlap, brute force). That state floats at rest too,
    and compressed back to F_TEST[0] jams again, every disk in equilibrium (brute force)."""
    F0, state = F_TEST[0], relaxed[3].take([0])
    with pytest.raises(CellFloats, match="point 0: the cell has come apart") as floats:
        rve.evaluate(1.03 * F0, state)
    assert isinstance(floats.value, RigidityLostError)
    W, P, A, floating = floats.value.outputs
    assert W == 0.0 and not P.any() and not A.any()
    x = rve.positions(1.03 * F0, floating)[0]
    a = 1.03 * F0 @ np.diag(packing.box)
    for sx in (-1, 0, 1):
        for sy in (-1, 0, 1):
            d = np.linalg.norm(x[None] + a @ [sx, sy] - x[:, None], axis=2)
            if sx == 0 and sy == 0:
                np.fill_diagonal(d, np.inf)
            assert (d >= packing.radii[:, None] + packing.radii[None]).all()
    with pytest.raises(CellFloats):
        rve.evaluate(1.03 * F0, floating)
    P, jammed = rve.evaluate(F0, floating)[1::2]
    assert np.abs(P).max() > 0.5 * np.abs(relaxed[1][0]).max()
    f, mean = net_forces(packing, rve.positions(F0, jammed)[0], F0)
    assert np.linalg.norm(f, axis=1).max() <= 1e-9 * mean


def test_the_small_strain_modulus_is_symmetric_and_below_taylors(packing, rve):
    C = rve.small_strain_modulus().reshape(4, 4)
    Ct = TaylorRVE(packing, K_N).small_strain_modulus().reshape(4, 4)
    np.testing.assert_allclose(C, C.T, atol=1e-9 * np.abs(C).max())
    assert np.linalg.eigvalsh(Ct - C).min() >= -1e-9 * np.abs(Ct).max()


def test_the_state_records_distance_from_affine_and_rearrangements(rve, relaxed):
    _, _, _, state = relaxed
    assert np.all(state.fluctuation > 0.0) and np.all(state.rearranged)  # from F = I
    np.testing.assert_array_equal(state.F, F_TEST)
    _, _, again = rve.stress(F_TEST, state)  # the same F again: nothing moves
    assert not again.rearranged.any()


def test_the_benchmark_runs(capsys, tmp_path):
    """It times both relaxed RVEs, and --save / --against compare their W, P, A (a run against
    its own file: no difference)."""
    import relaxed as benchmark  # benchmarks/relaxed.py

    saved = str(tmp_path / "points.npz")
    benchmark.main(["--points", "3", "--particles", "70", "--save", saved])
    out = capsys.readouterr().out
    assert "ratio" in out and "ms/point" in out and "frictional P+A" in out
    assert set(np.load(saved)) == {"W", "P", "A", "W_frictional", "P_frictional", "A_frictional"}
    benchmark.main(["--points", "3", "--particles", "70", "--against", saved])
    out = capsys.readouterr().out
    assert out.count("largest relative difference 0.0e+00; points beyond 1e-10: []") == 6


def test_contacts_are_those_of_the_relaxed_positions(rve, relaxed):
    """The force network of a relaxed point: branch vectors between its relaxed centres, and
    forces k_n * overlap that balance on every disk."""
    _, _, _, state = relaxed
    one = state.take([1])
    c = rve.contacts(F_TEST[1], one)
    x = rve.positions(F_TEST[1], one)[0]
    lattice = F_TEST[1] @ np.diag(rve.packing.box)
    i, j = c.pairs.T
    np.testing.assert_allclose(c.branch, x[j] + c.shift @ lattice.T - x[i], atol=1e-12)
    r = rve.packing.radii
    np.testing.assert_allclose(c.overlap, r[i] + r[j] - np.linalg.norm(c.branch, axis=1))
    f = np.zeros_like(x)
    n = c.branch / np.linalg.norm(c.branch, axis=1)[:, None]
    np.add.at(f, i, -c.force[:, None] * n)
    np.add.at(f, j, c.force[:, None] * n)
    assert np.abs(f).max() <= 1e-9 * c.force.mean()
    with pytest.raises(ValueError, match="one-point state"):
        rve.contacts(F_TEST[1], state)


def test_the_force_network_is_drawn_at_the_relaxed_positions(rve, relaxed):
    from dolfinx_granular.io.postprocess import force_network

    one = relaxed[3].take([1])
    quads, centers, _, sliding = force_network(rve, F_TEST[1], 1e-3, state=one)
    x = rve.positions(F_TEST[1], one)[0] - F_TEST[1] @ (0.5 * rve.packing.box)
    np.testing.assert_allclose(centers, x, atol=1e-12)
    c = rve.contacts(F_TEST[1], one)
    np.testing.assert_allclose(quads[:, [0, 3]].mean(axis=1), x[c.pairs[:, 0]], atol=1e-9)
    assert not sliding.any() and len(quads) == len(c.force)


def test_small_steps_from_an_equilibrium_need_no_fire():
    """Warm-started strain steps of 1e-4 from an equilibrium of 700 disks at 0.5 % compression
    (the speed benchmark's case) converge by Newton alone, to 1e-9 of the mean contact force.
    A rattler squeezed between two partners has no stiffness across them: before its Newton
    move was bounded (newton.RATTLER_REACH), 3 of these 20 points stalled and went through
    FIRE."""
    rve = RelaxedRVE(reference_packing(), 2.8e7)
    F0 = 0.995 * np.eye(2)
    w0 = relax(rve.cell, F0, np.zeros((700, 2)), False, rve.settings).w
    d = np.random.default_rng(0).normal(size=(20, 2, 2))
    d /= np.linalg.norm(d, axis=(1, 2))[:, None, None]
    for q in range(20):
        eq = relax(rve.cell, F0 + 1e-4 * d[q], w0, False, rve.settings)
        assert eq.fire_steps == 0, f"point {q} went through FIRE"
        assert eq.residual <= 1e-9, f"point {q}: net force {eq.residual:.3g} of the mean"


def test_where_newton_fails_from_fires_positions_fire_goes_closer():
    """70 disks kicked by 2 % of the smallest radius sum, FIRE stopping at 0.1 of the mean
    contact force and Newton given 3 steps: Newton fails from FIRE's first positions (a net
    force of 0.27 after its 3 steps, before FIRE went on), and a later round, FIRE to a
    thousandth of that, reaches the equilibrium (brute force over pairs and images)."""
    rve = RelaxedRVE(generate_packing(70, seed=1), 1e8)
    settings = replace(rve.settings, fire_tol=0.1, max_iterations=3)
    F = 0.99 * np.eye(2)
    w0 = np.random.default_rng(0).uniform(-1, 1, (70, 2)) * 0.02 * rve.cell.R.min()
    eq = relax(rve.cell, F, w0, False, settings)
    assert eq.fire_steps > 0 and eq.residual <= settings.force_tol
    p = rve.packing
    f, mean = net_forces(p, (p.centers + eq.w) @ F.T, F)
    assert np.linalg.norm(f, axis=1).max() <= 1e-9 * mean


def test_where_fire_runs_out_of_steps_newton_takes_the_last_try():
    """The 70 kicked disks above, Newton given 3 steps and FIRE 200 (too few to relax them):
    Newton from where FIRE stopped, without the stall limit, reaches the equilibrium (brute
    force over pairs and images). Given 3 steps there too, the error names both. (FIRE runs out
    of steps where it lingers near a saddle of the energy, as 70 frictionless disks at p / k_n
    = 1e-3 did in biaxial compression.)"""
    rve = RelaxedRVE(generate_packing(70, seed=1), 1e8)
    settings = replace(rve.settings, max_iterations=3, fire_steps=FIRE_CHUNK)
    F = 0.99 * np.eye(2)
    w0 = np.random.default_rng(0).uniform(-1, 1, (70, 2)) * 0.02 * rve.cell.R.min()
    eq = relax(rve.cell, F, w0, False, settings)
    assert eq.fire_steps == FIRE_CHUNK and eq.residual <= settings.force_tol
    p = rve.packing
    f, mean = net_forces(p, (p.centers + eq.w) @ F.T, F)
    assert np.linalg.norm(f, axis=1).max() <= 1e-9 * mean
    with pytest.raises(RelaxationError, match="FIRE did not relax the cell in 200 steps, nor"):
        relax(rve.cell, F, w0, False, replace(settings, final_iterations=3))


def test_a_big_step_follows_the_quasi_static_path():
    """Near jamming a cell has several equilibria at one F. One evaluate over 1 % strain from
    a confined packing (jammed and compressed at p / k_n = 1e-2) ends where 50 committed steps
    of 0.02 % end, in 8 directions; a relaxation from the committed positions carried
    affinely lands elsewhere in one of them (W 549.1 Pa against 557.8)."""
    from dolfinx_granular.drivers.confinement import confined_packing

    packing = confined_packing(generate_packing(70, seed=0, pressure=1e-2), 2.8e7, 1e-2)
    rve = RelaxedRVE(packing, 2.8e7)
    _, _, _, start = rve.evaluate(np.eye(2)[None], rve.initial_state(1))
    d = np.random.default_rng(1).normal(size=(8, 2, 2))
    d /= np.linalg.norm(d, axis=(1, 2))[:, None, None]
    for k in range(8):
        W, P, _, _ = rve.evaluate((np.eye(2) + 0.01 * d[k])[None], start)
        state = start
        for step in range(1, 51):
            Wp, Pp, _, state = rve.evaluate((np.eye(2) + 0.01 * d[k] * step / 50)[None], state)
        np.testing.assert_allclose(W, Wp, rtol=1e-9)
        np.testing.assert_allclose(P, Pp, rtol=1e-7, atol=1e-9 * np.abs(Pp).max())


def test_the_batch_is_the_python_path():
    """evaluate relaxes a rank's points in one compiled call (laws/relaxed/batch.py); each
    point on its own Python path (RelaxedRVE.equilibrium) ends in the same place: strain steps
    of 1e-4, one of 3e-3 (substeps), the committed F (at rest), and a point whose committed
    positions reach past the candidate list (the batch hands it to the Python path)."""
    packing = generate_packing(70, seed=0)
    rve = RelaxedRVE(packing, K_N)
    F0 = np.diag([0.995, 0.995])
    _, _, _, one = rve.evaluate(F0[None], rve.initial_state(1))
    state = RelaxedState.concatenate([one] * 5)
    far = state.w.copy()
    far[4, 7] += 0.3 * np.asarray(packing.box)  # one disk across the cell
    state = RelaxedState.from_arrays({**state.to_arrays(), "w": far})
    d = np.random.default_rng(2).normal(size=(5, 2, 2))
    F = F0 + 1e-4 * d / np.linalg.norm(d, axis=(1, 2))[:, None, None]
    F[1] = F0 + 3e-3 * np.array([[0.6, 0.8], [0.0, 0.0]])
    F[2] = F0
    W, P, A, new = RelaxedRVE(packing, K_N).evaluate(F, state)
    for q in range(5):
        eq = rve.equilibrium(F[q], state, q)
        assert abs(W[q] - eq.W) <= 1e-12 * abs(eq.W)
        assert np.abs(P[q] - eq.P).max() <= 1e-11 * np.abs(eq.P).max()
        assert np.abs(A[q] - eq.A).max() <= 1e-10 * np.abs(eq.A).max()
        assert np.abs(new.w[q] - eq.w).max() <= 1e-9 * np.abs(eq.w).max()
        assert (
            np.abs(new.sensitivity[q] - eq.sensitivity).max() <= 1e-8 * np.abs(eq.sensitivity).max()
        )
    _, P2, without = RelaxedRVE(packing, K_N).stress(F, state)
    assert np.abs(P2 - P).max() <= 1e-11 * np.abs(P).max() and not without.sensitivity.any()
    np.testing.assert_array_equal(without.network, new.network)
