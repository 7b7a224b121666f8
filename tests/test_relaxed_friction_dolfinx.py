"""The frictional relaxed RVE in DOLFINx: GranularMaterial holds its state like any history law
(commit at converged solves only, restore, the restart files' point order), Newton converges on
its non-symmetric tangent with the direct and the iterative linear solver, serial = 2 ranks, and
the slope builds it for ``--rve relaxed --friction MU`` and resumes it."""

import json
import os
import subprocess
import sys
from types import SimpleNamespace

from dolfinx_granular import (
    FrictionalRelaxedRVE,
    FrictionalRelaxedState,
    RelaxedRVE,
    generate_packing,
)
from dolfinx_granular.drivers.confinement import confined_packing
from dolfinx_granular.drivers.protocol import unconfined_relaxed

import numpy as np
import pytest
from mpi4py import MPI

from helpers import MPI_ENV, ROOT, granular_column

K_N = 2.8e7
PK = 1e-2  # the confining pressure over k_n: 2.8e5 Pa
MU = 0.5
LOADS = (1e4, 2e4)  # Pa on the column's top, on top of the confinement


def confined(seed=0):
    """70 disks jammed at p / k_n = PK, compressed to it and relaxed."""
    return confined_packing(generate_packing(70, seed=seed, pressure=PK), K_N, PK)


@pytest.fixture(scope="module")
def packing():
    return confined()


def frictional(packing, rolling=0.0):
    """The law under test: k_t = k_n, mu = MU, rolling friction ``rolling``."""
    return FrictionalRelaxedRVE(packing, K_N, K_N, MU, rolling_friction=rolling)


def press(rve, prefix, loads=LOADS, **solver_kwargs):
    """The held column of 2 x 2 cells (16 RVEs) pressed by ``loads`` (Pa) in turn:
    ``(Column, [SolveResult per load])``."""
    column = granular_column(rve, prefix, n=2, hold=True, **solver_kwargs)
    results = []
    for load in loads:
        column.p.value = load
        results.append(column.solver.solve())
    return column, results


def settlement(u):
    """The column top's largest downward displacement (m, < 0), the same on every rank."""
    uy = u.x.array[1::2]
    return MPI.COMM_WORLD.allreduce(float(uy.min(initial=0.0)), op=MPI.MIN)


def asymmetry(A):
    """(n,) max |A_abcd - A_cdab| / max |A_abcd| per point of tangents A (n, 2, 2, 2, 2)."""
    flat = A.reshape(len(A), 16)
    diff = np.abs(A - A.transpose(0, 3, 4, 1, 2)).reshape(len(A), 16)
    return diff.max(axis=1) / np.abs(flat).max(axis=1)


def matrix_asymmetry(J):
    """|J - J^T| / |J| (Frobenius) of an assembled PETSc matrix (collective)."""
    from petsc4py import PETSc

    T = PETSc.Mat()
    J.transpose(T)  # (a new matrix: J.transpose() alone transposes J in place)
    T.axpy(-1.0, J)
    ratio = T.norm(PETSc.NormType.FROBENIUS) / J.norm(PETSc.NormType.FROBENIUS)
    T.destroy()
    return ratio


def largest(values):
    """The largest of this rank's ``values`` over every rank (-inf where there are none)."""
    return MPI.COMM_WORLD.allreduce(float(np.max(values, initial=-np.inf)), op=MPI.MAX)


@pytest.mark.mpi
def test_newton_converges_on_the_non_symmetric_tangent(packing):
    """Sliding contacts make dP/dF non-symmetric at some points and the assembled Jacobian with
    them; LU takes it as it is and Newton converges superlinearly. The frictionless relaxed RVE
    of the same packing assembles a symmetric Jacobian (the measure's zero)."""
    (solver, material, u, _), results = press(frictional(packing), "frx_")
    assert all(r.converged for r in results), [r.reason_name for r in results]
    rates = []
    for r in results:
        e = [h[2] for h in r.history]
        rates += [np.log(b) / np.log(a) for a, b in zip(e[:-1], e[1:]) if 1e-25 < a < 1e-2]
    assert rates and max(rates) > 1.5, rates
    assert MPI.COMM_WORLD.allreduce(int(material.state.sliding.sum())) > 0
    assert material.dissipated_energy() > 0.0
    assert largest(asymmetry(material.tangent)) > 1e-3  # the law's A at the Gauss points
    assert matrix_asymmetry(solver.A) > 1e-4  # the Jacobian Newton factorised last
    assert settlement(u) < 0.0
    solver.destroy()
    (frictionless, *_), results = press(RelaxedRVE(packing, K_N), "frx_frictionless_")
    assert all(r.converged for r in results)
    assert matrix_asymmetry(frictionless.A) < 1e-12
    frictionless.destroy()


@pytest.mark.mpi
def test_gmres_and_lu_agree_on_the_non_symmetric_tangent(packing):
    """The iterative linear solver (GMRES + GAMG) reaches the direct one's answer."""
    answers = []
    for kind in ("direct", "iterative"):
        rve = frictional(packing)
        (solver, material, u, _), results = press(rve, f"frx_{kind}_", linear_solver=kind)
        assert all(r.converged for r in results), (kind, [r.reason_name for r in results])
        answers.append((settlement(u), material.dissipated_energy()))
        solver.destroy()
    np.testing.assert_allclose(answers[1], answers[0], rtol=1e-10)


@pytest.mark.mpi
def test_a_failed_solve_keeps_the_committed_state(packing):
    """A solve cut off after one Newton step leaves the committed state and u as they were; the
    next full solve commits its own state."""
    (solver, material, u, p), _ = press(frictional(packing), "frx_fail_")
    committed, u_good = material.state, u.x.array.copy()
    assert committed is material.trial_state and isinstance(committed, FrictionalRelaxedState)
    solver.max_it = 1
    p.value = 3e4
    assert not solver.solve(warn=False).converged
    assert material.state is committed and np.array_equal(u.x.array, u_good)
    solver.max_it = 20
    assert solver.solve().converged and material.state is not committed
    before = MPI.COMM_WORLD.allreduce(float(u_good[1::2].min(initial=0.0)), op=MPI.MIN)
    assert settlement(u) < before
    solver.destroy()


@pytest.mark.mpi
def test_rolling_resistance_in_the_column(packing):
    """With rolling friction the column converges superlinearly too, its points carry rolling
    moments (some on their caps), and it settles less than without them."""
    answers = []
    for rolling in (0.0, 0.1):
        (solver, material, u, _), results = press(frictional(packing, rolling), f"frx_r{rolling}_")
        assert all(r.converged for r in results), [r.reason_name for r in results]
        e = [h[2] for h in results[-1].history]
        rates = [np.log(b) / np.log(a) for a, b in zip(e[:-1], e[1:]) if 1e-25 < a < 1e-2]
        assert rates and max(rates) > 1.5, rates
        answers.append(settlement(u))
        moments = MPI.COMM_WORLD.allreduce(float(np.abs(material.state.rolling).sum()))
        assert (moments > 0.0) == (rolling > 0.0)
        solver.destroy()
    assert 0.0 > answers[1] > answers[0]


@pytest.mark.mpi
@pytest.mark.parametrize("rolling", [0.0, 0.1])
def test_the_state_round_trips_through_arrays_and_the_restart_order(packing, rolling):
    """export_state -> to_arrays -> from_arrays -> restore_state gives the very same P and A at
    the same u (the rolling moments too); PointOrder (the slope's restart files) moves it to a
    fresh material; a state of another law or size is refused."""
    from dolfinx_granular.io.runwriter import PointOrder

    rve = frictional(packing, rolling)
    (solver, material, u, _), _ = press(rve, f"frx_state{rolling}_")
    u_done = u.x.array.copy()
    material.update()  # at the converged u, from the committed state
    P, A = material.P.x.array.copy(), material.A.x.array.copy()
    saved = material.export_state()
    u.x.array[:] *= 1.2
    material.update()  # a trial state elsewhere, not committed
    assert material.state is saved and material.trial_state is not saved
    material.restore_state(FrictionalRelaxedState.from_arrays(saved.to_arrays()))
    assert material.state.equals(saved) and material.trial_state is material.state
    u.x.array[:] = u_done
    material.update()
    assert np.array_equal(material.P.x.array, P) and np.array_equal(material.A.x.array, A)
    order = PointOrder(MPI.COMM_WORLD, material.points, 1e-9)
    gathered = order.gather_material(material)
    arrays = MPI.COMM_WORLD.bcast(None if gathered is None else gathered.to_arrays(), root=0)
    X = MPI.COMM_WORLD.bcast(order.X, root=0)
    _, fresh, *_ = granular_column(rve, f"frx_state_fresh{rolling}_", n=2, hold=True)
    order.restore_material(fresh, arrays, X)
    assert fresh.export_state().equals(material.export_state())
    with pytest.raises(ValueError, match="restore_state needs a FrictionalRelaxedState of"):
        fresh.restore_state(saved.take(np.arange(saved.n_points - 1)))
    with pytest.raises(ValueError, match="restore_state needs a FrictionalRelaxedState of"):
        fresh.restore_state(RelaxedRVE(packing, K_N).initial_state(fresh.n_points))
    solver.destroy()


@pytest.mark.mpi
def test_the_slope_figure_marks_the_sliding_contacts(packing):
    """contact_network (figure 7's insets) takes a frictional relaxed point's sliding flags."""
    from dolfinx_granular.io.postprocess import contact_network

    rve = frictional(packing)
    (solver, material, *_), _ = press(rve, "frx_network_")
    state = material.state
    slid = [q for q in range(state.n_points) if state.contacts(q)[2].any()]
    if slid:  # (a rank whose points have none has nothing to check)
        q = slid[0]
        c, force, sliding = contact_network(rve, material.F[q], state.take([q]))
        assert sliding.any() and np.array_equal(sliding, c.sliding) and force.min() > 0.0
    assert MPI.COMM_WORLD.allreduce(len(slid)) > 0
    solver.destroy()


def test_an_unconfined_frictional_relaxed_rve_gets_the_remedy(packing):
    """The solvers' remedy for a relaxed RVE on a stress-free packing (confined_packing and
    holding_traction) names the frictional one too (its Coulomb limits vanish with the normal
    forces)."""
    free = frictional(generate_packing(70, seed=1))
    held = frictional(packing)
    assert unconfined_relaxed([SimpleNamespace(rve=free)])
    assert not unconfined_relaxed([SimpleNamespace(rve=held)])


def test_the_slope_options_build_the_frictional_relaxed_rve(packing):
    """--rve relaxed --friction MU: the FrictionalRelaxedRVE of the confined packing, k_t = k_n
    unless given; the command line accepts it."""
    from dolfinx_granular.slope.cli import build_parser, options_of
    from dolfinx_granular.slope.options import SlopeOptions

    raw = generate_packing(70, seed=0, pressure=PK)
    common = dict(rve="relaxed", friction=MU, confinement=PK * K_N)
    law = SlopeOptions(**common).law(raw)
    assert type(law) is FrictionalRelaxedRVE and law.friction == MU
    assert law.tangential_stiffness == law.normal_stiffness == K_N
    np.testing.assert_array_equal(law.packing.centers, packing.centers)
    law = SlopeOptions(**common, tangential_stiffness=1e7).law(raw)
    assert law.tangential_stiffness == 1e7 and law.normal_stiffness == K_N
    argv = ["--rve", "relaxed", "--friction", "0.5", "--confinement", "2.8e5"]
    options = options_of(build_parser().parse_args(argv))
    assert (options.rve, options.friction, options.confinement) == ("relaxed", 0.5, 2.8e5)
    assert "--friction > 0" in build_parser().format_help()


SLOPE = dict(rve="relaxed", friction=MU, confinement=PK * K_N, gravity_steps=20)


def slope_run(out, stop_after, restart=None):
    """The 2-row slope (160 RVEs) with the frictional relaxed RVE, stopped after a step."""
    from dolfinx_granular.slope.geometry import SlopeGeometry
    from dolfinx_granular.slope.run import SlopeOptions, run_slope

    run = dict(out=out, stop_after=stop_after, figure=False, verbose=False)
    if restart is not None:
        return run_slope(restart["packing"], restart=restart, **run)
    options = SlopeOptions(**SLOPE, geometry=SlopeGeometry(rows=2))
    raw = generate_packing(70, seed=0, pressure=PK)
    return run_slope(raw, options, **run)


@pytest.mark.slow
def test_the_frictional_relaxed_slope_resumes_to_the_same_answer(tmp_path):
    """Two gravity steps straight, and one then one more from the restart file (which carries
    the contacts' forces and the disks' rotations): the same settlements and dissipation (to
    round-off: the resumed law builds its candidate contacts afresh, in another order)."""
    from dolfinx_granular.slope.run import load_restart

    straight = slope_run(tmp_path / "straight", 2)
    assert straight["status"] == "stopped" and straight["rve"] == "relaxed"
    assert straight["friction"] == MU and straight["dissipated_energy"] > 0.0
    slope_run(tmp_path / "resumed", 1)
    with np.load(tmp_path / "resumed" / "restart.npz") as f:
        assert {"history_theta", "history_force", "history_keys"} <= set(f.files)
    resumed = slope_run(tmp_path / "resumed", 2, load_restart(tmp_path / "resumed"))
    assert resumed["iterations"] == straight["iterations"]
    for run in (straight, resumed):
        assert [s["phase"] for s in run["step_info"]] == ["gravity", "gravity"]
    np.testing.assert_allclose(
        [s["settlement"] for s in resumed["step_info"]],
        [s["settlement"] for s in straight["step_info"]],
        rtol=1e-9,
    )
    assert resumed["dissipated_energy"] == pytest.approx(straight["dissipated_energy"], rel=1e-9)


PRESS = """
import json
from mpi4py import MPI
from test_relaxed_friction_dolfinx import confined, frictional, press, settlement
(solver, material, u, _), results = press(frictional(confined(), ROLLING), "np_")
answer = dict(
    converged=[r.converged for r in results],
    iterations=[r.iterations for r in results],
    settlement=settlement(u),
    energy=material.integrate(material.W),
    dissipated=material.dissipated_energy(),
)
if MPI.COMM_WORLD.rank == 0:
    print(json.dumps(answer))
"""


def _press(ranks, rolling=0.0):
    """The column's answer (a dict), pressed on ``ranks`` processes (rolling friction
    ``rolling``)."""
    from dolfinx_granular.fem.compat import mpi_command

    cmd = [sys.executable, "-c", f"ROLLING = {rolling!r}" + PRESS]
    if ranks > 1:
        cmd = [*mpi_command(ranks), *cmd]
    env = dict(MPI_ENV, PYTHONPATH=os.path.join(ROOT, "tests"))
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.slow
@pytest.mark.parametrize("rolling", [0.0, 0.1])
def test_serial_and_two_ranks_agree(rolling):
    """Every point relaxes on its own rank: the partition changes only the summation order
    (with rolling resistance too)."""
    one, two = _press(1, rolling), _press(2, rolling)
    assert one["converged"] == two["converged"] == [True, True]
    assert one["iterations"] == two["iterations"]
    for key in ("settlement", "energy", "dissipated"):
        assert two[key] == pytest.approx(one[key], rel=1e-10), key
