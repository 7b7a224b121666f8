"""Newton on the frictional relaxed cell: the disks' fluctuations and rotations at which every
net force and moment vanishes, the contacts under the return map of one increment.

Each step takes the consistent Jacobian of the return map (non-symmetric where contacts slip),
factorised by the block LU (:mod:`.block_lu`; SuperLU where its block pivots fail, for the
tangent), and a backtracking line search on the squared residual (slip has no energy). In 2-D
the Coulomb cone is a pair of lines, so this is a semismooth Newton over the contacts'
stick/slip statuses: quadratic near the equilibrium, but a step that changes many statuses at
once can find no smaller residual, or the statuses can cycle. Newton then stops (no step lowers
the residual, or it fell by less than half over 4 steps) and the caller's fallbacks take over:
pseudo-transient continuation (:mod:`.pseudo_time`: damped implicit steps, ``solve(...,
pseudo=True)``), then FIRE (:mod:`~dolfinx_granular.laws.relaxed_friction.fire`) before Newton
takes up again. The loop itself is compiled (:mod:`.newton_kernel`, where its constants live).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse.linalg import splu

from ..relaxed.cell import Cell
from ..relaxed.errors import CameApart, RelaxationError
from ..tools import chunks
from . import newton_kernel, pseudo_time
from .block_lu import BlockLU
from .cell_state import CellState, Increment, Springs
from .settings import Settings

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
    factorisation), steps of the fallbacks (pseudo-transient continuation's among ``steps``
    too), rearrangements (:func:`~dolfinx_granular.laws.relaxed_friction.point.rearranged`);
    ``history`` the residual of every iterate; ``newton_seconds`` the wall time in the
    compiled loops."""

    steps: int = 0
    factorisations: int = 0
    chord_steps: int = 0
    pseudo_steps: int = 0
    fire_steps: int = 0
    rearrangements: int = 0
    history: list = field(default_factory=list)
    newton_seconds: float = 0.0


def factorise(cell: Cell, springs: Springs, F, s: CellState, tangent: bool,
              free_rotation: float = 1.0):  # fmt: skip
    """The Jacobian at s (3N, 3N) factorised (:func:`.newton_kernel.factorise`: Newton's, or
    the ``tangent``'s over the network), the pinned disk's translation and for the tangent the
    rattlers' unknowns held; ``free_rotation`` scales the diagonal of the rotations no sticking
    contact holds. Returns ``(lu, held (3N,) bool)``, lu with ``solve(b)``: the block LU
    (:mod:`.block_lu`; the cell's one for its pattern, valid until the next factorisation), or
    SuperLU of the same matrix where a block pivot is singular; RuntimeError where the Jacobian
    is."""
    used = np.flatnonzero(s.network if tangent else s.on)
    p, lu, cover = cell.block_pattern(
        -1, int(used[-1]) + 1 if used.size else 1, d=3, new_factor=BlockLU.on
    )
    code, held, _ = newton_kernel.factorise_entry(
        np.ascontiguousarray(F, dtype=np.float64), *chunks(s.arrays()),
        *chunks(newton_kernel.cell_arrays(cell)), newton_kernel.spring_arrays(springs),
        *chunks(newton_kernel.pattern_arrays(p, cover)), lu.arrays(), 0.0, tangent,
        float(free_rotation),
    )  # fmt: skip
    lu.ok = code == 0
    if lu.ok:
        return lu, held
    return splu(lu.to_csc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.1), held


def solve(cell: Cell, springs: Springs, F, w, th, inc: Increment, settings: Settings,
          counts: Counts, pseudo: bool = False) -> tuple:  # fmt: skip
    """Newton from (w (N, 2), th (N,)) to the equilibrium of the increment (or, ``pseudo``,
    pseudo-transient continuation: :mod:`.pseudo_time`): ``(w, th, state, residual)``;
    RelaxationError where it fails or stalls (the caller's fallback takes over). The steps are
    :func:`.newton_kernel.newton`'s (:func:`.pseudo_time.transient`'s)."""
    w, th = np.array(w, dtype=np.float64), np.array(th, dtype=np.float64)
    history = counts.history
    start, steps = len(history), counts.steps
    t0 = time.perf_counter()
    if pseudo:
        code, why, w, th = newton_kernel.run(
            cell, springs, F, w, th, inc, settings, counts, pseudo_time.transient_entry,
            settings.pseudo_steps, (np.array([pseudo_time.SIGMA_START]),),
        )  # fmt: skip
        counts.pseudo_steps += counts.steps - steps
    else:
        code, why, w, th = newton_kernel.run(cell, springs, F, w, th, inc, settings, counts)
    counts.newton_seconds += time.perf_counter() - t0
    if code == newton_kernel.RIGIDITY_LOST:
        raise CameApart("no two disks touch (the cell has come apart)", w, th)
    if code == newton_kernel.FAILED:
        last = history[-1] if len(history) > start else np.inf
        what = "pseudo-transient continuation: " if pseudo else ""
        raise RelaxationError(what + _FAILURES[why].format(len(history) - start - 1, last))
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
