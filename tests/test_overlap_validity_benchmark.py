"""benchmarks/overlap_validity.py runs (tiny slope) so that it cannot rot."""

import json

import pytest

pytest.importorskip("dolfinx")
import overlap_validity  # noqa: E402  (benchmarks/, on pytest's pythonpath)


def test_overlap_validity_benchmark_reports_the_final_state(capsys):
    lines = overlap_validity.main(["--particles", "70", "--steps", "2"])
    assert capsys.readouterr().out.splitlines() == lines
    summary = json.loads(lines[1].removeprefix("overlap_validity "))
    assert summary["points"] == 1520 and summary["threshold"] == 0.10
    beyond = json.loads(lines[2].split(": ")[1].split(" of ")[0])  # 5, 10, 20, 50 %
    assert beyond[1] == summary["points_above"] and beyond == sorted(beyond, reverse=True)
    probes = [line for line in lines if line.startswith("probe ")]
    assert [p.split()[1] for p in probes] == ["A", "B", "C", "D"]
    ratios = [float(p.split("overlap ratio ")[1].split(",")[0]) for p in probes]
    assert 0 < max(ratios) <= round(summary["max_ratio"], 4)  # probes see part of the points
