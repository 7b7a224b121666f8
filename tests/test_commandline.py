"""Every command line prints its help (and its argument errors) once under MPI, not once per
rank; exit statuses as without MPI."""

import subprocess
import sys

from dolfinx_granular.io.commandline import world_rank

import pytest

from helpers import MPI_ENV, demo_command

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
