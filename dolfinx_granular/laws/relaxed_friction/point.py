"""One frictional relaxed point: an increment solved (Newton, its fallbacks), the stress and
tangent there, and the quasi-static path from the committed state to a new F in substeps.

The path is followed in substeps of the right stretch U = (F^T F)^(1/2) at most
``settings.substep`` apart, as the frictionless relaxed RVE's; each substep is one
backward-Euler increment of the contact law from the last one (its tangential forces
committed), so the substep length is part of the model. Every solve starts from the last
positions carried to the new F to first order (the sensitivities of the last tangent; the
rotations also turn with F's polar rotation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..relaxed.cell import Cell
from ..relaxed.errors import RelaxationError
from ..relaxed.path import stretches_between
from .cell_state import CellState, Increment, Springs
from .contact_law import STICK
from .fire import fire
from .newton import Counts, solve
from .settings import Settings
from .system import dissipation, energy
from .tangent import condensation


@dataclass
class Equilibrium:
    """A frictional relaxed point at F after its increment.

    Attributes:
        w: (N, 2) fluctuations; theta: (N,) rotations; W: stored energy (Pa); P: (2, 2);
        A: (2, 2, 2, 2) or None; sensitivity: (N, 3, 4) d(w, theta)/dF or zeros;
        state: the :class:`CellState` (contacts, forces, statuses); dissipated: the energy the
        increment dissipated (Pa); residual: the largest net force or moment over the mean
        contact force (and radius); counts: the solver's :class:`Counts`.
    """

    w: np.ndarray
    theta: np.ndarray
    W: float
    P: np.ndarray
    A: np.ndarray | None
    sensitivity: np.ndarray
    state: CellState
    dissipated: float
    residual: float
    counts: Counts


def polar_angle(F) -> float:
    """The angle of F's polar rotation, atan2(F21 - F12, F11 + F22)."""
    return float(np.arctan2(F[1, 0] - F[0, 1], F[0, 0] + F[1, 1]))


def predicted(w, th, dq, Fc, F):
    """(w, th) at Fc carried to F: the sensitivities dq (N, 3, 4) times the rotation-free
    increment dF_C = Fc^-T (C - C_c) / 2, and the rotations turned by F's polar rotation."""
    dF = 0.5 * np.linalg.solve(Fc.T, F.T @ F - Fc.T @ Fc)
    move = dq.reshape(-1, 4) @ dF.ravel()
    move = move.reshape(-1, 3)
    return w + move[:, :2], th + move[:, 2] + polar_angle(F) - polar_angle(Fc)


def relax(cell: Cell, springs: Springs, F, inc: Increment, dq, settings: Settings,
          tangent: bool) -> Equilibrium:  # fmt: skip
    """The equilibrium of the increment from ``inc`` to F (2, 2): Newton from the predicted
    start, then from the committed positions turned with F, then FIRE from there and Newton."""
    counts = Counts()
    starts = [predicted(inc.w0, inc.th0, dq, inc.F0, F)]
    if dq.any():
        starts.append(predicted(inc.w0, inc.th0, np.zeros_like(dq), inc.F0, F))
    for w, th in starts:
        try:
            w, th, s, residual = solve(cell, springs, F, w, th, inc, settings, counts)
            break
        except RelaxationError:
            continue
    else:
        w, th, steps = fire(cell, springs, F, *starts[-1], inc, settings)
        counts.fire_steps = steps
        w, th, s, residual = solve(cell, springs, F, w, th, inc, settings, counts)
    return finish(cell, springs, F, w, th, s, residual, counts, tangent)


def finish(cell, springs, F, w, th, s, residual, counts, tangent) -> Equilibrium:
    """The :class:`Equilibrium` at the solved state s."""
    A, dq = condensation(cell, springs, F, s) if tangent else (None, None)
    if dq is None:
        dq = np.zeros((cell.n_disks, 3, 4))
    sp = springs
    W = energy(s.e, s.ft, s.status, sp.kn, sp.kt, sp.inv_area)
    D = dissipation(s.ft, s.fstar, s.status, sp.kt, sp.inv_area)
    return Equilibrium(w, th, W, s.P, A, dq, s, D, residual, counts)


def at_rest(cell: Cell, springs: Springs, F, inc: Increment, tangent: bool) -> Equilibrium:
    """The committed state itself (F = F0): nothing moves, every contact's trial force is its
    committed one (a contact at the cone sticks there)."""
    s = CellState(cell, springs, F, inc.w0, inc.th0, inc, None)
    residual, _ = s.residual(cell)
    return finish(cell, springs, F, inc.w0, inc.th0, s, residual, Counts(), tangent)


def committed(cell: Cell, eq: Equilibrium, F) -> Increment:
    """The next substep's committed side: this equilibrium's positions and tangential forces
    (those of open contacts dropped)."""
    ft = np.zeros(cell.pi.shape[0])
    on = eq.state.on
    ft[: on.shape[0]][on] = eq.state.ft[on]
    return Increment(np.array(F, dtype=np.float64), eq.w, eq.theta, ft)


def follow(cell: Cell, springs: Springs, F, inc: Increment, dq, settings: Settings,
           tangent: bool) -> tuple[Equilibrium, float]:  # fmt: skip
    """The equilibrium at F reached from ``inc`` along the quasi-static path, and the energy
    dissipated on the way (Pa)."""
    dissipated = 0.0
    for Uk in stretches_between(inc.F0, F, settings.substep):
        eq = relax(cell, springs, Uk, inc, dq, settings, True)
        dissipated += eq.dissipated
        inc, dq = committed(cell, eq, Uk), eq.sensitivity
    eq = relax(cell, springs, F, inc, dq, settings, tangent)
    return eq, dissipated + eq.dissipated


def sticking(eq: Equilibrium) -> np.ndarray:
    """(m,) contacts that stick."""
    return eq.state.status == STICK
