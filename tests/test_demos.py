"""Every demo in demos/ at its small size, serially (``--small``) and under ``mpirun -n 2``
(``DEMO_SMALL=1``), each checked for its files; the demos are jupytext percent scripts. One rule
for their output folders (:mod:`dolfinx_granular.io.outfolder`): a second run into the same
``--out`` is refused before any work, ``--force`` replaces the demo's own files and no others,
and ``--small`` has its own default folder."""

import csv
import glob
import json
import os
import subprocess

from dolfinx_granular.io.outfolder import (
    OutFolderError,
    RunExistsError,
    claim_out,
    default_out,
    held_files,
)
from dolfinx_granular.slope.run import RUN_FILES

import numpy as np
import pytest
from mpi4py import MPI

from helpers import (
    DEMOS,
    MPI_ENV,
    ROOT,
    assert_user_error,
    demo_command,
    is_png,
    load_demo,
    run_demo,
)

#: a user's own file in an output folder: no run may touch it
NOTE = "notes.txt"


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
    assert summary["status"] == "converged" and summary["converged"]  # (the slope's schema)
    assert summary["cells"] == 120 and summary["points"] == 960
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


def check_relaxed_friction_study(out, stdout):
    # 1. the substep: each load step is 1, 2, 4, 8 substeps; the dissipation's difference to
    # the finest substep shrinks with it at about first order (every substep is a backward-Euler
    # increment of the contact law: 4.7, 2.4, 0.9 % here, first order gives 7 : 3 : 1); the
    # stress ratios agree to 1e-3 at every substep (2e-4 here; not monotone: on 200 disks to
    # gamma = 2 % they scatter around 5e-5)
    conv = read_csv(out / "convergence.csv")
    assert [float(r["substep"]) for r in conv] == [1e-3, 5e-4, 2.5e-4, 1.25e-4]
    assert [r["substeps_per_step"] for r in conv] == ["1-1", "2-2", "4-4", "8-8"]
    assert all(r["status"] == "ok" and float(r["gamma"]) == 0.01 for r in conv)
    d = [abs(float(r["rel_diff_dissipation"])) for r in conv]
    assert d[3] == 0.0 and d[0] > 1.5 * d[1] > 2.25 * d[2] > 0.0 and d[0] < 0.2, d
    for key in ("diff_sigma12_over_p", "diff_q_over_p"):
        assert max(abs(float(r[key])) for r in conv) < 1e-3, key
    assert all(float(r["dissipation_Pa"]) > 0.0 for r in conv)  # mu = 0.5: contacts slide
    # 2. confined shear: every step holds sigma_22 = -p, both laws and both mu got to 1 %
    steps = read_csv(out / "shear_steps.csv")
    columns = ("gamma", "q_over_p", "tau_over_p", "volumetric_strain", "z", "sliding_share",
               "dissipation_Pa", "wall_s")  # fmt: skip
    assert set(columns) <= set(steps[0]), steps[0].keys()
    assert {(r["law"], float(r["mu"])) for r in steps} == {
        (law, mu) for law in ("relaxed", "taylor") for mu in (0.0, 0.5)
    }
    p = 1e-2 * 2.8e7
    for r in steps:
        if int(r["step"]) > 0:  # (or off by a jump of the stress across -p, at most 1 %)
            miss = abs(float(r["control_error_Pa"]))
            assert abs(float(r["sigma22_Pa"]) + p) <= 1e-8 * p + miss and miss <= 1e-2 * p
    relaxed = [r for r in steps if r["law"] == "relaxed"]
    for r in relaxed:  # rigid networks: frictionless z >= 4, frictional z >= 3 (isostatic)
        assert float(r["z"]) >= (4.0 if float(r["mu"]) == 0.0 else 3.0)
        if float(r["mu"]) == 0.0:  # no tangential force: no sliding share, no dissipation
            assert r["sliding_share"] == "" and float(r["dissipation_Pa"]) == 0.0
    last = relaxed[-1]
    assert float(last["mu"]) == 0.5 and float(last["dissipation_Pa"]) > 0.0
    assert 0.0 < float(last["sliding_share"]) < 1.0
    tests = {(r["law"], float(r["mu"])): r for r in read_csv(out / "shear_tests.csv")}
    assert len(tests) == 4
    for (law, mu), t in tests.items():
        assert t["stopped"] == "False" and float(t["gamma_reached"]) == 0.01, (law, mu, t)
    # friction raises the mobilised stress ratio, relaxed (and Taylor) alike
    for law in ("relaxed", "taylor"):
        assert float(tests[law, 0.0]["qp_final"]) < float(tests[law, 0.5]["qp_final"])
    # without friction the relaxed disks reach about the literature's q/p of 0.1 (0.11 here);
    # the Taylor RVE, held affine, mobilises several times that at the same strain
    assert 0.05 < float(tests["relaxed", 0.0]["qp_final"]) < 0.2
    assert float(tests["taylor", 0.0]["qp_final"]) > 2 * float(tests["relaxed", 0.0]["qp_final"])
    for t in tests.values():  # critical state: the mean over the last quarter of gamma
        assert float(t["critical_from"]) == 0.0075
        assert float(t["qp_critical_last_quarter"]) <= float(t["qp_peak"])
    assert len(read_csv(out / "shear_summary.csv")) == 4
    check_relaxed_friction_biaxial(out, p)
    # every test of both loadings kept in OUT/tests (2 laws x 2 mu each), for a run started again
    assert len(list((out / "tests").glob("*.json"))) == 8
    for name in ("convergence", "qp_gamma", "biaxial", "qp_mu"):
        assert is_png(out / f"relaxed_friction_{name}.png"), name
    assert "substep convergence" in stdout and "wrote" in stdout
    assert "\nshear: mean" in stdout and "\nbiaxial: mean" in stdout


def check_relaxed_friction_biaxial(out, p):
    """3. The small biaxial test (70 disks, p / k_n = 1e-2, mu = 0 and 0.5, eps1 to 1 % in 4
    steps): F = diag(F11, lam (1 - eps1)) with F12 = F21 = 0, sigma_11 = -p held."""
    steps = read_csv(out / "biaxial_steps.csv")
    columns = ("eps1", "e11", "F11", "F12", "F21", "F22", "sigma11_Pa", "sigma12_Pa",
               "sigma22_Pa", "q_over_p", "volumetric_strain", "z", "sliding_share",
               "dissipation_Pa", "newton_iterations", "wall_s")  # fmt: skip
    assert set(columns) <= set(steps[0]), steps[0].keys()
    tests = {(r["law"], float(r["mu"])): r for r in read_csv(out / "biaxial_tests.csv")}
    assert set(tests) == {(law, mu) for law in ("relaxed", "taylor") for mu in (0.0, 0.5)}
    for (law, mu), t in tests.items():
        rows = [r for r in steps if (r["law"], float(r["mu"])) == (law, mu)]
        assert [float(r["eps1"]) for r in rows] == pytest.approx([0, 0.0025, 0.005, 0.0075, 0.01])
        lam = float(rows[0]["F11"])  # (the confined F_c = lam I)
        for r in rows:
            s11, s12, s22 = (float(r[f"sigma{ij}_Pa"]) for ij in ("11", "12", "22"))
            assert float(r["F12"]) == float(r["F21"]) == 0.0
            assert float(r["F22"]) == pytest.approx(lam * (1.0 - float(r["eps1"])), rel=1e-14)
            # q / p from the principal stresses (s1 <= s3 < 0): (s3 - s1) / -(s1 + s3)
            s1, s3 = np.linalg.eigvalsh([[s11, s12], [s12, s22]])
            assert float(r["q_over_p"]) == pytest.approx((s3 - s1) / -(s1 + s3), rel=1e-9)
            if int(r["step"]) > 0:  # the lateral stress held, the axial one the larger
                miss = abs(float(r["control_error_Pa"]))
                assert abs(s11 + p) <= 1e-8 * p + miss and miss <= 1e-2 * p and -s22 > p
            if law == "relaxed":  # rigid networks (as in the shear)
                assert float(r["z"]) >= (4.0 if mu == 0.0 else 3.0)
            if mu == 0.0:
                assert r["sliding_share"] == "" and float(r["dissipation_Pa"]) == 0.0
        assert t["stopped"] == "False", (law, mu, t)
        assert float(t["eps1_reached"]) == pytest.approx(0.01, rel=1e-12)
        assert float(t["critical_from"]) == pytest.approx(0.0075, rel=1e-12)
        assert float(t["qp_critical_last_quarter"]) <= float(t["qp_peak"])
        assert np.mean([float(r["q_over_p"]) for r in rows[3:]]) == pytest.approx(
            float(t["qp_critical_last_quarter"]), rel=1e-12
        )
    last = tests["relaxed", 0.5]
    assert float(last["dissipation_final_Pa"]) > 0.0 and 0.0 < float(last["sliding_final"]) < 1.0
    qp = {k: float(t["qp_critical_last_quarter"]) for k, t in tests.items()}
    # friction raises q/p (critical 0.12 -> 0.33 at 1 %); the affine Taylor RVE mobilises more
    # than the relaxed disks without friction (0.29)
    assert 0.05 < qp["relaxed", 0.0] < 0.2 and qp["relaxed", 0.5] > 2 * qp["relaxed", 0.0]
    assert qp["taylor", 0.0] > 2 * qp["relaxed", 0.0]
    summary = read_csv(out / "biaxial_summary.csv")
    assert len(summary) == 4 and {"qp_peak_mean", "qp_critical_last_quarter_mean",
                                  "eps1_reached_min", "stopped"} <= set(summary[0])  # fmt: skip


def test_relaxed_friction_study_goes_on_where_it_stopped(tmp_path):
    """A study stopped after mu = 0 and started again (``--force``, now with mu = 0 and 0.5)
    takes the tests it ran from ``OUT/tests``: their rows come back as they were, wall times
    included, and only the new ones run."""
    demo = load_demo("relaxed_friction_study")
    options = dict(small=True, verbose=False, tests=("biaxial",))
    demo.run(tmp_path, mus=(0.0,), **options)
    first = read_csv(tmp_path / "biaxial_steps.csv")
    assert len(list((tmp_path / "tests").glob("*.json"))) == 2
    demo.run(tmp_path, force=True, **options)
    again = read_csv(tmp_path / "biaxial_steps.csv")
    assert len(list((tmp_path / "tests").glob("*.json"))) == 4
    assert [r for r in again if float(r["mu"]) == 0.0] == first  # (wall_s alike: not run again)
    assert {float(r["mu"]) for r in again} == {0.0, 0.5}


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


def own_files(name):
    """The files (names, patterns) that demo ``name`` writes in its ``--out``."""
    return RUN_FILES if name == "slope" else load_demo(name).FILES


def snapshot(folder):
    """{path: (size, mtime in ns)} of every file under ``folder``: equal if none was written."""
    return {
        str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in folder.rglob("*")
        if p.is_file()
    }


def assert_refused(name, folder, *args, ranks=1, env=None):
    """Running the demo into ``folder`` again is refused on every rank: exit status 2, one line
    ``error: --out ... holds a ... run``, no file touched."""
    before = snapshot(folder)
    proc = subprocess.run(
        demo_command(name, *args, "--out", folder, ranks=ranks),
        cwd=ROOT,
        env=dict(MPI_ENV, **(env or {})),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert_user_error(proc, f"--out {folder} holds a", "--force", mpirun=ranks > 1)
    assert snapshot(folder) == before


@pytest.mark.parametrize("name", demo_params())
def test_demo_runs_small_serially(name, tmp_path):
    """``--force`` into a folder with a killed run's leftover and a user's note: the leftover goes,
    the note stays; the same command again without ``--force`` is refused."""
    (tmp_path / NOTE).write_text("mine")
    leftover = tmp_path / f"{own_files(name)[0]}.tmp4242"  # (an atomic write's temporary file)
    leftover.write_text("stale")
    proc = run_demo(name, "--small", "--force", "--out", tmp_path)
    CHECKS[name](tmp_path, proc.stdout)
    assert not leftover.exists() and (tmp_path / NOTE).read_text() == "mine"
    assert_refused(name, tmp_path, "--small")


@pytest.mark.parametrize("name", demo_params())
def test_demo_runs_small_under_mpi(name, tmp_path):
    """A folder with only a user's note holds no run: the demo writes beside it; run again, it is
    refused on both ranks alike."""
    (tmp_path / NOTE).write_text("mine")
    proc = run_demo(name, "--out", tmp_path, ranks=2, env={"DEMO_SMALL": "1"})
    CHECKS[name](tmp_path, proc.stdout)
    assert (tmp_path / NOTE).read_text() == "mine"
    assert_refused(name, tmp_path, ranks=2, env={"DEMO_SMALL": "1"})


@pytest.mark.parametrize("name", [n for n in DEMOS if n != "slope"])
def test_a_small_run_has_its_own_default_folder(name):
    if os.environ.get("DEMO_SMALL") == "1":
        pytest.skip("DEMO_SMALL=1 makes every run small")
    demo = load_demo(name)
    assert demo.parse_args([]).out == os.path.join("results", name)
    assert demo.parse_args(["--small"]).out == os.path.join("results", f"{name}-small")
    assert demo.parse_args(["--small", "--out", "mine"]).out == "mine"


@pytest.mark.parametrize("name", ["footing3d", "fabric3d"])
def test_overwrite_is_the_deprecated_name_of_force(name):
    demo = load_demo(name)
    assert not demo.parse_args([]).force
    with pytest.warns(FutureWarning, match="--overwrite is deprecated: use --force"):
        assert demo.parse_args(["--overwrite"]).force


# -- the rule itself ---------------------------------------------------------------------------

FILES = ("table.csv", "figure.png", "run_[0-9]*/summary.json")


def run_files_of_fill():
    return ["run_1/summary.json", "table.csv", "table.csv.tmp99"]


def fill(folder):
    """A folder with a run's files (one in a run's subfolder, one left by a killed atomic
    write) and a user's: returns the run's, sorted."""
    for name in ("table.csv", "table.csv.tmp99", "run_1/summary.json", NOTE, "run_x/summary.json"):
        (folder / name).parent.mkdir(exist_ok=True)
        (folder / name).write_text("x")
    return run_files_of_fill()


def test_a_folder_with_the_commands_files_is_refused_and_force_removes_only_them(tmp_path):
    run = fill(tmp_path)
    assert held_files(tmp_path, FILES) == run
    before = snapshot(tmp_path)
    with pytest.raises(RunExistsError) as refusal:
        claim_out(tmp_path, FILES, False, "demo")
    assert str(refusal.value) == (
        f"--out {tmp_path} holds a demo run (run_1/summary.json, table.csv, table.csv.tmp99): "
        "add --force to replace it, or choose another --out"
    )
    assert snapshot(tmp_path) == before
    assert claim_out(tmp_path, FILES, True, "demo") == run
    assert sorted(snapshot(tmp_path)) == [NOTE, "run_x/summary.json"]
    assert claim_out(tmp_path, FILES, False, "demo") == []  # (nothing of a run left)


def test_a_new_folder_is_created_and_an_unwritable_one_refused(tmp_path):
    assert claim_out(tmp_path / "new" / "out", FILES, False, "demo") == []
    assert (tmp_path / "new" / "out").is_dir()
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutFolderError, match="cannot be written.*choose a writable folder"):
        claim_out(tmp_path / "file" / "out", FILES, True, "demo")


def test_a_long_list_of_files_is_cut_short(tmp_path):
    for k in range(12):
        (tmp_path / f"f{k:02d}.csv").write_text("x")
    with pytest.raises(RunExistsError, match=r"f07.csv and 4 more\): add --force"):
        claim_out(tmp_path, ["f*.csv"], False, "demo")


def test_default_folders():
    assert default_out("demo") == os.path.join("results", "demo")
    assert default_out("demo", small=True) == os.path.join("results", "demo-small")


@pytest.mark.mpi
def test_every_rank_gets_rank_0s_answer(tmp_path):
    comm = MPI.COMM_WORLD
    folder = comm.bcast(tmp_path, root=0)  # (each rank's pytest has its own temporary folder)
    if comm.rank == 0:
        fill(folder)
    comm.barrier()
    with pytest.raises(RunExistsError, match="holds a demo run"):
        claim_out(folder, FILES, False, "demo", comm)
    # rank 0 removed them; every rank is told which
    assert claim_out(folder, FILES, True, "demo", comm) == run_files_of_fill()
