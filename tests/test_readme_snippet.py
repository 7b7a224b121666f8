"""The README's snippets of "Use it in your own DOLFINx model" run as printed (serial and MPI):
the granular column, the granular layer on a linear elastic base, the 3-D column, and the
pyvista look at the slope's results."""

import os
import re

import numpy as np
import pytest

from helpers import ROOT, run_slope_demo

SECTION = "## Use it in your own DOLFINx model"


def readme_snippets():
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as f:
        text = f.read()
    assert SECTION in text, f"README.md lost its section {SECTION!r}"
    section = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 4, "the section holds the column, the layered column, 3-D and pyvista"
    return blocks


def run(code, capsys, namespace=None):
    namespace = namespace if namespace is not None else {"__name__": "readme_snippet"}
    exec(compile(code, "README.md", "exec"), namespace)
    return namespace, capsys.readouterr().out


def test_snippets_are_short():
    assert [len(b.strip().splitlines()) <= 25 for b in readme_snippets()] == [True] * 4


@pytest.mark.mpi
def test_snippet_runs_and_converges(capsys):
    namespace, out = run(readme_snippets()[0], capsys)
    lines = [line for line in out.splitlines() if line.startswith("p = ")]
    assert len(lines) == 3 and all(line.endswith("converged: True") for line in lines), out
    assert all(r"Newton steps" in line for line in lines)
    assert namespace["result"].converged
    # The column settles under the pressure (u_y < 0 somewhere on every rank that owns a node).
    u = namespace["u"]
    assert u.x.array[1::2].min() < 0.0


@pytest.mark.mpi
def test_layered_snippet_carries_the_load(capsys):
    column, layered = readme_snippets()[:2]
    namespace, _ = run(column, capsys)
    namespace, out = run(layered, capsys, namespace)
    assert "3e5 Pa carried: True" in out, out
    assert namespace["stepper"].failed is None
    assert namespace["rock"].cauchy()[:, 1, 1].max(initial=-1.0) < 0.0  # the base is compressed


@pytest.mark.mpi
def test_3d_snippet_converges(capsys):
    namespace, out = run(readme_snippets()[2], capsys)
    assert out.strip().endswith("converged: True"), out
    assert namespace["material"].dim == 3 and namespace["material"].P.x.array.size
    u = namespace["u"]
    assert u.x.array[2::3].min(initial=0.0) <= 0.0  # the top settles
    if u.x.array.size:
        assert np.abs(u.x.array[0::3]).max() < np.abs(u.x.array[2::3]).max()


def test_pyvista_snippet_reads_the_last_step(tmp_path):
    """Run as a post-processing script of its own (a separate process, as a user would)."""
    import subprocess
    import sys

    from dolfinx_granular.slope.geometry import SlopeGeometry

    out = tmp_path / "results" / "slope"
    steps = 2
    _, summary = run_slope_demo(out, "--particles", "40", "--steps", steps, "--no-figure")
    check = (
        "\nvm = slope.cell_data['von_mises']\n"
        "print('steps', reader.time_values, 'cells', len(vm), vm.min() > 0)\n"
    )
    script = tmp_path / "look.py"
    script.write_text(readme_snippets()[3] + check)
    env = dict(os.environ, PYVISTA_OFF_SCREEN="true")
    if not env.get("DISPLAY"):  # headless: render through EGL as the package's figure does
        env["VTK_DEFAULT_OPENGL_WINDOW"] = "vtkEGLRenderWindow"
    proc = subprocess.run(
        [sys.executable, str(script)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    # every load step (gravity, then the footing's) on the demo's mesh
    times = [float(k) for k in range(1, steps + 2)]
    assert summary["completed_steps"] == len(times)
    assert f"steps {times} cells {SlopeGeometry().n_cells} True" in proc.stdout
