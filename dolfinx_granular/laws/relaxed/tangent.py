"""Stress and tangent of a relaxed equilibrium.

P = -K F S(Q) over the contacts (the Taylor stress at the relaxed branch vectors Q), and the
tangent of the relaxed response, condensed over the network's fluctuations,

    A = W_FF - W_Fw W_ww^-1 W_wF,

W_FF the Taylor (Born) tangent at Q, W_ww the network's stiffness (rattlers add nothing), one
disk pinned; its positive definiteness is the cell's rigidity.
"""

from __future__ import annotations

import numpy as np

from .. import taylor_kernel
from . import newton
from .cell import Cell
from .contact_state import ContactState
from .errors import RigidityLostError


def condensation(
    cell: Cell, F: np.ndarray, s: ContactState, counts: np.ndarray | None = None
) -> tuple:
    """``(A, dw)`` at an equilibrium s: the tangent A (2, 2, 2, 2) and the sensitivities
    dw/dF = -W_ww^-1 W_wF (N, 2, 4) of the fluctuations (F flattened row-major; zero for the
    rattlers and the pinned disk), both from one factorisation of the network's stiffness
    (added to ``counts`` (6,), :func:`~dolfinx_granular.laws.relaxed.newton.newton`'s, if
    given); :class:`RigidityLostError` where it is not positive definite."""
    A = _affine(cell, F, s)
    N = cell.n_disks
    if s.keep.sum() < 2:  # one non-rattler, pinned: nothing to condense
        return A, np.zeros((N, 2, 4))
    pat, fac = cell.kernel_pattern(
        int(np.argmax(s.keep)), newton.held(s.network, cell.pi, cell.pj, s.m)
    )
    pd, B, X = newton.network_tangent(
        F,
        s.m,
        s.qx,
        s.qy,
        s.lx,
        s.ly,
        s.d,
        s.e,
        s.keep,
        s.network,
        *cell.geometry(),
        *pat,
        *fac,
        np.zeros(6, np.int64) if counts is None else counts,
    )
    if not pd:
        raise RigidityLostError(
            "the non-rattlers' stiffness (one disk pinned) is not positive definite"
        )
    return A - (B.reshape(-1, 4).T @ X.reshape(-1, 4)).reshape(2, 2, 2, 2), -X


def _affine(cell, F, s):
    """Born part: the Taylor tangent (eqs. 12-13) over the network at the branch vectors Q."""
    acc = np.empty(9)
    use = s.network
    X, Y, R = s.qx[use].copy(), s.qy[use].copy(), cell.R[: s.m][use].copy()
    taylor_kernel.moment_sums(F[0, 0], F[0, 1], F[1, 0], F[1, 1], X, Y, R, X.shape[0], True, acc)
    return taylor_tangent(F, acc, cell.K)


def taylor_tangent(F: np.ndarray, acc: np.ndarray, K: float) -> np.ndarray:
    """A_abcd = K [F_ae F_cf T_efbd - delta_ac S_bd] (2, 2, 2, 2) from the Taylor kernel's
    moment sums ``acc`` (9,) (S in acc[1:4] by b + d, T in acc[4:9] by e + f + b + d)."""
    S, T = acc[1:4], acc[4:9]
    i = np.arange(2)
    T4 = T[
        i[:, None, None, None]
        + i[None, :, None, None]
        + i[None, None, :, None]
        + i[None, None, None, :]
    ]
    S2 = S[i[:, None] + i[None, :]]
    A = np.einsum("ae,cf,efbd->abcd", F, F, T4) - np.einsum("ac,bd->abcd", np.eye(2), S2)
    return K * A


def stress(cell: Cell, F: np.ndarray, s: ContactState) -> tuple[float, np.ndarray]:
    """(W, P (2, 2)) at the contact state s: W = K/2 sum e^2 and P = -K F S(Q) over every
    contact (e > 0)."""
    on = s.on
    b = s.e[on] / s.d[on]
    qx, qy = s.qx[on], s.qy[on]
    sxy = np.dot(b, qx * qy)
    S = np.array([[np.dot(b, qx * qx), sxy], [sxy, np.dot(b, qy * qy)]])
    return s.energy(cell, on), -cell.K * F @ S
