"""demos/slope_collapse.py at small size: both methods on one mesh and the uplift; its files."""

import csv
import json

import pytest

from helpers import load_demo


@pytest.mark.slow
def test_collapse_study_runs(tmp_path, capsys):
    assert (
        load_demo("slope_collapse").main(
            [
                "--particles",
                "70",
                "--seed",
                "1",
                "--steps",
                "4",
                "--meshes",
                "1",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    summary = json.loads((tmp_path / "collapse.json").read_text())
    assert set(summary) == {"load_control_380", "path_380", "uplift_path_380"}
    control, path = summary["load_control_380"], summary["path_380"]
    # load control stops at the limit load; the path passes the same peak and goes on
    limit = control["limit_load"]["t_converged"] * 2.0
    assert abs(path["peak"]["load_factor"] - limit) <= 0.02 * limit
    assert path["status"] == "converged" and control["status"] == "failed"
    with open(tmp_path / "collapse.csv") as f:
        rows = list(csv.DictReader(f))
    assert {r["run"] for r in rows} == set(summary)
    assert (tmp_path / "collapse.png").stat().st_size > 10_000
    assert "peak x" in capsys.readouterr().out
