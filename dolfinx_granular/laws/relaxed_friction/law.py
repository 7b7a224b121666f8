"""The frictional relaxed RVE: disks with contact friction and rotations in static equilibrium
in the periodic cell deformed by F, a history law.

Each point's state holds the disks' fluctuations and rotations and the tangential force of
every contact (:class:`~dolfinx_granular.laws.relaxed_friction.state.FrictionalRelaxedState`).
A new F is reached along the quasi-static path from the committed state
(:mod:`~dolfinx_granular.laws.relaxed_friction.point`), every substep a backward-Euler
increment of the contact law of :class:`~dolfinx_granular.FrictionalRVE`.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from ...packings.packing import Packing
from ..history_methods import HistoryLawMethods
from ..relaxed.errors import CellFloats, RelaxationError, evaluated
from ..relaxed.law import RelaxedRVE, RelaxedState
from ..taylor import ContactSet
from ..tools import as_batch, non_negative, output_buffers, to_float
from .cell_state import Increment, Springs
from .contact_law import SLIP
from .point import Equilibrium, at_rest, follow, rest_state, within_cones
from .settings import Settings
from .state import FrictionalRelaxedState

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


class FrictionalRelaxedRVE(HistoryLawMethods):
    """Periodic disk packing with normal springs, Coulomb friction and rotations, relaxed to
    static equilibrium at every F (a :class:`~dolfinx_granular.HistoryLaw`).

    Args:
        packing: the reference microstructure (e.g. a confined packing).
        normal_stiffness: k_n > 0 (N/m²).
        tangential_stiffness: k_t > 0 (N/m²) where friction or rolling_friction > 0.
        friction: Coulomb coefficient mu >= 0. With mu = 0 (and rolling_friction = 0) no
            contact carries a tangential force and nothing resists a rotation: the point is
            the frictionless :class:`~dolfinx_granular.RelaxedRVE`'s, computed by it (the
            rotations stay).
        min_stretch: smallest singular value of F supported (the candidates' reach).
        force_tol: equilibrium when every net force is at most this times the mean contact
            force, and every net moment this times the mean contact force times the mean
            radius.
        substep: the quasi-static path's longest substep in the right stretch; substeps are
            also at most a quarter of the mean overlap over the mean radius sum (part of the
            model: each substep is one increment of the contact law,
            :class:`~dolfinx_granular.laws.relaxed_friction.settings.Settings`).
        rolling_friction: mu_r >= 0, rolling resistance: every contact also carries a rolling
            moment, a spring on the disks' relative rotation capped at mu_r r_eff f_n
            (r_eff = r_i r_j / (r_i + r_j); Iwashita & Oda, LIGGGHTS' epsd2;
            :mod:`~dolfinx_granular.laws.relaxed_friction.rolling`). 0: none (the law
            without it, bit for bit).
        rolling_stiffness: beta > 0, the rolling spring k_r = beta k_t r_eff^2 (1: epsd2's).

    The contact law is :class:`~dolfinx_granular.FrictionalRVE`'s: k_n, k_t, the cap mu f_n,
    sliding measured with lever arms r_i, r_j (:mod:`.contact_law`); W is the stored energy
    sum [k_n e^2 / 2 + f_t^2 / (2 k_t) + m_r^2 / (2 k_r)] / V, P and A per reference area
    (Pa), A = dP/dF at
    fixed committed history (not symmetric where contacts slip).
    """

    dim = 2

    def __init__(
        self,
        packing: Packing,
        normal_stiffness: float,
        tangential_stiffness: float,
        friction: float,
        min_stretch: float = 0.5,
        force_tol: float = 1e-10,
        substep: float = 1e-3,
        rolling_friction: float = 0.0,
        rolling_stiffness: float = 1.0,
    ) -> None:
        self._frictionless = RelaxedRVE(packing, normal_stiffness, min_stretch, force_tol)
        kt = non_negative(tangential_stiffness, "tangential_stiffness", " (N/m²)")
        mu = non_negative(friction, "friction")
        mu_r = non_negative(rolling_friction, "rolling_friction")
        beta = non_negative(rolling_stiffness, "rolling_stiffness")
        if (mu > 0.0 or mu_r > 0.0) and kt == 0.0:
            raise ValueError(
                "tangential_stiffness must be > 0 where friction or rolling_friction > 0 (a "
                "contact without a tangential spring has no stick state); pass e.g. "
                "tangential_stiffness = normal_stiffness"
            )
        if mu_r > 0.0 and beta == 0.0:
            raise ValueError(
                "rolling_stiffness must be > 0 where rolling_friction > 0 (the rolling spring "
                "k_r = rolling_stiffness k_t r_eff^2 has no stick state without it); the usual "
                "value is 1 (LIGGGHTS' epsd2)"
            )
        step = to_float(substep, "substep")
        if not (np.isfinite(step) and step > 0.0):
            raise ValueError(f"substep must be a finite number > 0, got {substep!r}")
        self.packing = packing
        self.normal_stiffness = self._frictionless.normal_stiffness
        self.tangential_stiffness = kt
        self.friction = mu
        self.rolling_friction = mu_r
        self.rolling_stiffness = beta
        self.min_stretch = self._frictionless.min_stretch
        self.candidates = self._frictionless.candidates
        self.cell = self._frictionless.cell
        self.settings = Settings(force_tol=self._frictionless.settings.force_tol, substep=step)
        self.springs = Springs(self.normal_stiffness, kt, mu, 1.0 / packing.area, beta * kt, mu_r)

    def set_friction(self, friction: float, rolling_friction: float | None = None) -> None:
        """Change the Coulomb coefficient mu (and mu_r; None: as it is) of every point from
        their next evaluation on: strength reduction at a fixed F. A committed state whose
        forces or moments lie outside the new cones is relaxed at its own F (it slides);
        one inside them stays at rest. The stiffnesses stay; ValueError where the change would
        switch between the law with and without friction (mu = mu_r = 0 is computed by
        the frictionless relaxed RVE, with another state)."""
        mu = non_negative(friction, "friction")
        mu_r = self.rolling_friction if rolling_friction is None else rolling_friction
        mu_r = non_negative(mu_r, "rolling_friction")
        if (mu == 0.0 and mu_r == 0.0) != self._without_friction:
            raise ValueError(
                f"set_friction({mu:g}, {mu_r:g}) on a law with friction {self.friction:g} and "
                f"rolling friction {self.rolling_friction:g}: friction cannot be switched on "
                "or off (mu = mu_r = 0 is the frictionless relaxed RVE); reduce it to a small "
                "positive value instead"
            )
        if mu_r > 0.0 and self.springs.kr == 0.0:
            raise ValueError(
                "rolling_friction > 0 needs rolling springs: build the law with "
                "rolling_stiffness > 0"
            )
        self.friction, self.rolling_friction = mu, mu_r
        self.springs = dataclasses.replace(self.springs, mu=mu, mu_r=mu_r)

    @property
    def _without_friction(self) -> bool:
        """Neither sliding nor rolling friction: the frictionless relaxed RVE's points."""
        return self.friction == 0.0 and self.rolling_friction == 0.0

    # -- states ----------------------------------------------------------------------------------

    def initial_state(self, n: int) -> FrictionalRelaxedState:
        """n points at F = I in the stress-free packing: no fluctuation, rotation or force."""
        N = self.cell.n_disks
        z = np.zeros
        return FrictionalRelaxedState(
            z((n, N, 2)), z((n, N)), np.tile(np.eye(2), (n, 1, 1)), z((n, N, 3, 4)), z(n),
            z(n), z(n + 1, np.int64), z(0, np.int64), z(0), z(0, bool), z(0),
        )  # fmt: skip

    def increment(self, state: FrictionalRelaxedState, q: int) -> Increment:
        """Point q of ``state`` as the committed side of an increment (its tangential forces
        and rolling moments by this RVE's candidates)."""
        keys, forces, _, moments = state.contacts(q)
        idx = self.cell.index_of(keys)
        ft0, mr0 = np.zeros(self.cell.pi.shape[0]), np.zeros(self.cell.pi.shape[0])
        ft0[idx] = forces
        mr0[idx] = moments
        return Increment(state.F[q].copy(), state.w[q], state.theta[q], ft0, None, mr0)

    # -- one point -------------------------------------------------------------------------------

    def equilibrium(
        self, F: np.ndarray, state: FrictionalRelaxedState, q: int, tangent: bool = True
    ) -> tuple[Equilibrium, float]:
        """Point q of ``state`` at F (2, 2) along its quasi-static path: its
        :class:`~dolfinx_granular.laws.relaxed_friction.point.Equilibrium` and the energy
        dissipated on the way (Pa). A committed F is not relaxed again, unless the friction
        was lowered below what its state carries (:meth:`set_friction`)."""
        inc = self.increment(state, q)
        if np.array_equal(F, state.F[q]):
            # (the cones before the tangent: out of them the committed state is no equilibrium,
            # and the tangent at it, which need not exist, is not wanted)
            s = rest_state(self.cell, self.springs, F, inc)
            if within_cones(s, inc, float(self.cell.radii.mean())):
                return at_rest(self.cell, self.springs, F, inc, s, tangent), 0.0
        dq = state.sensitivity[q]
        return follow(self.cell, self.springs, F, inc, dq, self.settings, tangent)

    def _frictionless_point(self, F, state, q, tangent):
        """Point q by the frictionless relaxed RVE (mu = 0): ``(W, P, A, w, dq, floating)``,
        floating where its path ended in a cell come apart (A zero)."""
        one = RelaxedState(
            state.w[q : q + 1], state.F[q : q + 1], state.fluctuation[q : q + 1],
            np.zeros(1, bool), np.zeros(1, np.uint64), state.sensitivity[q : q + 1, :, :2],
        )  # fmt: skip
        try:
            W, P, A, new = self._frictionless._run(F[None], one, tangent)
            floating = False
        except CellFloats as err:
            (W, P, A, new), floating = err.outputs, True
        dq = np.zeros((self.cell.n_disks, 3, 4))
        dq[:, :2] = new.sensitivity[0]
        return W[0], P[0], (A[0] if tangent else None), new.w[0], dq, floating

    def _point(self, F, state, q, tangent) -> tuple:
        """Point q of ``state`` at F (2, 2): ``(W, P, A (zero where floating; None without
        tangent), w, theta, dq, dissipated, (keys, tangential forces, sliding, rolling
        moments), floating)``, floating where its path ended in a cell come apart."""
        if self._without_friction:
            W, P, a, w, dq, floats = self._frictionless_point(F, state, q, tangent)
            none = (np.zeros(0, np.int64), np.zeros(0), np.zeros(0, bool), np.zeros(0))
            return W, P, a, w, state.theta[q], dq, 0.0, none, floats
        eq, dissipated = self.equilibrium(F, state, q, tangent)
        a = np.zeros((2, 2, 2, 2)) if eq.floating and tangent else eq.A
        history = self._history(eq, state, q)
        return eq.W, eq.P, a, eq.w, eq.theta, eq.sensitivity, dissipated, history, eq.floating

    # -- the law ---------------------------------------------------------------------------------

    def _run(self, F, state, tangent, out=None):
        F, single = as_batch(F)
        n = F.shape[0]
        if not isinstance(state, FrictionalRelaxedState):
            raise TypeError(f"state must be a FrictionalRelaxedState, got {type(state).__name__}")
        if state.n_points != n:
            raise ValueError(f"state has {state.n_points} points, F has {n}")
        W, P, A = output_buffers(n, tangent, out)
        w, th = np.empty_like(state.w), state.theta.copy()
        dq, D = np.empty_like(state.sensitivity), state.dissipation.copy()
        histories, floating = [], []
        for q in range(n):
            try:
                W[q], P[q], a, w[q], th[q], dq[q], dissipated, history, floats = self._point(
                    F[q], state, q, tangent
                )
            except RelaxationError as err:
                raise type(err)(f"point {q}: {err}", np.array([q])) from None
            D[q] += dissipated
            histories.append(history)
            if floats:
                floating.append(q)
            if tangent:
                A[q] = a
        keys, forces, sliding, moments = (list(h) for h in zip(*histories)) if n else ([],) * 4
        moved = np.sqrt((np.einsum("qab,qnb->qna", F, w) ** 2).sum(axis=2).mean(axis=1))
        off = np.zeros(n + 1, np.int64)
        np.cumsum([k.size for k in keys], out=off[1:])
        new = FrictionalRelaxedState(
            w, th, F.copy(), dq, D, moved / float(self.packing.radii.mean()), off,
            np.concatenate(keys) if keys else np.zeros(0, np.int64),
            np.concatenate(forces) if forces else np.zeros(0),
            np.concatenate(sliding) if sliding else np.zeros(0, bool),
            np.concatenate(moments) if moments else np.zeros(0),
        )  # fmt: skip
        return evaluated(W, P, A, new, single, floating)

    def _history(self, eq: Equilibrium, state, q) -> tuple:
        """``(keys, tangential forces, sliding, rolling moments)`` of the contacts of an
        equilibrium of point q (at rest at its committed F: the committed contacts, which slid
        in the increment to it)."""
        s, c = eq.state, self.cell
        on = np.flatnonzero(s.on)
        keys = c.keys_of(c.pi[on], c.pj[on], np.asarray(c.shift)[on])
        if eq.rested:
            committed, _, slid, _ = state.contacts(q)
            sliding = np.zeros(on.size, bool)
            if committed.size:
                order = np.argsort(committed)
                k = order[
                    np.minimum(np.searchsorted(committed, keys, sorter=order), order.size - 1)
                ]
                sliding = (committed[k] == keys) & slid[k]
            return keys, s.ft[on].copy(), sliding, s.mr[on].copy()
        return keys, s.ft[on].copy(), s.status[on] == SLIP, s.mr[on].copy()

    def evaluate(self, F: ArrayLike, state: FrictionalRelaxedState, out: tuple | None = None):
        """``(W (n,), P (n, 2, 2), A (n, 2, 2, 2, 2), trial_state)`` at F from the committed
        ``state`` (left untouched). Where a point's path ends in a cell that came apart, raises
        :class:`~dolfinx_granular.laws.relaxed.errors.CellFloats` with these outputs (that
        point's P of round-off, its A zero) after every point was evaluated."""
        return self._run(F, state, True, out)

    def small_strain_modulus(self) -> np.ndarray:
        """The tangent (2, 2, 2, 2) at F = I from the initial state: every reference contact
        sticks (its trial force 0 lies in its cone), condensed over the network."""
        return self._run(np.eye(2), self.initial_state(1), True)[2]

    # -- what a user reads -----------------------------------------------------------------------

    def contacts(self, F: ArrayLike, state: FrictionalRelaxedState) -> ContactSet:
        """The contacts (overlap > 0) of one point of ``state`` at F (2, 2) after its
        increment, with ``tangential`` (the force on j along t = (-n_y, n_x), = -f_t; the
        balance of forces takes it times R / d), ``sliding`` and ``rolling`` (the couple on
        j)."""
        F = np.asarray(F, dtype=np.float64)
        if F.shape != (2, 2) or state.n_points != 1:
            raise ValueError(
                f"contacts() takes one F of shape (2, 2) and a one-point state, got F of shape "
                f"{F.shape} and {state.n_points} points (state.take([i]) selects one)"
            )
        if self._without_friction:
            c = self._frictionless.contacts(F, self._frictionless_state(state))
            zero = np.zeros(c.force.shape[0])
            return ContactSet(c.pairs, c.shift, c.branch, c.overlap, c.force, zero, zero > 0, zero)
        eq = self.equilibrium(F, state, 0, False)[0]
        s = eq.state
        on = np.flatnonzero(s.on)
        sliding = self._history(eq, state, 0)[2]
        c = self.cell
        return ContactSet(
            pairs=np.stack([c.pi[on], c.pj[on]], axis=1).astype(np.int64),
            shift=np.asarray(c.shift)[on],
            branch=np.stack([s.lx[on], s.ly[on]], axis=1),
            overlap=s.e[on],
            force=self.normal_stiffness * s.e[on],
            tangential=-s.ft[on],
            sliding=sliding,
            rolling=s.mr[on].copy(),
        )

    def _frictionless_state(self, state):
        return RelaxedState(
            state.w, state.F, state.fluctuation, np.zeros(state.n_points, bool),
            np.zeros(state.n_points, np.uint64), state.sensitivity[:, :, :2],
        )  # fmt: skip

    def rotations(self, state: FrictionalRelaxedState) -> np.ndarray:
        """(n, N) the disks' rotations (rad, counter-clockwise positive)."""
        return np.array(state.theta)

    def positions(self, F: ArrayLike, state: FrictionalRelaxedState) -> np.ndarray:
        """(n, N, 2) relaxed centres in the current cell F [0, box) of ``state``'s points."""
        return self._frictionless.positions(F, self._frictionless_state(state))
