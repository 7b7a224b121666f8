"""The scripts the tests run (benchmarks and demos are not a package): import them as modules, or
build the command line that runs the slope demo, serially or under mpirun."""

import csv
import importlib.util
import json
import os
import shutil
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SLOPE = os.path.join(ROOT, "demos", "slope.py")
# mpirun as root (CI containers) needs these
MPI_ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")


def _load(folder, name):
    spec = importlib.util.spec_from_file_location(name, os.path.join(ROOT, folder, f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def load_benchmark(name):
    """The module ``benchmarks/<name>.py``."""
    return _load("benchmarks", name)


def load_demo(name):
    """The module ``demos/<name>.py``."""
    return _load("demos", name)


def slope_command(*args, ranks=1):
    """``python demos/slope.py *args``, under ``mpirun -n ranks`` if ranks > 1 (the test is
    skipped without mpirun)."""
    cmd = [sys.executable, SLOPE, *map(str, args)]
    if ranks > 1:
        mpirun = shutil.which("mpirun")
        if mpirun is None:
            pytest.skip("mpirun not found")
        cmd = [mpirun, "-n", str(ranks), "--oversubscribe", *cmd]
    return cmd


def read_outputs(out):
    """The slope demo's ``summary.json`` (a dict) and ``convergence.csv`` (a list of row dicts)
    in the folder ``out``."""
    with open(os.path.join(out, "summary.json")) as f:
        summary = json.load(f)
    with open(os.path.join(out, "convergence.csv")) as f:
        rows = list(csv.DictReader(f))
    return summary, rows
