"""The slope's command line keeps results and refuses what it would ignore: an ``--out`` that
holds a run (unless ``--force``, which removes that run's files and no others), options that
``--resume`` or load control would ignore, abbreviations; ``--allow-overlaps`` travels with the
run; the load-settlement curve is signed as the log and ``summary.json``."""

import json

import numpy as np
import pytest

from helpers import assert_user_error, load_demo, run_slope_demo

SMALL = ["--particles", "70", "--seed", "1", "--no-figure"]


def demo(*args):
    """The slope demo's process for ``args``, not checked (it is to fail)."""
    return run_slope_demo(None, *args, timeout=300, check=False)[0]


def snapshot(folder):
    return {p.name: p.read_bytes() for p in folder.iterdir()}


@pytest.fixture
def old_run(tmp_path):
    """A folder with an earlier run's files (their content does not matter) and a user's own."""
    out = tmp_path / "old"
    out.mkdir()
    for name in ("summary.json", "restart.npz", "slope.png", "load_settlement.png"):
        (out / name).write_text(f"the earlier run's {name}")
    (out / "notes.txt").write_text("the user's own file")
    return out


def test_out_that_holds_a_run_is_refused(old_run):
    before = snapshot(old_run)
    line = assert_user_error(demo("--out", str(old_run), *SMALL), "--out", "holds a slope run")
    assert "--force" in line and f"--resume {old_run}" in line and "notes.txt" not in line
    assert snapshot(old_run) == before


@pytest.mark.parametrize(
    "args, words",
    [
        (["--particle", "50"], ["unrecognized arguments: --particle 50"]),
        (["--resume", "x", "--steps", "3"], ["--resume", "drop --steps", "--stop-after"]),
        (["--resume", "x", "--friction", "0.3"], ["--resume", "drop --friction"]),
        (["--resume", "x", "--force"], ["--resume", "drop --force"]),
        (["--resume", "x", "--out", "y"], ["--resume", "drop --out"]),
        (["--resume", "x", "--slope-ratio", "2"], ["--resume", "drop --slope-ratio"]),
        (["--resume", "x", "--steps", "20"], ["drop --steps"]),  # even the default value
        (["--max-increments", "5"], ["--max-increments", "--path-following"]),
        (["--path-following", "gravity", "--steps", "3"], ["gravity", "drop --steps"]),
        (["--path-following", "sideways"], ["invalid choice: 'sideways'"]),
        (["--rve", "relaxed"], ["confining pressure", "--confinement"]),
        (["--rve", "relaxed", "--friction", "0.5"], ["confining pressure", "--confinement"]),
        (["--confinement", "1e6"], ["confinement", "280000"]),
        (["--rolling-friction", "0.1"], ["rolling resistance", "--rve relaxed"]),
        (["--rolling-friction", "-0.1"], ["--rolling-friction", ">= 0"]),
        (["--residual-tolerance", "0.5"], ["residual_tolerance", "[0, 0.01]", "stalls"]),
        (["--residual-tolerance", "-0.0001"], ["--residual-tolerance", ">= 0"]),
        (["--resume", "x", "--residual-tolerance", "1e-5"], ["drop --residual-tolerance"]),
    ],
)
def test_options_that_would_be_ignored_are_refused(args, words):
    assert_user_error(demo(*args), *words)


@pytest.mark.slow
def test_force_replaces_the_run_and_keeps_other_files(old_run):
    """--force: the earlier run's files go (its figures too, with --no-figure), the user's stay."""
    proc, summary = run_slope_demo(old_run, *SMALL, "--steps", "1", "--force")
    assert summary["status"] == "converged" and summary["completed_steps"] == 2
    assert (old_run / "notes.txt").read_text() == "the user's own file"
    assert not (old_run / "slope.png").exists() and not (old_run / "load_settlement.png").exists()
    assert (old_run / "restart.npz").read_bytes()[:2] == b"PK"


@pytest.mark.slow
def test_allow_overlaps_is_used_recorded_and_resumed(tmp_path):
    """One disk's radius x 1.15 (its contacts overlap by 9 % of the radius sums, P(I) is 0.5 %
    of the modulus): refused with the option named; with --allow-overlaps the run takes the
    packing as it is, records it, and --resume keeps it."""
    from dolfinx_granular import Packing, generate_packing

    p = generate_packing(70, seed=1)
    radii = p.radii.copy()
    radii[0] *= 1.15
    swollen = tmp_path / "swollen.npz"
    Packing(p.centers, radii, p.box).save(swollen)
    args = ["--packing", swollen, "--steps", "2", "--no-figure"]
    assert_user_error(demo(*args, "--out", str(tmp_path / "refused")), "--allow-overlaps")
    out = tmp_path / "run"
    _, summary = run_slope_demo(out, *args, "--allow-overlaps", "--stop-after", "1")
    assert summary["status"] == "stopped" and summary["allow_overlaps"] is True
    with np.load(out / "restart.npz") as f:
        assert json.loads(str(f["options"]))["allow_overlaps"] is True
    proc, _ = run_slope_demo(None, "--resume", out, "--no-figure", "--stop-after", "2")
    with open(out / "summary.json") as f:
        resumed = json.load(f)
    assert resumed["resumed_from"] == 1 and resumed["completed_steps"] == 2
    assert resumed["allow_overlaps"] is True and resumed["prestress_ratio"] > 1e-3


@pytest.mark.slow
def test_step_log_after_cutbacks(tmp_path):
    """The doubled load cuts back toward its limit load: more steps than the nominal 3, each
    logged with its phase and load parameter (no "step 4/3")."""
    proc, summary = run_slope_demo(
        tmp_path, *SMALL, "--steps", "2", "--load-factor", "2", check=False
    )
    assert proc.returncode == 1 and summary["cutbacks"] and summary["steps"] == 3
    steps = [ln for ln in proc.stdout.splitlines() if ln.startswith("step ")]
    assert len(steps) == summary["completed_steps"] > 3
    for line, info in zip(steps, summary["step_info"]):
        assert line.startswith(f"step {info['step']:2d} ({info['phase']}, t = {info['t']:.4g}): ")
    assert proc.stdout.splitlines()[-1].startswith("slope: failed after ")
    # said once, in the run's own log: no warning of the stepper or the solver beside it
    assert "LoadPathWarning" not in proc.stderr and "SolveFailedWarning" not in proc.stderr


@pytest.mark.parametrize(
    "elapsed,done,left,bound,note",
    [
        (60.0, 2, 3, False, "; ~1.5 min left"),
        (20.0, 2, 3, False, "; ~30 s left"),
        (600.0, 3, 37, False, "; ~2.1 h left"),
        (120.0, 4, 40, True, "; at most ~20.0 min left"),
        (1.0, 2, 3, False, ""),  # a fast run: no estimate
        (60.0, 0, 3, False, ""),
        (60.0, 5, 0, False, ""),  # past the nominal steps (cut-backs)
    ],
)
def test_time_left(elapsed, done, left, bound, note):
    from dolfinx_granular.slope.run import time_left_note

    assert time_left_note(elapsed, done, left, bound) == note


def test_load_settlement_curve_is_signed_as_the_summary():
    """Settlement and footing load negative = downward, as in the log and summary.json."""
    pytest.importorskip("dolfinx")
    from dolfinx_granular.slope.summary import load_settlement_curve

    info = [
        {"phase": "gravity", "t": 1.0, "settlement": -0.5, "footing_load": 0.0},
        {"phase": "footing", "t": 0.5, "settlement": -2.0, "footing_load": -2e7},
        {"phase": "footing", "t": 1.0, "settlement": -3.8, "footing_load": -4e7},
    ]
    settlement, load = load_settlement_curve(info)
    assert settlement.tolist() == [-0.5, -2.0, -3.8] and load.tolist() == [0.0, -2e7, -4e7]
    for s in info:
        s["non_elliptic_points"] = 0
    settlement, load, _ = load_demo("slope_collapse").curve({"step_info": info})
    assert settlement == [-2.0, -3.8] and load == [-20.0, -40.0]  # the footing steps, MN/m


def test_load_settlement_title_is_not_clipped(tmp_path):
    """The slope's title (the longest law name) lies inside the figure: it was cut at the
    right edge ('... as in summary.jso')."""
    from dolfinx_granular.io.postprocess import plot_load_settlement

    title = (
        "slope, 700-particle RVE, Coulomb friction mu = 0.5 (negative = downward, as in "
        "summary.json)"
    )
    fig = plot_load_settlement(
        tmp_path / "curve.png", [("law", [0.0, -1.0], [0.0, -1e6], None)], title=title
    )
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()
    box = fig.axes[0].title.get_window_extent(renderer)
    assert fig.bbox.x0 <= box.x0 and box.x1 <= fig.bbox.x1 and box.y1 <= fig.bbox.y1, box
