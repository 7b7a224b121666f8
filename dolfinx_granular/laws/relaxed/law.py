"""The relaxed RVE: every disk in static equilibrium in the periodic cell deformed by F.

Under the Taylor assumption every disk follows F (an upper bound of the response). Here the
disks move to the minimum of the contact energy in the cell spanned by F, and the tangent is the
exact derivative of that relaxed response (:mod:`~dolfinx_granular.laws.relaxed.equilibrium`).
The state of a point is where its disks are: fluctuations w (N, 2) in the reference frame, x_i =
F (X_i + w_i), so that a new F carries them with fixed fractional coordinates. A new F is
reached along the quasi-static path (:mod:`~dolfinx_granular.laws.relaxed.path`), each
relaxation warm-started by the first-order change dw/dF that the last tangent computed (the
committed one's sensitivities are kept in the state).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...packings.packing import Packing, require_disks
from ..contacts import ContactCandidates
from ..history_methods import HistoryLawMethods
from ..taylor import ContactSet
from ..tools import as_batch, output_buffers, to_float
from ..tools import normal_stiffness as normal_stiffness_of
from . import batch, equilibrium, path
from .cell import Cell, fingerprint
from .contact_state import ContactState
from .errors import RelaxationError, evaluated
from .settings import Settings

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

    from numpy.typing import ArrayLike

_KEYS = ("w", "F", "fluctuation", "rearranged", "network", "sensitivity")


@dataclass(frozen=True, eq=False)
class RelaxedState:
    """Relaxed positions of n points (immutable by convention).

    Attributes:
        w: (n, N, 2) fluctuations of the disks in the reference frame (length; x = F (X + w)).
        F: (n, 2, 2) the deformation gradient the positions are relaxed at.
        fluctuation: (n,) root mean square of |F w_i| over the disks, relative to the mean
            radius: how far the point moved from the affine positions.
        rearranged: (n,) bool, the non-rattlers' contact set changed during the last increment.
        network: (n,) uint64 fingerprint of the non-rattlers' contact set.
        sensitivity: (n, N, 2, 4) dw/dF at these positions (F flattened row-major; zero for
            rattlers, and where no tangent was computed): the warm start's first-order
            predictor.
    """

    w: np.ndarray
    F: np.ndarray
    fluctuation: np.ndarray
    rearranged: np.ndarray
    network: np.ndarray
    sensitivity: np.ndarray

    @property
    def n_points(self) -> int:
        return self.w.shape[0]

    def take(self, indices: ArrayLike) -> RelaxedState:
        idx = np.asarray(indices, dtype=np.int64)
        return RelaxedState(*(getattr(self, k)[idx] for k in _KEYS))

    @classmethod
    def concatenate(cls, states: Iterable[RelaxedState]) -> RelaxedState:
        states = list(states)
        return cls(*(np.concatenate([getattr(s, k) for s in states]) for k in _KEYS))

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {k: np.array(getattr(self, k)) for k in _KEYS}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, ArrayLike]) -> RelaxedState:
        missing = [k for k in _KEYS if k not in arrays and k != "sensitivity"]
        if missing:
            raise ValueError(f"RelaxedState arrays lack {', '.join(missing)}")
        w = np.asarray(arrays["w"], dtype=np.float64)
        n = w.shape[0] if w.ndim == 3 else -1
        if w.ndim != 3 or w.shape[2] != 2 or np.shape(arrays["F"]) != (n, 2, 2):
            raise ValueError(f"RelaxedState: w must be (n, N, 2) and F (n, 2, 2), got {w.shape}")
        if not np.isfinite(w).all():
            raise ValueError("RelaxedState.w has NaN or inf entries")
        # (a state saved before the sensitivities were kept: no predictor)
        dw = np.asarray(arrays.get("sensitivity", np.zeros(w.shape + (4,))), dtype=np.float64)
        if dw.shape != w.shape + (4,):
            raise ValueError(f"RelaxedState: sensitivity must be {w.shape + (4,)}, got {dw.shape}")
        return cls(
            w,
            np.asarray(arrays["F"], dtype=np.float64),
            np.asarray(arrays["fluctuation"], dtype=np.float64),
            np.asarray(arrays["rearranged"], dtype=bool),
            np.asarray(arrays["network"], dtype=np.uint64),
            dw,
        )


class RelaxedRVE(HistoryLawMethods):
    """Frictionless periodic disk packing relaxed to static equilibrium at every F.

    Same contact law and units as :class:`~dolfinx_granular.TaylorRVE`: linear normal springs
    k_n (N/m²), energy and stresses per reference area (Pa). A history law
    (:class:`~dolfinx_granular.HistoryLaw`): ``evaluate(F, state)`` relaxes each point from the
    committed positions ``state`` and returns the trial state beside W, P and A.

    Args:
        packing: the reference microstructure (jammed and stress-free, e.g. from
            :func:`~dolfinx_granular.generate_packing`).
        normal_stiffness: k_n > 0 in N/m².
        min_stretch: smallest singular value of F supported (the candidate contacts' reach).
        force_tol: equilibrium when every disk's net force is at most this times the mean
            contact force.

    Attributes:
        candidates: the packing's :class:`~dolfinx_granular.ContactCandidates`.
        cell: the candidates as the micro solver takes them
            (:class:`~dolfinx_granular.laws.relaxed.cell.Cell`; pairs a rearrangement brings
            within reach are appended to it).
        settings: the micro solver's tolerances
            (:class:`~dolfinx_granular.laws.relaxed.settings.Settings`).

    A point whose F equals the committed one is not relaxed again: its committed positions are
    at rest (the initial state, the stress-free packing at F = I, included). Where the micro
    solver fails, or the cell loses its rigidity, :class:`RelaxationError` /
    :class:`RigidityLostError` (both :class:`~dolfinx_granular.LawEvaluationError`) name the
    point, so that load stepping cuts back.
    """

    dim = 2

    def __init__(
        self,
        packing: Packing,
        normal_stiffness: float,
        min_stretch: float = 0.5,
        force_tol: float = 1e-10,
    ) -> None:
        k = normal_stiffness_of(normal_stiffness)
        # (from_packing refuses what is no Packing and a min_stretch outside (0, 1])
        self.candidates = ContactCandidates.from_packing(
            packing, to_float(min_stretch, "min_stretch")
        )
        require_disks(packing, "RelaxedRVE")
        self.packing = packing
        self.normal_stiffness = k
        self.min_stretch = self.candidates.min_stretch
        self.settings = Settings(force_tol=to_float(force_tol, "force_tol"))
        self.cell = Cell.of(self.candidates, packing, k / packing.area)

    def initial_state(self, n: int) -> RelaxedState:
        """n points at F = I in the stress-free packing (no fluctuation)."""
        N = self.packing.radii.shape[0]
        eye = np.broadcast_to(np.eye(2), (n, 2, 2)).copy()
        w, dw = np.zeros((n, N, 2)), np.zeros((n, N, 2, 4))
        return RelaxedState(w, eye, np.zeros(n), np.zeros(n, bool), np.zeros(n, np.uint64), dw)

    def _run(self, F, state, tangent, out=None):
        F, single = as_batch(F)
        n = F.shape[0]
        if state.n_points != n:
            raise ValueError(f"state has {state.n_points} points, F has {n}")
        res = batch.Outputs(n, self.cell.n_disks)
        q, floating = 0, []
        while q < n:  # the points in compiled code, one that needs more on its own path
            q = batch.relax_points(self.cell, self.settings, F, state, tangent, q, res)
            if q < n:
                if self._one_point(F, state, q, tangent, res):
                    floating.append(q)
                q += 1
        W, P, A = output_buffers(n, tangent, out)
        W[:], P[:] = res.W, res.P
        if tangent:
            A[:] = res.A
        rearranged = res.network != state.network
        new = RelaxedState(res.w, F.copy(), res.moved, rearranged, res.network, res.dw)
        return evaluated(W, P, A, new, single, floating)

    def _one_point(self, F, state, q, tangent, res) -> bool:
        """Point q on the Python path (:meth:`equilibrium`) into the outputs ``res``: True
        where its path ended in a cell come apart (A and the sensitivities zero)."""
        try:
            eq = self.equilibrium(F[q], state, q, tangent)
        except RelaxationError as err:
            raise type(err)(f"point {q}: {err}", np.array([q])) from None
        res.W[q], res.P[q], res.w[q] = eq.W, eq.P, eq.w
        if tangent:
            res.A[q] = 0.0 if eq.floating else eq.A
            res.dw[q] = eq.sensitivity
        u = eq.w @ F[q].T
        res.moved[q] = np.sqrt((u * u).sum(axis=1).mean()) / float(self.packing.radii.mean())
        c = self.cell
        res.network[q] = fingerprint(c.pi, c.pj, c.shift, eq.network, c.n_disks)
        return eq.floating

    def equilibrium(
        self, F: np.ndarray, state: RelaxedState, q: int, tangent: bool = True
    ) -> equilibrium.Equilibrium:
        """Point q of ``state`` relaxed at F (2, 2) along its quasi-static path (the
        :class:`~dolfinx_granular.laws.relaxed.equilibrium.Equilibrium`, with the solver's
        counts): what :meth:`evaluate` does for each point. A committed F is not relaxed again."""
        if np.array_equal(F, state.F[q]):  # the committed positions are at rest
            return equilibrium.at_rest(self.cell, F, state.w[q], tangent)
        w, dw, Fc = state.w[q], state.sensitivity[q], state.F[q]
        return path.follow(self.cell, F, w, dw, Fc, tangent, self.settings)

    def evaluate(self, F: ArrayLike, state: RelaxedState, out: tuple | None = None) -> tuple:
        """``(W (n,), P (n, 2, 2), A (n, 2, 2, 2, 2), trial_state)`` at F relaxed from
        ``state`` (left untouched); A = dP/dF of the relaxed response. Where a point's path
        ends in a cell that came apart, raises
        :class:`~dolfinx_granular.laws.relaxed.errors.CellFloats` with these outputs (that
        point's P of round-off, its A zero) after every point was evaluated."""
        return self._run(F, state, True, out)

    def small_strain_modulus(self) -> np.ndarray:
        """The relaxed modulus C (2, 2, 2, 2) at F = I: the linear response of the reference
        contact network (the stress-free packing is in equilibrium to the generator's accuracy,
        with overlaps ~1e-11 of a diameter that a relaxation would only open), condensed over
        the non-rattlers."""
        N = self.packing.radii.shape[0]
        return equilibrium.at_rest(self.cell, np.eye(2), np.zeros((N, 2)), True).A

    def contacts(self, F: ArrayLike, state: RelaxedState) -> ContactSet:
        """The contacts (rattlers' included) of one point of ``state``, relaxed at F (2, 2): its
        committed F (for force networks and diagnostics)."""
        F = np.asarray(F, dtype=np.float64)
        if F.shape != (2, 2) or state.n_points != 1:
            raise ValueError(
                f"contacts() takes one F of shape (2, 2) and a one-point state, got F of shape "
                f"{F.shape} and {state.n_points} points (state.take([i]) selects one)"
            )
        s = ContactState(self.cell, F, state.w[0])
        on = np.flatnonzero(s.on)
        c = self.cell
        return ContactSet(
            pairs=np.stack([c.pi[on], c.pj[on]], axis=1).astype(np.int64),
            shift=np.asarray(c.shift)[on],
            branch=np.stack([s.lx[on], s.ly[on]], axis=1),
            overlap=s.e[on],
            force=self.normal_stiffness * s.e[on],
        )

    def positions(self, F: ArrayLike, state: RelaxedState) -> np.ndarray:
        """(n, N, 2) relaxed centres in the current cell F [0, box) of ``state``'s points."""
        Fb, _ = as_batch(F)
        box = self.packing.box
        xi = self.packing.centers[None] + state.w
        xi = xi - np.floor(xi / box) * box
        return np.einsum("qab,qnb->qna", Fb, xi)
