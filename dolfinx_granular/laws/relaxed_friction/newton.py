"""Newton on the frictional relaxed cell: the disks' fluctuations and rotations at which every
net force and moment vanishes, the contacts under the return map of one increment.

Each step takes the consistent Jacobian of the return map (non-symmetric where contacts slip),
factorised by the block LU (:mod:`.block_lu`; SuperLU where its block pivots fail, for the
tangent), and a backtracking line search on the squared residual (slip has no energy). In 2-D
the Coulomb cone is a pair of lines, so this is a semismooth Newton over the contacts'
stick/slip statuses: quadratic near the equilibrium, but a step that changes many statuses at
once can find no smaller residual, or the statuses can cycle. Newton then stops (no step lowers
the residual, or it fell by less than half over 4 steps) and the caller's fallback relaxes the
cell (:mod:`~dolfinx_granular.laws.relaxed_friction.fire`) before Newton takes up again: that
ends the cycling. The loop itself is compiled (:mod:`.newton_kernel`, where its constants live).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from ..relaxed.cell import Cell
from ..relaxed.errors import RelaxationError, RigidityLostError
from . import newton_kernel
from .block_lu import BlockLU, assemble
from .cell_state import RATTLER_REACH, RATTLER_SHIFT, CellState, Increment, Springs, diagonal
from .contact_law import OPEN
from .settings import Settings
from .system import EXACT, SKIPPED

#: the cell state's residual at the compiled loop's equilibrium is at most CHECK times the
#: tolerance (a safety net: both compute the same balance)
CHECK = 10.0
#: why Newton failed (:data:`newton_kernel.STALLED`, ``NO_DESCENT``), with its steps and residual
_FAILURES = {
    newton_kernel.STALLED: "Newton stalled after {} steps (largest net force or moment {:.3g} "
    "of the mean contact force)",
    newton_kernel.NO_DESCENT: "the line search found no smaller residual (after {} steps, "
    "largest net force or moment {:.3g} of the mean contact force)",
}


@dataclass
class Counts:
    """What a solve did: Newton steps, factorisations, chord steps (on an earlier
    factorisation), steps of the fallback; ``history`` the residual of every iterate;
    ``newton_seconds`` the wall time in Newton's loop."""

    steps: int = 0
    factorisations: int = 0
    chord_steps: int = 0
    fire_steps: int = 0
    history: list = field(default_factory=list)
    newton_seconds: float = 0.0


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


def solve(cell: Cell, springs: Springs, F, w, th, inc: Increment, settings: Settings,
          counts: Counts) -> tuple:  # fmt: skip
    """Newton from (w (N, 2), th (N,)) to the equilibrium of the increment: ``(w, th, state,
    residual)``; RelaxationError where it fails or stalls (the caller's fallback takes over).
    The steps are :func:`.newton_kernel.newton`'s."""
    w, th = np.array(w, dtype=np.float64), np.array(th, dtype=np.float64)
    history = counts.history
    start = len(history)
    t0 = time.perf_counter()
    code, why, w, th = newton_kernel.run(cell, springs, F, w, th, inc, settings, counts)
    counts.newton_seconds += time.perf_counter() - t0
    if code == newton_kernel.RIGIDITY_LOST:
        raise RigidityLostError("no two disks touch (the cell has come apart)")
    if code == newton_kernel.FAILED:
        last = history[-1] if len(history) > start else np.inf
        raise RelaxationError(_FAILURES[why].format(len(history) - start - 1, last))
    if code == newton_kernel.CONVERGED:
        s = CellState(cell, springs, F, w, th, inc)
        residual, floor = s.residual(cell)
        if residual > CHECK * max(settings.force_tol, floor):  # (the two sum in other orders)
            raise RelaxationError(
                f"the compiled Newton loop's equilibrium does not hold in the cell state "
                f"(largest net force or moment {residual:.3g} of the mean contact force)"
            )
        return w, th, s, residual
    raise AssertionError(f"unknown outcome {code} of the compiled Newton loop")
