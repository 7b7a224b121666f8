"""The benchmark scripts run (at tiny size) so that they cannot rot."""

from dolfinx_granular import TaylorRVE, generate_packing

import numpy as np

import kernel


def test_kernel_benchmark_runs(capsys):
    kernel.main(["--points", "20", "--sizes", "70", "--repeats", "1"])
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.strip().startswith("70 ")]
    assert len(rows) == 1 and rows[0].endswith("x")


def test_kernel_comparison_agrees_and_times_every_implementation():
    F = kernel.deformations(12)
    assert F.shape == (12, 2, 2) and np.allclose(F.mean(axis=0), 0.98 * np.eye(2), atol=2e-3)
    rve = TaylorRVE(generate_packing(30, seed=1), kernel.K_N)
    r = kernel.compare(rve, F, repeats=1, numpy_points=3)
    assert r["agree"] < 1e-12 and r["candidates"] == rve.n_candidates
    assert 0 < r["active"] <= r["visited"] <= r["candidates"]
    assert all(r[k] > 0 for k in ("us_pa", "us_p", "us_loop", "us_numpy"))
