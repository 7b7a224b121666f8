"""The consistent tangent of the frictional relaxed RVE at an equilibrium, at fixed committed
history:

    A = K_FF - K_Fq K_qq^-1 K_qF,

K_FF = dP/dF at fixed (w, theta), K_Fq = dP/dq, K_qF = dr/dF and K_qq = dr/dq over the network
(the contacts between non-rattlers; a rattler's unknowns held, one disk's translation pinned),
the contacts' return map fixed (stick or slip). Where contacts slip, K_Fq differs from K_qF^T and
A is not symmetric. It is the exact derivative of the algorithmic P(F) wherever no contact
changes status.
"""

from __future__ import annotations

import numpy as np

from ..relaxed.cell import Cell
from ..relaxed.errors import RigidityLostError
from .cell_state import CellState, Springs
from .newton import factorise
from .system import mixed


def condensation(
    cell: Cell, springs: Springs, F, s: CellState, free_rotation: float = 1.0
) -> tuple:
    """``(A (2, 2, 2, 2), dq (N, 3, 4))``: the tangent and the sensitivities d(w, theta)/dF =
    -K_qq^-1 K_qF (zero for the held unknowns); RigidityLostError where K_qq is singular.
    ``free_rotation`` scales the diagonal of the rotations that no sticking contact holds
    (:func:`~dolfinx_granular.laws.relaxed_friction.cell_state.diagonal`; A does not depend
    on it)."""
    if s.keep.sum() < 2:
        raise RigidityLostError("no disk has 2 contacts or more (all are rattlers)")
    sp = springs
    KFF, KFq, KqF = mixed(
        F, s.qx, s.qy, s.lx, s.ly, s.d, s.e, s.ft, s.fstar, s.status, cell.pi, cell.pj,
        cell.R, cell.radii, sp.kn, sp.kt, sp.mu, sp.inv_area, cell.n_disks, s.network,
    )  # fmt: skip
    try:
        lu, held = factorise(cell, springs, F, s, True, free_rotation=free_rotation)
    except RuntimeError:
        raise RigidityLostError("the network's stiffness (one disk pinned) is singular") from None
    KqF[held] = 0.0
    X = lu.solve(KqF)
    if not np.isfinite(X).all():
        raise RigidityLostError("the network's stiffness (one disk pinned) is singular")
    A = (KFF - KFq @ X).reshape(2, 2, 2, 2)
    dq = -X.reshape(cell.n_disks, 3, 4)
    # a rotation no sticking contact holds is not set by F (its column of K_qq is zero, its
    # entry of X scales with the arbitrary diagonal): no predictor for it
    dq[~s.held_rotations(cell), 2] = 0.0
    return A, dq
