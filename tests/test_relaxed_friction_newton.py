"""The compiled Newton loop of the frictional relaxed RVE (laws/relaxed_friction/newton_kernel.py):
its residual and merit against the Python cell state's, its hand-backs (a contact beyond the block
pattern, a trial beyond the Verlet skin) and what run() does with them, and its counts."""

from dolfinx_granular import FrictionalRelaxedRVE, generate_packing
from dolfinx_granular.laws.relaxed.newton import visited
from dolfinx_granular.laws.relaxed_friction import cell_state
from dolfinx_granular.laws.relaxed_friction import newton_kernel as nk
from dolfinx_granular.laws.relaxed_friction.block_lu import BlockLU
from dolfinx_granular.laws.relaxed_friction.cell_state import CellState
from dolfinx_granular.laws.relaxed_friction.newton import Counts, solve
from dolfinx_granular.laws.relaxed_friction.point import predicted
from dolfinx_granular.laws.tools import CHUNK, chunks

import numpy as np
import pytest

F1 = np.diag([0.99, 0.99])
F2 = np.array([[0.99, 0.003], [0.001, 0.991]])


@pytest.fixture(scope="module")
def start():
    """A frictional relaxed cell committed at F1 and the predicted start of its increment to
    F2: ``(rve, inc, w, th)``."""
    rve = FrictionalRelaxedRVE(generate_packing(70, seed=1), 1e8, 1e8, friction=0.3)
    committed = rve.evaluate(F1, rve.initial_state(1))[3]
    inc = rve.increment(committed, 0)
    w, th = predicted(inc.w0, inc.th0, committed.sensitivity[0], inc.F0, F2)
    return rve, inc, w, th


def _arguments(rve, inc, F):
    cell = rve.cell
    return (
        inc.arrays(cell.pi.shape[0]),
        nk.cell_arrays(cell),
        nk.spring_arrays(rve.springs),
    )


def test_its_residual_is_the_cell_states(start):
    rve, inc, w, th = start
    cell = rve.cell
    s = CellState(cell, rve.springs, F2, w, th, inc)
    k = nk.cell_state(F2, w, th, *_arguments(rve, inc, F2), s.m)
    assert np.array_equal(k[8], s.status) and np.allclose(
        k[14], s.r, rtol=0, atol=1e-12 * abs(s.r).max()
    )
    residual, floor = nk.residual(k, cell.R, cell.radii)
    assert residual == pytest.approx(s.residual(cell)[0], rel=1e-12)
    assert floor == pytest.approx(s.residual(cell)[1], rel=1e-9)
    assert residual > 1e-6  # (a start, not an equilibrium)


def _pattern(cell, cover):
    p, lu, cover = cell.block_pattern(-1, cover, d=3, new_factor=BlockLU.on)
    return nk.pattern_arrays(p, cover), lu.arrays()


def test_a_contact_beyond_the_pattern_hands_back_and_run_takes_a_longer_one(start):
    rve, inc, w, th = start
    cell = rve.cell
    F_smin = float(np.linalg.svd(F2, compute_uv=False)[-1])
    pattern, lu = _pattern(cell, 3)
    history, counts = np.empty(100), np.zeros(4, np.int64)
    code, why, w_out, _, _ = nk.newton(
        F2, F_smin, w, th, *_arguments(rve, inc, F2), cell.geometry(), cell.verlet(), pattern,
        lu, 1e-10, 60, history, counts,
    )  # fmt: skip
    assert (code, why) == (nk.HAND_BACK, nk.BEYOND_PATTERN) and np.array_equal(w_out, w)
    tally = Counts()
    code, _, w_end, th_end = nk.run(cell, rve.springs, F2, w, th, inc, rve.settings, tally)
    assert code == nk.CONVERGED and tally.factorisations >= 1
    s = CellState(cell, rve.springs, F2, w_end, th_end, inc)
    assert s.residual(cell)[0] <= rve.settings.force_tol
    assert tally.history[-1] == pytest.approx(s.residual(cell)[0], rel=1e-6, abs=1e-14)


def test_the_list_grown_around_an_iterate_and_a_trial_holds_both(start):
    rve, inc, w, _ = start
    cell = rve.cell
    reached = w.copy()
    reached[5] += 0.8 * cell.R.min()  # one disk past the sorted list and any Verlet skin
    F_smin = float(np.linalg.svd(F2, compute_uv=False)[-1])
    assert visited(F_smin, reached, cell.geometry(), cell.verlet()) == -1  # (must grow)
    nk._grow(cell, F2, w, reached)
    geo, verlet = cell.geometry(), cell.verlet()
    for x in (w, reached, 0.5 * (w + reached)):
        assert visited(F_smin, x, geo, verlet) >= 0


def test_a_start_that_grows_the_list_is_solved_with_a_force_for_every_candidate():
    """Positions that reach past the sorted list (as FIRE's can) grow it before Newton: the
    committed forces must cover the new candidates (they are read by index)."""
    rve = FrictionalRelaxedRVE(generate_packing(70, seed=1), 1e8, 1e8, friction=0.3)
    committed = rve.evaluate(F1, rve.initial_state(1))[3]
    inc = rve.increment(committed, 0)
    w, th = predicted(inc.w0, inc.th0, committed.sensitivity[0], inc.F0, F2)
    w[5] += 0.8 * rve.cell.R.min()  # (past the sorted list: the list must grow)
    before, counts = rve.cell.pi.shape[0], Counts()
    nk.run(rve.cell, rve.springs, F2, w, th, inc, rve.settings, counts)
    assert rve.cell.pi.shape[0] > before and inc.ft0.shape[0] == rve.cell.pi.shape[0]
    s = CellState(rve.cell, rve.springs, F2, w, th, inc)
    assert counts.history[0] == pytest.approx(s.residual(rve.cell)[0], rel=1e-9)


def test_a_missing_committed_force_is_refused(start):
    """The compiled loop reads the committed forces and rolling moments by candidate index: a
    list shorter than the candidates' is an error, not a read past its end."""
    rve, inc, w, th = start
    cell = rve.cell
    F_smin = float(np.linalg.svd(F2, compute_uv=False)[-1])
    pattern, lu = _pattern(cell, cell.pi.shape[0])
    args = list(_arguments(rve, inc, F2))
    full = args[0]
    for short in (3, 4):  # (a tangential force, a rolling moment)
        args[0] = tuple(a[:-1] if k == short else a for k, a in enumerate(full))
        with pytest.raises(ValueError, match=r"rolling moment\) is missing for a candidate"):
            nk.newton(F2, F_smin, w, th, *args, cell.geometry(), cell.verlet(), pattern, lu,
                      1e-10, 60, np.empty(100), np.zeros(4, np.int64))  # fmt: skip


def test_solve_counts_what_it_did(start):
    rve, inc, w, th = start
    counts = Counts()
    w_end, th_end, s, residual = solve(rve.cell, rve.springs, F2, w, th, inc, rve.settings,
                                       counts)  # fmt: skip
    assert residual <= rve.settings.force_tol and s.residual(rve.cell)[0] == residual
    assert counts.steps == len(counts.history) - 1 >= 1
    assert 1 <= counts.factorisations <= counts.steps and counts.chord_steps >= 0
    assert counts.history[0] > 1e3 * counts.history[-1]  # (from a start far from it)


def test_newtons_step_turns_an_all_slipping_disk_back_into_the_cone():
    """Disk 0 touches disks 1 and 2, both contacts slipping: the moment r[0, 2] > 0 turns it
    clockwise (d theta < 0), which lowers the trial force of the contact with f* < 0 (d f* /
    d theta = -k_t r): its diagonal makes the step put that contact DEPTH into the cone. The
    tangent's diagonal stays k_t r^2 per slipping contact / V."""
    kn, kt, mu, inv_area = 1e8, 5e7, 0.5, 2.0
    radii = np.array([0.3, 0.2, 0.25])
    pi, pj = np.array([0, 0]), np.array([1, 2])
    status = np.array([cell_state.SLIP, cell_state.SLIP], np.int8)
    e = np.array([4e-8, 6e-8])
    fstar = np.array([-10.0, 8.0])  # (caps 2 and 3: both far outside the cone)
    r = np.zeros((3, 3))
    r[0, 2] = 0.5
    no_rolling = np.zeros(2, np.int8)
    args = (status, no_rolling, np.ones(2, bool), np.ones(3, bool), pi, pj, radii, r, fstar,
            np.zeros(2), e, kn, kt, mu, 0.0, 0.0, inv_area, 1, 1.0,
            cell_state.RATTLER_SHIFT)  # fmt: skip
    newton_diag = cell_state.diagonal(*args, False, 1.0)
    turn = -r[0, 2] / newton_diag[2]
    assert fstar[0] - kt * radii[0] * turn == pytest.approx(-(1 - cell_state.DEPTH) * 2.0)
    tangent_diag = cell_state.diagonal(*args, True, 1.0)
    assert tangent_diag[2] == pytest.approx(kt * radii[0] ** 2 * 2 * inv_area)
    r[0, 2] = -0.5  # (turning the other way lowers the second contact's)
    newton_diag = cell_state.diagonal(*args, False, 1.0)
    turn = -r[0, 2] / newton_diag[2]
    assert fstar[1] - kt * radii[0] * turn == pytest.approx((1 - cell_state.DEPTH) * 3.0)


def test_newtons_step_turns_a_rolling_disk_back_inside_its_cap():
    """As above with rolling springs: disk 0's sliding contacts do not bound its turn (the turn
    raises their trial forces), its first rolling spring does (d m*/d theta_i = k_r): the step
    puts that moment DEPTH inside its cap mu_r r_eff k_n e."""
    kn, kt, mu, inv_area, mu_r = 1e8, 5e7, 0.5, 2.0, 0.1
    radii = np.array([0.3, 0.2, 0.25])
    pi, pj = np.array([0, 0]), np.array([1, 2])
    slip = np.array([cell_state.SLIP, cell_state.SLIP], np.int8)
    e = np.array([4e-8, 6e-8])
    fstar = np.array([10.0, 8.0])
    reff = radii[0] * radii[1:] / (radii[0] + radii[1:])
    rcap = mu_r * reff * kn * e
    mstar = np.array([5.0 * rcap[0], -5.0 * rcap[1]])
    r = np.zeros((3, 3))
    r[0, 2] = 0.5  # (the turn d theta < 0 raises both trial forces: r f* > 0)
    args = (slip, slip, np.ones(2, bool), np.ones(3, bool), pi, pj, radii, r, fstar, mstar, e,
            kn, kt, mu, kt, mu_r, inv_area, 1, 1.0, cell_state.RATTLER_SHIFT)  # fmt: skip
    turn = -r[0, 2] / cell_state.diagonal(*args, False, 1.0)[2]
    assert turn < 0.0
    k_r = kt * reff[0] ** 2
    assert mstar[0] + k_r * turn == pytest.approx((1 - cell_state.DEPTH) * rcap[0])
    r[0, 2] = -0.5  # (the other way: the second spring's moment, before the trial forces')
    turn = -r[0, 2] / cell_state.diagonal(*args, False, 1.0)[2]
    k_r = kt * reff[1] ** 2
    assert mstar[1] + k_r * turn == pytest.approx(-(1 - cell_state.DEPTH) * rcap[1])


def test_a_disk_that_barely_touches_is_a_rattler():
    """Disks 0-3 hold each other on overlaps near 1e-3; disk 4 touches 0 and 1 with overlaps a
    millionth of the mean and less: it counts as loose (as Newton then treats it: pushed off)."""
    pi = np.array([0, 0, 1, 0, 1, 2, 0, 1])
    pj = np.array([1, 2, 2, 3, 3, 3, 4, 4])
    e = np.array([1e-3, 2e-3, 1e-3, 1.5e-3, 1e-3, 2e-3, 3e-10, 2e-10])
    keep = cell_state.holding(pi, pj, e, 5)
    assert keep.tolist() == [True, True, True, True, False]
    e[6:] = 1e-4  # (a tenth of the mean: it holds)
    assert cell_state.holding(pi, pj, e, 5).all()


def test_the_entries_take_every_argument_in_chunks_numba_types_from_its_cache(start):
    """What crosses from Python into the compiled loop: every tuple in chunks of at most 4
    items, joined back to the tuple it was, each with a type fingerprint Numba caches (at most
    40 bytes: Numba before 0.57 corrupts a longer one and types it in Python at every call)."""
    from numba import _dispatcher

    rve, inc, w, th = start
    cell = rve.cell
    s = CellState(cell, rve.springs, F2, w, th, inc)
    pattern, lu = _pattern(cell, s.m)
    long = (*_arguments(rve, inc, F2), cell.geometry(), pattern, s.arrays())
    for t in long:
        parts = chunks(t)
        assert sum(parts, ()) == t and all(0 < len(c) <= CHUNK for c in parts)
        for c in parts:
            fingerprint = _dispatcher.compute_fingerprint(c)
            assert len(fingerprint) <= 40 and fingerprint == _dispatcher.compute_fingerprint(c)
    assert max(len(_dispatcher.compute_fingerprint(t)) for t in long) > 40  # (why chunks)
    code, held, statuses = nk.factorise(F2, s.arrays(), *_arguments(rve, inc, F2)[1:], pattern,
                                        lu, 0.0, False, 1.0)  # fmt: skip
    again = nk.factorise_entry(F2, *chunks(s.arrays()), *chunks(nk.cell_arrays(cell)),
                               nk.spring_arrays(rve.springs), *chunks(pattern), lu, 0.0, False,
                               1.0)  # fmt: skip
    assert code == again[0] and np.array_equal(held, again[1])
    assert np.array_equal(statuses, again[2])
