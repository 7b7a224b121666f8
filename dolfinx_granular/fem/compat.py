"""Every difference between the supported DOLFINx releases (0.5.2 to 0.11), in one place.

The rest of the package calls these helpers and never tests a version: each helper detects the
feature it needs (a name, a signature), not a version number. Tested on DOLFINx 0.5.2 (Debian
bookworm), 0.9.0 (Debian trixie) and 0.11.0 (the ``dolfinx-solver-real`` wheel on PyPI).

The package's ``__init__`` imports ``dolfinx_solver`` first when it is installed (the PyPI wheel
loads its MPI library there; ``import dolfinx`` fails without it: ``libmpi.so.12``).
"""

from __future__ import annotations

import functools
import inspect
import logging
import os
import shutil
import sys
from typing import TYPE_CHECKING, Any

import basix
import numpy as np
import ufl
from dolfinx import fem
from petsc4py import PETSc

from ..io.runwriter import atomic_write

if TYPE_CHECKING:
    from collections.abc import Callable
    from os import PathLike

    from dolfinx.mesh import Mesh
    from mpi4py.MPI import Comm
    from numpy.typing import ArrayLike
    from ufl.core.expr import Expr

# basix.ufl.quadrature_element exists from DOLFINx 0.7; earlier releases use UFL's legacy elements
try:
    from basix.ufl import quadrature_element as _quadrature_element
except ImportError:  # DOLFINx 0.5 / 0.6
    _quadrature_element = None


class _CompilerChatter(logging.Filter):
    """Drops the INFO lines of the C compiler runs behind DOLFINx's JIT (setuptools logs every
    command line on the root logger, which FFCx has given a stderr handler)."""

    def filter(self, record):
        where = record.pathname.replace(os.sep, "/")
        return not (
            record.levelno < logging.WARNING and ("/distutils/" in where or "/setuptools/" in where)
        )


logging.getLogger().addFilter(_CompilerChatter())


def show_warnings() -> None:
    """Make Python warnings visible in a program that has not configured logging (call it at a
    command line's entry). FFCx 0.9 routes every warning to the logger ``py.warnings``
    (``logging.captureWarnings``), which then drops it unless the root logger has a handler."""
    if not logging.getLogger().handlers:
        logging.basicConfig(level=logging.WARNING, format="%(message)s")


#: SNES reason for a NaN residual: DIVERGED_FNORM_NAN up to PETSc 3.19, then renamed
SNES_NAN_REASON = int(
    getattr(PETSc.SNES.ConvergedReason, "DIVERGED_FNORM_NAN", None)
    or PETSc.SNES.ConvergedReason.DIVERGED_FUNCTION_NANORINF
)
#: ``fem.functionspace`` (0.7+) or the ``fem.FunctionSpace`` constructor (0.5, 0.6)
_NEW_SPACES = hasattr(fem, "functionspace")
#: ``Expression.eval(mesh, cells)`` (0.7+) or ``Expression.eval(cells)`` (0.5, 0.6)
_EVAL_TAKES_MESH = "mesh" in inspect.signature(fem.Expression.eval).parameters


def function_space(
    msh: Mesh, family: str, degree: int, shape: tuple[int, ...] = ()
) -> fem.FunctionSpace:
    """Lagrange/DG space of the given value ``shape`` (``()`` scalar, ``(2,)`` vector)."""
    if _NEW_SPACES:
        return fem.functionspace(msh, (family, degree, tuple(shape)) if shape else (family, degree))
    if shape:
        return fem.VectorFunctionSpace(msh, (family, degree), dim=shape[0])
    return fem.FunctionSpace(msh, (family, degree))


def tensor_space(
    msh: Mesh, family: str, degree: int, shape: tuple[int, int] = (2, 2)
) -> fem.FunctionSpace:
    """Space of ``shape``-tensor values (a DG0 (d, d) space for cell-wise stresses):
    ``fem.functionspace(msh, (family, degree, shape))`` (0.7+) or ``fem.TensorFunctionSpace``
    (0.5, 0.6). One block of ``prod(shape)`` values per dof, row-major."""
    if _NEW_SPACES:
        return fem.functionspace(msh, (family, degree, tuple(shape)))
    return fem.TensorFunctionSpace(msh, (family, degree), shape=tuple(shape))


def xdmf_cell_tensor(f: fem.Function) -> fem.Function:
    """A DG0 (2, 2) Function as ``XDMFFile.write_function`` must get it for ParaView and pyvista
    to read the components right. XDMF tensors have 9 components (3x3, row-major); DOLFINx 0.5
    and 0.6 embed a 2x2 tensor in them, 0.7 and later write its 4 values first and pad with
    zeros (a reader then takes s10 for s_xz). There, the values are copied into a DG0 (3, 3)
    Function of the same name (last row and column 0). The writer changed with the arrival of
    ``fem.functionspace`` (0.7), which is the feature tested."""
    if not _NEW_SPACES or f.ufl_shape == (3, 3):  # a 3-D mesh's tensor: written as it is
        return f
    msh = f.function_space.mesh
    g = fem.Function(tensor_space(msh, "DG", 0, (3, 3)), name=f.name)
    g.x.array.reshape(-1, 3, 3)[:, :2, :2] = f.x.array.reshape(-1, 2, 2)
    return g


def vector_space(msh: Mesh, degree: int = 1, family: str = "Lagrange") -> fem.FunctionSpace:
    """Vector space with one component per geometric dimension (displacements)."""
    return function_space(msh, family, degree, (msh.geometry.dim,))


def quadrature_space(msh: Mesh, degree: int, shape: tuple[int, ...]) -> fem.FunctionSpace:
    """Space of values of ``shape`` at the points of the "default" quadrature scheme of
    ``degree`` (the scheme that a measure with matching metadata integrates with)."""
    cell = msh.topology.cell_type.name
    if _quadrature_element is not None:
        element = _quadrature_element(
            cell, value_shape=tuple(shape), scheme="default", degree=degree
        )
        return fem.functionspace(msh, element)
    if shape:
        element = ufl.TensorElement(
            "Quadrature", msh.ufl_cell(), degree, shape=tuple(shape), quad_scheme="default"
        )
    else:
        element = ufl.FiniteElement("Quadrature", msh.ufl_cell(), degree, quad_scheme="default")
    return fem.FunctionSpace(msh, element)


def quadrature_points(msh: Mesh, degree: int) -> np.ndarray:
    """Reference points (n_qp, tdim) of the "default" scheme of ``degree`` on the mesh's cells."""
    celltype = getattr(basix.CellType, msh.topology.cell_type.name)
    X, _ = basix.make_quadrature(celltype, degree)
    return X


def quadrature_weights(msh: Mesh, degree: int) -> np.ndarray:
    """Reference weights (n_qp,) of the "default" scheme of ``degree`` (the points of
    :func:`quadrature_points`, in the same order)."""
    celltype = getattr(basix.CellType, msh.topology.cell_type.name)
    _, w = basix.make_quadrature(celltype, degree)
    return np.asarray(w)


def expression(e: Expr, X: np.ndarray) -> fem.Expression:
    """A compiled :class:`dolfinx.fem.Expression` of the UFL expression ``e`` at points ``X``."""
    return fem.Expression(e, X)


def evaluate(expr: fem.Expression, msh: Mesh, cells: ArrayLike) -> np.ndarray:
    """Values of ``expr`` on ``cells`` as (n_cells, n_points * value_size), row-major per point."""
    cells = np.asarray(cells, dtype=np.int32)
    if cells.size == 0:
        return np.zeros((0, 0))
    values = expr.eval(msh, cells) if _EVAL_TAKES_MESH else expr.eval(cells)
    return np.asarray(values).reshape(cells.size, -1)


def petsc_vec(u: fem.Function) -> PETSc.Vec:
    """The PETSc vector (ghosted) behind a Function: ``u.x.petsc_vec`` (0.8+) or ``u.vector``."""
    vec = getattr(u.x, "petsc_vec", None)
    return vec if vec is not None else u.vector


def cell_dofs(dofmap: fem.DofMap) -> np.ndarray:
    """The dofmap as (n_cells, dofs per cell) (an AdjacencyList in 0.5/0.6, an array later)."""
    dofs = dofmap.list
    return np.asarray(getattr(dofs, "array", dofs)).reshape(-1, dofmap.dof_layout.num_dofs)


def vtk_mesh(V: fem.FunctionSpace) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(topology, cell_types, geometry)`` of a space for pyvista/VTK."""
    from dolfinx import plot

    make = getattr(plot, "vtk_mesh", None) or plot.create_vtk_mesh
    return make(V)


def gmsh_model_to_mesh(model: Any, comm: Comm, rank: int, gdim: int) -> tuple[Mesh, Any, Any]:
    """Distribute a gmsh model built on ``rank``: ``(mesh, cell_tags, facet_tags)``."""
    # model: the ``gmsh.model`` module; the tags: MeshTagsMetaClass (0.5) / MeshTags (0.9+)
    try:
        from dolfinx.io import gmsh as gmshio  # 0.10+
    except ImportError:
        from dolfinx.io import gmshio
    data = gmshio.model_to_mesh(model, comm, rank, gdim=gdim)
    if hasattr(data, "facet_tags"):  # 0.10+: a MeshData record
        return data.mesh, data.cell_tags, data.facet_tags
    return tuple(data)


def create_mesh(
    comm: Comm,
    cells: ArrayLike,
    x: ArrayLike,
    cell: str,
    gdim: int,
    max_facet_to_cell_links: int = 2,
) -> Mesh:
    """A mesh of affine ``cell`` s ("interval", "triangle", ...) from node coordinates ``x``
    (n, gdim) and connectivity ``cells`` (m, nodes per cell), given on rank 0 (other ranks'
    arrays are ignored) and distributed over ``comm``. ``max_facet_to_cell_links`` > 2 allows
    branching (three bars meeting at a node of an interval mesh): DOLFINx >= 0.10 needs to be
    told, or the ranks do not share such a node; on 0.9, which cannot be told, such a mesh stays
    on rank 0."""
    from dolfinx import mesh

    if _quadrature_element is not None:  # basix.ufl elements (0.7+)
        from basix.ufl import element

        domain = ufl.Mesh(element("Lagrange", cell, 1, shape=(gdim,)))
    else:
        domain = ufl.Mesh(
            ufl.VectorElement("Lagrange", ufl.Cell(cell, geometric_dimension=gdim), 1, dim=gdim)
        )
    cells = np.asarray(cells, dtype=np.int64)
    x = np.asarray(x, dtype=np.float64)
    if comm.rank != 0:
        cells, x = cells[:0], x[:0]
    params = inspect.signature(mesh.create_mesh).parameters
    kwargs = {"domain" if "domain" in params else "e": domain}  # 0.5 / later (x moved in 0.10)
    if "max_facet_to_cell_links" in params:
        kwargs["max_facet_to_cell_links"] = max_facet_to_cell_links
    elif max_facet_to_cell_links > 2 and comm.size > 1 and "ghost_mode" not in params:
        # DOLFINx 0.9 cannot be told about branching: distributed, it gives the ranks their own
        # copies of a branching node (a disconnected mesh, a singular tangent). Keep such a mesh
        # on rank 0. (0.5 shares such a node without being told, 0.10+ when told.)
        kwargs["partitioner"] = _on_rank_zero(len(cells))
    return mesh.create_mesh(comm, cells=cells, x=x, **kwargs)


def _on_rank_zero(n_local: int) -> Callable:
    """A cell partitioner (DOLFINx 0.6-0.9 signature) that sends this rank's ``n_local`` cells
    to rank 0."""
    from dolfinx import graph

    def partitioner(comm, n_parts, *args):
        return graph.adjacencylist(
            np.zeros(n_local, np.int32), np.arange(n_local + 1, dtype=np.int32)
        )

    return partitioner


def mpi_command(ranks: int) -> list[str] | None:
    """The command prefix that starts ``ranks`` processes with the MPI library of this Python's
    mpi4py, whatever PATH says: the venv's own ``mpiexec`` where the PyPI wheel installed one
    (MPICH); else the first launcher of the same MPI implementation among ``mpirun``/``mpiexec``
    beside the base interpreter (Debian's ``/usr/bin``) and then on PATH (Open MPI gets
    ``--oversubscribe`` for more ranks than cores and ``--allow-run-as-root`` for containers and
    CI, which run as root); None if there is no such launcher."""
    own = os.path.join(sys.prefix, "bin", "mpiexec")
    if os.access(own, os.X_OK):
        return [own, "-n", str(ranks)]
    from mpi4py import MPI

    open_mpi = "Open MPI" in MPI.Get_library_version()
    for launcher in _launcher_candidates():
        if _is_open_mpi_launcher(launcher) == open_mpi:
            extra = ["--oversubscribe", "--allow-run-as-root"] if open_mpi else []
            return [launcher, "-n", str(ranks), *extra]
    return None


def _launcher_candidates() -> list[str]:
    """Executable ``mpirun``/``mpiexec`` files: beside the base interpreter first, then on PATH
    (an activated venv of another stack puts its own launcher first there)."""
    base = os.path.join(sys.base_prefix, "bin")
    found = [os.path.join(base, name) for name in ("mpirun", "mpiexec")]
    found += [shutil.which(name) for name in ("mpirun", "mpiexec")]
    unique = dict.fromkeys(f for f in found if f and os.access(f, os.X_OK))
    return list(unique)


@functools.cache
def _is_open_mpi_launcher(launcher: str) -> bool:
    """True for Open MPI's launcher (``mpirun (Open MPI) 4.1.4``), False for MPICH's (HYDRA);
    asked once per launcher and process (every MPI run of the tests calls mpi_command)."""
    import subprocess

    try:
        proc = subprocess.run(
            [launcher, "--version"], capture_output=True, text=True, timeout=30, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return False
    return "Open MPI" in proc.stdout + proc.stderr


_XINCLUDE_WRONG = 'xmlns:xi="https://www.w3.org/2001/XInclude"'
_XINCLUDE = 'xmlns:xi="http://www.w3.org/2001/XInclude"'


def repair_xdmf(path: str | PathLike[str]) -> None:
    """Give an XDMF file written by DOLFINx the XInclude namespace of the W3C standard.

    DOLFINx 0.9 and later write ``xmlns:xi="https://..."``; XInclude's namespace is the ``http``
    URI, and VTK's XDMF reader (pyvista, ParaView) then cannot resolve the file's ``xi:include``
    elements and crashes. A no-op for files with the right namespace (DOLFINx 0.5). Call it on
    one rank after the file is closed.
    """
    with open(path, encoding="utf-8") as f:
        text = f.read()
    if _XINCLUDE_WRONG in text:
        atomic_write(path, text.replace(_XINCLUDE_WRONG, _XINCLUDE))
