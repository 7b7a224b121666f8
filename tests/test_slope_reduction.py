"""Strength reduction by continuation on the confined slope at reduced size (2 rows: 40 cells,
160 frictional relaxed RVEs of 70 disks): after the weight, the ``reduction`` phase lowers the
contact friction at the whole load, step by step; every RVE is then back inside its smaller
cones, the slope settles further, and a run stopped in the phase resumes to the same state."""

import numpy as np
import pytest

pytest.importorskip("dolfinx")
from dolfinx_granular import generate_packing  # noqa: E402
from dolfinx_granular.slope.geometry import SlopeGeometry  # noqa: E402
from dolfinx_granular.slope.run import (  # noqa: E402
    SlopeOptions,
    SlopeRun,
    _tolerated_note,
    load_restart,
)

CONFINEMENT = 2.8e5  # Pa: p / k_n = 1e-2
MU = 0.5
OPTIONS = dict(
    rve="relaxed",
    friction=MU,
    confinement=CONFINEMENT,
    gravity_steps=4,
    load_factor=0.0,
    geometry=SlopeGeometry(rows=2),
    reduction=MU / 64,
    reduction_steps=16,
)
#: the weight in 4 steps, then 2 reduction steps (mu = 0.5 / 64^(t) at t = 1/16, 2/16 without
#: a cut-back: 0.39, 0.30)
STEPS = 6


def _shared(folder):
    """One folder for every rank (rank 0's; pytest gives each process its own)."""
    from mpi4py import MPI

    return MPI.COMM_WORLD.bcast(str(folder) if MPI.COMM_WORLD.rank == 0 else None, root=0)


@pytest.fixture(scope="module")
def packing():
    return generate_packing(70, seed=0, pressure=CONFINEMENT / 2.8e7)


def _run(packing, out, stop_after, restart=None):
    """The SlopeRun after ``stop_after`` converged steps (its model kept for the tests)."""
    run = SlopeRun(
        packing,
        None if restart else SlopeOptions(**OPTIONS),
        out,
        verbose=False,
        restart=restart,
        stop_after=stop_after,
    )
    run.run()
    return run


@pytest.fixture(scope="module")
def reduced(packing, tmp_path_factory):
    return _run(packing, _shared(tmp_path_factory.mktemp("reduced")), STEPS)


def test_the_phases_are_the_weight_then_the_reduction():
    o = SlopeOptions(**OPTIONS)
    assert o.phases == ("gravity", "reduction")
    assert o.reduced_friction(0.0) == (MU, 0.0)
    assert o.reduced_friction(1.0)[0] == pytest.approx(MU / 64, rel=1e-14)
    footing = SlopeOptions(**{**OPTIONS, "load_factor": 0.5, "rolling_friction": 0.1})
    assert footing.phases == ("gravity", "footing", "reduction")
    mu, mu_r = footing.reduced_friction(0.5)
    assert mu == pytest.approx(MU / 8) and mu_r == pytest.approx(0.1 / 8)


@pytest.mark.parametrize(
    "change, words",
    [
        (dict(rve="taylor"), "frictional relaxed RVE"),
        (dict(friction=0.0), "frictional relaxed RVE"),
        (dict(reduction=0.6), r"in \(0, friction"),
        (dict(reduction=0.0), r"in \(0, friction"),
        (dict(path_following="gravity"), "drop --path-following"),
        (dict(reduction_steps=0), "reduction_steps must be an integer >= 1"),
    ],
)
def test_bad_reductions_are_named(change, words):
    with pytest.raises(ValueError, match=words):
        SlopeOptions(**{**OPTIONS, **change})


def test_a_step_accepted_out_of_balance_says_so_in_its_line():
    """A step that --residual-tolerance accepted says its residual; one at round-off does not."""
    tolerated = {"converged_by": "tolerance", "residual_norm": 4692.1}
    assert _tolerated_note(tolerated) == ", out of balance by 4.69e+03 N (--residual-tolerance)"
    assert _tolerated_note({**tolerated, "converged_by": "round-off"}) == ""


@pytest.mark.mpi
def test_the_reduction_lowers_the_friction_of_every_rve(reduced):
    """The steps' frictions fall geometrically at the whole weight; the law's friction is the
    last one's; every contact of every RVE (this rank's) lies in its new cone, some on it; the
    slope settles further and dissipates more as mu falls."""
    info = reduced.step_info
    assert [s["phase"] for s in info] == ["gravity"] * 4 + ["reduction"] * 2
    assert all(s["gravity"] == 1.0 for s in info[3:])
    mus = [s["friction"] for s in info]
    assert mus[:4] == [MU] * 4
    o = reduced.options
    assert mus[4:] == [o.reduced_friction(s["t"])[0] for s in info[4:]]
    assert MU > mus[4] > mus[5] > MU / 64
    law, material = reduced.law, reduced.model.material
    assert law.friction == mus[-1]
    state = material.state
    sliding = 0
    for q in range(0, material.n_points, 7):
        c = law.contacts(state.F[q], state.take([q]))
        assert np.all(np.abs(c.tangential) <= law.friction * c.force * (1 + 1e-12))
        sliding += int(c.sliding.sum())
    assert sliding > 0
    settle = [s["settlement"] for s in info[3:]]
    assert abs(settle[2]) > abs(settle[1]) > abs(settle[0])
    dissipated = [s["dissipated_energy"] for s in info[3:]]
    assert dissipated[2] > dissipated[1] > dissipated[0]


@pytest.mark.slow
def test_a_run_stopped_in_the_reduction_resumes_to_the_same_state(packing, reduced, tmp_path):
    """Stopped after the first reduction step and resumed (the friction of that step set again
    from the phase's t): the second step ends where the straight run's did."""
    out = _shared(tmp_path)
    _run(packing, out, STEPS - 1)
    resumed = _run(packing, out, STEPS, restart=load_restart(out))
    assert resumed.law.friction == reduced.law.friction
    a, b = reduced.step_info[-1], resumed.step_info[-1]
    assert a["t"] == b["t"] and a["friction"] == b["friction"]
    assert abs(b["settlement"] - a["settlement"]) <= 1e-9 * abs(a["settlement"])
    u0, u1 = reduced.model.u.x.array, resumed.model.u.x.array
    assert np.abs(u1 - u0).max() <= 1e-9 * np.abs(u0).max()
