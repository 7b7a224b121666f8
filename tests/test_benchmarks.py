"""The benchmark scripts run (at tiny size) so that they cannot rot."""

from scripts import load_benchmark


def test_kernel_benchmark_runs(capsys):
    load_benchmark("kernel").main(["--points", "20", "--sizes", "70", "--repeats", "1"])
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.strip().startswith("70 ")]
    assert len(rows) == 1 and rows[0].endswith("x")
