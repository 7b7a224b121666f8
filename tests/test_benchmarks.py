"""The benchmark scripts run (at tiny size) so that they cannot rot."""

from dolfinx_granular import TaylorRVE, generate_packing

import numpy as np
import pytest

import friction_path
import kernel
import relaxed
import three_d


def test_kernel_benchmark_runs(capsys):
    kernel.main(["--points", "20", "--sizes", "70", "--repeats", "1"])
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.strip().startswith("70 ")]
    assert len(rows) == 1 and rows[0].endswith("x")


def test_relaxed_benchmark_counts_and_times_the_parts(capsys, tmp_path):
    saved = tmp_path / "wpa.npz"
    relaxed.main(["--points", "3", "--particles", "70", "--repeats", "1", "--save", str(saved)])
    out = capsys.readouterr().out
    assert "relaxed P+A" in out and "ratio" in out and "floor:" in out
    for part in ("Newton steps", "factorisations", "solves", "trial states", "solver's pattern"):
        assert part in out, part
    assert "frictional P+A" in out and "x the frictionless relaxed RVE" in out
    assert "block LU:" in out and "GFLOP/s); floor" in out and "compiled Newton loop" in out
    relaxed.main(["--points", "3", "--particles", "70", "--repeats", "1", "--against", str(saved)])
    out = capsys.readouterr().out
    assert "A: largest relative difference 0.0e+00; points beyond 1e-10: []" in out


def test_kernel_comparison_agrees_and_times_every_implementation():
    F = kernel.deformations(12)
    assert F.shape == (12, 2, 2) and np.allclose(F.mean(axis=0), 0.98 * np.eye(2), atol=2e-3)
    rve = TaylorRVE(generate_packing(30, seed=1), kernel.K_N)
    r = kernel.compare(rve, F, repeats=1, numpy_points=3)
    assert r["agree"] < 1e-12 and r["candidates"] == rve.n_candidates
    assert 0 < r["active"] <= r["visited"] <= r["candidates"]
    assert all(r[k] > 0 for k in ("us_pa", "us_p", "us_loop", "us_numpy"))


@pytest.mark.slow
def test_friction_path_benchmark_writes_its_section(tmp_path):
    pytest.importorskip("dolfinx")
    args = ["--particles", "70", "--steps", "2", "--ranks", "1", "--sizes", "70"]
    args += ["--points", "20", "--repeats", "1", "--no-refine", "--out", str(tmp_path)]
    res = friction_path.main(args)
    text = (tmp_path / "performance.md").read_text()
    assert text.count(friction_path.BEGIN) == 1 and "## 7. Friction and path following" in text
    slope = res["slope"]
    assert set(slope) == set(friction_path.slope_cases(refine=False))
    assert all(s["converged"] for name, s in slope.items() if "load control" not in name)
    friction = slope[f"friction mu = {friction_path.MU}, unloaded"]
    assert friction["permanent_settlement"] < 0 < friction["dissipated_energy"]
    path = slope["2x load, path following"]["path_following"]
    assert path["peak"] is not None and path["critical_points"]
    for name, s in slope.items():
        assert f"| {name} | {s['completed_steps']} | {sum(s['iterations'])} |" in text


def test_relaxed_bvp_benchmark_cases_run_and_make_a_section():
    """The benchmark's column case in its own process (the confined Taylor column: the added
    load in 5 steps), and its section from such records."""
    import relaxed_bvp

    column = relaxed_bvp.run_case("column", "taylor", 1)
    assert column["failed"] is None and len(column["steps"]) == relaxed_bvp.COLUMN_STEPS
    settlements = [s["settlement"] for s in column["steps"]]
    assert settlements[0] < 0.0 and np.all(np.diff(settlements) < 0.0)
    slope = relaxed_bvp.slope_case("taylor", stop_after=1)
    assert len(slope["steps"]) == 1 and slope["steps"][0]["settlement"] < 0.0
    res = {(case, law, n): (column if case == "column" else slope)
           for case in ("column", "slope", "speedup", "slope path") for law in relaxed_bvp.LAWS
           for n in (1, 2)}  # fmt: skip
    text = relaxed_bvp.markdown(res, "python benchmarks/relaxed_bvp.py", 0.1)
    assert text.startswith(relaxed_bvp.BEGIN) and text.endswith(relaxed_bvp.END)
    assert "## 9. The relaxed RVE in boundary value problems" in text
    for law in relaxed_bvp.LAWS:
        assert f"| {law} | {len(column['steps'])} |" in text
    for law in relaxed_bvp.RELAXED:
        assert f"| {law}, path following, 2 ranks |" in text
    law = relaxed_bvp.confined_law("relaxed_friction", 1, relaxed_bvp.COLUMN_CONFINEMENT)
    assert law.springs.mu == relaxed_bvp.FRICTION and law.springs.kt == relaxed_bvp.K_N


@pytest.mark.slow
def test_three_d_benchmark_runs_and_writes_its_section(tmp_path):
    pytest.importorskip("dolfinx")
    doc = tmp_path / "performance.md"
    res = three_d.main(["--quick", "--out", str(tmp_path / "out"), "--doc", str(doc)])
    text = doc.read_text()
    assert "## 10. Three dimensions" in text and text.count("<!-- begin: benchmarks/three_d.py")
    for k in res["kernels"]:
        assert k["phi"] >= 0.6 and k["z"] >= 5.5 and 0 < k["visited"] <= k["candidates"]
        assert 0 < k["us_stress"] and 0 < k["us_evaluate"]
        assert f"| {k['n']} | {k['generate_s']:.1f} |" in text
    direct, iterative = res["footing"]["direct"], res["footing"]["iterative"]
    assert iterative["settlement_m"] == pytest.approx(direct["settlement_m"], rel=1e-10)
    assert f"| iterative | {iterative['settlement_m']:.6f} |" in text
    assert set(res["sizes"]) == {100, 200} and all(len(r) == 2 for r in res["sizes"].values())
    # a second run measures nothing again: everything comes from the stored JSON
    again = three_d.main(["--quick", "--out", str(tmp_path / "out"), "--doc", str(doc)])
    assert again == res
