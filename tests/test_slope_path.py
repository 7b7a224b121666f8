"""The slope past its limit load (--path-following, 70-particle RVE): through the peak and down the
softening branch, every increment on disk, the same path on two ranks and after a restart, and the
uplift case stopping with its reason."""

import numpy as np
import pytest

from helpers import is_png, read_outputs, run_slope_demo

SMALL = ["--particles", "70", "--seed", "1", "--steps", "4", "--no-figure", "--path-following"]
PATH_GRAVITY = ["--path-following", "gravity"]


def demo(out, *args, ranks=1, status=0):
    """The small path-following run in ``out``, which must exit with ``status``: its stdout,
    summary and convergence rows."""
    return demo_run(out, *SMALL, *args, ranks=ranks, status=status)


def demo_run(out, *args, ranks=1, status=0):
    """``demos/slope.py *args`` in ``out``, which must exit with ``status``: its stdout,
    summary and convergence rows."""
    proc, _ = run_slope_demo(out, *args, ranks=ranks, timeout=900, check=False)
    assert proc.returncode == status, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc.stdout, *read_outputs(out)


@pytest.fixture(scope="module")
def doubled(tmp_path_factory):
    return demo(tmp_path_factory.mktemp("doubled"), "--load-factor", "2")


def footing_path(summary):
    steps = [s for s in summary["step_info"] if s["phase"] == "footing"]
    return np.array([[s["footing_load"], s["settlement"]] for s in steps])


@pytest.mark.slow
def test_doubled_load_passes_the_peak_and_softens(doubled):
    stdout, s, rows = doubled
    path = s["path_following"]
    assert s["status"] == "converged" and path["failed"] is None
    peak, loads = path["peak"], -footing_path(s)[:, 0]
    # the peak lies past the nominal load, below the doubled one, and the path goes on after it
    assert 1.0 < peak["load_factor"] < 2.0
    k = int(np.argmax(loads))
    assert 0 < k < len(loads) - 1 and loads[k] == pytest.approx(-peak["footing_load"], rel=1e-12)
    assert loads[-1] <= 0.9 * loads[k] < loads[-2]  # down to 0.9 x the peak, no further
    assert "fell to" in path["stopped"]
    # det K changed sign at the peak: a limit point inside the increment that holds it
    # (the sampled peak is an end of the increment that holds the true one)
    limits = [c for c in path["critical_points"] if c["kind"] == "limit"]
    assert limits, path["critical_points"]
    ends = max(abs(limits[0]["lam_before"]), abs(limits[0]["lam_after"]))
    assert ends == pytest.approx(abs(peak["load_factor"]), rel=1e-12)
    # every increment on disk, and the path's record matches the step records
    assert len(path["path"]) == len(loads) == s["completed_steps"] - 1 <= 100
    assert sorted({int(r["step"]) for r in rows}) == list(range(1, s["completed_steps"] + 1))
    assert all(r["converged_by"] in ("energy norm", "round-off") for r in rows if r["converged_by"])
    # the softening branch: RVEs under the footing have lost strong ellipticity along the path
    assert max(p["non_elliptic_points"] for p in path["path"]) > 0
    assert "peak footing load" in stdout


@pytest.mark.slow
def test_path_is_the_same_on_two_ranks(tmp_path, doubled):
    """Every increment converges to round-off (|R| <= 1e-12 of the forces), so the two
    partitions' states differ by round-off amplified by the conditioning, far below 1e-8; the
    step sizes follow integer iteration counts, which agree."""
    _, two, _ = demo(tmp_path, "--load-factor", "2", ranks=2)
    a, b = footing_path(doubled[1]), footing_path(two)
    assert a.shape == b.shape
    # per column (footing load, settlement), each against its own scale
    assert np.all(np.abs(a - b).max(axis=0) <= 1e-8 * np.abs(a).max(axis=0))


@pytest.mark.slow
def test_resume_continues_the_path(tmp_path, doubled):
    out = tmp_path / "run"
    stdout, stopped, _ = demo(out, "--load-factor", "2", "--stop-after", "5")
    # stopped where asked, before the path's end: a stopped run, as under load control
    assert stopped["status"] == "stopped" and not stopped["converged"]
    assert stopped["path_following"]["stopped"] == "asked to stop"
    assert f"continue with --resume {out}" in stdout
    run_slope_demo(None, "--resume", out, "--no-figure", timeout=900)
    summary, _ = read_outputs(out)
    assert summary["resumed_from"] == 5
    a, b = footing_path(doubled[1]), footing_path(summary)
    assert a.shape == b.shape and np.abs(a - b).max() <= 1e-12 * np.abs(a).max()
    assert (
        summary["path_following"]["critical_points"]
        == doubled[1]["path_following"]["critical_points"]
    )


@pytest.mark.slow
def test_uplift_stops_where_no_equilibrium_path_continues(tmp_path):
    stdout, s, _ = demo(tmp_path, "--load-factor", "-0.25", status=1)
    path = s["path_following"]
    assert s["status"] == "failed" and path["failed"]
    assert "lost every contact" in s["failed"]["reason"]
    assert "no equilibrium path continues" in stdout
    # it got past its small peak uplift load first (a limit point), then the soil let go
    assert 0 < -path["peak"]["load_factor"] < 0.05  # an uplift: a negative load factor
    assert path["critical_points"][0]["kind"] == "limit"
    assert abs(footing_path(s)[-1, 0]) < abs(path["peak"]["footing_load"])


@pytest.mark.slow
def test_the_weight_by_path_following_is_the_weight_by_load_control(tmp_path):
    """--path-following gravity (the Taylor slope, elastic: one equilibrium per load): the path
    carries the weight and stops there, without a footing phase, and its last state is the
    load-controlled equilibrium at the same gravity factor; a resumed run ends where the whole
    run ends."""
    from dolfinx_granular.slope.cli import make_packing
    from dolfinx_granular.slope.model import SlopeModel
    from dolfinx_granular.slope.run import SlopeOptions

    from mpi4py import MPI

    args = ["--particles", "70", "--seed", "1", "--gravity-steps", "3", *PATH_GRAVITY]
    stdout, s, _ = demo_run(tmp_path / "path", *args)
    assert is_png(tmp_path / "path" / "load_settlement.png")  # gravity factor and settlement
    path = s["path_following"]
    assert s["status"] == "converged" and path["phase"] == "gravity" and path["failed"] is None
    assert "reached" in path["stopped"] and "peak gravity factor" in stdout
    assert {i["phase"] for i in s["step_info"]} == {"gravity"} and len(path["path"]) >= 3
    lam, settlement = path["path"][-1]["gravity"], path["path"][-1]["settlement"]
    assert lam >= 1.0 and lam == path["peak"]["gravity"] and settlement < 0.0
    assert path["critical_points"] == []  # the Taylor slope carries its weight: no limit point
    o = SlopeOptions()
    model = SlopeModel(MPI.COMM_SELF, o.law(make_packing(70, 1)), o.geometry)
    model.set_gravity(lam)
    assert model.solver.solve().converged
    assert model.settlement() == pytest.approx(settlement, rel=1e-8)
    model.solver.destroy()
    out = tmp_path / "resumed"
    demo_run(out, *args, "--no-figure", "--stop-after", "2")
    run_slope_demo(None, "--resume", out, "--no-figure", timeout=900)
    resumed, _ = read_outputs(out)
    assert resumed["resumed_from"] == 2 and resumed["status"] == "converged"
    assert resumed["path_following"]["path"][-1]["settlement"] == pytest.approx(
        settlement, rel=1e-12
    )
