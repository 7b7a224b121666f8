"""benchmarks/blas.py names the loaded BLAS, times a matrix product and writes its section."""

import re

import blas
import numpy as np


def test_the_loaded_blas_is_named():
    libraries = blas.loaded_libraries()  # numpy is loaded: its BLAS is mapped
    assert libraries and all("blas" in p or "lapack" in p for p in libraries)
    assert blas.blas_name(libraries) != "unknown"
    assert blas.blas_name(["/usr/lib/x86_64-linux-gnu/blas/libblas.so.3.11.0"]) == "reference"
    serial = "/usr/lib/x86_64-linux-gnu/openblas-serial/libblas.so.3"
    assert blas.blas_name([serial]) == "OpenBLAS (serial)"


def test_two_saved_runs_compare_into_a_section(tmp_path, capsys):
    for name in ("a", "b"):
        blas.main(["--parts", "matmul", "--repeats", "1", "--save", str(tmp_path / name)])
    np.savez(tmp_path / "a.npz", demo=np.array([-3.0, -3.0]))
    np.savez(tmp_path / "b.npz", demo=np.array([-3.0 * (1 + 1e-15)] * 2))
    doc = tmp_path / "performance.md"
    doc.write_text("# Performance\n")
    blas.main(["--compare", str(tmp_path / "a"), str(tmp_path / "b"), "--doc", str(doc)])
    out = capsys.readouterr().out
    assert "GFLOP/s" in out and "slope demo: settlement" in out
    text = doc.read_text()
    assert "## 11. The platform's BLAS" in text and "<!-- end: benchmarks/blas.py -->" in text
    assert "| matmul 1000 x 1000, GFLOP/s |" in text and re.search(r"\| [0-9.]+e-1[56] \|", text)
