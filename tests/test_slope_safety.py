"""``demos/slope.py --factor-of-safety``: the command line's one-line refusals (bad options, an
``--out`` that holds a run) and, slow, the ``--small`` run on 2 ranks: safety.json's fields, FS
consistent with its trials and bracketed to the tolerance, Bishop's numbers those of
``bishop_factor_of_safety`` called directly, the trials' run folders, the mechanism figure, a
second run refused without --force, a resume of the finished run that changes nothing and one of
a run cut short that takes the finished trials from their folders."""

import csv
import json
import math
import os
import shutil
from pathlib import Path

from dolfinx_granular.io.strength_table import read_curve, write_curve
from dolfinx_granular.slope.geometry import SlopeGeometry
from dolfinx_granular.slope.limit_equilibrium import (
    bishop_factor_of_safety,
    infinite_slope_factor_of_safety,
)
from dolfinx_granular.slope.safety import continuation_stop
from dolfinx_granular.slope.safety_strength import Strength

import pytest

from helpers import assert_user_error, is_png, run_slope_demo

pytest.importorskip("dolfinx")

#: the slope's demo script
DEMO = Path(__file__).resolve().parent.parent / "demos" / "slope.py"
#: what a test of the command line passes besides its own options
FS = ["--factor-of-safety", "--no-figure"]


@pytest.fixture(scope="module")
def curve_csv(tmp_path_factory):
    """A strength curve by hand at p/k_n = 1e-2 (the default confinement), mu 0.05 to 1."""
    from dolfinx_granular.drivers.strength import COLUMNS

    rows = []
    for mu in (0.05, 0.25, 0.5, 1.0):
        phi = 10.0 + 20.0 * math.sqrt(mu)
        row = {k: 0.0 for k in COLUMNS}
        row.update(
            law="relaxed",
            mu=mu,
            p_over_kn=1e-2,
            phi_cs_deg_mean=phi,
            phi_peak_deg_mean=phi + 2.0,
            stop_reasons="",
        )
        rows.append(row)
    path = tmp_path_factory.mktemp("curve") / "strength.csv"
    write_curve(path, rows)
    return path


def main(capsys, *argv):
    """The slope's command line in this process: (exit status, stderr's lines)."""
    from dolfinx_granular.slope.cli import main as slope_main

    code = slope_main([*FS, *argv])
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    return code, err


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--fs-tolerance", "-0.01"], "--fs-tolerance: must be a number in (0, 1)"),
        (["--fs-tolerance", "0"], "must be a number in (0, 1)"),
        (["--friction", "0"], "give --friction MU > 0"),
        (["--friction", "-0.5"], "--friction: must be a finite number >= 0"),
        (["--footing-scale", "-1"], "--footing-scale: must be a finite number >= 0"),
        (["--rve", "taylor"], "frictional relaxed RVE"),
        (["--path-following", "gravity"], "drop --path-following"),
        (["--load-factor", "2"], "drop --load-factor"),
        (["--unload"], "drop --unload"),
        (["--steps", "3"], "give --footing-scale S > 0, or drop --steps"),
        (["--confinement", "0"], "needs a confining pressure"),
        (["--packing", "p.npz"], "give --strength CSV measured for it"),
        (["--strength", "no/such.csv"], "--strength no/such.csv:"),
        (["--resume", "no/such/run"], "no factor-of-safety run to continue there"),
        (["--resume", "x", "--friction", "0.3"], "drop --friction"),
        (["--reduction-steps", "4"], "--reduction-steps applies to --continuation"),
        (["--continuation", "--reduction-steps", "0"], "--reduction-steps: must be"),
        (["--continuation", "--resume", "x"], "drop --continuation"),
    ],
)
def test_bad_options_are_one_line_errors(capsys, tmp_path, argv, words):
    out = tmp_path / "out"
    code, err = main(capsys, *argv, *([] if "--resume" in argv else ["--out", str(out)]))
    assert code == 2 and len(err) == 1 and err[0].startswith("error: "), err
    assert words in err[0], err[0]
    assert not out.exists()  # (refused before the folder is touched)


def test_a_curve_that_lacks_the_slope_is_refused(capsys, tmp_path, curve_csv):
    out = tmp_path / "out"
    code, err = main(
        capsys, "--strength", str(curve_csv), "--confinement", "2.8e4", "--out", str(out)
    )
    assert code == 2 and "p_over_kn = 0.001 is not in the curve" in err[0] and len(err) == 1
    code, err = main(capsys, "--strength", str(curve_csv), "--friction", "2", "--out", str(out))
    assert code == 2 and "mu = 2 lies outside" in err[0] and not out.exists()
    code, err = main(capsys, "--strength", str(curve_csv), "--strength-seeds", "2")
    assert code == 2 and "apply to a measured strength curve" in err[0]


def test_several_curves_are_merged_and_checked(capsys, tmp_path, curve_csv):
    """``--strength A B``: B's rows replace A's at the same mu; a row of other particles is
    refused naming both files, and the merged curve is checked against the slope as one."""
    from dolfinx_granular.io.strength_table import read_curve, write_curve

    rows = read_curve(curve_csv)
    bigger = tmp_path / "bigger.csv"
    write_curve(bigger, [dict(rows[2], particles=200)])
    out = tmp_path / "out"
    code, err = main(capsys, "--strength", str(curve_csv), str(bigger), "--out", str(out))
    assert code == 2 and len(err) == 1 and not out.exists()
    assert f"--strength {curve_csv} {bigger}: the rows at law relaxed, mu 0.5" in err[0], err[0]
    assert "differ in particles" in err[0]
    more = tmp_path / "more.csv"
    write_curve(more, [dict(rows[2], seeds=9)])
    code, err = main(
        capsys, "--strength", str(curve_csv), str(more), "--confinement", "2.8e4", "--out", str(out)
    )
    assert code == 2 and "p_over_kn = 0.001 is not in the curve" in err[0] and not out.exists()


def test_small_takes_a_given_curve_without_its_own_curves_options(capsys, tmp_path, curve_csv):
    """``demos/slope.py --small --strength CSV``: --small's --strength-seeds and
    --strength-strain (for a curve it measures) are left out, so the run goes on to check the
    curve (here refused for its pressure, before anything runs)."""
    import runpy

    demo = runpy.run_path(str(DEMO), run_name="slope_demo")
    for extra in ([], ["--continuation"]):
        out = tmp_path / f"out{len(extra)}"
        code = demo["main"]([*FS, "--small", *extra, "--strength", str(curve_csv),
                             "--confinement", "2.8e4", "--out", str(out)])  # fmt: skip
        err = capsys.readouterr().err
        assert code == 2 and "p_over_kn = 0.001 is not in the curve" in err, err
        assert not out.exists()


def test_safety_options_without_factor_of_safety_are_refused(capsys):
    from dolfinx_granular.slope.cli import main as slope_main

    assert slope_main(["--footing-scale", "0.5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "error: --footing-scale apply to --factor-of-safety only: add it, or drop them"


def test_rows_sets_the_mesh(capsys):
    from dolfinx_granular.slope.cli import build_parser, main, options_of

    def geometry(*argv):
        return options_of(build_parser().parse_args(list(argv))).geometry

    assert geometry("--rows", "2", "--slope-ratio", "2") == SlopeGeometry.with_slope_ratio(
        2, rows=2
    )
    assert (
        geometry("--rows", "2").n_cells == 40 and geometry("--rows", "2", "--refine", "2").rows == 4
    )
    assert geometry() == SlopeGeometry()
    assert main(["--rows", "0"]) == 2
    assert "--rows: must be an integer >= 1, got 0" in capsys.readouterr().err


def test_an_out_that_holds_a_safety_run_is_refused(capsys, tmp_path, curve_csv):
    out = tmp_path / "old"
    (out / "trials" / "mu_0.5").mkdir(parents=True)
    (out / "safety.json").write_text("the earlier run's answer")
    (out / "trials" / "mu_0.5" / "summary.json").write_text("an earlier trial")
    (out / "notes.txt").write_text("the user's own")
    code, err = main(capsys, "--strength", str(curve_csv), "--out", str(out))
    assert code == 2 and len(err) == 1
    assert "holds a factor-of-safety run" in err[0] and "--force" in err[0]
    assert f"--factor-of-safety --resume {out}" in err[0]
    assert (out / "safety.json").read_text() == "the earlier run's answer"
    assert (out / "trials" / "mu_0.5" / "summary.json").read_text() == "an earlier trial"


# -- the --small run on 2 ranks ----------------------------------------------------------------


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """The --small factor-of-safety run on 2 ranks: (folder, its log, safety.json)."""
    out = tmp_path_factory.mktemp("safety") / "small"
    proc, _ = run_slope_demo(out, "--factor-of-safety", "--small", ranks=2, timeout=1500)
    with open(out / "safety.json") as f:
        return out, proc.stdout, json.load(f)


@pytest.mark.slow
def test_safety_json_holds_the_answer(small):
    _, log, s = small
    for key in (
        "factor_of_safety",
        "mu_ratio",
        "phi_cs",
        "phi_peak",
        "bishop_cs",
        "bishop_peak",
        "infinite_slope_cs",
        "geometry",
        "footing_scale",
        "trials",
    ):
        assert s[key] is not None, key
    assert s["status"] == "done" and s["converged"] and s["bound"] is None
    assert s["footing_scale"] == 0.5 and s["mu"] == 0.5 and s["tolerance"] == 0.05
    assert SlopeGeometry(**s["geometry"]) == SlopeGeometry(rows=2)
    for t in s["trials"]:
        assert set(t) >= {"mu_f", "carried", "passed", "seconds", "why"}
        assert f"mu_f = {t['mu_f']:.6g}" in log
    assert f"factor of safety {s['factor_of_safety']:.4g}" in log


@pytest.mark.slow
def test_the_trials_bracket_the_factor_of_safety(small):
    out, _, s = small
    trials = s["trials"]
    failing = max((t for t in trials if not t["passed"]), key=lambda t: t["mu_f"])
    passing = min((t for t in trials if t["passed"]), key=lambda t: t["mu_f"])
    assert failing["mu_f"] < s["mu_f"] < passing["mu_f"]
    assert s["mu_f_bracket"] == [failing["mu_f"], passing["mu_f"]]
    assert not any(t["passed"] for t in trials if t["mu_f"] <= failing["mu_f"])
    assert all(t["passed"] for t in trials if t["mu_f"] >= passing["mu_f"])
    assert failing["carried"] < 1.0 <= passing["carried"]
    # FS from the curve the run wrote: tan phi(mu) / tan phi(mu_f), the ends within 5 %
    strength = Strength(read_curve(out / "strength.csv"), s["p_over_kn"], s["mu"])
    at_pass, at_fail = (strength.factor_of_safety(t["mu_f"]) for t in (passing, failing))
    lo, hi = sorted([at_pass, at_fail])
    assert s["factor_of_safety_bracket"] == [lo, hi]
    if s["curve_limited"]:  # the frictions bracketed to the tolerance, FS as known as phi
        assert passing["mu_f"] / failing["mu_f"] - 1.0 <= s["tolerance"] or at_fail < at_pass
    else:
        assert 0.0 <= at_fail / at_pass - 1.0 <= s["tolerance"]
    assert lo <= s["factor_of_safety"] <= hi
    assert s["factor_of_safety"] == strength.factor_of_safety(s["mu_f"])
    assert s["phi_cs"] == strength.phi(s["mu"]) and s["mu_ratio"] == s["mu"] / s["mu_f"]
    assert s["factor_of_safety_peak"] == strength.factor_of_safety(s["mu_f"], "peak")


@pytest.mark.slow
def test_limit_equilibrium_is_bishops_own(small):
    _, _, s = small
    g = SlopeGeometry(**s["geometry"])
    for which in ("cs", "peak"):
        circle = bishop_factor_of_safety(g, s[f"phi_{which}"], s["footing_scale"])
        assert s[f"bishop_{which}"] == circle.factor_of_safety
        assert s[f"bishop_circle_{which}"]["radius"] == circle.radius
        # the confinement (2.8e5 Pa, the default) as the cohesion p tan phi
        c = s["options"]["confinement"] * math.tan(math.radians(s[f"phi_{which}"]))
        confined = bishop_factor_of_safety(g, s[f"phi_{which}"], s["footing_scale"], cohesion=c)
        assert s[f"bishop_{which}_confined"] == confined.factor_of_safety
        assert confined.factor_of_safety > circle.factor_of_safety
    assert s["infinite_slope_cs"] == infinite_slope_factor_of_safety(g, s["phi_cs"])


@pytest.mark.slow
def test_every_trial_has_its_run_folder_and_row(small):
    out, _, s = small
    with open(out / "trials.csv") as f:
        rows = list(csv.DictReader(f))
    assert [float(r["mu_f"]) for r in rows] == [t["mu_f"] for t in s["trials"]]
    assert [r["passed"] for r in rows] == [str(t["passed"]) for t in s["trials"]]
    for t in s["trials"]:
        with open(out / t["folder"] / "summary.json") as f:
            summary = json.load(f)
        assert summary["friction"] == t["mu_f"] and summary["status"] == t["status"]
    assert is_png(out / "mechanism.png") and s["mechanism"]["mu_f"] == s["mu_f_bracket"][0]


@pytest.mark.slow
def test_a_second_run_is_refused_and_a_resume_changes_nothing(small):
    out, _, s = small
    before = {p: p.read_bytes() for p in (out / "safety.json", out / "trials.csv")}
    proc, _ = run_slope_demo(out, "--factor-of-safety", "--small", check=False)
    assert_user_error(proc, "holds a factor-of-safety run", "--force")
    proc, _ = run_slope_demo(None, "--factor-of-safety", "--resume", out)
    assert "nothing to resume" in proc.stdout
    assert {p: p.read_bytes() for p in before} == before
    assert os.path.isdir(out / "strength_cache")


@pytest.mark.slow
def test_a_resume_takes_the_finished_trials_from_their_folders(small, tmp_path):
    """safety.json cut back to the first two trials, as if the run had been killed: the resume
    reads the others from their run folders (no trial runs again) and gives the same answer."""
    out, _, s = small
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    cut = dict(s, status="running", trials=s["trials"][:2])
    (copy / "safety.json").write_text(json.dumps(cut))
    proc, _ = run_slope_demo(None, "--factor-of-safety", "--resume", copy)
    assert (
        proc.stdout.count("finished before") == len(s["trials"]) and "slope: 1:1" not in proc.stdout
    )
    with open(copy / "safety.json") as f:
        again = json.load(f)
    assert again["trials"] == s["trials"] and again["status"] == "done"
    for key in ("factor_of_safety", "factor_of_safety_bracket", "mu_f_bracket", "bishop_cs"):
        assert again[key] == s[key], key
    assert is_png(copy / "mechanism.png")


@pytest.mark.slow
def test_with_rolling_friction_the_trials_divide_both_frictions(tmp_path):
    """--rolling-friction 0.1 (mu 0.5): every trial runs at mu_f and 0.2 mu_f, the strength is
    measured on that line, and phi at mu is read there (a coarse bracket: few trials)."""
    out = tmp_path / "rolling"
    run_slope_demo(out, "--factor-of-safety", "--small", "--rolling-friction", "0.1",
                   "--fs-tolerance", "0.5", ranks=2, timeout=1500)  # fmt: skip
    with open(out / "safety.json") as f:
        s = json.load(f)
    assert s["status"] == "done" and s["rolling_friction"] == 0.1 and len(s["trials"]) >= 2
    for t in s["trials"]:
        with open(out / t["folder"] / "summary.json") as f:
            run = json.load(f)
        assert run["friction"] == t["mu_f"]
        assert run["rolling_friction"] == pytest.approx(0.2 * t["mu_f"], rel=1e-14)
    curve = read_curve(out / "strength.csv")
    assert all(r["mu_r"] == pytest.approx(0.2 * r["mu"], rel=1e-12) for r in curve)
    assert s["phi_cs"] == Strength(curve, 1e-2, 0.5, rolling_ratio=0.2).phi(0.5)


# -- strength reduction by continuation ------------------------------------------------------------


@pytest.mark.slow
def test_the_continuation_brackets_the_factor_of_safety_in_one_run(tmp_path):
    """--small --continuation on 2 ranks: one run (trials/reduction) carries the weight at mu
    and lowers mu until a step finds no equilibrium; safety.json's bracket is its last
    friction carried and the one that failed, FS between their FS, the mechanism drawn; a
    resume changes nothing."""
    out = tmp_path / "continuation"
    proc, _ = run_slope_demo(out, "--factor-of-safety", "--small", "--continuation", ranks=2,
                             timeout=1500)  # fmt: skip
    with open(out / "safety.json") as f:
        s = json.load(f)
    assert s["status"] == "done" and s["method"] == "continuation"
    assert s["options"]["reduction"] == pytest.approx(0.5 / 64, rel=1e-14)
    passing, failing = s["trials"]
    assert passing["passed"] and not failing["passed"]
    assert failing["folder"] == passing["folder"] == os.path.join("trials", "reduction")
    lo, hi = s["mu_f_bracket"]
    assert (lo, hi) == (failing["mu_f"], passing["mu_f"]) and lo < s["mu_f"] < hi < 0.5
    fs_lo, fs_hi = s["factor_of_safety_bracket"]
    assert fs_lo <= s["factor_of_safety"] <= fs_hi and s["factor_of_safety"] > 1.0
    assert s["mu_ratio"] == pytest.approx(0.5 / s["mu_f"], rel=1e-14)
    with open(out / "trials" / "reduction" / "summary.json") as f:
        run = json.load(f)
    reduction = [x for x in run["step_info"] if x["phase"] == "reduction"]
    assert reduction[-1]["friction"] == passing["mu_f"] and run["failed"]["phase"] == "reduction"
    stop = continuation_stop(run)  # (how it ended, read from the run's own steps)
    assert {k: s[k] for k in stop} == stop and stop["settlement_growth"] is not None
    assert "the settlement's growth over the last steps" in proc.stdout
    assert is_png(out / "mechanism.png")
    assert "safety: continuation from mu = 0.5" in proc.stdout
    proc, _ = run_slope_demo(None, "--factor-of-safety", "--resume", out)
    assert "nothing to resume" in proc.stdout
    # a run stopped after its trials were written (status running) ends from them alone
    with open(out / "safety.json", "w") as f:
        json.dump({**s, "status": "running"}, f)
    proc, _ = run_slope_demo(None, "--factor-of-safety", "--resume", out)
    with open(out / "safety.json") as f:
        again = json.load(f)
    assert again["status"] == "done" and again["trials"] == s["trials"]
    assert {k: again[k] for k in stop} == stop
