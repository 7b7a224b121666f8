"""The performance report runs end to end at tiny size, so that it cannot rot."""

import json
import re

import pytest

from scripts import load_benchmark

dolfinx = pytest.importorskip("dolfinx")


def test_flops_measures_a_positive_peak():
    m = load_benchmark("flops").measure(seconds=0.002, repeats=3)
    assert m["gflops_per_core"] > 0.1 and m["cores"] >= 1
    assert m["gflops_machine"] == pytest.approx(m["gflops_per_core"] * m["cores"])


@pytest.mark.slow
def test_tiny_report(tmp_path):
    report = load_benchmark("report")
    raw = tmp_path / "raw.json"
    assert report.main(["--tiny", "--out", str(tmp_path), "--json", str(raw), "--quiet"]) == 0
    md = (tmp_path / "performance.md").read_text()
    for heading in ("## 1. Kernel", "## 2. One Newton iteration on the slope", "## 3. Scaling",
                    "## 4. Speed against error", "## 5. Paying only for what a scene needs",
                    "## Targets"):
        assert heading in md, heading
    # header: machine, cores, versions, load
    assert re.search(r"\d+ cores", md) and f"dolfinx {dolfinx.__version__}" in md and "load average" in md
    assert "TINY" in md
    # every figure is referenced and is a real PNG of reasonable size
    for name in ("perf_kernel.png", "perf_iteration.png", "perf_scaling.png", "perf_speed_error.png"):
        assert f"]({name})" in md
        data = (tmp_path / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, name
    res = json.loads(raw.read_text())
    # one kernel row per size, measured and agreeing with the two reference implementations
    assert [r["particles"] for r in res["kernel"]] == res["config"]["kernel_sizes"]
    for r in res["kernel"]:
        assert 0 < r["us_p"] and 0 < r["us_pa"] and r["agree"] < 1e-12
        assert 0 < r["peak_frac_pa"] < 1
        assert f"| {r['particles']} | {r['candidates']} |" in md
    # the Newton breakdown adds up and the yardstick took the UFL path (no RVE work)
    it = res["iteration"]
    for lv in ("taylor", "taylor_skip", "small_strain", "ufl_linear"):
        b = it[lv]["best"]
        parts = b["F"] + b["kernel"] + b["assembly"] + b["linear_solve"] + b["rest"]
        assert parts == pytest.approx(b["newton"], rel=1e-9) and b["newton"] > 0, lv
        assert it[lv]["run"]["converged"], lv
    # (its CPU "kernel" is the call of a no-op update: microseconds)
    assert it["ufl_linear"]["run"]["times"]["kernel"] == 0.0 and it["taylor"]["best"]["kernel"] > 0
    assert it["ufl_linear"]["best"]["kernel"] < 0.1 * it["taylor"]["best"]["kernel"]
    # the stress-only final residual: one per load step, nothing else changes
    t, s = it["taylor"]["run"], it["taylor_skip"]["run"]
    assert s["calls"]["residual"] - s["calls"]["jacobian"] == s["steps"]
    assert t["calls"]["residual"] - t["calls"]["jacobian"] == s["steps"]
    assert s["settlement"] == pytest.approx(t["settlement"], rel=1e-10)
    # scaling and refinement sections carry measured rows
    assert set(res["ranks"]) == {"1", "2"}
    assert [r["cells"] for r in res["refinement"]] == [380, 1520]
    # speed against error: one row per size and per level, the reference size has zero error
    sizes = res["config"]["error_sizes"]
    assert len(res["sizes"]) == len(sizes) * res["config"]["seeds"]
    assert re.search(rf"\| Taylor RVE \(full\) \| {sizes[-1]} \| 1/1 \| \d+ \| [\d.]+ ± [\d.]+ \| "
                     r"-[\d.]+ ± [\d.]+ \| 0\.00 % \|", md)
    for label in ("SmallStrainRVE", "UFL linear", "AdaptiveRVE (provable)", "AdaptiveRVE (strain only)"):
        assert label in md
    # the provable adaptive level is Taylor wherever it did not prove linearity: same answer
    ad = [r for r in res["levels"] if r["level"] == "adaptive"]
    base = [r for r in res["sizes"] if r["particles"] == res["config"]["particles"]]
    assert ad and all(a["settlement"] == pytest.approx(b["settlement"], rel=1e-9) for a, b in zip(ad, base))
    assert "| target | measured | status |" in md
    # the figures and markdown can be redrawn from the raw numbers alone
    redo = tmp_path / "redo"
    assert report.main(["--render", str(raw), "--out", str(redo)]) == 0
    assert (redo / "performance.md").read_text().split("\n", 3)[3] == md.split("\n", 3)[3]
