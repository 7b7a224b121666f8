"""One relaxed RVE's geometry and its contact state at (F, w).

:class:`Cell` holds a packing's candidate contacts as the relaxed kernels take them and makes
sure the fluctuations never carry two disks into contact that are no candidate pair.
:class:`ContactState` is everything the micro solver reads at one (F, w): overlaps, contacts,
rattlers (fewer than :data:`MIN_CONTACTS` contacts, removed recursively) and the network of the
others.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..packings import neighbours
from . import block_ldlt
from . import relaxed_kernel as rk
from .protocol import LawEvaluationError
from .tools import singular_values_2x2

#: contacts a disk needs to be no rattler (d + 1 in d = 2 dimensions)
MIN_CONTACTS = 3
#: Verlet skin of the candidates added beyond the reference list, relative to the smallest
#: radius sum
SKIN = 0.1
#: a block pattern holds this part of the visited prefix more (:meth:`Cell.block_pattern`)
PATTERN_MARGIN = 0.05
#: block patterns a cell keeps (each about 1 MB at 700 disks)
PATTERNS_KEPT = 8


class RelaxationError(LawEvaluationError):
    """The micro solver could not relax a point (no equilibrium reached, or its candidate
    contacts no longer cover the fluctuations)."""


@dataclass
class Cell:
    """One RVE's candidate contacts as the kernels take them (the first m are visited)."""

    pi: np.ndarray
    pj: np.ndarray
    X: np.ndarray
    Y: np.ndarray
    R: np.ndarray
    ratio: np.ndarray
    n_disks: int
    K: float
    min_stretch: float

    box: np.ndarray
    centers: np.ndarray
    radii: np.ndarray
    shift: np.ndarray
    #: length of the list built from the reference packing, sorted by |L| / R (pairs appended
    #: by :meth:`extend` follow it)
    n_sorted: int

    @classmethod
    def of(cls, candidates, packing, stiffness_per_area):
        """The cell of a packing's :class:`~dolfinx_granular.ContactCandidates`."""
        X, Y = candidates.components
        pairs = candidates.pairs
        return cls(
            np.ascontiguousarray(pairs[:, 0]),
            np.ascontiguousarray(pairs[:, 1]),
            X,
            Y,
            candidates.radius_sum,
            candidates.ratio,
            packing.radii.shape[0],
            float(stiffness_per_area),
            candidates.min_stretch,
            packing.box,
            packing.centers,
            packing.radii,
            candidates.shift,
            len(candidates),
        )

    def visited(self, F, w):
        """How many candidates (a prefix) can be in contact at F with fluctuations w.

        |F Q| < R needs |L| / R < 1 / s_min(F) + 2 max|w - mean w| / min R (a common translation
        changes no branch vector). Where that reaches past the sorted list (a rattler that
        crossed its cage, a rearrangement), :meth:`extend` adds the pairs now within reach and
        the whole list is visited."""
        s_min = float(singular_values_2x2(F[None])[1][0])
        v = w - w.mean(axis=0)
        reach = 1.0 / s_min + 2.0 * np.sqrt((v * v).sum(axis=1).max()) / self.R.min()
        if reach <= 1.0 / self.min_stretch:
            return int(np.searchsorted(self.ratio[: self.n_sorted], reach, side="right"))
        ref = self.__dict__.get("_verlet")
        if ref is not None and s_min >= ref[1]:
            moved = w - ref[0]
            moved -= moved.mean(axis=0)
            if (moved * moved).sum(axis=1).max() <= (0.5 * ref[2]) ** 2:
                return self.pi.shape[0]
        skin = SKIN * self.R.min()
        self.extend(w, s_min, skin)
        self._verlet = (w.copy(), s_min, skin)
        return self.pi.shape[0]

    def extend(self, w, s_min, skin):
        """Append every pair whose relaxed reference distance is below (r_i + r_j) / s_min(F)
        + skin and that is no candidate yet (indices of the earlier candidates do not change).
        The list then stays complete while no disk moves by more than skin / 2 (a Verlet
        list)."""
        x = self.centers + w
        wraps = np.floor(x / self.box).astype(np.int64)
        m, pi, pj, ps = neighbours.find_pairs(
            x - wraps * self.box, self.radii, self.box, 1.0 / s_min, skin, True
        )
        i, j = pi[:m].astype(np.int64), pj[:m].astype(np.int64)
        shift = ps[:m] + wraps[j] - wraps[i]
        flip = j < i
        i[flip], j[flip], shift[flip] = j[flip], i[flip], -shift[flip]
        keys = self.keys_of(i, j, shift)
        known = self.known_keys()
        pos = np.minimum(np.searchsorted(known, keys), known.size - 1)
        fresh = np.flatnonzero(known[pos] != keys)
        if fresh.size == 0:
            return
        a, b, sh = i[fresh], j[fresh], shift[fresh]
        L = self.centers[b] + sh * self.box - self.centers[a]
        R = self.radii[a] + self.radii[b]
        self.pi, self.pj = np.concatenate([self.pi, a]), np.concatenate([self.pj, b])
        self.X, self.Y = np.concatenate([self.X, L[:, 0]]), np.concatenate([self.Y, L[:, 1]])
        self.R = np.concatenate([self.R, R])
        self.ratio = np.concatenate([self.ratio, np.hypot(L[:, 0], L[:, 1]) / R])
        self.shift = np.concatenate([self.shift, sh])
        self._known = np.sort(np.concatenate([known, keys[fresh]]))
        for a in (self.pi, self.pj, self.X, self.Y, self.R, self.ratio, self.shift):
            a.flags.writeable = False  # as the list of Cell.of: one compiled kernel, not two

    def geometry(self) -> tuple:
        """The cell as the compiled Newton loop takes it
        (:mod:`~dolfinx_granular.laws.relaxed_newton`): ``(pi, pj, X, Y, R, ratio, n_sorted,
        n_candidates, 1 / min_stretch, min R, n_disks, K)``."""
        return (
            self.pi, self.pj, self.X, self.Y, self.R, self.ratio, self.n_sorted,
            self.pi.shape[0], 1.0 / self.min_stretch, float(self.R.min()), self.n_disks, self.K,
        )  # fmt: skip

    def verlet(self) -> tuple:
        """The Verlet reference of the list ``(w (N, 2), s_min, skin, valid)`` (valid False
        while the list has not grown)."""
        ref = self.__dict__.get("_verlet")
        if ref is None:
            return np.zeros((self.n_disks, 2)), 1.0, 0.0, False
        return ref[0], float(ref[1]), float(ref[2]), True

    def grow(self, F, w):
        """Bring the list up to fluctuations w (N, 2) at F (:meth:`extend`), whatever
        :meth:`visited` would say, and make w the Verlet reference."""
        s_min = float(singular_values_2x2(F[None])[1][0])
        skin = SKIN * self.R.min()
        self.extend(w, s_min, skin)
        self._verlet = (np.array(w, dtype=np.float64), s_min, skin)

    def block_pattern(self, pinned: int, m: int | None = None) -> tuple:
        """``(pattern, factor, cover)``: the symbolic block LDL^T of the stiffness on a prefix of
        the candidate pairs that holds the first m (all without m), disk ``pinned`` left out
        (:func:`~dolfinx_granular.laws.block_ldlt.analyse`), a numeric factor on it and the
        length of that prefix.

        The prefix reaches :data:`PATTERN_MARGIN` beyond m, so that the small changes of m
        along a point's Newton steps and its neighbours' find it again; the last
        :data:`PATTERNS_KEPT` patterns are kept (a pattern holds for a longer list too: the
        list only grows at its end)."""
        total = self.pi.shape[0]
        m = total if m is None else int(m)
        cache = self.__dict__.setdefault("_patterns", [])
        for k, (p, factor, cover) in enumerate(cache):
            if p.pinned == pinned and m <= cover:
                cache.append(cache.pop(k))
                return p, factor, cover
        cover = min(total, m + max(32, int(PATTERN_MARGIN * m)))
        pairs = np.c_[self.pi[:cover], self.pj[:cover]]
        p = block_ldlt.analyse(self.n_disks, pairs, int(pinned))
        cache.append((p, p.new_factor(), cover))
        del cache[:-PATTERNS_KEPT]
        return cache[-1]

    def known_keys(self) -> np.ndarray:
        """Sorted (M,) :meth:`keys_of` of the candidates."""
        if "_known" not in self.__dict__:
            self._known = np.sort(self.keys_of(self.pi, self.pj, np.asarray(self.shift)))
        return self._known

    def keys_of(self, i, j, shift) -> np.ndarray:
        """(k,) int64 identity of pairs (i, j, shift (k, 2)), j >= i: one integer each."""
        n = np.int64(self.n_disks)
        sh = np.asarray(shift, dtype=np.int64) + 64
        return ((np.asarray(i, np.int64) * n + j) * 128 + sh[:, 0]) * 128 + sh[:, 1]

    def pair_keys(self, idx: np.ndarray) -> np.ndarray:
        """(k,) identity of the candidates ``idx``, independent of their order in the list."""
        return self.keys_of(self.pi[idx], self.pj[idx], np.asarray(self.shift)[idx])


class ContactState:
    """The contacts of a cell at F (2, 2) and fluctuations w (N, 2) over the first m candidates
    (by default :meth:`Cell.visited`).

    Attributes:
        m: candidates visited (a prefix of the cell's list).
        qx, qy, lx, ly, d, e: (m,) relaxed reference branch Q, current branch l = F Q, |l| and
            the overlap e = R - |l|.
        on: (m,) contacts, e > 0.
        mean_overlap: mean e over the contacts (0 without contacts).
        keep: (N,) the non-rattlers.
        network: (m,) contacts between two non-rattlers.
        rattling: (m,) contacts that touch a rattler.
    """

    def __init__(self, cell: Cell, F: np.ndarray, w: np.ndarray, m: int | None = None) -> None:
        self.m = m = cell.visited(F, w) if m is None else m
        self.qx, self.qy, self.lx, self.ly, self.d, self.e = rk.contact_state(
            F, w, cell.pi, cell.pj, cell.X, cell.Y, cell.R, m
        )
        self.on = self.e > 0.0
        self.mean_overlap = float(self.e[self.on].mean()) if self.on.any() else 0.0
        self.keep = rk.non_rattlers(cell.pi, cell.pj, self.e, cell.n_disks, MIN_CONTACTS)
        both = self.both(cell, self.keep)
        self.network = self.on & both
        self.rattling = self.on & ~both

    def both(self, cell: Cell, keep: np.ndarray) -> np.ndarray:
        """(m,) candidates whose two disks are in ``keep`` (N,)."""
        return keep[cell.pi[: self.m]] & keep[cell.pj[: self.m]]

    def forces(self, cell: Cell, F: np.ndarray, use: np.ndarray) -> tuple:
        """``(g, f)`` (N, 2) each over the contacts ``use``: see :func:`relaxed_kernel.forces`."""
        return rk.forces(
            F, cell.pi, cell.pj, self.lx, self.ly, self.d, self.e, cell.K, cell.n_disks, use
        )

    def energy(self, cell: Cell, use: np.ndarray) -> float:
        """Energy of the contacts ``use`` (Pa)."""
        return rk.energy(self.e, cell.K, use)

    def resolution(self, cell: Cell) -> float:
        """The net force, relative to the mean contact force, below which (F, w) resolve no
        more: an overlap is the difference of lengths of the order of R, good to eps R, so a
        contact force is good to eps R / e of itself (~ eps mean R / mean e; inf without
        contacts)."""
        if not self.on.any():
            return np.inf
        return float(np.finfo(float).eps * cell.R[: self.m][self.on].mean() / self.mean_overlap)

    def force_scale(self, cell: Cell) -> float:
        """Mean contact force K e over the contacts (K times length; 0 without contacts)."""
        return cell.K * self.mean_overlap
