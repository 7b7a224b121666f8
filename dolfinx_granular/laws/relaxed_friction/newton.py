"""Newton on the frictional relaxed cell: the disks' fluctuations and rotations at which every
net force and moment vanishes, the contacts under the return map of one increment.

Each step takes the consistent Jacobian of the return map (non-symmetric where contacts slip),
factorised by SuperLU (:func:`scipy.sparse.linalg.splu`), and a backtracking line search on the
squared residual (slip has no energy). In 2-D the Coulomb cone is a pair of lines, so this is a
semismooth Newton over the contacts' stick/slip statuses: quadratic near the equilibrium, but a
step that changes many statuses at once can find no smaller residual, or the statuses can
cycle. Newton then stops (no step lowers the residual, or it fell by less than
:data:`STALL_RATE` over :data:`STALL_STEPS` steps) and the caller's fallback relaxes the cell
(:mod:`~dolfinx_granular.laws.relaxed_friction.fire`) before Newton takes up again: that ends
the cycling.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from ..relaxed.cell import Cell
from ..relaxed.errors import RelaxationError, RigidityLostError
from .block_lu import BlockLU, assemble
from .cell_state import RATTLER_REACH, RATTLER_SHIFT, CellState, Increment, Springs, diagonal
from .contact_law import OPEN, SLIP, STICK
from .settings import Settings
from .system import EXACT, SKIPPED

#: longest move of a disk in one step (its centre, or its surface by turning), relative to the
#: smallest radius sum
MAX_STEP = 0.1
#: a contact whose trial force is within this part of its cap of the cone's edge can take
#: either side's Jacobian (:func:`_step`)
EDGE = 0.05
#: Newton counts as stalled where its residual fell by less than STALL_RATE over the last
#: STALL_STEPS steps
STALL_STEPS, STALL_RATE = 4, 0.5
#: a step that cut the residual to below this part takes the next on the same factorisation
#: (a chord step) while no contact has changed its status since it
CHORD_RATE = 0.1


@dataclass
class Counts:
    """What a solve did: Newton steps, factorisations, chord steps (on an earlier
    factorisation), steps of the fallback; ``history`` the residual of every iterate."""

    steps: int = 0
    factorisations: int = 0
    chord_steps: int = 0
    fire_steps: int = 0
    history: list = field(default_factory=list)


def factorise(cell: Cell, springs: Springs, F, s: CellState, tangent: bool,
              free_rotation: float = 1.0):  # fmt: skip
    """The Jacobian at s (3N, 3N) factorised, the pinned disk's translation and (for the
    ``tangent``) the rattlers' unknowns held (``diagonal``); ``free_rotation`` scales the
    diagonal of the rotations no sticking contact holds. Returns ``(lu, held (3N,) bool)``, lu
    with ``solve(b)``: the block LU (:mod:`.block_lu`; the cell's one for its pattern, valid
    until the next factorisation), or SuperLU where a block pivot of the block LU is singular;
    RuntimeError where the Jacobian is."""
    N, m = cell.n_disks, s.m
    mode = np.full(m, EXACT, np.int8)
    if tangent:
        mode[~s.network] = SKIPPED
    _, _, (rows, cols, vals) = s.equations(cell, springs, F, mode, True)
    pinned = int(np.argmax(s.keep))
    reach = RATTLER_REACH * s.e[s.on].mean()
    diag = diagonal(
        s.status, s.network, s.keep, cell.pi[:m], cell.pj[:m], cell.radii, s.r, springs.kn,
        springs.kt, springs.inv_area, pinned, reach, RATTLER_SHIFT, tangent, free_rotation,
    )  # fmt: skip
    held = np.zeros(3 * N, bool)
    held[[3 * pinned, 3 * pinned + 1]] = True
    if tangent:
        out = np.flatnonzero(~s.keep)
        held[3 * out], held[3 * out + 1], held[3 * out + 2] = True, True, True
    contacts = np.flatnonzero((s.status != OPEN) & (mode == EXACT))
    # (the pattern's one BlockLU: each factorisation overwrites the last one's)
    p, lu, _ = cell.block_pattern(
        -1, int(contacts[-1]) + 1 if contacts.size else 1, d=3, new_factor=BlockLU.on
    )
    assemble(p.n, p.diag_slot, p.pair_slot, p.pair_flip, cell.pi, cell.pj, contacts,
             vals.reshape(-1, 6, 6), held, diag, lu.values)  # fmt: skip
    if lu.factorise():
        return lu, held
    use = ~(held[rows] | held[cols])
    idx = np.arange(3 * N)
    J = sp.csc_matrix(
        (np.concatenate([vals[use], diag]),
         (np.concatenate([rows[use], idx]), np.concatenate([cols[use], idx]))),
        shape=(3 * N, 3 * N),
    )  # fmt: skip
    return splu(J, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.1), held


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
          counts: Counts) -> tuple:  # fmt: skip
    """Newton from (w (N, 2), th (N,)) to the equilibrium of the increment: ``(w, th, state,
    residual)``; RelaxationError where it fails or stalls (the caller's fallback takes over)."""
    w, th = np.array(w, dtype=np.float64), np.array(th, dtype=np.float64)
    history = counts.history
    start = len(history)
    s = CellState(cell, springs, F, w, th, inc)
    chord = None
    for step in range(settings.max_iterations + 1):
        if s.count == 0:
            raise RigidityLostError("no two disks touch (the cell has come apart)")
        residual, floor = s.residual(cell)
        history.append(residual)
        if residual <= max(settings.force_tol, floor):
            return w, th, s, residual
        k = len(history) - 1 - STALL_STEPS
        if step == settings.max_iterations or (k >= start and residual > STALL_RATE * history[k]):
            raise RelaxationError(
                f"Newton stalled after {step} steps (largest net force or moment "
                f"{residual:.3g} of the mean contact force)"
            )
        found = None
        if chord is not None and np.array_equal(chord[2], s.status):
            found = _line_search(cell, springs, F, w, th, inc, s, _direction(chord, s), chord[1])
            counts.chord_steps += found is not None
        if found is None:
            found, chord = _step(cell, springs, F, w, th, inc, s, counts)
        if found is None:
            raise RelaxationError("the line search found no smaller residual")
        w, th, trial = found
        if trial.residual(cell)[0] > CHORD_RATE * residual:
            chord = None  # (a chord step would converge slowly: factorise at the next)
        s = trial
        counts.steps += 1
    raise AssertionError("unreachable")


def _direction(factorised, s):
    """The Newton direction (N, 3) of the residual at s on a factorisation ``(lu, held,
    statuses)``."""
    lu, held, _ = factorised
    rhs = s.r.ravel().copy()
    rhs[held] = 0.0
    return -lu.solve(rhs).reshape(-1, 3)


def _step(cell, springs, F, w, th, inc, s, counts):
    """A step on the consistent Jacobian with a backtracking line search on the squared
    residual: ``((w, th, state), (lu, held, statuses))`` the new unknowns and state and the
    factorisation, or ``(None, None)`` where no step lowers the residual. Where none does, the
    contacts near the cone's edge (:data:`EDGE`) take the other side's Jacobian (the
    generalised Jacobian of the return map has both there) and the step is tried again."""
    for edge in (0.0, EDGE):
        status = s.status
        if edge:
            near = s.near_edge(springs, edge)
            if not near.any():
                return None, None
            s.status = np.where(near, np.where(status == STICK, SLIP, STICK), status)
        jacobian_status = s.status
        try:
            lu, held = factorise(cell, springs, F, s, False)
        except RuntimeError:
            continue
        finally:
            s.status = status
        counts.factorisations += 1
        factorised = (lu, held, jacobian_status)
        found = _line_search(cell, springs, F, w, th, inc, s, _direction(factorised, s), held)
        if found is not None:
            return found, factorised
    return None, None


def _line_search(cell, springs, F, w, th, inc, s, dq, held):
    """Backtracking on the squared residual along dq: the new ``(w, th, state)``, or None."""
    if not np.isfinite(dq).all():
        return None
    mean_radius = float(cell.radii.mean())
    phi0 = _merit(s, held, mean_radius)
    alpha = _limit(cell, F, dq)
    for _ in range(30):
        wt, tt = w + alpha * dq[:, :2], th + alpha * dq[:, 2]
        trial = CellState(cell, springs, F, wt, tt, inc)
        if _merit(trial, held, mean_radius) <= (1.0 - 2e-4 * alpha) * phi0:
            return wt, tt, trial
        alpha *= 0.5
    return None
