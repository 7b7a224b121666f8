"""The frictional RVE in DOLFINx: GranularMaterial with history, commit only at converged solves,
the slope with friction and unloading (permanent settlement, dissipation), restarts that carry
the history, and serial = MPI."""

import json

from dolfinx_granular import generate_packing
from dolfinx_granular.drivers.loading import LoadStepper
from dolfinx_granular.laws.friction import FrictionalRVE

import numpy as np
import pytest
from mpi4py import MPI

from helpers import granular_column, run_slope_demo

K_N = 2.8e7


def frictional_rve(mu=0.5, n=70, seed=4):
    return FrictionalRVE(
        generate_packing(n, seed=seed), normal_stiffness=K_N, tangential_stiffness=K_N, friction=mu
    )


@pytest.mark.mpi
def test_history_is_committed_only_by_converged_solves():
    """Every evaluation starts from the committed state; a converged solve commits the state of
    its answer, a failed one (a crushing load) leaves the committed state and u as they were."""
    solver, material, u, p = granular_column(frictional_rve(), "fric_commit_", n=4)
    initial = material.state
    p.value = 2e5
    result = solver.solve()
    assert result.converged and material.state is not initial
    assert material.state is material.trial_state
    committed, u_good = material.state, u.x.array.copy()
    assert MPI.COMM_WORLD.allreduce(float(np.abs(committed.force).sum())) > 0  # forces built up
    p.value = 3e7  # far beyond what the column carries
    assert not solver.solve().converged
    assert material.state is committed and np.array_equal(u.x.array, u_good)
    # the data belong to u from the committed state: evaluating there changes nothing (values
    # equal; a zero force may come back as -0.0)
    trial = material.trial_state
    assert all(
        np.array_equal(getattr(trial, k), getattr(committed, k))
        for k in ("F", "dissipation", "offsets", "force")
    )
    solver.destroy()


@pytest.mark.mpi
def test_newton_converges_superlinearly_with_sliding_contacts():
    solver, material, u, p = granular_column(frictional_rve(0.3), "fric_newton_", n=6)
    stepper = LoadStepper(solver)
    rates = []

    def record(step, t, result):
        e = [h[2] for h in result.history]
        rates.extend(np.log(b) / np.log(a) for a, b in zip(e[:-1], e[1:]) if 1e-25 < a < 1e-2)

    assert stepper.run("press", lambda t: setattr(p, "value", 6e5 * t), 0.25, on_converged=record)
    assert rates and min(rates) > 1.3, rates  # superlinear (quadratic up to the slip switches)
    assert MPI.COMM_WORLD.allreduce(material.dissipated_energy()) > 0
    solver.destroy()


def run_demo(out, *args, ranks=1):
    """The 70-particle frictional slope (mu = 0.5, unloaded) in ``out``; its summary."""
    options = ("--particles", "70", "--seed", "1", "--steps", "2", "--friction", "0.5", "--unload")
    return run_slope_demo(out, *options, "--no-figure", *args, ranks=ranks)[1]


@pytest.fixture(scope="module")
def friction_run(tmp_path_factory):
    return run_demo(tmp_path_factory.mktemp("friction"))


@pytest.mark.slow
def test_footing_leaves_a_permanent_settlement(friction_run):
    s = friction_run
    assert s["converged"] and s["friction"] == 0.5 and s["steps"] == 5
    phases = [i["phase"] for i in s["step_info"]]
    assert phases == ["gravity", "footing", "footing", "unloading", "unloading"]
    gravity, loaded, unloaded = (s["step_info"][k]["settlement"] for k in (0, 2, 4))
    assert loaded < unloaded < gravity  # down under load, back up, not all the way
    assert s["permanent_settlement"] == pytest.approx(unloaded - gravity, rel=1e-12)
    assert s["permanent_settlement"] < -0.01  # more than a centimetre stays
    D = [i["dissipated_energy"] for i in s["step_info"]]
    assert D[0] > 0 and all(b >= a for a, b in zip(D, D[1:])) and D[-1] == s["dissipated_energy"]


@pytest.mark.slow
def test_friction_serial_and_two_ranks_agree(tmp_path, friction_run):
    two = run_demo(tmp_path / "np2", ranks=2)
    for key in ("footing_settlement", "permanent_settlement", "dissipated_energy", "max_von_mises"):
        assert abs(two[key] - friction_run[key]) <= 1e-10 * abs(friction_run[key]), key


@pytest.mark.slow
def test_resume_carries_the_history(tmp_path, friction_run):
    """Stopped after the first footing step and resumed, on one rank and on two: the restart
    file carries the contacts' tangential forces, and the answer is the uninterrupted one."""
    for ranks in (1, 2):
        out = tmp_path / f"r{ranks}"
        run_demo(out, "--stop-after", "2")
        with np.load(out / "restart.npz") as f:
            assert {"history_force", "history_points", "history_F"} <= set(f.files)
            # one reference point (x, y) per RVE of the run
            assert f["history_points"].shape == (friction_run["rves"], 2)
        run_slope_demo(None, "--resume", out, "--no-figure", ranks=ranks)
        resumed = json.loads((out / "summary.json").read_text())
        for key in ("footing_settlement", "permanent_settlement", "dissipated_energy"):
            tol = 1e-12 if ranks == 1 else 1e-10
            assert abs(resumed[key] - friction_run[key]) <= tol * abs(friction_run[key]), key


def test_frictionless_default_is_the_taylor_rve():
    from dolfinx_granular.laws.taylor import TaylorRVE
    from dolfinx_granular.slope import SlopeOptions

    packing = generate_packing(20, seed=1)
    assert type(SlopeOptions().law(packing)) is TaylorRVE
    law = SlopeOptions(friction=0.3).law(packing)
    assert isinstance(law, FrictionalRVE) and law.tangential_stiffness == law.normal_stiffness
