"""The benchmark scripts run (at tiny size) so that they cannot rot."""

import importlib.util
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def load(name):
    spec = importlib.util.spec_from_file_location(name, os.path.join(ROOT, "benchmarks", f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_kernel_benchmark_runs(capsys):
    load("kernel").main(["--points", "20", "--sizes", "70", "--repeats", "1"])
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.strip().startswith("70 ")]
    assert len(rows) == 1 and rows[0].endswith("x")
