"""The README's snippets run as printed: the material point on the shipped packing; in "Use it in
your own DOLFINx model" the granular column, the relaxed column on a confined packing, the 3-D
column (serial and MPI: printing on rank 0 only) and the pyvista look at the slope's results; and
docs/solvers.md's granular layer on rock, which continues the column."""

import os
import re
import time

import numpy as np
import pytest
from mpi4py import MPI

from helpers import ROOT, run_slope_demo

SECTION = "## Use it in your own DOLFINx model"


def snippets(name, section):
    """The python blocks of ``section`` (a heading) of the Markdown file ``name``."""
    with open(os.path.join(ROOT, name), encoding="utf-8") as f:
        text = f.read()
    assert section in text, f"{name} lost its section {section!r}"
    body = text.split(section, 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```", body, flags=re.S)


def readme_snippets():
    blocks = snippets("README.md", SECTION)
    assert len(blocks) == 4, "the section holds the column, the relaxed column, 3-D and pyvista"
    return blocks


def layered_snippet():
    (block,) = snippets(os.path.join("docs", "solvers.md"), "## Several materials: a layer on rock")
    return block


def run(code, capsys, namespace=None):
    namespace = namespace if namespace is not None else {"__name__": "readme_snippet"}
    exec(compile(code, "README.md", "exec"), namespace)
    return namespace, capsys.readouterr().out


def printed(out):
    """The lines printed on this rank: all of them on rank 0, none elsewhere."""
    if MPI.COMM_WORLD.rank != 0:
        assert out == "", f"rank {MPI.COMM_WORLD.rank} printed {out!r}"
    return out.splitlines()


def test_snippets_are_short():
    blocks = [*snippets("README.md", "## The material point"), *readme_snippets()]
    assert [len(b.strip().splitlines()) <= 25 for b in blocks] == [True] * 5


def test_material_point_snippet_runs_on_the_shipped_packing(tmp_path, monkeypatch):
    """It reads no file of the user's (it used to load a packing.npz that nothing had made)."""
    from dolfinx_granular import reference_packing

    monkeypatch.chdir(tmp_path)  # (an empty folder: no packing.npz to find)
    (code,) = snippets("README.md", "## The material point")
    namespace = {"__name__": "readme_snippet"}
    exec(compile(code, "README.md", "exec"), namespace)
    assert namespace["packing"].n_particles == reference_packing().n_particles == 700
    assert namespace["P"].shape == (1, 2, 2) and namespace["P"][0, 0, 0] < 0.0  # compressed
    assert namespace["a"].shape == (1, 2, 2, 2, 2) and namespace["C"].shape == (2, 2, 2, 2)
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as f:
        assert "python -m dolfinx_granular generate" in f.read()  # and how to make your own


@pytest.mark.mpi
def test_snippet_runs_and_converges(capsys):
    namespace, out = run(readme_snippets()[0], capsys)
    lines = [line for line in printed(out) if line.startswith("p = ")]
    if MPI.COMM_WORLD.rank == 0:
        assert len(lines) == 3 and all(line.endswith("converged: True") for line in lines), out
        assert all(r"Newton steps" in line for line in lines)
    assert namespace["result"].converged
    # The column settles under the pressure (u_y < 0 somewhere on every rank that owns a node).
    u = namespace["u"]
    assert u.x.array[1::2].min() < 0.0


@pytest.mark.mpi
def test_layered_snippet_carries_the_load(capsys):
    namespace, _ = run(readme_snippets()[0], capsys)
    namespace, out = run(layered_snippet(), capsys, namespace)
    assert printed(out) == (["3e5 Pa carried: True"] if MPI.COMM_WORLD.rank == 0 else []), out
    assert namespace["stepper"].failed is None
    assert namespace["rock"].cauchy()[:, 1, 1].max(initial=-1.0) < 0.0  # the base is compressed


@pytest.mark.mpi
def test_relaxed_snippet_carries_the_load_on_a_confined_packing(capsys):
    """The issue: RelaxedRVE swapped into the column failed at once (a stress-free packing
    unjams). On the confined packing, held by holding_traction, the column carries the load in
    its two steps; its reference state is the confinement, -1e5 Pa."""
    namespace, _ = run(readme_snippets()[0], capsys)
    start = time.perf_counter()
    namespace, out = run(readme_snippets()[1], capsys, namespace)
    seconds = MPI.COMM_WORLD.allreduce(time.perf_counter() - start, op=MPI.MAX)
    assert printed(out) == (["5e4 Pa carried: True"] if MPI.COMM_WORLD.rank == 0 else []), out
    stepper, material = namespace["stepper"], namespace["material"]
    assert stepper.failed is None and not stepper.cutbacks and stepper.step == 2
    P0 = material.reference_stress()
    np.testing.assert_allclose(np.diag(P0), -1e5, rtol=1e-8)
    uy = namespace["u"].x.array[1::2]
    assert MPI.COMM_WORLD.allreduce(float(uy.min(initial=0.0)), op=MPI.MIN) < 0.0  # settles
    assert seconds < 60.0, f"the relaxed snippet took {seconds:.1f} s"  # (2 s on this machine)


@pytest.mark.mpi
def test_3d_snippet_converges(capsys):
    namespace, _ = run(readme_snippets()[0], capsys)  # (the 3-D snippet continues its imports)
    namespace, out = run(readme_snippets()[2], capsys, namespace)
    lines = printed(out)
    assert MPI.COMM_WORLD.rank != 0 or lines[-1].endswith("converged: True"), out
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
