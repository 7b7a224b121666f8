"""The scripts the tests run: the demos (not a package) imported as modules, and the command line
that runs the slope demo, serially or under mpirun. Benchmark scripts need nothing here: pytest
puts ``benchmarks/`` on the path (``pythonpath`` in pyproject.toml), so tests ``import kernel``."""

import csv
import importlib
import importlib.util
import json
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SLOPE = os.path.join(ROOT, "demos", "slope.py")
# mpirun as root (CI containers) needs these
MPI_ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")


def load_benchmark(name):
    """The module ``benchmarks/<name>.py`` (a plain import: ``benchmarks/`` is on pytest's path)."""
    return importlib.import_module(name)


def load_demo(name):
    """The module ``demos/<name>.py``."""
    spec = importlib.util.spec_from_file_location(name, os.path.join(ROOT, "demos", f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # (dataclasses look their module up there)
    spec.loader.exec_module(module)
    return module


def slope_command(*args, ranks=1):
    """``python demos/slope.py *args``, under MPI with ``ranks`` processes if ranks > 1 (with the
    launcher of this Python's MPI; the test fails without one)."""
    cmd = [sys.executable, SLOPE, *map(str, args)]
    if ranks > 1:
        from dolfinx_granular._dolfinx import mpi_command

        launcher = mpi_command(ranks)
        assert launcher is not None, "no MPI launcher (mpiexec/mpirun) found"
        cmd = [*launcher, *cmd]
    return cmd


def read_outputs(out):
    """The slope demo's ``summary.json`` (a dict) and ``convergence.csv`` (a list of row dicts)
    in the folder ``out``."""
    with open(os.path.join(out, "summary.json")) as f:
        summary = json.load(f)
    with open(os.path.join(out, "convergence.csv")) as f:
        rows = list(csv.DictReader(f))
    return summary, rows
