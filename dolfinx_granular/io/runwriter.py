"""Nothing lost: a run's records on disk after every converged step, and restarts on any ranks.

:class:`RunWriter` replaces its files atomically on rank 0 (a reader or a killed run sees the old
file or the new one, never a partial one): CSV tables, JSON summaries and a restart ``.npz``.
:class:`NodeOrder` and :class:`PointOrder` gather a Function's nodal values, or per-point data of
the quadrature points (e.g. the history of a frictional material), on rank 0 in an order that does
not depend on the partition, and scatter them back to any partition by matching coordinates: a
run restarted on another number of ranks continues with the same state.
"""

from __future__ import annotations

import csv
import io
import json
import os
from typing import TYPE_CHECKING, Any

import numpy as np
from mpi4py import MPI

from ..laws.protocol import check_state
from .atomic_file import atomic_write

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence

    from dolfinx.fem import Function, FunctionSpace
    from numpy.typing import ArrayLike

    from ..laws.protocol import HistoryState


class RestartError(ValueError):
    """A restart file that cannot be used (missing, damaged, another mesh)."""


class RunWriter:
    """Atomic files of one run in the folder ``out`` (written by rank 0 of ``comm``).

    Args:
        out: output folder (created).
        comm: the run's communicator; only its rank 0 writes.
    """

    def __init__(self, out: str | os.PathLike[str], comm: MPI.Comm = MPI.COMM_WORLD) -> None:
        self.out, self.comm = str(out), comm
        if comm.rank == 0:
            os.makedirs(self.out, exist_ok=True)

    def path(self, name: str) -> str:
        return os.path.join(self.out, name)

    def csv(self, name: str, header: Sequence[str], rows: Iterable[Iterable[Any]]) -> None:
        """Write a CSV table; floats with 17 significant digits (round trip exact)."""
        if self.comm.rank != 0:
            return
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(header)
        w.writerows([f"{v:.16e}" if isinstance(v, float) else v for v in row] for row in rows)
        atomic_write(self.path(name), buf.getvalue())

    def json(self, name: str, obj: Any) -> None:
        if self.comm.rank == 0:
            atomic_write(self.path(name), json.dumps(obj, indent=1))

    def npz(self, name: str, **arrays: ArrayLike) -> None:
        """Write numpy arrays (and 0-d string arrays for JSON metadata) as ``name``."""
        if self.comm.rank != 0:
            return
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        atomic_write(self.path(name), buf.getvalue())


def read_npz(path: str | os.PathLike[str], format_name: str) -> dict[str, np.ndarray]:
    """The arrays of a restart file written with ``format=format_name``, as a dict; raises
    :class:`RestartError` naming the problem."""
    if not os.path.isfile(path):
        raise RestartError(
            f"{path!r} does not exist; give the output folder of a run that "
            "completed at least one load step"
        )
    try:
        with np.load(path, allow_pickle=False) as f:
            if str(f["format"]) != format_name:
                raise ValueError(f"not a {format_name} file")
            return {k: np.array(f[k]) for k in f.files}
    except Exception as err:  # zip, key or format errors: all mean an unusable file
        raise RestartError(
            f"{path!r} is not a usable restart file ({err}); start the run again without resuming"
        ) from err


class _CoordinateOrder:
    """Per-rank rows keyed by coordinates X (m, 2), gathered on rank 0 sorted by x then y."""

    def __init__(self, comm: MPI.Comm, X: ArrayLike, tolerance: float) -> None:
        self.comm, self.tolerance = comm, tolerance
        self.X_local = np.asarray(X)
        parts = comm.gather(self.X_local, root=0)
        self.X = self.order = None
        if comm.rank == 0:
            X = np.concatenate(parts)
            self.order = np.lexsort((X[:, 1], X[:, 0]))
            self.X = X[self.order]

    def gather(self, values: ArrayLike) -> np.ndarray | None:
        """Rank 0: the rows of every rank, in coordinate order; other ranks: None."""
        parts = self.comm.gather(np.asarray(values), root=0)
        return np.concatenate(parts)[self.order] if self.comm.rank == 0 else None

    def match(self, X_stored: ArrayLike, X_here: ArrayLike) -> np.ndarray:
        """Indices into ``X_stored`` of the rows at ``X_here``; RestartError if any row has no
        stored counterpart within the tolerance (decided on every rank alike)."""
        from scipy.spatial import cKDTree

        dist, idx = cKDTree(X_stored).query(X_here) if len(X_here) else (np.zeros(0), [])
        worst = self.comm.allreduce(float(dist.max()) if len(dist) else 0.0, op=MPI.MAX)
        if worst > self.tolerance:
            raise RestartError(
                "the restart file belongs to another mesh; start the run again without resuming"
            )
        return np.asarray(idx, dtype=np.int64)


class NodeOrder(_CoordinateOrder):
    """The owned nodal values of a vector Function, partition-independent (nodes by x, then y)."""

    def __init__(self, comm: MPI.Comm, V: FunctionSpace, tolerance: float) -> None:
        self.V = V
        self.bs = V.dofmap.index_map_bs
        self.n_owned = V.dofmap.index_map.size_local
        x = V.tabulate_dof_coordinates()[:, :2]
        super().__init__(comm, x[: self.n_owned], tolerance)
        self._x_all = x

    def gather_function(self, u: Function) -> np.ndarray | None:
        """Rank 0: (n_nodes, bs) values of ``u`` in node order."""
        return self.gather(u.x.array[: self.bs * self.n_owned].reshape(-1, self.bs).copy())

    def scatter_function(self, values: ArrayLike, X_stored: ArrayLike, u: Function) -> None:
        """Set ``u`` (owned and ghost dofs) from ``values`` (n, bs) stored at nodes ``X_stored``."""
        idx = self.match(X_stored, self._x_all)
        u.x.array[:] = np.asarray(values)[idx].ravel()


class PointOrder(_CoordinateOrder):
    """Per-point data of a quadrature material's points (reference coordinates ``points``),
    partition-independent: arrays, or a law's state (a
    :class:`~dolfinx_granular.HistoryState`, e.g. a FrictionState). A material's state
    moves only through its ``export_state`` / ``restore_state``: :meth:`gather_material` and
    :meth:`restore_material`."""

    def local_rows(self, X_stored: ArrayLike) -> np.ndarray:
        """Indices into the stored (ordered) points of this rank's points, in local order."""
        return self.match(X_stored, self.X_local)

    def gather_state(self, state: HistoryState) -> HistoryState | None:
        """Rank 0: the state of every rank's points in coordinate order (other ranks: None)."""
        parts = self.comm.gather(check_state(state).to_arrays(), root=0)
        if self.comm.rank != 0:
            return None
        cls = type(state)
        return cls.concatenate([cls.from_arrays(p) for p in parts]).take(self.order)

    def scatter_state(
        self, cls: type, arrays: Mapping[str, ArrayLike], X_stored: ArrayLike
    ) -> HistoryState:
        """This rank's part of a state stored (``to_arrays`` of a gathered one) at ``X_stored``."""
        return cls.from_arrays(arrays).take(self.local_rows(X_stored))

    def gather_material(self, material: Any) -> HistoryState | None:
        """Rank 0: the committed state of a material (``export_state``) over every rank, in
        coordinate order; other ranks: None."""
        return self.gather_state(material.export_state())

    def restore_material(
        self, material: Any, arrays: Mapping[str, ArrayLike], X_stored: ArrayLike
    ) -> None:
        """Give a material (``restore_state``) this rank's part of a state stored (``to_arrays``
        of :meth:`gather_material`) at ``X_stored``, on any partition."""
        cls = type(material.export_state())
        material.restore_state(self.scatter_state(cls, arrays, X_stored))
