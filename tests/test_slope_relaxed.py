"""The confined slope at reduced size (2 rows: 40 cells, 160 RVEs of 70 disks): the confinement
traction balances the RVEs' reference stress, and the relaxed slope takes its first gravity step
with a few Newton steps, settles more than the Taylor slope of the same confined packing and
draws its relaxed force networks."""

import numpy as np
import pytest

pytest.importorskip("dolfinx")
from dolfinx_granular import generate_packing  # noqa: E402
from dolfinx_granular.slope.geometry import SlopeGeometry  # noqa: E402
from dolfinx_granular.slope.run import SlopeOptions, run_slope  # noqa: E402

from helpers import is_png  # noqa: E402

CONFINEMENT = 2.8e5  # Pa: p / k_n = 1e-2
COMMON = dict(confinement=CONFINEMENT, gravity_steps=20, geometry=SlopeGeometry(rows=2))


@pytest.fixture(scope="module")
def packing():
    return generate_packing(70, seed=0, pressure=CONFINEMENT / 2.8e7)


def _solve_at_rest(packing, confined):
    """Newton (one step at most) from u = 0 without gravity or footing load."""
    from dolfinx_granular.slope.model import SlopeModel, newton_solver

    from mpi4py import MPI

    o = SlopeOptions(**COMMON)
    model = SlopeModel(
        MPI.COMM_WORLD,
        o.law(packing),
        o.geometry,
        solver_factory=lambda *a: newton_solver(*a, max_it=1),
        confined=confined,
    )
    model.set_gravity(0.0)
    result = model.solver.solve()
    model.solver.destroy()
    return result


@pytest.mark.mpi
def test_the_confinement_traction_balances_the_reference_stress(packing):
    balanced = _solve_at_rest(packing, confined=True)
    assert balanced.converged and balanced.iterations == 0
    assert balanced.residual_norm <= 1e-9 * CONFINEMENT * COMMON["geometry"].width
    assert not _solve_at_rest(packing, confined=False).converged  # P(I) alone is unbalanced


@pytest.mark.slow
def test_the_relaxed_slope_settles_more_than_taylor(packing, tmp_path):
    relaxed = run_slope(
        packing,
        SlopeOptions(rve="relaxed", **COMMON),
        out=tmp_path / "relaxed",
        stop_after=1,
        verbose=False,
    )
    taylor = run_slope(
        packing, SlopeOptions(**COMMON), out=tmp_path / "taylor", stop_after=1, figure=False
    )
    assert relaxed["status"] == taylor["status"] == "stopped"
    assert relaxed["rve"] == "relaxed" and relaxed["confinement"] == CONFINEMENT
    assert 2 <= relaxed["iterations"][0] <= 6  # the consistent tangent: a few Newton steps
    settle = [s["step_info"][-1]["settlement"] for s in (relaxed, taylor)]
    assert settle[0] < settle[1] < 0.0, settle  # down, and further down with relaxation
    assert is_png(tmp_path / "relaxed" / "slope.png")
    assert np.isfinite(relaxed["max_von_mises"])
