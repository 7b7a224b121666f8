"""Candidate contacts of a periodic packing: the geometry every contact law builds on.

A candidate contact c is a pair of particles (i, j), j possibly a periodic image of the cell,
with reference branch vector L_c = X_j + shift_c * box - X_i and radius sum R_c = r_i + r_j. Under
the Taylor assumption its current branch vector is l = F L; it is active when R - |l| >= 0. Only
pairs that can touch at some supported F are candidates: those with rho = |L| / R <= 1 /
min_stretch (|F L| >= s_min(F) |L|). They are sorted by rho, so that a point with smallest
singular value s_min(F) needs only the prefix rho <= 1 / s_min(F) (the kernels' loop range).

The arrays are laid out for any dimension d (shape (m, d) per vector): disks in 2-D, spheres in
3-D, both found by the cell list of
:func:`~dolfinx_granular.packings.neighbours.candidate_pairs`. Lengths are in the packing's units.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..packings import neighbours
from ..packings.packing import Packing


def _readonly(a):
    a = np.ascontiguousarray(a).view()  # a view: the caller's array stays writeable
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class ContactCandidates:
    """The candidate contacts of a packing, sorted by ``ratio`` (read-only arrays).

    Build it with :meth:`from_packing`; every law of the package holds one (``law.candidates``).

    Attributes:
        branch: (m, d) reference branch vectors L = X_j + shift * box - X_i (length).
        radius_sum: (m,) R = r_i + r_j (length).
        ratio: (m,) rho = |L| / R, ascending (dimensionless).
        pairs: (m, 2) int64 particle indices i, j (j > i, or j == i for a particle and its own
            periodic image, listed once per pair of opposite shifts).
        shift: (m, d) int64 periodic image offset of j, in cells.
        smaller_radius: (m,) min(r_i, r_j) (length), the scale of the validity measure.
        min_stretch: the smallest singular value of F for which the list is complete.
        components: d contiguous (m,) arrays, the columns of ``branch`` (structure of arrays:
            contiguous loads let the kernels' loops vectorise).
    """

    branch: np.ndarray
    radius_sum: np.ndarray
    ratio: np.ndarray
    pairs: np.ndarray
    shift: np.ndarray
    smaller_radius: np.ndarray
    min_stretch: float

    def __post_init__(self):
        m = np.shape(self.radius_sum)[0]
        for name in ("branch", "radius_sum", "ratio", "pairs", "shift", "smaller_radius"):
            a = np.asarray(getattr(self, name))
            if a.shape[:1] != (m,):
                raise ValueError(
                    f"ContactCandidates.{name} has shape {a.shape}, expected one row per "
                    f"candidate ({m}): build it with ContactCandidates.from_packing"
                )
            object.__setattr__(self, name, _readonly(a))
        object.__setattr__(self, "min_stretch", float(self.min_stretch))

    @classmethod
    def from_packing(cls, packing: Packing, min_stretch: float = 0.5) -> ContactCandidates:
        """Every pair of ``packing`` that can touch at an F with s_min(F) >= ``min_stretch``
        (0 < min_stretch <= 1); a cell list, O(N)."""
        if not isinstance(packing, Packing):
            raise TypeError(
                f"packing must be a dolfinx_granular.Packing, got {type(packing).__name__}"
            )
        s = float(min_stretch)
        if not (0.0 < s <= 1.0):
            raise ValueError(f"min_stretch must lie in (0, 1], got {min_stretch!r}")
        L, R, rho, ij, shift = neighbours.candidate_pairs(
            packing.centers, packing.radii, packing.box, 1.0 / s
        )
        r = packing.radii
        return cls(L, R, rho, ij, shift, np.minimum(r[ij[:, 0]], r[ij[:, 1]]), s)

    def __len__(self) -> int:
        return self.radius_sum.shape[0]

    def __repr__(self) -> str:
        return f"ContactCandidates(m={len(self)}, dim={self.dim}, min_stretch={self.min_stretch})"

    @property
    def dim(self) -> int:
        """Spatial dimension d."""
        return self.branch.shape[1]

    @cached_property
    def components(self) -> tuple[np.ndarray, ...]:
        """The d columns of ``branch`` as contiguous (m,) arrays (the kernels' X, Y)."""
        return tuple(_readonly(self.branch[:, k]) for k in range(self.dim))

    @cached_property
    def max_branch_length2(self) -> float:
        """max |L|² over the candidates (length²; 1.0 without candidates, a harmless scale)."""
        if not len(self):
            return 1.0
        X = self.components
        s = X[0] ** 2
        for k in range(1, self.dim):
            s = s + X[k] ** 2
        return float(np.max(s))

    @cached_property
    def inverse_smaller_radius(self) -> np.ndarray:
        """(m,) 1 / min(r_i, r_j) (1 / length)."""
        return _readonly(1.0 / self.smaller_radius)

    def overlaps(self, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Current branch vectors l = F L (m, d) and overlaps eps = R - |l| (m,) of every
        candidate at one F (d, d) (length; eps >= 0: active), with the kernels' arithmetic, so
        that the active set is theirs."""
        F = np.asarray(F, dtype=np.float64)
        if F.shape != (self.dim, self.dim):
            raise ValueError(f"overlaps() takes one F of shape {(self.dim,) * 2}, got {F.shape}")
        X = self.components
        rows = []
        for a in range(self.dim):
            la = F[a, 0] * X[0]
            for k in range(1, self.dim):
                la = la + F[a, k] * X[k]
            rows.append(la)
        d2 = rows[0] * rows[0]
        for k in range(1, self.dim):
            d2 = d2 + rows[k] * rows[k]
        return np.stack(rows, axis=1), self.radius_sum - np.sqrt(d2)

    def visited(self, smallest_stretch: np.ndarray) -> np.ndarray:
        """(n,) int64 number of candidates a point with the given s_min(F) (n,) can reach: the
        prefix rho <= 1 / s_min (the kernels' loop range)."""
        return np.searchsorted(self.ratio, 1.0 / np.asarray(smallest_stretch), side="right")
