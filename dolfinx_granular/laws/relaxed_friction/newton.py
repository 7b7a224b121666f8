"""Newton on the frictional relaxed cell: the disks' fluctuations and rotations at which every
net force and moment vanishes, the contacts under the return map of one increment.

The Jacobian is the consistent one of the return map (non-symmetric where contacts slip),
factorised by SuperLU (:func:`scipy.sparse.linalg.splu`). In 2-D the Coulomb cone is a pair of
lines, so this is a semismooth Newton over the contacts' stick/slip statuses; its
globalisation:

* a backtracking line search on the squared residual (slip has no energy), each step moving no
  disk by more than :data:`MAX_STEP` of the smallest radius sum;
* where the line search fails, a Levenberg-Marquardt shift of the diagonal, a decade at a time;
* after ``freeze_after`` steps the statuses are frozen (no cycling); at the frozen equilibrium an
  active-set pass releases every contact whose status breaks the Coulomb law (a stick beyond
  the cone, a slip inside it), and Newton goes on, at most :data:`ACTIVE_SET_PASSES` times.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from ..relaxed.cell import SKIN, Cell
from ..relaxed.errors import RelaxationError, RigidityLostError
from .cell_state import RATTLER_REACH, CellState, Increment, Springs, diagonal
from .contact_law import FREE
from .settings import Settings

#: longest move of a disk in one step (its centre, or its surface by turning), relative to the
#: smallest radius sum
MAX_STEP = 0.1
#: active-set passes at the frozen equilibrium before the solver gives up
ACTIVE_SET_PASSES = 20
#: Levenberg-Marquardt shifts tried (decades from 1e-8 of the diagonal's scale)
LM_DECADES = 12


@dataclass
class Counts:
    """What a solve did: Newton steps, factorisations, LM-shifted factorisations, active-set
    passes and steps of the fallback."""

    steps: int = 0
    factorisations: int = 0
    shifted: int = 0
    passes: int = 0
    fire_steps: int = 0
    history: list = field(default_factory=list)


def factorise(cell: Cell, springs: Springs, F, s: CellState, tangent: bool, shift: float = 0.0,
              free_rotation: float = 1.0):  # fmt: skip
    """SuperLU of the Jacobian at s (sparse (3N, 3N) csc), the pinned disk's translation and
    (for the ``tangent``) the rattlers' unknowns held; ``shift`` adds to every diagonal entry.
    ``free_rotation`` scales the diagonal of the rotations no sticking contact holds. Returns
    ``(lu, pinned, held (3N,) bool)``; RuntimeError where it is singular."""
    N, m = cell.n_disks, s.m
    mode = s.newton_mode()
    if tangent:
        mode[~s.network] = 0
    _, _, (rows, cols, vals) = s.equations(cell, springs, F, mode, True)
    pinned = int(np.argmax(s.keep))
    reach = RATTLER_REACH * s.e[s.on].mean()
    diag = diagonal(
        s.status, s.network, s.keep, cell.pi[:m], cell.pj[:m], cell.radii, s.r, springs.kn,
        springs.kt, springs.inv_area, pinned, reach, 1e-8, tangent, free_rotation,
    )  # fmt: skip
    held = np.zeros(3 * N, bool)
    held[[3 * pinned, 3 * pinned + 1]] = True
    if tangent:
        out = np.flatnonzero(~s.keep)
        held[3 * out], held[3 * out + 1], held[3 * out + 2] = True, True, True
    use = ~(held[rows] | held[cols])
    scale = np.abs(vals[use & (rows == cols)]).mean() if use.any() else 1.0
    idx = np.arange(3 * N)
    J = sp.csc_matrix(
        (np.concatenate([vals[use], diag + shift * scale]),
         (np.concatenate([rows[use], idx]), np.concatenate([cols[use], idx]))),
        shape=(3 * N, 3 * N),
    )  # fmt: skip
    lu = splu(J, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.1)
    return lu, pinned, held


def _merit(s: CellState, held, mean_radius):
    """Half the squared residual, rotations' rows over the mean radius, the held unknowns out."""
    r = s.r.copy()
    r[:, 2] /= mean_radius
    r = r.ravel()
    r[held] = 0.0
    return 0.5 * float(r @ r)


def _limit(cell, F, dq):
    """The largest step length <= 1 along dq (N, 3) that moves no disk's centre (current
    frame) nor its surface by turning by more than MAX_STEP of the smallest radius sum."""
    move = np.sqrt(((dq[:, :2] @ F.T) ** 2).sum(axis=1)).max()
    turn = (np.abs(dq[:, 2]) * cell.radii).max()
    big = max(move, turn)
    return min(1.0, MAX_STEP * cell.R.min() / big) if big > 0.0 else 1.0


def solve(cell: Cell, springs: Springs, F, w, th, inc: Increment, settings: Settings,
          counts: Counts, stall: bool = True) -> tuple:  # fmt: skip
    """Newton from (w (N, 2), th (N,)) to the equilibrium of the increment: ``(w, th, state,
    residual)``; RelaxationError where it fails (the caller's fallback takes over)."""
    w, th = np.array(w, dtype=np.float64), np.array(th, dtype=np.float64)
    frozen = None
    mean_radius = float(cell.radii.mean())
    for step in range(settings.max_iterations + 1):
        s = CellState(cell, springs, F, w, th, inc, frozen)
        if s.count == 0:
            raise RigidityLostError("no two disks touch (the cell has come apart)")
        residual, floor = s.residual(cell)
        counts.history.append(residual)
        if residual <= max(settings.force_tol, floor):
            if frozen is None:
                return w, th, s, residual
            bad = s.inadmissible(springs)
            if not bad.any():
                return w, th, s, residual
            counts.passes += 1
            if counts.passes > ACTIVE_SET_PASSES:
                raise RelaxationError("the contacts' statuses did not settle")
            frozen = _padded(frozen, s.m)
            frozen[: s.m][bad] = FREE
        if step == settings.max_iterations:
            raise RelaxationError(
                f"no equilibrium after {step} Newton steps (largest net force or moment "
                f"{residual:.3g} of the mean contact force)"
            )
        if step >= settings.freeze_after and frozen is None:
            frozen = s.statuses()
        w, th = _step(cell, springs, F, w, th, inc, s, frozen, mean_radius, counts)
        counts.steps += 1
    raise AssertionError("unreachable")


def _padded(frozen, m):
    """``frozen`` (k,) int8 extended with free statuses to at least m."""
    if frozen.shape[0] >= m:
        return frozen
    return np.concatenate([frozen, np.full(m - frozen.shape[0], FREE, np.int8)])


def _step(cell, springs, F, w, th, inc, s, frozen, mean_radius, counts):
    """One Newton step with its line search (LM-shifted where that fails): the new (w, th)."""
    for decade in range(LM_DECADES + 1):
        shift = 0.0 if decade == 0 else 10.0 ** (decade - 9)
        try:
            lu, pinned, held = factorise(cell, springs, F, s, False, shift)
        except RuntimeError:  # exactly singular: shift it
            continue
        counts.factorisations += 1
        counts.shifted += decade > 0
        rhs = s.r.ravel().copy()
        rhs[held] = 0.0
        dq = -lu.solve(rhs).reshape(-1, 3)
        if not np.isfinite(dq).all():
            continue
        found = _line_search(cell, springs, F, w, th, inc, s, frozen, dq, held, mean_radius)
        if found is not None:
            return found
    raise RelaxationError("the line search found no smaller residual, even with a shift")


def _line_search(cell, springs, F, w, th, inc, s, frozen, dq, held, mean_radius):
    """Backtracking on the squared residual along dq: the new (w, th), or None."""
    phi0 = _merit(s, held, mean_radius)
    alpha = _limit(cell, F, dq)
    for _ in range(40):
        wt = w + alpha * dq[:, :2]
        tt = th + alpha * dq[:, 2]
        trial = CellState(cell, springs, F, wt, tt, inc, frozen)
        if _merit(trial, held, mean_radius) <= (1.0 - 2e-4 * alpha) * phi0:
            return wt, tt
        alpha *= 0.5
    return None


def grow(cell: Cell, F, w) -> None:
    """Bring the candidate list up to w (a Verlet skin that holds a line search's trials)."""
    cell.grow(F, w, max(SKIN, 4.0 * MAX_STEP) * cell.R.min())
