"""Values gathered across MPI ranks: the same answer on every rank, ties to the lowest rank."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from mpi4py.MPI import Comm
    from numpy.typing import ArrayLike


def global_extremum(
    comm: Comm, values: ArrayLike, points: np.ndarray, kind: str = "max"
) -> tuple[float, list[float]]:
    """Global max or min of per-rank ``values`` (n,) with the ``points`` (n, d) where it occurs.

    Returns ``(value, point)``, the same on every rank (ties: lowest rank).
    """
    values = np.asarray(values, dtype=float)
    if values.size:
        i = int(np.argmax(values) if kind == "max" else np.argmin(values))
        local = (float(values[i]), np.asarray(points[i], dtype=float).tolist())
    else:
        local = (-np.inf if kind == "max" else np.inf, None)
    found = comm.allgather(local)
    pick = max if kind == "max" else min
    return pick((v for v in found if v[1] is not None), key=lambda vp: vp[0])


def nearest_point(
    comm: Comm, points: np.ndarray, target: ArrayLike
) -> tuple[int, int, np.ndarray | None]:
    """The point nearest to ``target`` over all ranks: ``(rank, index on that rank, point)``,
    identical on every rank (ties: lowest rank). ``points``: (n, d) this rank's coordinates."""
    target = np.asarray(target, dtype=float)
    if len(points):
        d = np.linalg.norm(np.asarray(points) - target, axis=1)
        i = int(np.argmin(d))
        local = (float(d[i]), comm.rank, i, np.asarray(points[i]))
    else:
        local = (np.inf, comm.rank, -1, None)
    _, rank, i, point = min(comm.allgather(local), key=lambda t: (t[0], t[1]))
    return rank, i, point
