"""The relaxed RVE in DOLFINx: GranularMaterial holds its state like any history law, the
consistent tangent makes Newton converge superlinearly, and relaxation softens the column."""

import json
import os
import subprocess
import sys
import warnings

from dolfinx_granular import (
    LoadPathWarning,
    LoadStepper,
    SolveFailedWarning,
    TaylorRVE,
    generate_packing,
)
from dolfinx_granular.laws.relaxed import RelaxedRVE

import numpy as np
import pytest
from mpi4py import MPI

from helpers import MPI_ENV, ROOT, granular_column

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


@pytest.mark.mpi
def test_an_unconfined_relaxed_column_says_why_and_what_to_do():
    """The issue: RelaxedRVE swapped into the README column printed '0 Newton steps, converged:
    False', the reason only in result.error. The stress-free packing unjams at the first
    iterate: the solve warns once with the reason and names the confined packing and the
    holding traction; a load stepper that gives up does the same, once."""
    solver, _, _, p = granular_column(
        RelaxedRVE(generate_packing(70, seed=1), K_N), "unconfined_", n=4
    )
    p.value = 1e5
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        result = solver.solve()
        stepper = LoadStepper(solver, max_cutbacks=0)
        assert not stepper.run("press", lambda t: setattr(p, "value", 1e5 * t), 1.0)
    said = [w for w in record if issubclass(w.category, (SolveFailedWarning, LoadPathWarning))]
    assert not result.converged and [w.category for w in said] == [
        SolveFailedWarning,
        LoadPathWarning,
    ]
    # (the reason is this rank's: where its own RVEs failed to relax)
    assert result.why.rstrip(".") in str(said[0].message)
    for w in said:
        message = str(w.message)
        assert "Remedy: a RelaxedRVE on a stress-free packing" in message, message
        assert "confined_packing(packing" in message and "holding_traction(material)" in message
    solver.destroy()


SETTLE = """
import json
from mpi4py import MPI
from dolfinx_granular import RelaxedRVE, generate_packing
from test_relaxed_dolfinx import settle
s, history, _ = settle(RelaxedRVE(generate_packing(70, seed=4), 2.8e7), "relaxed_np_")
if MPI.COMM_WORLD.rank == 0:
    print(json.dumps(dict(settlement=s, iterations=len(history) - 1)))
"""


def _settle(ranks):
    """The relaxed column's settlement and iterations, solved on ``ranks`` processes."""
    from dolfinx_granular.fem.compat import mpi_command

    cmd = [sys.executable, "-c", SETTLE]
    if ranks > 1:
        cmd = [*mpi_command(ranks), *cmd]
    env = dict(MPI_ENV, PYTHONPATH=os.path.join(ROOT, "tests"))
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_serial_and_two_ranks_agree():
    """Every point relaxes on its own rank: the partition changes only the summation order."""
    one, two = _settle(1), _settle(2)
    assert one["iterations"] == two["iterations"]
    np.testing.assert_allclose(two["settlement"], one["settlement"], rtol=1e-12)
