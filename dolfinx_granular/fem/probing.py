"""Read the material where you want it: per-point values and probes gathered across ranks.

:func:`point_values` gives this rank's quadrature-point data of a
:class:`~dolfinx_granular.GranularMaterial` (coordinates, F, P, Cauchy stress).
:func:`probe` answers for any coordinates, on every rank alike: the values of the material's
quadrature point nearest to each coordinate, whichever rank owns it.

**The rule.** For each coordinate, the nearest quadrature point (reference coordinates, Euclidean
distance) among the points of the material's owned cells on all ranks; points at exactly the same
distance are ordered by their coordinates (smaller x, then smaller y, then smaller z), which does
not depend on how the mesh is partitioned. Serial and distributed runs therefore pick the same point
and return the same values to round-off. (Two points whose distances differ by round-off only can be
picked differently by different partitions: a probe exactly halfway between two Gauss points is
ill-posed.)

**The values.** F (d, d) at the last ``material.update()`` (d, the mesh's dimension: 2 or 3); P
(d, d), the first Piola stress the residual uses (the quadrature Function ``material.P``, a
stabilising stress included); the Cauchy stress (d, d) of the law at that F and the committed
state (as ``material.cauchy()``: without a stabiliser); the contact statistics of
:mod:`~dolfinx_granular.laws.validity` (active contacts, mean coordination number 2 contacts /
particles, largest overlap over the smaller radius): of the law's ``overlap_statistics(F)``
(Taylor, frictional), or of its ``contacts(F, state)`` at the state of the last update (the
relaxed RVE: the disks where they moved to); NaN for a law with neither. Units: Pa, m.
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
        points: (n, d) reference coordinates (m).
        F: (n, d, d) deformation gradient.
        P: (n, d, d) first Piola stress (Pa), as the residual reads it.
        cauchy: (n, d, d) Cauchy stress (Pa).
    """

    points: np.ndarray
    F: np.ndarray
    P: np.ndarray
    cauchy: np.ndarray


def point_stress(material: Any) -> np.ndarray:
    """(n_points, d, d) copy of the first Piola stress (Pa) at this rank's points of a
    GranularMaterial, ordered like ``material.points``: its quadrature Function ``P`` read at
    the points' slots (the cell-major layout the material checks at construction)."""
    slots = (material.cells[:, None] * material.n_qp + np.arange(material.n_qp)).ravel()
    d = material.dim
    return material.P.x.array.reshape(-1, d, d)[slots].copy()


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
        targets: (m, d) the coordinates asked for (m).
        points: (m, d) the quadrature points found (reference coordinates, m).
        distance: (m,) |points - targets| (m).
        F, P, cauchy: (m, d, d) as in :class:`PointValues`.
        contacts: (m,) float, active contacts in the point's RVE (NaN: a law without
            ``overlap_statistics`` or ``contacts``).
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


def _targets(points, d):
    T = np.asarray(points, dtype=float)
    if T.ndim == 1 and T.shape == (d,):
        T = T[None]
    if T.ndim != 2 or T.shape[1] != d or not np.isfinite(T).all():
        raise ValueError(
            f"probe points must be finite coordinates of shape (m, {d}) (or one ({d},) point), "
            f"in m (the mesh is {d}-D); got shape {np.shape(points)}"
        )
    return T


def _distance(X, t):
    """(n,) |X - t| of points X (n, d) and t (d,) or (n, d) (np.hypot in 2-D)."""
    if X.shape[1] == 2:
        return np.hypot(X[:, 0] - t[..., 0], X[:, 1] - t[..., 1])
    return np.linalg.norm(X - t, axis=1)


def _local_nearest(X, T):
    """Per target: (distance, x, y[, z]) of this rank's nearest point and its index (-1: none)."""
    key = np.full((T.shape[0], 1 + T.shape[1]), np.inf)
    index = np.full(T.shape[0], -1)
    if len(X):
        order = np.lexsort(X.T[::-1])  # coordinate order (x, then y, then z) breaks exact ties
        Xs = X[order]
        for k, t in enumerate(T):
            d = _distance(Xs, t)
            i = int(np.argmin(d))  # the first of equal distances: the smallest coordinates
            key[k] = (d[i], *Xs[i])
            index[k] = order[i]
    return key, index


def _winners(comm, key):
    """(m,) bool: the targets whose nearest point over all ranks is this rank's."""
    keys = np.asarray(comm.allgather(key))  # (ranks, m, 1 + d)
    best = np.empty(key.shape[0], dtype=int)
    for k in range(key.shape[0]):
        best[k] = np.lexsort(keys[:, k, ::-1].T)[0]  # distance, then x, y, z
    return best == comm.rank


def _values_at(material, idx):
    """(k, d + 3 d² + 2) rows [point d, F d², P d², cauchy d², contacts, max ratio] at local
    points idx."""
    law, F, d = material.rve, np.array(material.F[idx]), material.dim
    slots = material.cells[idx // material.n_qp] * material.n_qp + idx % material.n_qp
    P = material.P.x.array.reshape(-1, d, d)[slots]
    committed = material.export_state()
    sigma = law.cauchy(F) if committed is None else law.cauchy(F, committed.take(idx))
    stats = _contact_statistics(material, idx, F)
    flat = [material.points[idx], F.reshape(-1, d * d), P.reshape(-1, d * d)]
    return np.hstack([*flat, sigma.reshape(-1, d * d), stats])


def _contact_statistics(material, idx, F):
    """(k, 2) [active contacts, largest overlap / smaller radius] at local points idx and their
    F (k, d, d); NaN for a law that has neither ``overlap_statistics(F)`` nor ``contacts(F,
    state)``."""
    law, stats = material.rve, np.full((idx.size, 2), np.nan)
    if callable(getattr(law, "overlap_statistics", None)):  # overlaps set by F alone (Taylor)
        ratio, contacts = law.overlap_statistics(F)
        stats[:, 0], stats[:, 1] = contacts, ratio
        return stats
    state = getattr(material, "trial_state", None)
    if state is None or not callable(getattr(law, "contacts", None)):
        return stats
    # the relaxed RVE: the contacts of its disks where they moved to at F (the state of the
    # last update, the committed one after a solve)
    radii = law.packing.radii
    for k, i in enumerate(idx):
        c = law.contacts(F[k], state.take([i]))
        smaller = radii[c.pairs].min(axis=1)  # (m,) of the two disks of each contact
        stats[k] = len(c.overlap), np.max(c.overlap / smaller, initial=0.0)
    return stats


def probe(material: Any, points: ArrayLike) -> ProbeResult:
    """The material's values at the quadrature points nearest to ``points`` (m, d) (m), by the
    rule of the module docstring, gathered over the mesh's communicator: every rank gets the same
    :class:`ProbeResult`. Collective: call it on every rank with the same ``points``. Reads the
    state of the last ``material.update()`` (a converged step's, after a solve)."""
    comm, d = material.mesh.comm, material.dim
    T = _targets(points, d)
    X = np.asarray(material.points)
    key, index = _local_nearest(X, T)
    if comm.allreduce(int(X.shape[0])) == 0:
        raise ValueError("the material has no quadrature points on any rank: nothing to probe")
    mine = np.flatnonzero(_winners(comm, key))
    e = d * d  # columns: point d, F e, P e, cauchy e, contacts, ratio
    rows = np.zeros((T.shape[0], d + 3 * e + 2))
    if mine.size:
        rows[mine] = _values_at(material, index[mine])
    rows = comm.allreduce(rows, op=MPI.SUM)  # one rank holds each row, the others add zeros
    n = getattr(getattr(material.rve, "packing", None), "n_particles", np.nan)
    return ProbeResult(
        targets=T,
        points=rows[:, :d],
        distance=_distance(rows[:, :d], T),
        F=rows[:, d : d + e].reshape(-1, d, d),
        P=rows[:, d + e : d + 2 * e].reshape(-1, d, d),
        cauchy=rows[:, d + 2 * e : d + 3 * e].reshape(-1, d, d),
        contacts=rows[:, -2],
        coordination=2.0 * rows[:, -2] / n,
        max_overlap_ratio=rows[:, -1],
    )
