"""The DOLFINx compatibility layer (dolfinx_granular.fem.compat): one behaviour on every release.

Each helper is checked against what the rest of the package relies on (shapes, layouts, the
launcher), and the package's own DOLFINx calls raise no DeprecationWarning of DOLFINx, UFL, basix
or FFCx (run on the newest stack, this catches an API that is on its way out).
"""

import os
import subprocess
import sys
import warnings

from dolfinx_granular.fem import compat as dfx
from dolfinx_granular.slope import SlopeOptions, run_slope

import numpy as np
import pytest
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI

from helpers import ROOT

LIBRARIES = ("dolfinx", "ufl", "basix", "ffcx")


def square(n=2, cell=mesh.CellType.quadrilateral):
    return mesh.create_unit_square(MPI.COMM_WORLD, n, n, cell)


@pytest.mark.mpi
@pytest.mark.parametrize("cell", [mesh.CellType.quadrilateral, mesh.CellType.triangle])
def test_quadrature_space_is_cell_major(cell):
    msh = square(3, cell)
    X = dfx.quadrature_points(msh, 2)
    assert X.shape == ((4, 2) if cell == mesh.CellType.quadrilateral else (3, 2))
    Q = dfx.quadrature_space(msh, 2, (4, 4))
    n_owned = msh.topology.index_map(2).size_local
    n_all = n_owned + msh.topology.index_map(2).num_ghosts
    assert Q.dofmap.index_map_bs == 16
    assert Q.dofmap.index_map.size_local == n_owned * X.shape[0]
    assert np.array_equal(dfx.cell_dofs(Q.dofmap).ravel(), np.arange(n_all * X.shape[0]))


@pytest.mark.mpi
def test_evaluate_gives_row_major_points_per_cell():
    msh = square(2)
    V = dfx.vector_space(msh)
    u = fem.Function(V)
    u.interpolate(lambda x: np.stack([0.1 * x[0] + 0.2 * x[1], -0.3 * x[0]]))
    X = dfx.quadrature_points(msh, 2)
    cells = np.arange(msh.topology.index_map(2).size_local, dtype=np.int32)
    F = dfx.evaluate(dfx.expression(ufl.Identity(2) + ufl.grad(u), X), msh, cells)
    assert F.shape == (cells.size, X.shape[0] * 4)
    assert np.allclose(F.reshape(-1, 2, 2), [[1.1, 0.2], [-0.3, 1.0]], rtol=0, atol=1e-14)
    x = dfx.evaluate(dfx.expression(ufl.SpatialCoordinate(msh), X), msh, cells).reshape(-1, 2)
    assert x.shape == (cells.size * X.shape[0], 2) and np.all((x > 0) & (x < 1))
    assert dfx.evaluate(dfx.expression(ufl.grad(u), X), msh, cells[:0]).reshape(-1, 2, 2).shape == (
        0,
        2,
        2,
    )


@pytest.mark.mpi
def test_spaces_vectors_and_vtk_mesh():
    msh = square(2)
    V = dfx.vector_space(msh)
    assert V.dofmap.index_map_bs == 2
    D = dfx.function_space(msh, "DG", 0)
    assert D.dofmap.index_map.size_local == msh.topology.index_map(2).size_local
    u = fem.Function(V)
    u.x.array[:] = 1.0
    vec = dfx.petsc_vec(u)
    assert vec.getSize() == 2 * V.dofmap.index_map.size_global and vec.sum() == vec.getSize()
    topology, cell_types, geometry = dfx.vtk_mesh(V)
    assert geometry.shape[1] == 3 and len(cell_types) >= msh.topology.index_map(2).size_local


def test_mpi_command_matches_this_python():
    cmd = dfx.mpi_command(3)
    assert cmd is not None and cmd[1:3] == ["-n", "3"] and os.access(cmd[0], os.X_OK)


def test_mpi_command_ignores_another_stacks_launcher_first_on_path(tmp_path):
    """With another MPI's launcher first on PATH (an activated venv of the other stack), the
    command still starts this Python's MPI: 2 ranks that see a world of size 2."""
    other = "HYDRA build details:" if "Open MPI" in MPI.Get_library_version() else "(Open MPI) 4"
    for name in ("mpirun", "mpiexec"):
        fake = tmp_path / name
        fake.write_text(f"#!/bin/sh\necho '{other}'\nexit 0\n")
        fake.chmod(0o755)
    env = {**os.environ, "PATH": f"{tmp_path}{os.pathsep}{os.environ.get('PATH', '')}"}
    ask = "from dolfinx_granular.fem.compat import mpi_command; print(' '.join(mpi_command(2)))"
    cmd = subprocess.run(
        [sys.executable, "-c", ask], env=env, capture_output=True, text=True, check=True
    ).stdout.split()
    assert not cmd[0].startswith(str(tmp_path)), cmd
    # rank 0 alone prints what every rank saw (MPICH may interleave the ranks' output lines)
    size = "from mpi4py import MPI; c = MPI.COMM_WORLD; s = c.gather(c.size); print(s or '')"
    out = subprocess.run(
        [*cmd, sys.executable, "-c", size], env=env, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0 and out.stdout.split() == ["[2,", "2]"], out.stderr


@pytest.mark.mpi
def test_gmsh_model_to_mesh_gives_mesh_and_tags():
    from dolfinx_granular.slope.geometry import SOIL, SlopeGeometry, create_mesh

    msh, cells, facets = create_mesh(MPI.COMM_WORLD, SlopeGeometry())
    assert msh.topology.index_map(2).size_global == SlopeGeometry().n_cells
    assert set(np.unique(cells.values)) <= {SOIL} and facets.dim == 1


def test_no_deprecation_warning_from_the_package(tmp_path):
    """A small slope run (mesh, spaces, quadrature material, SNES, XDMF, restart) and a VTK mesh
    raise no DeprecationWarning of the FEniCS libraries."""
    from dolfinx_granular import generate_packing

    packing = generate_packing(20, seed=2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        summary = run_slope(
            packing, SlopeOptions(steps=1), out=str(tmp_path), figure=False, verbose=False
        )
        dfx.vtk_mesh(dfx.vector_space(square(1)))
    assert summary["converged"]
    ours = [
        f"{w.filename}:{w.lineno}: {w.message}"
        for w in caught
        if issubclass(w.category, (DeprecationWarning, PendingDeprecationWarning, FutureWarning))
        and (
            w.filename.startswith(ROOT)
            or any(
                f"{os.sep}{lib}{os.sep}" in w.filename or f"{os.sep}{lib}." in w.filename
                for lib in LIBRARIES
            )
        )
    ]
    assert not ours, "\n".join(ours)


def test_xdmf_gets_the_standard_xinclude_namespace(tmp_path):
    """DOLFINx >= 0.9 writes the XInclude namespace as https (VTK's reader then crashes on the
    file); the repaired file names the W3C's http URI, and a correct file is left alone."""
    from dolfinx import io

    path = str(tmp_path / "m.xdmf")
    msh = square(2)
    with io.XDMFFile(MPI.COMM_SELF, path, "w") as f:
        f.write_mesh(msh)
        f.write_function(fem.Function(dfx.vector_space(msh)), 0.0)
    dfx.repair_xdmf(path)
    text = open(path).read()
    assert 'xmlns:xi="http://www.w3.org/2001/XInclude"' in text and "https://www.w3" not in text
    before = os.stat(path).st_mtime_ns
    dfx.repair_xdmf(path)
    assert os.stat(path).st_mtime_ns == before and open(path).read() == text
