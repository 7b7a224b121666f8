"""The performance report runs end to end at tiny size, so that it cannot rot."""

import json
import re

import pytest

import flops
import report_markdown
import sections
from helpers import is_png

dolfinx = pytest.importorskip("dolfinx")

STACKS_BLOCK = (
    "<!-- begin: benchmarks/stacks.py -->\n## 6. DOLFINx releases\n\nkept as it was\n"
    "<!-- end: benchmarks/stacks.py -->"
)


def test_flops_measures_a_positive_peak():
    m = flops.measure(seconds=0.002, repeats=3)
    assert m["gflops_per_core"] > 0.1 and m["cores"] >= 1
    assert m["gflops_machine"] == pytest.approx(m["gflops_per_core"] * m["cores"])


def test_rewriting_the_report_keeps_the_stacks_section(tmp_path):
    path = tmp_path / "performance.md"
    report_markdown.write(path, "# old report\n")  # no file before, no section: written as is
    assert path.read_text() == "# old report\n"
    path.write_text("# old report\n\n## 1. Kernel\nold numbers\n\n\n" + STACKS_BLOCK + "\n")
    report_markdown.write(path, "# new report\n\n## Targets\nnew numbers\n")
    text = path.read_text()
    assert text.startswith("# new report\n") and "old numbers" not in text
    assert text.rstrip("\n").endswith(STACKS_BLOCK) and text.count(STACKS_BLOCK) == 1
    report_markdown.write(path, "# newer report\n")  # and again: still exactly one copy
    assert path.read_text() == "# newer report\n\n\n" + STACKS_BLOCK + "\n"


def test_each_script_replaces_only_its_own_section(tmp_path):
    path = str(tmp_path / "performance.md")
    begin, end = sections.markers("friction_path.py")
    seventh = f"{begin}\n## 7. Friction and path following\n\nfirst\n{end}\n"
    sections.write_section(path, seventh)  # no file yet: the section alone
    sections.write_section(path, STACKS_BLOCK)  # appended after it
    sections.write_section(path, seventh.replace("first", "second"))  # replaced in place
    text = open(path).read()
    assert text.count(begin) == 1 and "second" in text and "first" not in text
    assert text.index(begin) < text.index(STACKS_BLOCK)
    report_markdown.write(path, "# report\n")  # both kept, in the order of their headings
    kept = sections.marked_sections(open(path).read())
    assert kept == [STACKS_BLOCK, seventh.replace("first", "second").strip("\n")]


@pytest.mark.slow
def test_tiny_report(tmp_path):
    import dolfinx_granular.drivers.newton

    import report

    solver_class = dolfinx_granular.drivers.newton.NewtonSolver
    raw = tmp_path / "raw.json"
    (tmp_path / "performance.md").write_text("# an older report\n\n" + STACKS_BLOCK + "\n")
    assert report.main(["--tiny", "--out", str(tmp_path), "--json", str(raw), "--quiet"]) == 0
    assert dolfinx_granular.drivers.newton.NewtonSolver is solver_class  # nothing patched
    md = (tmp_path / "performance.md").read_text()
    assert md.rstrip("\n").endswith(STACKS_BLOCK) and "an older report" not in md
    for heading in (
        "## 1. Kernel",
        "## 2. One Newton iteration on the slope",
        "## 3. Scaling",
        "## 4. Speed against error",
        "## 5. Paying only for what a scene needs",
        "## Targets",
    ):
        assert heading in md, heading
    # header: machine, cores, versions, load
    assert re.search(r"\d+ cores", md) and f"dolfinx {dolfinx.__version__}" in md
    assert "load average" in md and "TINY" in md
    # every figure is referenced and is a real PNG of reasonable size
    for name in (
        "perf_kernel.png",
        "perf_iteration.png",
        "perf_scaling.png",
        "perf_speed_error.png",
    ):
        assert f"]({name})" in md
        png = tmp_path / name
        assert is_png(png) and png.stat().st_size > 10_000, name
    res = json.loads(raw.read_text())
    check_kernel(res, md)
    check_iteration(res)
    # scaling and refinement sections carry measured rows
    assert set(res["ranks"]) == {"1", "2"}
    assert all("error" not in r for r in res["ranks"].values()), res["ranks"]
    assert (
        res["ranks"]["2"]["points_per_rank"]
        and sum(res["ranks"]["2"]["points_per_rank"]) == res["ranks"]["1"]["points"]
    )
    assert [r["cells"] for r in res["refinement"]] == [380, 1520]
    check_speed_error(res, md)
    assert "| target | measured | status |" in md
    # the figures and markdown can be redrawn from the raw numbers alone
    redo = tmp_path / "redo"
    assert report.main(["--render", str(raw), "--out", str(redo)]) == 0
    assert (redo / "performance.md").read_text().split("\n", 3)[3] == md.split("\n", 3)[3].replace(
        "\n\n\n" + STACKS_BLOCK, ""
    )


def check_kernel(res, md):
    """One kernel row per size, measured and agreeing with the two reference implementations."""
    assert [r["particles"] for r in res["kernel"]] == res["config"]["kernel_sizes"]
    for r in res["kernel"]:
        assert 0 < r["us_p"] and 0 < r["us_pa"] and r["agree"] < 1e-12
        assert 0 < r["peak_frac_pa"] < 1
        assert f"| {r['particles']} | {r['candidates']} |" in md


def check_iteration(res):
    """The Newton breakdown adds up, the yardstick took the UFL path (no RVE work), the
    stress-only final residual saves one tangent per load step and changes nothing else."""
    it = res["iteration"]
    for lv in ("taylor", "taylor_skip", "small_strain", "ufl_linear"):
        b = it[lv]["best"]
        parts = b["F"] + b["kernel"] + b["assembly"] + b["linear_solve"] + b["rest"]
        assert parts == pytest.approx(b["newton"], rel=1e-9) and b["newton"] > 0, lv
        assembly = b["residual_assembly"] + b["jacobian_assembly"] + b["scale_assembly"]
        assert assembly == pytest.approx(b["assembly"], rel=1e-9), lv
        assert b["linear_solve"] > 0 and b["assembly"] > 0, lv
        run = it[lv]["run"]
        assert run["converged"] and run["calls"]["ksp"] >= run["iterations"], lv
        assert run["calls"]["updates"] >= run["calls"]["residual"] >= run["iterations"], lv
    assert it["ufl_linear"]["run"]["times"]["kernel"] == 0.0 and it["taylor"]["best"]["kernel"] > 0
    assert it["ufl_linear"]["best"]["F"] == 0.0  # UFL evaluates grad u inside the forms
    t, s = it["taylor"]["run"], it["taylor_skip"]["run"]
    assert s["calls"]["residual"] - s["calls"]["jacobian"] == s["steps"]
    assert t["calls"]["residual"] - t["calls"]["jacobian"] == s["steps"]
    assert s["settlement"] == pytest.approx(t["settlement"], rel=1e-10)
    assert s["iterations"] == t["iterations"]


def check_speed_error(res, md):
    """One row per size and per level; the reference size has zero error; the provable adaptive
    level is Taylor wherever it did not prove linearity: the same answer."""
    sizes = res["config"]["error_sizes"]
    assert len(res["sizes"]) == len(sizes) * res["config"]["seeds"]
    assert all(r["generation_time"] > 0 for r in res["sizes"])
    assert re.search(
        rf"\| Taylor RVE \(full\) \| {sizes[-1]} \| 1/1 \| \d+ \| [\d.]+ ± [\d.]+ "
        r"\| -[\d.]+ ± [\d.]+ \| 0\.00 % \|",
        md,
    )
    for label in (
        "SmallStrainRVE",
        "UFL linear",
        "AdaptiveRVE (provable)",
        "AdaptiveRVE (strain only)",
    ):
        assert label in md
    ad = [r for r in res["levels"] if r["level"] == "adaptive"]
    base = [r for r in res["sizes"] if r["particles"] == res["config"]["particles"]]
    assert ad and all(
        a["settlement"] == pytest.approx(b["settlement"], rel=1e-9) for a, b in zip(ad, base)
    )
