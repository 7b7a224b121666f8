"""One relaxed RVE's geometry: its candidate contacts, kept complete as the disks move, and the
block patterns of its stiffness.

:class:`Cell` holds a packing's candidate contacts as the relaxed kernels take them and makes
sure the fluctuations never carry two disks into contact that are no candidate pair (a prefix
of the list sorted by reference distance, a Verlet list beyond it); it keeps the symbolic
factorisations of the stiffness on prefixes of that list
(:mod:`~dolfinx_granular.laws.relaxed.block_ldlt`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ...packings import neighbours
from . import block_ldlt

#: Verlet skin of the candidates added beyond the reference list, relative to the smallest
#: radius sum
SKIN = 0.1
#: a block pattern holds this part of the prefix asked for more, and 16 pairs
#: (:meth:`Cell.block_pattern`)
PATTERN_MARGIN = 0.02
#: block patterns a cell keeps (each about 1 MB at 700 disks)
PATTERNS_KEPT = 8


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
    #: (pinned disk, prefix) of the last pattern the Newton loop asked for: the next point's
    #: first guess
    pattern_hint: tuple = (0, 0)

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
        s_min = smallest_stretch(np.ascontiguousarray(F, dtype=np.float64))
        m = reach_prefix(s_min, w, self.ratio, self.n_sorted, 1.0 / self.min_stretch, self.R_min)
        if m >= 0:
            return int(m)
        ref = self.__dict__.get("_verlet")
        if ref is not None and s_min >= ref[1]:
            moved = w - ref[0]
            moved -= moved.mean(axis=0)
            if (moved * moved).sum(axis=1).max() <= (0.5 * ref[2]) ** 2:
                return self.pi.shape[0]
        skin = SKIN * self.R_min
        self.extend(w, s_min, skin)
        self._verlet = (w.copy(), s_min, skin)
        return self.pi.shape[0]

    @property
    def R_min(self) -> float:
        """The smallest radius sum of the candidates (kept until the list grows)."""
        if "_R_min" not in self.__dict__:
            self._R_min = float(self.R.min())
        return self._R_min

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
        self.append(i[fresh], j[fresh], shift[fresh], keys[fresh])

    def append(self, a, b, sh, keys=None):
        """Append the pairs (a, b, shift sh (k, 2)), b >= a, that are no candidates yet, at the
        end of the list (their :meth:`keys_of` ``keys`` if known)."""
        keys = self.keys_of(a, b, sh) if keys is None else keys
        L = self.centers[b] + sh * self.box - self.centers[a]
        R = self.radii[a] + self.radii[b]
        self.pi, self.pj = np.concatenate([self.pi, a]), np.concatenate([self.pj, b])
        self.X, self.Y = np.concatenate([self.X, L[:, 0]]), np.concatenate([self.Y, L[:, 1]])
        self.R = np.concatenate([self.R, R])
        self.ratio = np.concatenate([self.ratio, np.hypot(L[:, 0], L[:, 1]) / R])
        self.shift = np.concatenate([self.shift, sh])
        self._known = np.sort(np.concatenate([self.known_keys(), keys]))
        self.__dict__.pop("_order", None)
        self.__dict__.pop("_R_min", None)
        for a in (self.pi, self.pj, self.X, self.Y, self.R, self.ratio, self.shift):
            a.flags.writeable = False  # as the list of Cell.of: one compiled kernel, not two

    def index_of(self, keys: np.ndarray) -> np.ndarray:
        """(k,) candidate indices of the pairs ``keys`` (k,) (:meth:`keys_of`); a pair that is
        no candidate (a contact of a list that grew in another run) is appended first."""
        keys = np.asarray(keys, dtype=np.int64)
        if "_order" not in self.__dict__:
            own = self.keys_of(self.pi, self.pj, np.asarray(self.shift))
            order = np.argsort(own)
            self._order = (own[order], order)
        sorted_keys, order = self._order
        pos = np.minimum(np.searchsorted(sorted_keys, keys), max(sorted_keys.size - 1, 0))
        missing = sorted_keys[pos] != keys
        if missing.any():
            new = np.unique(keys[missing])
            n = np.int64(self.n_disks)
            sh = np.stack([(new // 128) % 128 - 64, new % 128 - 64], axis=1)
            ij = new // (128 * 128)
            self.append(ij // n, ij % n, sh, new)
            return self.index_of(keys)
        return order[pos]

    def geometry(self) -> tuple:
        """The cell as the compiled Newton loop takes it
        (:mod:`~dolfinx_granular.laws.relaxed.newton`): ``(pi, pj, X, Y, R, ratio, n_sorted,
        n_candidates, 1 / min_stretch, min R, n_disks, K)``."""
        return (
            self.pi, self.pj, self.X, self.Y, self.R, self.ratio, self.n_sorted,
            self.pi.shape[0], 1.0 / self.min_stretch, self.R_min, self.n_disks, self.K,
        )  # fmt: skip

    def verlet(self) -> tuple:
        """The Verlet reference of the list ``(w (N, 2), s_min, skin, valid)`` (valid False
        while the list has not grown)."""
        ref = self.__dict__.get("_verlet")
        if ref is None:
            return np.zeros((self.n_disks, 2)), 1.0, 0.0, False
        return ref[0], float(ref[1]), float(ref[2]), True

    def grow(self, F, w, skin=None):
        """Bring the list up to fluctuations w (N, 2) at F (:meth:`extend`), whatever
        :meth:`visited` would say, and make w the Verlet reference: the list then holds while
        no disk moves by more than ``skin`` / 2 (default :data:`SKIN` times the smallest radius
        sum) from w, relative to their mean move."""
        s_min = smallest_stretch(np.ascontiguousarray(F, dtype=np.float64))
        skin = SKIN * self.R_min if skin is None else float(skin)
        self.extend(w, s_min, skin)
        self._verlet = (np.array(w, dtype=np.float64), s_min, skin)

    def block_pattern(
        self, pinned: int, m: int | None = None, d: int = 2, new_factor=None
    ) -> tuple:
        """``(pattern, factor, cover)``: the symbolic block LDL^T of the stiffness on the first
        ``cover`` candidate pairs, at least m of them (all without m), disk ``pinned`` left out
        (-1: none), in d x d blocks (3: a disk with its rotation)
        (:func:`~dolfinx_granular.laws.relaxed.block_ldlt.analyse`), and a numeric factor on it
        (``new_factor(pattern)``, default :meth:`BlockPattern.new_factor`), made once per
        pattern: its arrays are reused by every factorisation on the pattern.

        The compiled loop asks for the prefix that holds the contacts it assembles (the list is
        sorted by reference distance: fewer than the visited ones). The prefix reaches
        :data:`PATTERN_MARGIN` beyond m, so that the small changes of m along a point's Newton
        steps and its neighbours' find it again; the smallest kept pattern that holds m
        serves, unless it reaches twice the margin beyond; the last :data:`PATTERNS_KEPT`
        patterns are kept (a pattern holds for a longer list too: the list only grows at its
        end)."""
        total = self.pi.shape[0]
        m = total if m is None else int(m)
        margin = 16 + int(PATTERN_MARGIN * m)
        cache = self.__dict__.setdefault("_patterns", [])
        fits = [
            k for k, (p, _, c) in enumerate(cache) if p.pinned == pinned and p.d == d and m <= c
        ]
        if fits:
            k = min(fits, key=lambda k: cache[k][2])
            if cache[k][2] <= min(total, m + 2 * margin):
                cache.append(cache.pop(k))
                return cache[-1]
        cover = min(total, m + margin)
        pairs = np.c_[self.pi[:cover], self.pj[:cover]]
        p = block_ldlt.analyse(self.n_disks, pairs, int(pinned), d)
        cache.append((p, p.new_factor() if new_factor is None else new_factor(p), cover))
        del cache[:-PATTERNS_KEPT]
        return cache[-1]

    def kernel_pattern(self, pinned: int, m: int) -> tuple:
        """:meth:`block_pattern` as the compiled kernels take it: ``(pat, fac)``, the tuples
        of :mod:`~dolfinx_granular.laws.relaxed.newton`."""
        p, f, cover = self.block_pattern(pinned, m)
        pat = (p.pinned, cover, p.n, p.perm, p.Lp, p.Li, p.Rp, p.Rc, p.Rq, p.Ap, p.Ai,
               p.diag_slot, p.pair_slot)  # fmt: skip
        return pat, (f.values, f.Lx, f.D, f.Dinv, f.y)

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


@njit(cache=True)
def fingerprint(pi, pj, shift, contacts, n_disks):
    """An order-free hash of the set of candidates ``contacts`` (k,) (splitmix64 of their
    :meth:`Cell.keys_of`, summed mod 2^64)."""
    total = np.uint64(0)
    for c in contacts:
        key = ((pi[c] * n_disks + pj[c]) * 128 + shift[c, 0] + 64) * 128 + shift[c, 1] + 64
        z = np.uint64(key) + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        total += z ^ (z >> np.uint64(31))
    return total


@njit(cache=True)
def smallest_stretch(F):
    """The smaller singular value of F (2, 2) (as
    :func:`~dolfinx_granular.laws.tools.singular_values_2x2`)."""
    q = np.hypot(0.5 * (F[0, 0] + F[1, 1]), 0.5 * (F[1, 0] - F[0, 1]))
    r = np.hypot(0.5 * (F[0, 0] - F[1, 1]), 0.5 * (F[1, 0] + F[0, 1]))
    return abs(q - r)


@njit(cache=True)
def reach_prefix(s_min, w, ratio, n_sorted, inv_min_stretch, R_min):
    """The candidates of the sorted list (a prefix) that can touch at fluctuations w (N, 2)
    under an F whose smaller singular value is s_min: |F Q| < R needs |L| / R < 1 / s_min +
    2 max|w - mean w| / min R (a common translation changes no branch vector). -1 where that
    reach passes the sorted list (:meth:`Cell.visited` then looks beyond it)."""
    mean = w.sum(axis=0) / w.shape[0]
    big = 0.0
    for i in range(w.shape[0]):
        vx, vy = w[i, 0] - mean[0], w[i, 1] - mean[1]
        big = max(big, vx * vx + vy * vy)
    reach = 1.0 / s_min + 2.0 * np.sqrt(big) / R_min
    if reach > inv_min_stretch:
        return -1
    return np.searchsorted(ratio[:n_sorted], reach, side="right")
