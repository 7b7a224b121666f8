"""The consistent tangent of the frictional relaxed RVE at an equilibrium, at fixed committed
history:

    A = K_FF - K_Fq K_qq^-1 K_qF,

K_FF = dP/dF at fixed (w, theta), K_Fq = dP/dq, K_qF = dr/dF and K_qq = dr/dq over the network
(the contacts between non-rattlers; a rattler's unknowns held, one disk's translation pinned),
the contacts' return map fixed (stick or slip). Where contacts slip, K_Fq differs from K_qF^T and
A is not symmetric. It is the exact derivative of the algorithmic P(F) wherever no contact
changes status; through a path of several substeps, :func:`path_condensation` adds the
history's dependence on F (:mod:`.path_tangent`).
"""

from __future__ import annotations

import numpy as np

from ..relaxed.cell import Cell
from ..relaxed.errors import RigidityLostError
from .cell_state import CellState, Increment, Springs
from .newton import factorise
from .path_tangent import Chain, force_derivatives, history_terms
from .system import mixed


def condensation(
    cell: Cell, springs: Springs, F, s: CellState, free_rotation: float = 1.0
) -> tuple:
    """``(A (2, 2, 2, 2), dq (N, 3, 4))``: the tangent and the sensitivities d(w, theta)/dF =
    -K_qq^-1 K_qF (zero for the held unknowns); RigidityLostError where K_qq is singular.
    ``free_rotation`` scales the diagonal of the rotations that no sticking contact holds
    (:func:`~dolfinx_granular.laws.relaxed_friction.cell_state.diagonal`; A does not depend
    on it)."""
    KFF, KFq, KqF, lu, held = _parts(cell, springs, F, s, free_rotation)
    X = _solve(lu, held, KqF)
    A = (KFF - KFq @ X).reshape(2, 2, 2, 2)
    return A, _predictor(cell, s, -X, ~s.held_rotations(cell))


def path_condensation(cell: Cell, springs: Springs, G, s: CellState, inc: Increment,
                      chain: Chain | None, DG, chained: bool = True) -> tuple:  # fmt: skip
    """The tangent through the path (:mod:`.path_tangent`) at the solution s of a substep to
    G (2, 2), dG/dF = DG (4, 4), from the committed side ``inc`` whose derivatives are
    ``chain`` (None: the path's start, whose history does not depend on F): ``(dP/dF (2, 2,
    2, 2), dq (N, 3, 4) at fixed history (the predictor's), the solution's :class:`Chain`
    (None unless ``chained``: a later substep starts from it))``."""
    KFF, KFq, KqF, lu, held = _parts(cell, springs, G, s, 1.0)
    sp, m, N = springs, s.m, cell.n_disks
    arrays = (s.qx, s.qy, s.lx, s.ly, s.d, s.e, s.ft, s.fstar, s.status)
    if chain is None:  # (no history terms: K_qq^-1 (K_qF DG) = (K_qq^-1 K_qF) DG)
        X = _solve(lu, held, KqF)
        X = np.hstack([X, X @ DG])
        Ph, dfh, dmh = 0.0, np.zeros((m, 4)), np.zeros((m, 4))
    else:
        Dft0, Dmr0 = chain.forces(cell.pi.shape[0])
        Rh, Ph, dfh, dmh = history_terms(
            G, *arrays, s.rstatus, cell.pi, cell.pj, cell.X, cell.Y, cell.R, cell.radii, inc.F0,
            inc.w0, sp.kn, sp.kt, sp.mu, sp.kr, sp.inv_area, s.network, chain.Dw, chain.Dth,
            Dft0, chain.DF0, Dmr0,
        )  # fmt: skip
        X = _solve(lu, held, np.hstack([KqF, KqF @ DG + Rh]))
    free = ~s.held_rotations(cell)
    total = -X[:, 4:].reshape(N, 3, 4)
    total[free, 2] = 0.0  # (as the predictor's: not set by F)
    A = (KFF @ DG + KFq @ total.reshape(3 * N, 4) + Ph).reshape(2, 2, 2, 2)
    dq = _predictor(cell, s, -X[:, :4], free)
    if not chained:
        return A, dq, None
    Dft, Dmr = np.zeros((cell.pi.shape[0], 4)), np.zeros((cell.pi.shape[0], 4))
    Dft[:m], Dmr[:m] = force_derivatives(
        G, *arrays, s.mr, s.rstatus, cell.pi, cell.pj, cell.R, cell.radii, sp.kn, sp.kt, sp.mu,
        sp.kr, sp.mu_r, s.network, total, DG, dfh, dmh,
    )  # fmt: skip
    return A, dq, Chain(total[:, :2], total[:, 2], Dft, DG, Dmr)


def _parts(cell, springs, F, s, free_rotation):
    """``(K_FF, K_Fq, K_qF, lu, held)`` over the network at s."""
    if s.apart:
        raise RigidityLostError("no disk has 2 contacts or more (all are rattlers)")
    sp = springs
    KFF, KFq, KqF = mixed(
        F, *s.contact_arrays(), cell.pi, cell.pj, cell.R, cell.radii, sp.kn, sp.kt, sp.mu,
        sp.kr, sp.mu_r, sp.inv_area, cell.n_disks, s.network,
    )  # fmt: skip
    try:
        lu, held = factorise(cell, springs, F, s, True, free_rotation=free_rotation)
    except RuntimeError:
        raise RigidityLostError("the network's stiffness (one disk pinned) is singular") from None
    return KFF, KFq, KqF, lu, held


def _solve(lu, held, B):
    """K_qq^-1 B (3N, k), the held rows of B zeroed."""
    B = np.array(B)
    B[held] = 0.0
    X = lu.solve(B)
    if not np.isfinite(X).all():
        raise RigidityLostError("the network's stiffness (one disk pinned) is singular")
    return X


def _predictor(cell, s, dq, free):
    """dq (3N, 4) as (N, 3, 4), the rotations ``free`` (N,) of disks no sticking contact holds
    zeroed: they are not set by F (their column of K_qq is zero, their entry scales with the
    arbitrary diagonal)."""
    dq = dq.reshape(cell.n_disks, 3, 4)
    dq[free, 2] = 0.0
    return dq
