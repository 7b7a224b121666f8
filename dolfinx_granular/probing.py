"""Read the material where you want it: per-point values and probes gathered across ranks.

:func:`point_values` gives this rank's quadrature-point data of a
:class:`~dolfinx_granular.material.GranularMaterial` (coordinates, F, P, Cauchy stress).
:func:`probe` answers for any coordinates, on every rank alike: the values of the material's
quadrature point nearest to each coordinate, whichever rank owns it.

**The rule.** For each coordinate, the nearest quadrature point (reference coordinates, Euclidean
distance) among the points of the material's owned cells on all ranks; points at exactly the same
distance are ordered by their coordinates (smaller x, then smaller y), which does not depend on
how the mesh is partitioned. Serial and distributed runs therefore pick the same point and return
the same values to round-off. (Two points whose distances differ by round-off only can be picked
differently by different partitions: a probe exactly halfway between two Gauss points is
ill-posed.)

**The values.** F (2, 2) at the last ``material.update()``; P (2, 2), the first Piola stress the
residual uses (the quadrature Function ``material.P``, a stabilising stress included); the Cauchy
stress (2, 2) of the law at that F and the committed state (as ``material.cauchy()``: without a
stabiliser); the contact statistics of :mod:`~dolfinx_granular.validity` (active contacts, mean
coordination number 2 contacts / particles, largest overlap over the smaller radius; NaN for a law
without ``overlap_statistics``). Units: Pa, m.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from mpi4py import MPI

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


@dataclass(frozen=True)
class PointValues:
    """Quadrature-point data of a material on this rank, point ``cell * n_qp + q`` of
    ``material.cells``.

    Attributes:
        points: (n, 2) reference coordinates (m).
        F: (n, 2, 2) deformation gradient.
        P: (n, 2, 2) first Piola stress (Pa), as the residual reads it.
        cauchy: (n, 2, 2) Cauchy stress (Pa).
    """

    points: np.ndarray
    F: np.ndarray
    P: np.ndarray
    cauchy: np.ndarray


def point_stress(material: Any) -> np.ndarray:
    """(n_points, 2, 2) copy of the first Piola stress (Pa) at this rank's points of a
    GranularMaterial, ordered like ``material.points``: its quadrature Function ``P`` read at
    the points' slots (the cell-major layout the material checks at construction)."""
    slots = (material.cells[:, None] * material.n_qp + np.arange(material.n_qp)).ravel()
    return material.P.x.array.reshape(-1, 2, 2)[slots].copy()


def point_values(material: Any) -> PointValues:
    """:class:`PointValues` (copies) of a GranularMaterial on this rank at its last update."""
    return PointValues(
        np.array(material.points),
        np.array(material.F),
        point_stress(material),
        np.asarray(material.cauchy()),
    )


@dataclass(frozen=True)
class ProbeResult:
    """The material's values at the points nearest to m probe coordinates (same on every rank).

    Attributes:
        targets: (m, 2) the coordinates asked for (m).
        points: (m, 2) the quadrature points found (reference coordinates, m).
        distance: (m,) |points - targets| (m).
        F, P, cauchy: (m, 2, 2) as in :class:`PointValues`.
        contacts: (m,) float, active contacts in the point's RVE (NaN: a law without
            ``overlap_statistics``).
        coordination: (m,) 2 contacts / particles.
        max_overlap_ratio: (m,) largest overlap / smaller radius (:mod:`validity`).
    """

    targets: np.ndarray
    points: np.ndarray
    distance: np.ndarray
    F: np.ndarray
    P: np.ndarray
    cauchy: np.ndarray
    contacts: np.ndarray
    coordination: np.ndarray
    max_overlap_ratio: np.ndarray

    def as_dict(self) -> dict:
        """Nested lists, JSON-ready (keys as the attributes)."""
        return {k: np.asarray(v).tolist() for k, v in self.__dict__.items()}


def _targets(points):
    T = np.asarray(points, dtype=float)
    if T.ndim == 1 and T.shape == (2,):
        T = T[None]
    if T.ndim != 2 or T.shape[1] != 2 or not np.isfinite(T).all():
        raise ValueError(
            "probe points must be finite coordinates of shape (m, 2) (or one (2,) point), in m; "
            f"got shape {np.shape(points)}"
        )
    return T


def _local_nearest(X, T):
    """Per target: (distance, x, y) of this rank's nearest point and its index (-1: none)."""
    key = np.full((T.shape[0], 3), np.inf)
    index = np.full(T.shape[0], -1)
    if len(X):
        order = np.lexsort((X[:, 1], X[:, 0]))  # coordinate order breaks exact ties
        Xs = X[order]
        for k, t in enumerate(T):
            d = np.hypot(Xs[:, 0] - t[0], Xs[:, 1] - t[1])
            i = int(np.argmin(d))  # the first of equal distances: the smallest coordinates
            key[k] = (d[i], Xs[i, 0], Xs[i, 1])
            index[k] = order[i]
    return key, index


def _winners(comm, key):
    """(m,) bool: the targets whose nearest point over all ranks is this rank's."""
    keys = np.asarray(comm.allgather(key))  # (ranks, m, 3)
    best = np.empty(key.shape[0], dtype=int)
    for k in range(key.shape[0]):
        best[k] = np.lexsort((keys[:, k, 2], keys[:, k, 1], keys[:, k, 0]))[0]
    return best == comm.rank


def _values_at(material, idx):
    """(k, 16) rows [point 2, F 4, P 4, cauchy 4, contacts, max ratio] at local points idx."""
    law, F = material.rve, np.array(material.F[idx])
    slots = material.cells[idx // material.n_qp] * material.n_qp + idx % material.n_qp
    P = material.P.x.array.reshape(-1, 2, 2)[slots]
    if getattr(material, "history", False):
        sigma = law.cauchy(F, material.state.take(idx))
    else:
        sigma = law.cauchy(F)
    stats = np.full((idx.size, 2), np.nan)
    if callable(getattr(law, "overlap_statistics", None)):
        ratio, contacts = law.overlap_statistics(F)
        stats[:, 0], stats[:, 1] = contacts, ratio
    flat = [material.points[idx], F.reshape(-1, 4), P.reshape(-1, 4), sigma.reshape(-1, 4), stats]
    return np.hstack(flat)


def probe(material: Any, points: ArrayLike) -> ProbeResult:
    """The material's values at the quadrature points nearest to ``points`` (m, 2) (m), by the
    rule of the module docstring, gathered over the mesh's communicator: every rank gets the same
    :class:`ProbeResult`. Collective: call it on every rank with the same ``points``. Reads the
    state of the last ``material.update()`` (a converged step's, after a solve)."""
    comm = material.mesh.comm
    T = _targets(points)
    X = np.asarray(material.points)
    key, index = _local_nearest(X, T)
    if comm.allreduce(int(X.shape[0])) == 0:
        raise ValueError("the material has no quadrature points on any rank: nothing to probe")
    mine = np.flatnonzero(_winners(comm, key))
    rows = np.zeros((T.shape[0], 16))
    if mine.size:
        rows[mine] = _values_at(material, index[mine])
    rows = comm.allreduce(rows, op=MPI.SUM)  # one rank holds each row, the others add zeros
    n = getattr(getattr(material.rve, "packing", None), "n_particles", np.nan)
    return ProbeResult(
        targets=T,
        points=rows[:, 0:2],
        distance=np.hypot(rows[:, 0] - T[:, 0], rows[:, 1] - T[:, 1]),
        F=rows[:, 2:6].reshape(-1, 2, 2),
        P=rows[:, 6:10].reshape(-1, 2, 2),
        cauchy=rows[:, 10:14].reshape(-1, 2, 2),
        contacts=rows[:, 14],
        coordination=2.0 * rows[:, 14] / n,
        max_overlap_ratio=rows[:, 15],
    )
