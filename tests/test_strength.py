"""The strength of an RVE (drivers/strength.py, ``python -m dolfinx_granular strength``) and the
element tests' cache (drivers/element_cache.py): 70 disks, p / k_n = 1e-2, mu 0 and 0.5, the
axial strain to 1-2 % in 2-4 steps."""

import contextlib
import copy
import csv
import io
import itertools
import json
import math

from dolfinx_granular import friction_angle, generate_packing, strength_curve
from dolfinx_granular.__main__ import main
from dolfinx_granular.drivers import element_progress
from dolfinx_granular.drivers import element_tests as et
from dolfinx_granular.drivers.element_cache import ElementTestCache
from dolfinx_granular.drivers.strength import COLUMNS, falls, nondecreasing
from dolfinx_granular.io.strength_table import falling_lines, merge_curves, read_curve, write_curve

import numpy as np
import pytest

P = 1e-2  # p / k_n
TARGETS = (0.005, 0.01)  # the cache's tests: eps1 to 1 % in 2 steps
#: the command's small curve: 70 disks, one seed, mu 0 and 0.5, eps1 to 2 % in 4 steps
SMALL = ["--particles", "70", "--seeds", "0", "--mus", "0,0.5", "--pressures", "1e-2",
         "--max-strain", "0.02", "--steps", "4"]  # fmt: skip


def plain(rows):
    """``rows`` as JSON text (NumPy scalars as Python's; NaN as NaN): equal iff equal values."""
    return json.dumps(rows, default=lambda v: v.item())


@pytest.fixture(scope="module")
def packing():
    return generate_packing(70, seed=0, pressure=P)


def run(cache, packing, mu=0.5, targets=TARGETS, budget=None, k_t=et.K_T, substep=None,
        mu_r=0.0):  # fmt: skip
    law = et.make_law("relaxed", packing, mu, k_t=k_t, mu_r=mu_r)
    if substep is not None:
        law.settings.substep = substep
    return cache.run(et.BIAXIAL, law, packing, 0, P, targets, budget)


def test_the_cache_reads_a_test_back_instead_of_running_it(tmp_path, packing):
    first = run(ElementTestCache(tmp_path), packing)
    assert not first.cached and first.stop == "" and len(first.rows) == 3
    [stored] = tmp_path.glob("*.json")
    mtime = stored.stat().st_mtime_ns
    # a fresh cache (as a study started again) and a fresh law: the same rows, the file untouched
    again = run(ElementTestCache(tmp_path), packing)
    assert again.cached and plain(again.rows) == plain(first.rows) and again.stop == first.stop
    assert again.seconds == first.seconds and stored.stat().st_mtime_ns == mtime
    # the rows come from the file, not from a run: a sentinel written into it comes back
    record = json.loads(stored.read_text())
    record["rows"][-1]["q_over_p"] = 42.0
    stored.write_text(json.dumps(record))
    assert run(ElementTestCache(tmp_path), packing).rows[-1]["q_over_p"] == 42.0


def test_the_rows_are_load_tests(tmp_path, packing):
    """The cache's first run is load_test's, row for row (the wall times aside)."""
    stored = run(ElementTestCache(tmp_path), packing)
    rows, stop = et.load_test(et.BIAXIAL, et.make_law("relaxed", packing, 0.5), P, TARGETS)
    drop = [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]
    assert plain(drop) == plain([{k: v for k, v in r.items() if k != "wall_s"}
                                 for r in stored.rows])  # fmt: skip
    assert stop == stored.stop == ""


@pytest.mark.parametrize(
    "change",
    [dict(mu=0.0), dict(targets=(0.005, 0.0075)), dict(k_t=0.5 * et.K_T), dict(substep=5e-4),
     dict(mu_r=0.1)],
    ids=["mu", "targets", "k_t", "substep", "mu_r"],
)  # fmt: skip
def test_a_changed_parameter_misses_the_cache(tmp_path, packing, change):
    cache = ElementTestCache(tmp_path)
    run(cache, packing)
    other = run(cache, packing, **change)
    assert not other.cached and len(list(tmp_path.glob("*.json"))) == 2
    assert run(cache, packing, **change).cached  # (and is stored under its own key)


def without_wall_times(rows):
    return plain([{k: v for k, v in r.items() if k != "wall_s"} for r in rows])


def assert_same_rows(a, b):
    """The rows a and b have the same columns, the same counts, and the same values to
    round-off (a resumed law builds its candidate contacts afresh, in another order); the wall
    times aside."""
    assert [list(r) for r in a] == [list(r) for r in b]
    for ra, rb in zip(a, b):
        for k, v in ra.items():
            if isinstance(v, int):
                assert v == rb[k], k
            elif k != "wall_s":
                np.testing.assert_allclose(v, rb[k], rtol=1e-12, atol=1e-12 * abs(ra["p_Pa"]),
                                           err_msg=k)  # fmt: skip


def test_a_test_stopped_by_its_budget_goes_on_under_a_larger_one(tmp_path, packing):
    cache = ElementTestCache(tmp_path)
    stopped = run(cache, packing, budget=0.0)  # (the budget is spent by the confinement)
    assert stopped.stop.startswith(f"stopped: {et.BUDGET_STOP}") and len(stopped.rows) == 1
    assert stopped.resumed_rows == 0
    [progress] = tmp_path.glob("*.progress.npz")  # (kept: the test can go on)
    assert run(cache, packing, budget=0.0).cached
    whole = run(cache, packing, budget=None)
    assert not whole.cached and whole.stop == "" and len(whole.rows) == 3
    assert whole.resumed_rows == 1  # (the confined state's row)
    assert whole.seconds > stopped.seconds  # (the confinement's seconds counted once, in both)
    assert not progress.exists()  # (the test has ended)
    assert run(cache, packing, budget=0.0).cached  # (the whole test serves any budget)
    # the same rows as the test run in one go (the confinement's row the stopped run's)
    straight = run(ElementTestCache(tmp_path / "straight"), packing)
    assert_same_rows(whole.rows, straight.rows)
    assert plain(whole.rows[0]) == plain(stopped.rows[0])


def test_a_killed_test_goes_on_from_its_last_step(tmp_path, packing):
    cache = ElementTestCache(tmp_path)
    stopped = run(cache, packing, budget=0.0)
    [record] = tmp_path.glob("*.json")
    record.unlink()  # (killed before its rows were written: only its progress is on disk)
    whole = run(cache, packing)
    assert not whole.cached and whole.stop == "" and len(whole.rows) == 3
    assert plain(whole.rows[0]) == plain(stopped.rows[0])  # (its wall time too: not run again)


def test_a_test_goes_on_from_any_step_to_the_same_rows(packing):
    """Resumed from its progress after each step (a fresh law, as a new process has), the test
    ends with the rows of the run in one go, to round-off: the resumed law builds its candidate
    contacts afresh, in another order."""
    kept = []
    law = et.make_law("relaxed", packing, 0.5)
    rows, stop = et.load_test(et.BIAXIAL, law, P, TARGETS, keep=lambda at: kept.append(
        copy.deepcopy(at)))  # fmt: skip
    assert stop == "" and [len(at.rows) for at in kept] == [1, 2, 3]
    for at in kept[:2]:
        again, stop = et.load_test(et.BIAXIAL, et.make_law("relaxed", packing, 0.5), P, TARGETS,
                                   resume=copy.deepcopy(at))  # fmt: skip
        assert stop == ""
        assert without_wall_times(again[: len(at.rows)]) == without_wall_times(at.rows)
        assert_same_rows(again, rows)


def test_the_progress_round_trips_and_refuses_another_key(tmp_path, packing):
    kept = []
    law = et.make_law("relaxed", packing, 0.5)
    et.load_test(et.BIAXIAL, law, P, TARGETS[:1], keep=kept.append)
    at, key, path = kept[-1], {"test": 1}, tmp_path / "p.npz"
    element_progress.save(path, at, key)
    back = element_progress.load(path, key, type(law.initial_state(1)))
    assert back.state.equals(at.state) and plain(back.rows) == plain(at.rows)
    assert np.array_equal(back.F, at.F) and np.array_equal(back.Fc, at.Fc)
    for name in ("targets", "done", "cuts", "left", "dissipation_c", "seconds"):
        assert getattr(back, name) == getattr(at, name), name
    assert element_progress.load(path, {"test": 2}, type(law.initial_state(1))) is None
    path.write_bytes(b"damaged")  # (a run killed while writing, or a file edited by hand)
    assert element_progress.load(path, key, type(law.initial_state(1))) is None


@pytest.fixture(scope="module")
def command(tmp_path_factory):
    """The small curve written by the command: (folder, its CSV's path, stdout)."""
    folder = tmp_path_factory.mktemp("strength")
    out = folder / "strength.csv"
    argv = ["strength", *SMALL, "-o", str(out)]
    code, printed = _main(argv)
    assert code == 0, printed
    return folder, out, printed


def _main(argv):
    """``main(argv)`` with its stdout: (exit status, text)."""
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        code = main(argv)
    return code, text.getvalue()


def test_the_command_writes_the_documented_columns(command, packing):
    folder, out, printed = command
    with open(out, newline="") as f:
        rows = list(csv.DictReader(f))
    assert tuple(rows[0]) == COLUMNS and len(rows) == 2
    assert [float(r["mu"]) for r in rows] == [0.0, 0.5]
    for r in rows:
        assert r["law"] == "relaxed" and float(r["p_over_kn"]) == P and float(r["kappa"]) == 100
        assert int(r["seeds"]) == 1 and int(r["stopped"]) == 0 and r["stop_reasons"] == ""
        assert float(r["eps1_reached_min"]) == pytest.approx(0.02, rel=1e-12)
        # the angles of the ratios: phi = asin(q/p), tan phi (one seed: no spread)
        for which in ("peak", "cs"):
            s = float(r[f"sin_phi_{which}_mean"])
            phi = float(r[f"phi_{which}_deg_mean"])
            assert phi == pytest.approx(math.degrees(math.asin(s)), rel=1e-12)
            assert float(r[f"tan_phi_{which}_mean"]) == pytest.approx(
                math.tan(math.radians(phi)), rel=1e-12
            )
            assert float(r[f"phi_{which}_deg_std"]) == 0.0
        assert float(r["sin_phi_cs_mean"]) <= float(r["sin_phi_peak_mean"])
    # the critical state of mu = 0.5 is the element test's: the mean q/p over the last quarter
    targets = np.linspace(0.0, 0.02, 5)[1:]
    steps, stop = et.load_test(et.BIAXIAL, et.make_law("relaxed", packing, 0.5), P, targets)
    m = et.measures(steps, stop, 0.02, et.BIAXIAL)
    assert float(rows[1]["sin_phi_cs_mean"]) == m["qp_critical_last_quarter"]
    assert float(rows[1]["sin_phi_peak_mean"]) == m["qp_peak"]
    # friction raises the strength (no number of the physics fixed here: that is the demo's)
    assert float(rows[1]["phi_cs_deg_mean"]) > float(rows[0]["phi_cs_deg_mean"]) > 0.0
    assert "phi_cs [deg]" in printed and "(2 run, 0 from" in printed


def test_a_second_command_reads_its_tests_from_the_cache(command):
    folder, out, _ = command
    before = out.read_text()
    code, printed = _main(["strength", *SMALL, "-o", str(out), "--force"])
    assert code == 0 and "(0 run, 2 from" in printed and printed.count("(cached)") == 2
    assert out.read_text() == before


def test_a_command_stopped_by_its_budget_goes_on_and_says_so(tmp_path, command):
    _, out, _ = command
    first = tmp_path / "first.csv"
    code, printed = _main(["strength", *SMALL, "--budget", "1e-6", "-o", str(first)])
    stopped = f"(stopped: {et.BUDGET_STOP} of 1e-06 s reached)"
    assert code == 0 and printed.count(stopped) == 2, printed
    code, printed = _main(["strength", *SMALL, "-o", str(tmp_path / "second.csv"),
                           "--cache", str(tmp_path / "strength_cache")])  # fmt: skip
    assert code == 0 and printed.count("eps1 2.00 % (went on from 0.00 %)") == 2, printed
    # the curve of the tests run in one go (to round-off: the resumed RVEs list their
    # candidate contacts afresh)
    a, b = read_curve(tmp_path / "second.csv"), read_curve(out)
    assert [r["mu"] for r in a] == [r["mu"] for r in b] and len(a) == 2
    for ra, rb in zip(a, b):
        for k in ("sin_phi_peak_mean", "sin_phi_cs_mean", "eps1_reached_mean"):
            np.testing.assert_allclose(ra[k], rb[k], rtol=1e-10, err_msg=k)


def test_each_step_prints_a_line_per_step_of_the_tests_that_run(tmp_path, command):
    _, out, _ = command
    argv = ["strength", *SMALL, "-o", str(tmp_path / "a.csv"), "--each-step"]
    code, printed = _main(argv)
    steps = [line for line in printed.splitlines() if line.startswith("  relaxed mu ")]
    # the confined state and 4 steps of each of the 2 tests, each before its test's line
    assert code == 0 and len(steps) == 10, printed
    assert steps[0].startswith("  relaxed mu 0 p/kn 0.01 seed 0: eps1 0.00 %, q/p ")
    assert steps[4].startswith("  relaxed mu 0 p/kn 0.01 seed 0: eps1 2.00 %, q/p ")
    assert printed.index(steps[4]) < printed.index("relaxed mu 0 p/kn 0.01 seed 0: eps1 2.00 %")
    # the tests read back run no step
    code, printed = _main([*argv[:-2], str(tmp_path / "b.csv"), "--each-step"])
    assert code == 0 and "  relaxed mu " not in printed


def test_the_python_function_gives_the_commands_curve(command):
    folder, out, _ = command
    curve = strength_curve(particles=70, seeds=(0,), mus=(0.0, 0.5), pressures=(P,),
                           max_strain=0.02, steps=4, cache=folder / "strength_cache")  # fmt: skip
    assert plain([[r[k] for k in COLUMNS] for r in curve]) == plain(
        [[r[k] for k in COLUMNS] for r in read_curve(out)]
    )


def test_an_existing_output_is_refused_without_force(command, capsys):
    _, out, _ = command
    before = out.read_bytes()
    assert main(["strength", *SMALL, "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "exists" in err and "--force" in err
    assert out.read_bytes() == before


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--mus", "0,-0.5"], "mu >= 0"),
        (["--mus", "0,x"], "'x' is not a number"),
        (["--pressures", "0.05"], "(0, 0.01]"),
        (["--pressures", "0"], "(0, 0.01]"),
        (["--particles", "5"], ">= 10"),
        (["--seeds", "0,0"], "repeats a value"),
        (["--max-strain", "1.2"], "(0, 0.9)"),
        (["--steps", "0"], ">= 1"),
        (["--kn", "-1"], "stiffness > 0"),
        (["--law", "dem"], "invalid choice"),
        (["--law", "taylor", "--substep", "1e-3"], "--substep"),
        (["--law", "taylor", "--rolling", "0.1"], "--rolling is a setting of the relaxed RVE"),
        (["--rolling", "-0.1"], "mu_r >= 0"),
        (["-o", "strength.txt"], ".csv"),
        (["-o", "no/such/folder/s.csv"], "does not exist"),
    ],
)
def test_bad_values_are_one_line_errors(tmp_path, capsys, argv, words):
    if not any(a.startswith("no/") or a.endswith(".txt") for a in argv):
        argv = [*argv, "-o", str(tmp_path / "s.csv")]
    assert main(["strength", "--cache", str(tmp_path / "cache"), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and len(err.splitlines()) == 1 and words in err, err
    assert not (tmp_path / "cache").exists()  # (refused before any work)


def test_the_python_function_names_a_bad_value(tmp_path):
    with pytest.raises(ValueError, match=r"mu = -0.1 is out of range: give contact friction"):
        strength_curve(mus=(-0.1,), cache=tmp_path)
    with pytest.raises(ValueError, match=r"p_over_kn = 0.02 is out of range"):
        strength_curve(pressures=(0.02,), cache=tmp_path)
    with pytest.raises(ValueError, match=r"mu repeats a value in \(0.5, 0.5\)"):
        strength_curve(mus=(0.5, 0.5), cache=tmp_path)
    assert not any(tmp_path.iterdir())  # (refused before any work)


CURVE = [  # a curve by hand: phi (cs) 10, 30, 32 degrees at mu 0, 0.5, 1; peak 2 degrees more
    dict(law="relaxed", mu=mu, p_over_kn=P, phi_cs_deg_mean=phi, phi_peak_deg_mean=phi + 2.0)
    for mu, phi in ((0.0, 10.0), (0.5, 30.0), (1.0, 32.0))
] + [dict(law="relaxed", mu=0.5, p_over_kn=1e-3, phi_cs_deg_mean=25.0, phi_peak_deg_mean=27.0)]


@pytest.mark.parametrize(
    "mu, which, phi",
    [(0.25, "cs", 20.0), (0.75, "cs", 31.0), (0.5, "cs", 30.0), (0.0, "cs", 10.0),
     (1.0, "cs", 32.0), (0.1, "peak", 16.0)],
)  # fmt: skip
def test_friction_angle_is_linear_in_mu(mu, which, phi):
    assert friction_angle(CURVE, mu, P, which) == pytest.approx(phi, rel=1e-14)


@pytest.mark.parametrize(
    "args, kwargs, words",
    [
        ((1.5, P), {}, "mu = 1.5 lies outside the curve's mu = 0 to 1"),
        ((-0.1, P), {}, "outside"),
        ((0.5, 2e-3), {}, "give one of 0.001, 0.01"),
        ((0.5, P), {"which": "mean"}, "give one of peak, cs"),
        ((0.5, 1e-3), {}, "outside"),  # (one mu there: no range to interpolate in)
    ],
)
def test_friction_angle_errors_outside_the_curve(args, kwargs, words):
    if args == (0.5, 1e-3):
        assert friction_angle(CURVE, *args) == 25.0  # (its one value, exactly)
        args = (0.4, 1e-3)
    with pytest.raises(ValueError, match=words.replace("(", r"\(")):
        friction_angle(CURVE, *args, **kwargs)


def test_friction_angle_errors_where_no_angle_was_measured():
    curve = [dict(r) for r in CURVE]
    curve[1]["phi_cs_deg_mean"] = math.nan  # mu = 0.5: its tests stopped before a step
    with pytest.raises(ValueError, match="stop_reasons"):
        friction_angle(curve, 0.25, P)
    assert friction_angle(curve, 0.0, P) == 10.0  # (a tabulated mu needs only its own value)


@pytest.mark.parametrize(
    "values, weights, fit",
    [
        ([1.0, 3.0, 2.0, 4.0], [1, 1, 1, 1], [1.0, 2.5, 2.5, 4.0]),
        ([1.0, 3.0, 2.0, 4.0], [1, 1, 3, 1], [1.0, 2.25, 2.25, 4.0]),
        ([5.0, 4.0, 3.0], [1, 1, 2], [3.75, 3.75, 3.75]),
        ([1.0, math.nan, 0.5, 2.0], [1, 1, 1, 1], [0.75, math.nan, 0.75, 2.0]),
    ],
)
def test_nondecreasing_pools_adjacent_violators(values, weights, fit):
    assert np.allclose(nondecreasing(values, weights), fit, rtol=1e-15, equal_nan=True)


def test_nondecreasing_is_the_least_squares_fit(rng):
    """Against every split of 7 values into consecutive runs whose weighted means do not fall:
    the best of them (the least squares over non-decreasing fits is one of these) is the fit,
    and a non-decreasing input comes back bit for bit."""
    for _ in range(20):
        values, weights = rng.normal(size=7), rng.uniform(0.5, 3.0, size=7)
        best, cost = None, math.inf
        for cuts in itertools.product((0, 1), repeat=6):
            ends = [k + 1 for k, c in enumerate(cuts) if c] + [7]
            starts = [0, *ends[:-1]]
            means = [np.average(values[a:b], weights=weights[a:b]) for a, b in zip(starts, ends)]
            if np.all(np.diff(means) >= 0.0):
                f = np.concatenate([np.full(b - a, m) for a, b, m in zip(starts, ends, means)])
                if (c := np.sum(weights * (f - values) ** 2)) < cost:
                    best, cost = f, c
        fit = nondecreasing(values, weights)
        assert np.all(np.diff(fit) >= 0.0) and np.allclose(fit, best, rtol=1e-13, atol=1e-15)
        ordered = np.sort(values)
        assert np.array_equal(nondecreasing(ordered, weights), ordered)


def test_friction_angle_on_the_monotone_fit_of_a_falling_curve():
    """phi_cs 10, 30, 26 degrees at mu 0, 0.5, 1 (3 seeds each): the fit pools 0.5 and 1 at
    28; a curve that does not fall reads the same either way."""
    falling = [dict(r, seeds=3) for r in CURVE[:3]]
    falling[2]["phi_cs_deg_mean"] = 26.0
    assert friction_angle(falling, 0.5, P) == 30.0
    assert friction_angle(falling, 0.5, P, monotone=True) == pytest.approx(28.0, rel=1e-15)
    assert friction_angle(falling, 0.25, P, monotone=True) == pytest.approx(19.0, rel=1e-15)
    for mu in (0.1, 0.5, 0.9):
        assert friction_angle(CURVE, mu, P, monotone=True) == friction_angle(CURVE, mu, P)


def _curve_file(path, rows):
    """``rows`` (mu, phi_cs, seeds, particles) at p / k_n = P written as a curve's CSV and read
    back."""
    full = []
    for mu, phi, seeds, particles in rows:
        row = dict.fromkeys(COLUMNS, 0.0)
        row.update(law="relaxed", mu=mu, p_over_kn=P, seeds=seeds, particles=particles,
                   k_n=2.8e7, k_t=2.8e7, phi_cs_deg_mean=phi, phi_peak_deg_mean=phi + 2.0,
                   stop_reasons="")  # fmt: skip
        full.append(row)
    write_curve(path, full)
    return read_curve(path)


def test_merged_curves_take_a_later_curves_rows(tmp_path):
    """3 packings at mu 0, 0.5, 1 (phi_cs falling from 30 to 26); 9 at 0.5 and a new 0.25: the
    later rows replace the earlier ones at the same mu, in their place, and add the others."""
    three = [(0.0, 10.0, 3, 70), (0.5, 30.0, 3, 70), (1.0, 26.0, 3, 70)]
    three = _curve_file(tmp_path / "a.csv", three)
    nine = _curve_file(tmp_path / "b.csv", [(0.5, 24.0, 9, 70), (0.25, 18.0, 9, 70)])
    merged = merge_curves([three, nine])
    assert [(r["mu"], r["seeds"]) for r in merged] == [(0.0, 3), (0.5, 9), (1.0, 3), (0.25, 9)]
    assert merged[1] is nine[0] and merged[0] is three[0]
    assert friction_angle(merged, 0.5, P) == 24.0 and friction_angle(merged, 0.75, P) == 25.0
    assert falls(merged, "cs") == [] and falls(three, "cs") == [(0.5, 1.0, 30.0, 26.0)]
    assert merge_curves([three]) == three and merge_curves([nine, three])[0]["seeds"] == 3
    other = _curve_file(tmp_path / "c.csv", [(0.5, 24.0, 3, 200)])
    with pytest.raises(ValueError, match=r"differ in particles \(70 and 200\)"):
        merge_curves([three, other])


def test_the_falls_of_a_curve_are_named_per_line():
    """phi_cs 30 -> 26 degrees from mu 0.5 to 1 on the line without rolling friction, and
    peak 42 -> 40 from 0.5 to 1 on mu_r = 0.2 mu (sharing the row at mu = 0): one line each;
    the other pressure's rows, on their own, do not fall."""
    rows = [dict(r, mu_r=0.0) for r in CURVE]
    rows[2]["phi_cs_deg_mean"] = 26.0
    rows += [
        dict(law="relaxed", mu=m, mu_r=0.2 * m, p_over_kn=P, phi_cs_deg_mean=phi,
             phi_peak_deg_mean=peak)
        for m, phi, peak in ((0.5, 30.0, 42.0), (1.0, 31.0, 40.0))
    ]  # fmt: skip
    assert falls(rows[:3], "cs") == [(0.5, 1.0, 30.0, 26.0)] and falls(rows[:3], "peak") == []
    lines = falling_lines(rows)
    assert len(lines) == 2, lines
    assert "p/kn 0.01 mu_r/mu 0: phi_cs 30.0 deg at mu 0.5 > 26.0 deg at mu 1 " in lines[0]
    assert "p/kn 0.01 mu_r/mu 0.2: phi_peak 42.0 deg at mu 0.5 > 40.0 deg at mu 1 " in lines[1]
    assert falling_lines([dict(r, mu_r=0.0) for r in CURVE]) == []
    # a line whose mu_r / mu differ in the last bits (0.2 x 0.3 / 0.3 and 0.2 x 0.7 / 0.7):
    # named once
    line = [
        dict(rows[0], mu=m, mu_r=0.2 * m, phi_cs_deg_mean=phi)
        for m, phi in ((0.3, 30.0), (0.7, 28.0))
    ]
    assert len({r["mu_r"] / r["mu"] for r in line}) == 2
    assert [ln.split("(")[0] for ln in falling_lines([dict(rows[0]), *line])] == [
        "  falls: relaxed p/kn 0.01 mu_r/mu 0.2: phi_cs 30.0 deg at mu 0.3 > 28.0 deg at mu 0.7 "
    ]


def test_friction_angle_of_the_commands_csv(command):
    _, out, _ = command
    curve = read_curve(out)
    mid = friction_angle(curve, 0.25, P)
    assert mid == pytest.approx(np.mean([r["phi_cs_deg_mean"] for r in curve]), rel=1e-14)


def test_rolling_friction_is_a_column_and_a_line_of_the_curve(tmp_path):
    """Rows at mu_r 0 and 0.2 mu: friction_angle follows the line mu_r = ratio mu (through
    mu = 0, a point of every line); the Taylor RVE has no rolling resistance."""
    rows = [dict(r, mu_r=0.0) for r in CURVE] + [
        dict(
            law="relaxed",
            mu=mu,
            mu_r=0.2 * mu,
            p_over_kn=P,
            phi_cs_deg_mean=phi,
            phi_peak_deg_mean=phi + 1.0,
        )
        for mu, phi in ((0.5, 40.0),)
    ]  # fmt: skip (mu = 0: mu_r = 0 on every line, the row without rolling)
    assert friction_angle(rows, 0.25, P) == pytest.approx(20.0, rel=1e-14)
    assert friction_angle(rows, 0.25, P, rolling_ratio=0.2) == pytest.approx(25.0, rel=1e-14)
    with pytest.raises(ValueError, match="outside"):
        friction_angle(rows, 0.25, P, rolling_ratio=0.1)  # (no row on that line but mu = 0)
    with pytest.raises(ValueError, match="rolling friction is a setting of the relaxed RVE"):
        strength_curve(law="taylor", rolling=(0.1,), cache=tmp_path)
    with pytest.raises(ValueError, match="rolling friction is a setting of the relaxed RVE"):
        et.make_law("taylor", generate_packing(20, seed=0), 0.5, mu_r=0.1)


def test_a_curve_without_the_rolling_column_reads_as_without_rolling(command, tmp_path):
    _, out, _ = command
    with open(out, newline="") as f:
        rows = list(csv.DictReader(f))
    old = tmp_path / "old.csv"
    with open(old, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=[c for c in COLUMNS if c != "mu_r"], extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    assert [r["mu_r"] for r in read_curve(old)] == [0.0, 0.0]
    assert friction_angle(read_curve(old), 0.25, P) == friction_angle(read_curve(out), 0.25, P)


def test_the_command_measures_rolling_resistance(tmp_path):
    """``--rolling 0,0.2`` at mu = 0.5: one row per mu_r; the rolling springs raise the peak
    strength (eps1 to 1 %, 70 disks)."""
    out = tmp_path / "s.csv"
    argv = ["strength", "--particles", "70", "--seeds", "0", "--mus", "0.5", "--rolling",
            "0,0.2", "--pressures", "1e-2", "--max-strain", "0.01", "--steps", "2", "-o",
            str(out)]  # fmt: skip
    code, printed = _main(argv)
    assert code == 0, printed
    rows = read_curve(out)
    assert [(r["mu"], r["mu_r"]) for r in rows] == [(0.5, 0.0), (0.5, 0.2)]
    assert rows[1]["sin_phi_peak_mean"] > rows[0]["sin_phi_peak_mean"]
    assert "mur0.2" in " ".join(p.name for p in (tmp_path / "strength_cache" / "tests").iterdir())
