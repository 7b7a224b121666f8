"""Where the model leaves its range: contact overlaps relative to the disks' size.

The contact law is a linear spring between rigid disks. It describes small overlaps; once two
disks overlap by a sizeable part of their radius, the spring's force means nothing (real grains
would have crushed, flattened or slid past each other). The measure here says where that happens.

**The measure.** At a material point with deformation gradient F, every active contact c (overlap
``eps_c = R_c - |F L_c| >= 0``, the rule of the stress kernel) has the overlap ratio
``eps_c / min(r_i, r_j)``: its overlap relative to the *smaller* of its two disks' radii. The
smaller radius because the small disk is the one a large overlap swallows: a fine grain pressed
into a coarse one by 0.3 r_small is far out of range even though that is a small part of the
coarse radius (relative to the radius sum it would be under 0.15). Two equal disks compressed
along their branch by a stretch lambda have the ratio ``2 (1 - lambda)``. The point's value is the
largest ratio over its active contacts (0 without any). It depends on F alone, for every law of
the package: friction adds tangential forces but leaves the overlaps those of the normal springs.

**The summary.** Over the points of a material, gathered across ranks: the largest ratio and
where it occurs, the number and fraction of points whose ratio exceeds a threshold
(:data:`OVERLAP_THRESHOLD`, 0.10 by default), and the number of points.

Cost: one pass over the candidate contacts each point can reach (the stress kernel's prefix),
without any stress arithmetic: about as much as a stress evaluation without tangent. For the
slope's 700-particle RVE at its final state, 6 ms for its 1520 points and 30 ms for 6080
(``benchmarks/overlap_validity.py``), once per load step.
"""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numba import njit

from ..gathers import global_extremum
from . import taylor_kernel_3d
from .taylor_kernel import FASTMATH, OK, check_F
from .tools import as_batch, unsupported_deformation

if TYPE_CHECKING:
    from mpi4py.MPI import Comm
    from numpy.typing import ArrayLike

#: overlap / smaller radius above which a contact counts as out of the linear springs' range
OVERLAP_THRESHOLD = 0.10


class ValidityWarning(UserWarning):
    """Contacts overlap beyond :data:`OVERLAP_THRESHOLD` of their smaller disk's radius: the
    linear springs between rigid disks are out of their range there."""


class OverlapStatistics(NamedTuple):
    """Contact statistics per point.

    Attributes:
        max_ratio: (n,) largest overlap / smaller radius over the active contacts (0: none).
        contacts: (n,) int64 number of active contacts (eps >= 0) in the RVE.
    """

    max_ratio: np.ndarray
    contacts: np.ndarray


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _largest_ratio(F00, F01, F10, F11, X, Y, R, inv_rmin, n_visit):
    """``(max(0, max_c eps_c / r_min,c), active count)`` over the first ``n_visit`` candidates,
    with the stress kernel's arithmetic for l = F L and eps = R - |l| (the same active set). An
    open contact has eps < 0, so the plain maximum leaves it out: no branch, the loop vectorises."""
    best = 0.0
    active = 0
    for c in range(n_visit):
        lx = F00 * X[c] + F01 * Y[c]
        ly = F10 * X[c] + F11 * Y[c]
        eps = R[c] - np.sqrt(lx * lx + ly * ly)
        active += 1 if eps >= 0.0 else 0
        best = max(best, eps * inv_rmin[c])
    return best, active


@njit(cache=True)
def _overlap_batch(F, X, Y, R, rho, inv_rmin, min_stretch, ratio, count, status):
    """Largest eps / r_min and active count per point over the candidates the stress kernel
    visits; status as the kernel's (ratio and count 0 where F is rejected)."""
    for q in range(F.shape[0]):
        F00, F01, F10, F11 = F[q, 0, 0], F[q, 0, 1], F[q, 1, 0], F[q, 1, 1]
        code, limit = check_F(F00, F01, F10, F11, min_stretch)
        status[q] = code
        ratio[q] = 0.0
        count[q] = 0
        if code == OK:
            n_visit = np.searchsorted(rho, limit, side="right")
            ratio[q], count[q] = _largest_ratio(F00, F01, F10, F11, X, Y, R, inv_rmin, n_visit)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _largest_ratio_3d(F, X, Y, Z, R, inv_rmin, n_visit):
    """:func:`_largest_ratio` of spheres: F (3, 3), the 3-D kernel's branch lengths."""
    best = 0.0
    active = 0
    for c in range(n_visit):
        eps = R[c] - taylor_kernel_3d.branch(F, X[c], Y[c], Z[c])
        active += 1 if eps >= 0.0 else 0
        best = max(best, eps * inv_rmin[c])
    return best, active


@njit(cache=True)
def _overlap_batch_3d(F, X, Y, Z, R, rho, inv_rmin, min_stretch, ratio, count, status):
    """:func:`_overlap_batch` of spheres: F (n, 3, 3)."""
    for q in range(F.shape[0]):
        code, limit = taylor_kernel_3d.stretch_bound(F[q], min_stretch)
        status[q] = code
        ratio[q] = 0.0
        count[q] = 0
        if code == OK:
            n_visit = np.searchsorted(rho, limit, side="right")
            ratio[q], count[q] = _largest_ratio_3d(F[q], X, Y, Z, R, inv_rmin, n_visit)


def candidate_inverse_radius(law: Any) -> np.ndarray:
    """(M,) 1 / the smaller radius of the two disks of each candidate contact of a law with
    ``candidates`` (a TaylorRVE)."""
    return law.candidates.inverse_smaller_radius


def overlap_statistics(
    law: Any, F: ArrayLike, inv_rmin: np.ndarray | None = None
) -> OverlapStatistics:
    """:class:`OverlapStatistics` of a law with ``candidates`` and ``min_stretch`` (a TaylorRVE)
    at F (n, d, d) (or (d, d): scalars); ``inv_rmin`` (M,) defaults to the candidates'
    :attr:`~dolfinx_granular.ContactCandidates.inverse_smaller_radius`. F outside the
    law's range raises UnsupportedDeformationError."""
    c = law.candidates
    Fb, single = as_batch(F, c.dim)
    inv_rmin = c.inverse_smaller_radius if inv_rmin is None else inv_rmin
    n = Fb.shape[0]
    ratio, count, status = np.empty(n), np.empty(n, np.int64), np.empty(n, np.int8)
    args = (c.radius_sum, c.ratio, inv_rmin, law.min_stretch, ratio, count, status)
    if c.dim == 2:
        _overlap_batch(Fb, *c.components, *args)
    else:
        _overlap_batch_3d(Fb, *c.components, *args)
    if status.any():
        raise unsupported_deformation(Fb, status, law.min_stretch)
    if single:
        return OverlapStatistics(float(ratio[0]), int(count[0]))
    return OverlapStatistics(ratio, count)


def coordination(contacts: ArrayLike, n_particles: int) -> np.ndarray:
    """Mean coordination number 2 * contacts / particles (rattlers included)."""
    return 2.0 * np.asarray(contacts, dtype=float) / n_particles


def overlap_ratios(material: Any) -> np.ndarray:
    """(n_points,) the validity measure at the material's points on this rank (its ``F`` of the
    last update), ordered like ``material.points``. The law must have ``overlap_statistics``
    (TaylorRVE, FrictionalRVE and the model levels do)."""
    law = material.rve
    if not callable(getattr(law, "overlap_statistics", None)):
        raise TypeError(
            f"{type(law).__name__} has no overlap_statistics(F): the validity measure needs a "
            "disk-packing law (TaylorRVE, FrictionalRVE, SmallStrainRVE, AdaptiveRVE)"
        )
    return np.asarray(law.overlap_statistics(material.F).max_ratio, dtype=float)


@dataclass(frozen=True)
class OverlapSummary:
    """The validity measure over all points of a material, the same on every rank.

    Attributes:
        max_ratio: largest overlap / smaller radius over all points (0: no contact anywhere).
        at: reference coordinates (m) of a point with ``max_ratio`` (lowest rank on ties), or
            None when there are no points.
        points_above: number of points whose ratio exceeds ``threshold``.
        points: number of points.
        fraction_above: points_above / points (0 for no points).
        threshold: the threshold used.
    """

    max_ratio: float
    at: list[float] | None
    points_above: int
    points: int
    fraction_above: float
    threshold: float

    @property
    def exceeded(self) -> bool:
        """True when some point's ratio exceeds the threshold."""
        return self.points_above > 0

    def as_dict(self) -> dict:
        """Plain JSON-ready values (keys as the attributes)."""
        return asdict(self)

    def message(self) -> str:
        """One line for a log: the largest ratio, where, and the share beyond the threshold."""
        where = f" at x = {[round(v, 3) for v in self.at]} m" if self.at is not None else ""
        return (
            f"contact overlaps reach {100 * self.max_ratio:.3g} % of the smaller disk radius"
            f"{where}; {self.points_above} of {self.points} points "
            f"({100 * self.fraction_above:.3g} %) beyond {100 * self.threshold:g} %"
        )


def _check_threshold(threshold):
    t = float(threshold)
    if not (np.isfinite(t) and t >= 0.0):
        raise ValueError(f"threshold must be a finite number >= 0 (e.g. 0.10), got {threshold!r}")
    return t


def summarise(
    comm: Comm, ratios: ArrayLike, points: ArrayLike, threshold: float = OVERLAP_THRESHOLD
) -> OverlapSummary:
    """:class:`OverlapSummary` of per-rank ``ratios`` (n,) at ``points`` (n, 2) (m), gathered
    over ``comm``; every rank gets the same."""
    t = _check_threshold(threshold)
    ratios = np.asarray(ratios, dtype=float)
    above = comm.allreduce(int(np.count_nonzero(ratios > t)))
    total = comm.allreduce(int(ratios.size))
    if total == 0:
        return OverlapSummary(0.0, None, 0, 0, 0.0, t)
    value, at = global_extremum(comm, ratios, np.asarray(points), "max")
    return OverlapSummary(float(value), list(at), above, total, above / total, t)


def validity_summary(material: Any, threshold: float = OVERLAP_THRESHOLD) -> OverlapSummary:
    """:class:`OverlapSummary` of a GranularMaterial at its last update, gathered over its
    mesh's communicator (call it on every rank)."""
    ratios = overlap_ratios(material)
    return summarise(material.mesh.comm, ratios, material.points, threshold)


class OverlapMonitor:
    """Issues one :class:`ValidityWarning`, the first time a summary passes its threshold.

    A run keeps one monitor and hands it every step's summary: ``monitor.check(summary,
    "step 12")``. The summary is the same on every rank, so every rank decides alike.

    Attributes:
        warned: True once the warning has been issued.
    """

    def __init__(self) -> None:
        self.warned = False

    def check(self, summary: OverlapSummary, where: str = "") -> bool:
        """Warn if ``summary`` exceeds its threshold and no warning was issued before; returns
        True when this call warned. ``where``: what to name in the message (a load step)."""
        if self.warned or not summary.exceeded:
            return False
        self.warned = True
        prefix = f"{where}: " if where else ""
        warnings.warn(
            f"{prefix}{summary.message()}. Linear springs between rigid disks do not describe "
            "such overlaps: the model is out of its range there",
            ValidityWarning,
            stacklevel=2,
        )
        return True
