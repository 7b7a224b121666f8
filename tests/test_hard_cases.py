"""The slope demo under hard loads at reduced size (70-particle RVE, 4 footing steps): the doubled
footing load and an uplift. Failed steps are cut back and logged; both loads exceed what the slope
can carry (a limit point of the load-settlement path), so the run stops at its last converged state
with every number finite and reports the limit load."""

import math

import numpy as np
import pytest

pytest.importorskip("dolfinx")
from dolfinx_granular import generate_packing  # noqa: E402
from dolfinx_granular.slope import SlopeOptions, load_restart, run_slope  # noqa: E402

from mpi4py import MPI  # noqa: E402

from helpers import read_outputs, run_slope_demo  # noqa: E402

PARTICLES, SEED, STEPS = 70, 1, 4
UPLIFT = -0.25  # the load factor of the uplift


def run(tmp_path, load_factor, **kwargs):
    options = SlopeOptions(steps=STEPS, load_factor=load_factor, **kwargs)
    summary = run_slope(
        generate_packing(PARTICLES, seed=SEED),
        options,
        out=str(tmp_path),
        comm=MPI.COMM_SELF,
        figure=False,
        verbose=False,
    )
    on_disk, rows = read_outputs(tmp_path)
    return summary, on_disk, rows


def check_consistent(summary, on_disk, rows):
    assert on_disk["completed_steps"] == summary["completed_steps"]
    assert on_disk["cutbacks"] == summary["cutbacks"]
    n = summary["completed_steps"]
    assert len(summary["iterations"]) == len(summary["step_info"]) == n
    # convergence.csv holds the converged steps only (one row per iterate), failed attempts are
    # in the cut-backs
    assert sorted({int(r["step"]) for r in rows}) == list(range(1, n + 1))
    assert sum(summary["iterations"]) + n == len(rows)
    ts = [(s["phase"], s["t"]) for s in summary["step_info"]]
    assert ts[0] == ("gravity", 1.0)
    footing_t = [t for phase, t in ts[1:]]
    assert all(b > a for a, b in zip(footing_t, footing_t[1:]))
    for cut in summary["cutbacks"]:
        assert cut["reason"] and cut["t_to"] > cut["t_from"]
    for key in ("footing_settlement", "max_von_mises", "min_von_mises", "min_singular_value_F"):
        assert math.isfinite(summary[key]), key
    for s in summary["step_info"]:
        assert s["converged"] and math.isfinite(s["residual_norm"])
    assert all(math.isfinite(float(r["residual_norm"])) for r in rows)
    return footing_t


def check_limit_load(summary, footing_t):
    """The run stopped at a limit point: the settlement rate grows without bound towards it."""
    failed = summary["failed"]
    assert not summary["converged"] and failed["phase"] == "footing"
    assert failed["reason"] and failed["t"] == footing_t[-1]
    limit = failed["limit_load"]
    assert limit is not None, "the stop should be recognised as a limit load"
    assert limit["t_converged"] == footing_t[-1] < limit["t_failed"]
    assert 0 < limit["stiffness_ratio"] <= 0.5
    # the extrapolated maximum lies within a few failed increments of the last converged state,
    # inside the failed one where the stiffness has fallen less than to 20 %
    assert abs(limit["t_estimate"] - footing_t[-1]) <= 2 * (limit["t_failed"] - footing_t[-1])
    assert limit["stiffness_ratio"] <= 0.2 or limit["t_estimate"] <= limit["t_failed"]
    return limit


def check_displacement_rate_grows(out):
    """Independent of limit_point's norm: the largest nodal displacement per load increment,
    from the stored states, is at least 10x that of the first footing increment at the end."""
    restart = load_restart(str(out))
    U = restart["u_history"]
    t = [0.0] + [s["t"] for s in restart["state"]["step_info"][1:]]  # U[0]: gravity, footing t = 0
    rates = [np.abs(U[k] - U[k - 1]).max() / (t[k] - t[k - 1]) for k in range(1, len(U))]
    assert rates[-1] >= 10 * rates[0], rates


@pytest.mark.slow
def test_doubled_footing_load_reaches_the_limit_load_past_the_nominal_one(tmp_path):
    summary, on_disk, rows = run(tmp_path, 2.0)
    footing_t = check_consistent(summary, on_disk, rows)
    assert summary["load_factor"] == 2.0
    assert summary["cutbacks"], "the doubled load needs smaller steps"
    # well past the nominal load (t = 0.5 of twice the load), short of the doubled one
    limit = check_limit_load(summary, footing_t)
    assert 0.55 <= limit["t_converged"] < 1.0
    # the soil under the footing has lost strong ellipticity before the limit; not under gravity
    assert summary["step_info"][0]["non_elliptic_points"] == 0
    assert summary["non_elliptic_points"] == summary["step_info"][-1]["non_elliptic_points"] > 0
    check_displacement_rate_grows(tmp_path)


@pytest.fixture(scope="module")
def uplift(tmp_path_factory):
    """The serial uplift run (no stabiliser), shared: its folder and run()'s results."""
    out = tmp_path_factory.mktemp("uplift")
    return out, run(out, UPLIFT)


@pytest.mark.slow
def test_uplift_is_cut_back_and_stops_at_its_limit_load(uplift):
    """Pulling the footing up: the soil under it loses its contacts (singular matrix, then no
    equilibrium once the uplift exceeds what the overburden holds)."""
    out, (summary, on_disk, rows) = uplift
    footing_t = check_consistent(summary, on_disk, rows)
    reasons = " ".join(c["reason"] for c in summary["cutbacks"])
    assert "singular" in reasons
    # the singular matrices are named: RVEs without contacts, and the fixes
    assert "RVE points have lost every contact" in reasons and "stabilise" in reasons, reasons
    limit = check_limit_load(summary, footing_t)
    # the last converged step carries an upward footing load, a small fraction of the nominal
    # one: the cohesionless soil holds the footing only through the weight of the cells below
    assert summary["step_info"][-1]["footing_load"] > 0
    assert 0 < limit["t_converged"] < 0.25
    check_displacement_rate_grows(out)


@pytest.mark.slow
def test_stabiliser_effect_is_measured_and_absent_while_contacts_hold(tmp_path, uplift):
    """Uplift with the stabiliser (1e-3 of the eq. 15 modulus): identical steps to the plain run
    as long as no RVE has lost its contacts; once some have, the stabiliser's share of the nodal
    forces is reported per step (and its maximum)."""
    plain = uplift[1][0]
    stab, on_disk, rows = run(tmp_path / "stab", UPLIFT, stabilise=1e-3)
    check_consistent(stab, on_disk, rows)
    assert stab["stabilise"] == 1e-3 and plain["stabiliser_force_max"] == 0.0
    same = 0
    for a, b in zip(plain["step_info"], stab["step_info"]):
        if b["open_points"] or a["t"] != b["t"]:
            break
        assert a["settlement"] == b["settlement"] and b["stabiliser_force"] == 0.0
        same += 1
    assert same >= 2
    shares = [s["stabiliser_force"] for s in stab["step_info"] if s["open_points"]]
    assert shares and all(0.0 < f < 0.1 for f in shares)
    assert stab["stabiliser_force_max"] == max(shares)


@pytest.mark.slow
def test_uplift_on_two_ranks_matches_serial(tmp_path, uplift):
    """The same cut-backs and the same stopping point under mpirun -n 2: RVE errors and singular
    factorisations on one rank are failures on all ranks, nobody hangs."""
    serial = uplift[1][0]
    proc, parallel = run_slope_demo(
        tmp_path / "np2",
        *("--particles", PARTICLES, "--seed", SEED, "--steps", STEPS, "--no-figure"),
        *("--load-factor", UPLIFT),
        ranks=2,
        timeout=300,
        check=False,
    )
    assert proc.returncode == 1, proc.stdout[-3000:] + proc.stderr[-3000:]  # stopped, not crashed
    assert "Traceback" not in proc.stderr
    assert parallel["ranks"] == 2 and parallel["status"] == serial["status"] == "failed"
    assert parallel["completed_steps"] == serial["completed_steps"]
    assert [c["t_to"] for c in parallel["cutbacks"]] == [c["t_to"] for c in serial["cutbacks"]]
    a, b = parallel["failed"]["limit_load"], serial["failed"]["limit_load"]
    assert a["t_converged"] == b["t_converged"]
    assert abs(a["stiffness_ratio"] / b["stiffness_ratio"] - 1) <= 1e-8
    rel = abs(parallel["footing_settlement"] / serial["footing_settlement"] - 1)
    assert rel <= 1e-10
