"""Stress and tangent of a relaxed equilibrium.

P = -K F S(Q) over the contacts (the Taylor stress at the relaxed branch vectors Q), and the
tangent of the relaxed response, condensed over the network's fluctuations,

    A = W_FF - W_Fw W_ww^-1 W_wF,

W_FF the Taylor (Born) tangent at Q, W_ww the network's stiffness (rattlers add nothing), one
disk pinned; its positive definiteness is the cell's rigidity. The kernels take the cell and
the block pattern as tuples (:mod:`~dolfinx_granular.laws.relaxed.newton`); the functions of a
:class:`ContactState` wrap them for Python.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..taylor_kernel import moment_sums
from .assembly import assemble, mixed
from .block_ldlt import substitute
from .cell import Cell
from .contact_state import ContactState
from .errors import RigidityLostError
from .newton import factorise_shifted, held


def condensation(
    cell: Cell, F: np.ndarray, s: ContactState, counts: np.ndarray | None = None
) -> tuple:
    """``(A, dw)`` at an equilibrium s: the tangent A (2, 2, 2, 2) and the sensitivities
    dw/dF = -W_ww^-1 W_wF (N, 2, 4) of the fluctuations (F flattened row-major; zero for the
    rattlers and the pinned disk), both from one factorisation of the network's stiffness
    (added to ``counts`` (6,), :func:`~dolfinx_granular.laws.relaxed.newton.newton`'s, if
    given); :class:`RigidityLostError` where it is not positive definite."""
    pat, fac = cell.kernel_pattern(*tangent_pattern(s.keep, s.network, cell.pi, cell.pj, s.m))
    ok, A, dw = condense_flat(
        F, s.m, s.qx, s.qy, s.lx, s.ly, s.d, s.e, s.keep, s.network, *cell.geometry(), *pat,
        *fac, np.zeros(6, np.int64) if counts is None else counts,
    )  # fmt: skip
    if not ok:
        raise RigidityLostError(
            "the non-rattlers' stiffness (one disk pinned) is not positive definite"
        )
    return A, dw


@njit(cache=True)
def tangent_pattern(keep, network, pi, pj, m):
    """(pinned disk, prefix) of the block pattern the condensation factorises on."""
    return np.argmax(keep), held(network, pi, pj, m)


@njit(cache=True)
def condense_flat(F, m, qx, qy, lx, ly, d, e, keep, network, pi, pj, X, Y, R, ratio, n_sorted,
                  n_all, inv_min_stretch, R_min, n_disks, K, pinned, cover, n, perm, Lp, Li, Rp,
                  Rc, Rq, Ap, Ai, diag_slot, pair_slot, values, Lx, D, Dinv, y,
                  counts):  # fmt: skip
    """:func:`condense` with its tuples flattened (as
    :func:`~dolfinx_granular.laws.relaxed.newton.newton`'s)."""
    return condense(
        F, m, qx, qy, lx, ly, d, e, keep, network,
        (pi, pj, X, Y, R, ratio, n_sorted, n_all, inv_min_stretch, R_min, n_disks, K),
        (pinned, cover, n, perm, Lp, Li, Rp, Rc, Rq, Ap, Ai, diag_slot, pair_slot),
        (values, Lx, D, Dinv, y), counts,
    )  # fmt: skip


@njit(cache=True)
def condense(F, m, qx, qy, lx, ly, d, e, keep, network, geo, pat, fac, counts):
    """``(positive definite, A (2, 2, 2, 2), dw (N, 2, 4))`` at an equilibrium (the arrays of
    its first m candidates): the network's exact stiffness (the rattlers' unknowns fixed, K on
    their diagonal; the pinned disk out) factorised on the pattern ``pat`` (which must hold
    :func:`tangent_pattern`), B = W_wF, A = W_FF - B^T W_ww^-1 B, dw = -W_ww^-1 B."""
    pi, pj, R, K, N = geo[0], geo[1], geo[4], geo[11], geo[10]
    A = born(F, m, qx, qy, R, network, K)
    dw = np.zeros((N, 2, 4))
    if keep.sum() < 2:  # one non-rattler, pinned: nothing to condense
        return True, A, dw
    assemble(F, pi[:m], pj[:m], lx, ly, d, e, R[:m], K, network, network, pat[11], pat[12], fac[0])
    total = np.zeros(N)
    for i in range(N):
        if not keep[i]:
            total[i] = K
    total[pat[0]] = K
    if not factorise_shifted(pat, fac, total, 0.0, N, counts):
        return False, A, dw
    B = mixed(F, pi[:m], pj[:m], qx, qy, lx, ly, d, e, R[:m], K, network, np.arange(N), 2 * N)
    B = B.reshape(N, 2, 4)
    substitute((0, 1), pat[2], pat[3], pat[4], pat[5], fac[1], fac[3], B, dw)
    for a in range(4):  # A -= B^T X
        for b in range(4):
            s = 0.0
            for i in range(N):
                s += B[i, 0, a] * dw[i, 0, b] + B[i, 1, a] * dw[i, 1, b]
            A[a // 2, a % 2, b // 2, b % 2] -= s
    return True, A, -dw


@njit(cache=True)
def born(F, m, qx, qy, R, network, K):
    """Born part W_FF (2, 2, 2, 2): the Taylor tangent (eqs. 12-13) over the network's
    contacts at their branch vectors Q, A_abcd = K [F_ae F_cf T_efbd - delta_ac S_bd] from the
    Taylor kernel's moment sums (S by b + d, T by e + f + b + d)."""
    k = network.sum()
    X, Y, Rn = np.empty(k), np.empty(k), np.empty(k)
    t = 0
    for c in range(m):
        if network[c]:
            X[t], Y[t], Rn[t] = qx[c], qy[c], R[c]
            t += 1
    acc = np.empty(9)
    moment_sums(F[0, 0], F[0, 1], F[1, 0], F[1, 1], X, Y, Rn, k, True, acc)
    A = np.empty((2, 2, 2, 2))
    for a in range(2):
        for b in range(2):
            for c in range(2):
                for dd in range(2):
                    s = 0.0
                    for e in range(2):
                        for f in range(2):
                            s += F[a, e] * F[c, f] * acc[4 + e + f + b + dd]
                    if a == c:
                        s -= acc[1 + b + dd]
                    A[a, b, c, dd] = K * s
    return A


@njit(cache=True)
def stress_at(F, e, d, qx, qy, K):
    """``(W, P (2, 2))`` over the contacts (e > 0) among the arrays' candidates: W = K/2 sum
    e^2 and P = -K F S(Q), S = sum (e / d) Q Q^T."""
    W = s00 = s01 = s11 = 0.0
    for c in range(e.shape[0]):
        if e[c] > 0.0:
            b = e[c] / d[c]
            W += e[c] * e[c]
            s00 += b * qx[c] * qx[c]
            s01 += b * qx[c] * qy[c]
            s11 += b * qy[c] * qy[c]
    P = np.empty((2, 2))
    for a in range(2):
        P[a, 0] = -K * (F[a, 0] * s00 + F[a, 1] * s01)
        P[a, 1] = -K * (F[a, 0] * s01 + F[a, 1] * s11)
    return 0.5 * K * W, P


def stress(cell: Cell, F: np.ndarray, s: ContactState) -> tuple[float, np.ndarray]:
    """(W, P (2, 2)) at the contact state s (:func:`stress_at`)."""
    return stress_at(F, s.e, s.d, s.qx, s.qy, cell.K)


def _affine(cell, F, s):
    """Born part at the contact state s (:func:`born`)."""
    return born(F, s.m, s.qx, s.qy, cell.R, s.network, cell.K)
