"""The relaxed RVE in DOLFINx: GranularMaterial holds its state like any history law, the
consistent tangent makes Newton converge superlinearly, and relaxation softens the column."""

from dolfinx_granular import TaylorRVE, generate_packing
from dolfinx_granular.laws.relaxed import RelaxedRVE

import numpy as np
import pytest
from mpi4py import MPI

from helpers import granular_column

K_N = 2.8e7
PRESSURE = 2e4  # Pa on the column's top


@pytest.fixture(scope="module")
def packing():
    return generate_packing(70, seed=4)


def settle(rve, prefix):
    """Settlement of the column's top corner (m) and the solve's energy-norm history."""
    solver, material, u, p = granular_column(rve, prefix, n=2)
    p.value = PRESSURE
    result = solver.solve()
    assert result.converged, result.reason_name
    uy = u.x.array.reshape(-1, 2)[:, 1]
    settlement = MPI.COMM_WORLD.allreduce(float(uy.min()) if uy.size else 0.0, op=MPI.MIN)
    solver.destroy()
    return settlement, [h[2] for h in result.history], material


@pytest.mark.slow
@pytest.mark.mpi
def test_the_relaxed_column_converges_superlinearly_and_is_softer(packing):
    relaxed, history, material = settle(RelaxedRVE(packing, K_N), "relaxed_col_")
    taylor, _, _ = settle(TaylorRVE(packing, K_N), "taylor_col_")
    assert relaxed < taylor < 0.0  # downward, and further down with relaxation
    tail = [e for e in history if 1e-25 < e < 1e-4]
    rates = [np.log(b) / np.log(a) for a, b in zip(tail[:-1], tail[1:])]
    assert rates and max(rates) > 1.5, history  # the last steps are quadratic
    moved = MPI.COMM_WORLD.allreduce(float(material.state.fluctuation.max()), op=MPI.MAX)
    assert moved > 0.0  # the committed state holds the relaxed positions
