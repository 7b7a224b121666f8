"""Frictional Taylor RVE: linear normal springs plus Coulomb friction with tangential springs.

The model is fixed by ``shared/notes/friction-taylor.md`` (the paper stops at normal springs),
with one correction (below). Every particle follows F and spins with its polar rotation
theta(F) = atan2(F21 - F12, F11 + F22); the sliding of contact c over a load step from the
committed F_n to F is

    ds = R wrap((phi - phi_n) - (theta - theta_n)) = R atan2(cross(Q l_n, l), dot(Q l_n, l)),

R = r_i + r_j, phi the branch angle, l = F L, l_n = F_n L, Q the rotation by theta - theta_n: the
branch's turn relative to the committed branch carried along with the particles. The trial force
f* = f_t,n + k_t ds sticks if |f*| <= mu f_n, else f_t = mu f_n sign(f*), with f_n = k_n eps.
Stress P = (1/V) sum_c [-f_n n (x) L + f_t ds/dF] (Hill-Mandel), consistent tangent at fixed
history (symmetric in stick, not in slip). History (:class:`FrictionState`) moves only when the
caller commits the returned state.

Error in the note, corrected here. The note's ds = rho (wrap(phi - phi_n) - wrap(theta - theta_n))
wraps the two increments separately. A superposed rotation increment alpha shifts both by alpha,
and ds stays the same only while neither wraps differently; when alpha carries one across +-pi
and not the other (alpha near a half turn), ds jumps by +-2 pi rho, so the note's model is not
objective there, contrary to its claim, and a barely deformed contact slides by ~2 pi rho. The
corrected formula above wraps once; it has the same derivatives (same P and A), equals the note's
wherever the note's |ds| < pi rho (every realistic load step: the two differ by a multiple of
2 pi rho), and is objective for any rotation increment. Shown by
``tests/test_friction.py::test_note_wraps_are_not_objective_near_a_half_turn``: with
alpha = -pi + 0.002 superposed on a 2 % shear step (40 disks, mu = 0.05), the note's formula (an
independent NumPy reference in the test) gives 20 of the 87 contacts |ds| ~ 2 pi R more and
raises the step's dissipation from 216 Pa to 45525 Pa, while this package's forces, dissipation
and rotated stress stay those of the unrotated step to round-off (also at alpha = 1,
pi - 0.002 and random angles), and equal the note's wherever the note is objective. In the kernel
(:mod:`~dolfinx_granular.laws.friction_kernel`) the committed F_n is replaced by Q F_n, Q from
theta(F) and theta(F_n) without trigonometry; theta's derivatives enter P and A as in the note.

Conventions where the note leaves a choice (all measure-zero cases):

- Normal springs act for eps >= 0 as in :class:`~dolfinx_granular.TaylorRVE` (same tangent at
  eps = 0); the tangential law, and the stored history, only for eps > 0.
- mu = 0 never sticks: with mu f_n = 0 the trial f* = 0 (e.g. at F = F_n) would otherwise stick and
  add k_t ds/dF (x) ds/dF to the tangent, and mu = 0 must give the frictionless tangent.
- The angle is evaluated in-kernel: a polynomial atan for steps whose increment without its spin,
  |F (Q F_n)^-1 - I|, is at most 0.045 (whatever the rotation), else a rational atan2; both are
  accurate to ~1 ulp (:func:`~dolfinx_granular.laws.friction_kernel.atan2`).

Verification of the note (tests/test_friction.py): its derivatives dphi/dF, dtheta/dF, ds/dF, the
stick and slip tangents, P = dPsi/dF in stick and the symmetry of sigma = P F^T / J all check out
against central differences and an independent NumPy reference. (Its d²s/dF² is left implicit;
here d²phi/dF² = -(t (x) n + n (x) t) L L / d², d²theta/dF² in
:func:`~dolfinx_granular.laws.friction_kernel._rotation`.)

Units: k_n, k_t in N/m² (force per unit length per unit thickness), mu dimensionless, forces in N
per unit thickness, lengths in the packing's units, W, P, A and dissipation in Pa.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..packings.packing import Packing, require_disks
from . import friction_kernel as fk
from .history_methods import HistoryLawMethods
from .taylor import TaylorRVE
from .tools import (
    as_batch,
    non_negative,
    output_buffers,
    unsupported_deformation,
)

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

    from numpy.typing import ArrayLike

    from .validity import OverlapStatistics

_KEYS = ("F", "dissipation", "offsets", "force")


def _readonly(a):
    a = a.view()
    a.flags.writeable = False
    return a


def _offsets(lengths):
    """Offsets (n + 1,) int64 of blocks of ``lengths`` (n,) stored one after the other."""
    off = np.zeros(len(lengths) + 1, np.int64)
    np.cumsum(lengths, out=off[1:])
    return off


@dataclass(frozen=True, eq=False)
class FrictionState:
    """Committed history of n material points (immutable; arrays are read-only).

    Layout: point q stores the tangential forces f_t,n (N per unit thickness) of the first
    ``offsets[q + 1] - offsets[q]`` candidates of the RVE (candidates sorted by |L|/R; the prefix
    the kernel visited at F_n) in ``force[offsets[q]:offsets[q + 1]]``; zero for contacts that
    were not active, and every candidate past the stored prefix counts as zero. The prefix is the
    kernel's own loop range, so reading the history costs one contiguous copy and no index decode.
    Memory: 8 bytes per visited candidate, about the number of active contacts under compression
    (700 disks at 2 % compression and 1 % shear: 12.4 kB per point), plus 48 bytes per point.

    Attributes:
        F: (n, 2, 2) committed deformation gradients F_n.
        dissipation: (n,) cumulative dissipated energy per unit reference area (Pa).
        offsets: (n + 1,) int64, offsets[0] = 0, non-decreasing.
        force: (offsets[-1],) float64 tangential forces.
    """

    F: np.ndarray
    dissipation: np.ndarray
    offsets: np.ndarray
    force: np.ndarray

    def __post_init__(self):
        F = np.array(self.F, dtype=np.float64, order="C")
        D = np.array(self.dissipation, dtype=np.float64, order="C")
        off = np.array(self.offsets, order="C")
        f = np.array(self.force, dtype=np.float64, order="C")
        if F.ndim != 3 or F.shape[1:] != (2, 2):
            raise ValueError(f"FrictionState.F must have shape (n, 2, 2), got {F.shape}")
        n = F.shape[0]
        if D.shape != (n,):
            raise ValueError(f"FrictionState.dissipation must have shape ({n},), got {D.shape}")
        if off.shape != (n + 1,) or not np.issubdtype(off.dtype, np.integer):
            raise ValueError(
                f"FrictionState.offsets must be integers of shape ({n + 1},), got "
                f"{off.dtype} {off.shape}"
            )
        if f.ndim != 1:
            raise ValueError(f"FrictionState.force must be 1-D, got shape {f.shape}")
        if off[0] != 0 or np.any(np.diff(off) < 0) or off[-1] != f.shape[0]:
            raise ValueError(
                "FrictionState.offsets must start at 0, never decrease and end at "
                f"len(force) = {f.shape[0]}"
            )
        if not (np.isfinite(F).all() and np.isfinite(D).all() and np.isfinite(f).all()):
            raise ValueError("FrictionState has NaN or inf entries")
        bad = np.flatnonzero(F[:, 0, 0] * F[:, 1, 1] - F[:, 0, 1] * F[:, 1, 0] <= 0.0)
        if bad.size:
            raise ValueError(f"FrictionState.F has det F <= 0 at points {bad[:5].tolist()}")
        for name, a in zip(_KEYS, (F, D, off.astype(np.int64), f)):
            object.__setattr__(self, name, _readonly(a))

    def __repr__(self):
        return (
            f"FrictionState(n_points={self.n_points}, stored_forces={self.force.size}, "
            f"nbytes={self.nbytes})"
        )

    @classmethod
    def _trusted(cls, F, dissipation, offsets, force):
        """A state from the kernel's own fresh arrays: no copies, no checks."""
        self = object.__new__(cls)
        for name, a in zip(_KEYS, (F, dissipation, offsets, force)):
            object.__setattr__(self, name, _readonly(a))
        return self

    @property
    def n_points(self) -> int:
        return self.F.shape[0]

    @property
    def nbytes(self) -> int:
        """Memory of the four arrays in bytes."""
        return sum(getattr(self, k).nbytes for k in _KEYS)

    @property
    def lengths(self) -> np.ndarray:
        """(n,) number of stored candidate forces per point."""
        return np.diff(self.offsets)

    def forces(self, q: int) -> np.ndarray:
        """Stored tangential forces of point q (candidates in the RVE's order)."""
        return self.force[self.offsets[q] : self.offsets[q + 1]]

    def take(self, indices: ArrayLike) -> FrictionState:
        """The points ``indices`` (int array, any order, repeats allowed) as a new state."""
        idx = np.asarray(indices)
        if idx.ndim != 1 or not (idx.size == 0 or np.issubdtype(idx.dtype, np.integer)):
            raise ValueError("take() needs a 1-D array of integer point indices")
        idx = idx.astype(np.int64)
        idx = np.where(idx < 0, idx + self.n_points, idx)
        if idx.size and (idx.min() < 0 or idx.max() >= self.n_points):
            raise IndexError(f"point index out of range for a state of {self.n_points} points")
        start, lengths = self.offsets[idx], np.diff(self.offsets)[idx]
        off = _offsets(lengths)
        gather = np.repeat(start - off[:-1], lengths) + np.arange(off[-1])
        return FrictionState._trusted(self.F[idx], self.dissipation[idx], off, self.force[gather])

    @classmethod
    def concatenate(cls, states: Iterable[FrictionState]) -> FrictionState:
        """The points of ``states`` (a sequence of FrictionState) one after the other."""
        states = list(states)
        if not states or not all(isinstance(s, FrictionState) for s in states):
            raise ValueError("concatenate() needs a non-empty sequence of FrictionState")
        return cls._trusted(
            np.concatenate([s.F for s in states]),
            np.concatenate([s.dissipation for s in states]),
            _offsets(np.concatenate([np.diff(s.offsets) for s in states])),
            np.concatenate([s.force for s in states]),
        )

    def to_arrays(self) -> dict:
        """Plain numpy arrays (copies) for ``np.savez``: keys F, dissipation, offsets, force."""
        return {k: np.array(getattr(self, k)) for k in _KEYS}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, ArrayLike]) -> FrictionState:
        """Inverse of :meth:`to_arrays` (a dict or an ``np.load`` result), validated."""
        missing = [k for k in _KEYS if k not in arrays]
        if missing:
            raise ValueError(f"friction state arrays lack {missing}; expected keys {list(_KEYS)}")
        return cls(*(np.asarray(arrays[k]) for k in _KEYS))

    def equals(self, other: object) -> bool:
        """Bit-for-bit equality of all arrays."""
        return isinstance(other, FrictionState) and all(
            getattr(self, k).shape == getattr(other, k).shape
            and getattr(self, k).tobytes() == getattr(other, k).tobytes()
            for k in _KEYS
        )

    def __eq__(self, other):
        if not isinstance(other, FrictionState):
            return NotImplemented
        return self.equals(other)

    __hash__ = None


@dataclass(frozen=True)
class FrictionContactSet:
    """Active contacts (eps >= 0) of one RVE after a step from its committed state to F.

    Attributes:
        pairs: (m, 2) disk indices i, j.
        shift: (m, 2) periodic image offset of j, in cells.
        branch: (m, 2) current branch vectors l = F L (length).
        overlap: (m,) eps >= 0 (length).
        normal_force: (m,) k_n eps (N per unit thickness).
        tangential_force: (m,) f_t along t = (-n_2, n_1) (N per unit thickness).
        sliding: (m,) True where |f_t| is at the Coulomb limit mu f_n (slid in this step; with
            mu = 0 every contact with eps > 0).
    """

    pairs: np.ndarray
    shift: np.ndarray
    branch: np.ndarray
    overlap: np.ndarray
    normal_force: np.ndarray
    tangential_force: np.ndarray
    sliding: np.ndarray


def _check_outputs(n, tangent, W, P, A):
    """Refuse ``out`` arrays the kernel cannot write into (it assumes their layout)."""
    for name, a, shape in (
        ("W", W, (n,)),
        ("P", P, (n, 2, 2)),
        ("A", A, (n, 2, 2, 2, 2) if tangent else None),
    ):
        if shape is not None and (
            a is None or a.shape != shape or a.dtype != np.float64 or not a.flags.c_contiguous
        ):
            raise ValueError(f"out {name} must be a C-contiguous float64 array of shape {shape}")


class FrictionalRVE(HistoryLawMethods):
    """Taylor RVE of a periodic disk packing with normal springs and Coulomb friction.

    Args:
        packing: the reference microstructure.
        normal_stiffness: k_n > 0 in N/m².
        tangential_stiffness: k_t >= 0 in N/m² (0: no tangential force).
        friction: Coulomb coefficient mu >= 0 (0: frictionless).
        min_stretch: smallest supported singular value of F, in (0, 1].
        allow_overlaps: accept far-overlapping disks at F = I, as :class:`TaylorRVE` does.

    The reference state is the Taylor RVE's: at F = I no contact has slid or carries a
    tangential force, so ``prestress`` (P(I)), ``prestress_ratio`` and ``max_reference_overlap``
    are those of ``TaylorRVE(packing, normal_stiffness)``.

    Every method takes F of shape (n, 2, 2) (or (2, 2) for one point) with the committed
    :class:`FrictionState` of the same n points, and never changes that state. F outside the
    supported range raises :class:`~dolfinx_granular.UnsupportedDeformationError`.

    Attributes:
        candidates: the :class:`~dolfinx_granular.ContactCandidates` of the wrapped
            TaylorRVE (the same object); a state's forces follow their order.
    """

    def __init__(
        self,
        packing: Packing,
        normal_stiffness: float,
        tangential_stiffness: float,
        friction: float,
        min_stretch: float = 0.5,
        allow_overlaps: bool = False,
    ) -> None:
        kt = non_negative(tangential_stiffness, "tangential_stiffness", " (N/m²)")
        mu = non_negative(friction, "friction")
        self._taylor = TaylorRVE(packing, normal_stiffness, min_stretch, allow_overlaps)
        require_disks(packing, "FrictionalRVE")
        self.packing = packing
        self.normal_stiffness = self._taylor.normal_stiffness
        self.tangential_stiffness = kt
        self.friction = mu
        self.min_stretch = self._taylor.min_stretch
        self.candidates = self._taylor.candidates
        self._inv_area = 1.0 / packing.area

    @property
    def prestress(self) -> np.ndarray:
        """P(I) in Pa, (2, 2): the reference stress (no contact has slid at F = I)."""
        return self._taylor.prestress

    @property
    def prestress_ratio(self) -> float:
        """|P(I)| / |C|, as :attr:`TaylorRVE.prestress_ratio`."""
        return self._taylor.prestress_ratio

    @property
    def max_reference_overlap(self) -> float:
        """Largest overlap / radius sum at F = I (~1e-11 for a generated packing)."""
        return self._taylor.max_reference_overlap

    @property
    def n_candidates(self) -> int:
        """Number of candidate contacts; a state stores at most this many forces per point."""
        return len(self.candidates)

    def initial_state(self, n: int) -> FrictionState:
        """Committed state of n points at F = I with no tangential force and no dissipation."""
        n = int(n)
        if n < 0:
            raise ValueError(f"initial_state needs n >= 0 points, got {n}")
        return FrictionState._trusted(
            np.tile(np.eye(2), (n, 1, 1)), np.zeros(n), np.zeros(n + 1, np.int64), np.zeros(0)
        )

    # -- batch evaluation -------------------------------------------------------------------------

    def _check_state(self, state, n):
        if not isinstance(state, FrictionState):
            raise TypeError(f"state must be a FrictionState, got {type(state).__name__}")
        if state.n_points != n:
            raise ValueError(
                f"state holds {state.n_points} points but F has {n}; pass the "
                "committed state of exactly these points (FrictionState.take)"
            )
        longest = int(state.lengths.max()) if n else 0
        if longest > self.n_candidates:
            raise ValueError(
                f"state stores {longest} candidate forces for a point but this RVE "
                f"has {self.n_candidates} candidates: it belongs to another RVE"
            )

    def _visited(self, F, state):
        """Candidates the kernel visits per point (n,) of the batch F (n, 2, 2) from ``state``;
        raises for a state of other points or an unsupported F."""
        n = F.shape[0]
        self._check_state(state, n)
        status = np.empty(n, np.int8)
        lengths = np.empty(n, np.int64)
        fk.prefix_lengths(F, self.candidates.ratio, self.min_stretch, status, lengths)
        if status.any():
            raise unsupported_deformation(F, status, self.min_stretch)
        return lengths

    def _run(self, F, state, tangent, out):
        F, single = as_batch(F)
        n = F.shape[0]
        off = _offsets(self._visited(F, state))
        W, P, A = output_buffers(n, tangent, out)
        _check_outputs(n, tangent, W, P, A)
        status = np.empty(n, np.int8)  # the kernel's own output; _visited has checked every F
        f = np.empty(off[-1])
        D = np.empty(n)
        c = self.candidates
        X, Y = c.components
        fk.evaluate_batch(
            F,
            X,
            Y,
            c.radius_sum,
            c.ratio,
            c.max_branch_length2,
            self.normal_stiffness,
            self.tangential_stiffness,
            self.friction,
            self._inv_area,
            self.min_stretch,
            tangent,
            state.F,
            state.offsets,
            state.force,
            state.dissipation,
            off,
            f,
            W,
            P,
            A if tangent else np.empty((0, 2, 2, 2, 2)),
            D,
            status,
        )
        new = FrictionState._trusted(F.copy(), D, off, f)
        if single:
            return W[0], P[0], (A[0] if tangent else None), new
        return W, P, A, new

    def evaluate(
        self, F: ArrayLike, state: FrictionState, out: tuple | None = None
    ) -> tuple[np.ndarray | float, np.ndarray, np.ndarray, FrictionState]:
        """Energy, first Piola stress, tangent at fixed history and the new state.

        Args:
            F: (n, 2, 2) deformation gradients.
            state: committed :class:`FrictionState` of the n points (not modified).
            out: optional ``(W, P, A)`` C-contiguous float64 arrays of shapes (n,), (n, 2, 2),
                (n, 2, 2, 2, 2) to write into.

        Returns:
            ``(W, P, A, new_state)``: W (n,) stored energy sum [k_n eps²/2 + f_t²/(2 k_t)] / V,
            P (n, 2, 2), A (n, 2, 2, 2, 2) with ``A[q, a, b, c, d] = dP_ab / dF_cd`` (Pa), and the
            state after the step (commit it only once the load step has converged).
        """
        return self._run(F, state, True, out)

    def small_strain_modulus(self) -> np.ndarray:
        """Stick tangent (2, 2, 2, 2) at F = I from the initial state, in Pa (fully symmetric).

        Eq. 15 of the normal springs plus (k_t / V) sum_c R² sym(t (x) n) (x) sym(t (x) n) over the
        contacts with eps > 0 at F = I (none if mu = 0: it never sticks)."""
        C = self._taylor.small_strain_modulus()
        kt, mu = self.tangential_stiffness, self.friction
        L, R = self.candidates.branch, self.candidates.radius_sum
        d = np.sqrt(L[:, 0] ** 2 + L[:, 1] ** 2)
        on = R - d > 0.0
        if kt == 0.0 or mu == 0.0 or not on.any():
            return C
        n = L[on] / d[on, None]
        t = np.stack([-n[:, 1], n[:, 0]], axis=1)
        tn = np.einsum("ma,mb->mab", t, n)
        g = R[on, None, None] * 0.5 * (tn + tn.transpose(0, 2, 1))  # R sym(t n) = ds/dF at I
        return C + kt * self._inv_area * np.einsum("mab,mcd->abcd", g, g)

    def contacts(self, F: ArrayLike, state: FrictionState) -> FrictionContactSet:
        """Active contacts (eps >= 0) after the step from the 1-point ``state`` to one F (2, 2)."""
        F = np.asarray(F, dtype=np.float64)
        if F.shape != (2, 2):
            raise ValueError(f"contacts() takes one F of shape (2, 2), got {F.shape}")
        F = np.ascontiguousarray(F)
        m = int(self._visited(F[None], state)[0])
        buf = np.zeros(m)
        stored = state.forces(0)[:m]
        buf[: stored.size] = stored
        eps, stick = np.empty(m), np.empty(m, np.int8)
        c = self.candidates
        X, Y = c.components
        fk.contact_step(
            F,
            np.ascontiguousarray(state.F[0]),
            X,
            Y,
            c.radius_sum,
            m,
            c.max_branch_length2,
            buf,
            self.normal_stiffness,
            self.tangential_stiffness,
            self.friction,
            eps,
            stick,
        )
        on = np.flatnonzero(eps >= 0.0)
        L = c.branch[on]
        return FrictionContactSet(
            pairs=c.pairs[on],
            shift=c.shift[on],
            branch=L @ F.T,
            overlap=eps[on],
            normal_force=self.normal_stiffness * eps[on],
            tangential_force=buf[on],
            sliding=(eps[on] > 0.0) & (stick[on] == 0),
        )

    def overlap_statistics(
        self, F: ArrayLike, state: FrictionState | None = None
    ) -> OverlapStatistics:
        """The validity measure at F (``TaylorRVE.overlap_statistics``); ``state`` is accepted
        for symmetry with the other methods and not needed: the overlaps depend on F alone."""
        return self._taylor.overlap_statistics(F)
