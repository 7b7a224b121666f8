"""Every command line prints its help (and its argument errors) once under MPI, not once per
rank; exit statuses as without MPI."""

import subprocess
import sys

from dolfinx_granular.io.commandline import world_rank

import pytest

from helpers import MPI_ENV, demo_command, load_demo

DEMOS = [
    "slope",
    "footing3d",
    "fabric3d",
    "granular_column",
    "relaxed_study",
    "relaxed_friction_study",
    "rve_study",
    "friction_study",
    "slope_collapse",
]


@pytest.mark.parametrize("name", DEMOS)
def test_help_is_printed_once_under_mpi(name):
    proc = subprocess.run(
        demo_command(name, "--help", ranks=2), env=MPI_ENV, capture_output=True, text=True
    )
    assert proc.returncode == 0 and proc.stdout.count("usage:") == 1, proc.stdout[-2000:]


def test_package_command_help_and_errors_once_under_mpi():
    launcher = demo_command("slope", ranks=2)[:-2]  # the launcher and its arguments alone
    base = [*launcher, sys.executable, "-m", "dolfinx_granular"]
    proc = subprocess.run([*base, "--help"], env=MPI_ENV, capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stdout.count("usage:") == 1, proc.stdout[-2000:]
    proc = subprocess.run([*base, "generate", "x"], env=MPI_ENV, capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stderr.count("error:") == 1, proc.stderr[-2000:]


def test_world_rank_outside_mpi_is_zero():
    assert world_rank() == 0


def test_relaxed_friction_study_options():
    """The issue's study from the command line (options in place of the full run's values)."""
    demo = load_demo("relaxed_friction_study")
    argv = ["--tests", "biaxial,shear", "--particles", "700", "--seeds", "0,1,2", "--mus",
            "0,0.1,0.3,0.5,1", "--pressures", "1e-3,1e-2", "--max-shear", "0.5", "--shear-steps",
            "250", "--budget", "0"]  # fmt: skip
    args = demo.parse_args(argv)
    options = {name: getattr(args, name) for name in demo.OPTIONS}
    cfg = demo.configuration(False, "default", options)
    assert cfg["tests"] == ("shear", "biaxial") and cfg["particles"] == 700
    assert cfg["seeds"] == (0, 1, 2) and cfg["mus"] == (0.0, 0.1, 0.3, 0.5, 1.0)
    assert cfg["pressures"] == (1e-3, 1e-2) and (cfg["max_shear"], cfg["shear_steps"]) == (0.5, 250)
    # the full run's biaxial test: to 30 % in steps of 0.5 %
    assert cfg["max_strain"] == 0.3 and cfg["max_strain"] / cfg["biaxial_steps"] == 0.005
    small = demo.configuration(True, None, {name: None for name in demo.OPTIONS})
    assert (small["max_strain"], small["biaxial_steps"], small["budget"]) == (0.01, 4, None)


@pytest.mark.parametrize(
    "option, value, words",
    [
        ("--tests", "shear,triaxial", "convergence, shear, biaxial"),
        ("--mus", "0,-0.5", "mu >= 0"),
        ("--mus", "0,x", "'x' is not a number"),
        ("--pressures", "0.05", "(0, 0.01]"),
        ("--particles", "5", ">= 10"),
        ("--seeds", "0,0", "repeats a value"),
        ("--max-strain", "1.2", "(0, 0.9)"),
        ("--biaxial-steps", "0", ">= 1"),
        ("--budget", "-1", ">= 0"),
    ],
)
def test_relaxed_friction_study_bad_option_is_an_error_naming_it(option, value, words, capsys):
    demo = load_demo("relaxed_friction_study")
    with pytest.raises(SystemExit) as exit_:
        demo.parse_args([option, value])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert exit_.value.code == 2 and f"error: argument {option}: " in err and words in err, err
    assert "give " in err and "e.g. " in err  # (the fix)
