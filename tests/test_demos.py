"""Every demo in demos/ at its small size, serially (``--small``) and under ``mpirun -n 2``
(``DEMO_SMALL=1``), each checked for its files; the demos are jupytext percent scripts."""

import csv
import glob
import json
import os

import numpy as np
import pytest

from helpers import DEMOS, ROOT, is_png, run_demo


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def check_fabric3d(out, stdout):
    rows = read_csv(out / "fabric3d.csv")
    assert [r["case"].split()[0] for r in rows] == ["F", "compression", "shear"]
    identity, compression, shear = rows
    A = {k: {c: float(r[f"A_{c}"]) for c in ("xx", "yy", "zz", "xz")} for k, r in (
        ("I", identity), ("c", compression), ("s", shear))}  # fmt: skip
    # compression along z adds contacts whose normals lie near +-z: A_zz grows, A_xx, A_yy fall
    assert int(compression["contacts"]) > int(identity["contacts"])
    assert A["c"]["zz"] > A["I"]["zz"]
    assert A["c"]["xx"] < A["I"]["xx"] and A["c"]["yy"] < A["I"]["yy"]
    # shear F = I + gamma e_x e_z opens the contacts along the stretched (1, 0, 1) and keeps
    # those along the compressed (1, 0, -1): n_x n_z < 0 on average, the major axis there
    assert int(shear["contacts"]) < int(identity["contacts"])
    assert A["s"]["xz"] < -0.1 < A["I"]["xz"]
    axis = np.array([float(shear[f"axis_{c}"]) for c in "xyz"])
    assert abs(axis @ np.array([1.0, 0.0, -1.0])) / np.sqrt(2.0) > 0.95
    assert is_png(out / "fabric3d.png") and "anisotropy" in stdout


def check_footing3d(out, stdout):
    summary = json.loads((out / "summary.json").read_text())
    assert summary["completed"] and summary["cells"] == 120 and summary["points"] == 960
    assert summary["settlement_m"] < 0.0 and summary["footing_load_N"] < 0.0
    assert [s["phase"] for s in summary["steps"]] == ["gravity"] * 2 + ["footing"] * 4
    rows = read_csv(out / "convergence.csv")
    assert len(rows) == summary["newton_iterations"]
    xdmf = (out / "footing3d.xdmf").read_text()
    assert xdmf.count('Attribute Name="displacement"') == 6
    assert is_png(out / "footing3d.png") and "settlement" in stdout


def check_granular_column(out, stdout):
    summary = json.loads((out / "summary.json").read_text())
    rows = read_csv(out / "probe.csv")
    assert summary["converged"] and summary["steps"] == len(rows) == 3
    assert summary["newton_iterations"] == sum(int(r["newton_iterations"]) for r in rows)
    assert float(rows[-1]["pressure_Pa"]) == 3e5
    # the probe carries the surface load: sigma_22 within 5 % of -p near the column's base
    s22 = np.array([float(r["sigma22_Pa"]) for r in rows])
    p = np.array([float(r["pressure_Pa"]) for r in rows])
    np.testing.assert_allclose(s22, -p, rtol=0.05)
    assert -1.0 < summary["top_settlement_m"] < 0.0 and summary["oedometer"]["e22"] < 0.0
    xdmf = (out / "column.xdmf").read_text()
    # every field at each of the 3 load factors
    assert xdmf.count('Attribute Name="displacement"') == xdmf.count('Attribute Name="cauchy"') == 3
    assert "top settlement" in stdout


def check_friction_study(out, stdout):
    for name in ("friction_cycles.csv", "friction_monotonic.csv", "friction_summary.csv"):
        assert len(read_csv(out / name)) > 0, name
    for name in ("hysteresis", "qp_gamma", "qp_mu", "dissipation"):
        assert is_png(out / f"friction_{name}.png"), name
    assert "wrote" in stdout


def check_relaxed_study(out, stdout):
    rows = read_csv(out / "moduli.csv")
    assert len(rows) == 2  # the small run: two pressures, one seed
    for r in rows:
        # relaxation never stiffens: B and G at most Taylor's at the same F
        assert float(r["B_relaxed"]) <= float(r["B_taylor"])
        assert float(r["G_relaxed"]) <= float(r["G_taylor"])
        assert float(r["z"]) >= 4.0  # a rigid network of frictionless disks: isostatic or more
    shear = read_csv(out / "shear.csv")
    assert {r["law"] for r in shear} == {"relaxed", "taylor"}
    for name in ("moduli", "coordination", "shear"):
        assert is_png(out / f"relaxed_{name}.png"), name
    assert "Taylor over relaxed G" in stdout


def check_rve_study(out, stdout):
    summary = json.loads((out / "summary.json").read_text())
    assert [row["n"] for row in summary["speed_error"]] == [70, 140]  # the small sizes
    for name in ("fig2_sieve_curve", "fig4_compression", "fig5_shear", "speed_error"):
        assert is_png(out / f"{name}.png"), name


def check_slope(out, stdout):
    summary = json.loads((out / "summary.json").read_text())
    assert summary["footing_settlement"] < 0.0 and len(summary["iterations"]) == 5  # 1 + 4 steps
    assert len(read_csv(out / "convergence.csv")) >= sum(summary["iterations"])
    assert (out / "slope.xdmf").is_file()


def check_slope_collapse(out, stdout):
    summary = json.loads((out / "collapse.json").read_text())
    assert set(summary) == {"load_control_380", "path_380", "uplift_path_380"}
    control, path = summary["load_control_380"], summary["path_380"]
    # load control stops at the limit load; the path passes the same peak and goes on
    limit = control["limit_load"]["t_converged"] * 2.0
    assert abs(path["peak"]["load_factor"] - limit) <= 0.02 * limit
    assert path["status"] == "converged" and control["status"] == "failed"
    assert {r["run"] for r in read_csv(out / "collapse.csv")} == set(summary)
    assert (out / "collapse.png").stat().st_size > 10_000
    assert "peak x" in stdout


CHECKS = {name: globals()[f"check_{name}"] for name in DEMOS}
SLOW = {"slope", "slope_collapse"}


def demo_params():
    return [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in DEMOS]


def test_every_demo_is_tested_and_a_jupytext_percent_script():
    found = sorted(os.path.basename(p)[:-3] for p in glob.glob(os.path.join(ROOT, "demos", "*.py")))
    assert found == sorted(DEMOS)
    for name in DEMOS:
        with open(os.path.join(ROOT, "demos", f"{name}.py"), encoding="utf-8") as f:
            text = f.read()
        assert text.startswith("# ---\n# jupyter:\n") and "format_name: percent" in text, name
        assert text.count("# %% [markdown]") >= 1 and "\n# %%\n" in text, name


@pytest.mark.parametrize("name", demo_params())
def test_demo_runs_small_serially(name, tmp_path):
    proc = run_demo(name, "--small", "--out", tmp_path)
    CHECKS[name](tmp_path, proc.stdout)


@pytest.mark.parametrize("name", demo_params())
def test_demo_runs_small_under_mpi(name, tmp_path):
    proc = run_demo(name, "--out", tmp_path, ranks=2, env={"DEMO_SMALL": "1"})
    CHECKS[name](tmp_path, proc.stdout)
