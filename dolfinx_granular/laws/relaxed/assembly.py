"""The relaxed RVE's second derivatives: the stiffness d2W/dw2 and the mixed d2W/dw dF.

A contact c (notation of :mod:`~dolfinx_granular.laws.relaxed.contact_state`) has the Hessian
H_c = d2phi/dl2 = K [(R/d) n n^T - (e/d) I]; its stiffness blocks in the fluctuations are
+-F^T H_c F. The mixed derivative with respect to F (flattened row-major, ab -> 2a + b) of
dphi/dw_(j, k) is delta_bk g_a + (F^T H)_ka Q_b (minus for disk i). The stiffness is assembled
straight into the values of a block pattern (:mod:`~dolfinx_granular.laws.relaxed.block_ldlt`).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _contact_hessian(F, lx, ly, d, e, R, K, c, geometric):
    """The 2x2 stiffness F^T H_c F of contact c in the reference frame, and F^T H_c; without
    ``geometric``, H_c keeps only its positive part (R/d) n n^T (a Gauss-Newton block)."""
    nx = lx[c] / d[c]
    ny = ly[c] / d[c]
    b = K * e[c] / d[c] if geometric else 0.0
    a = K * R[c] / d[c] if geometric else K
    h00 = a * nx * nx - b
    h01 = a * nx * ny
    h11 = a * ny * ny - b
    # F^T H (2x2), then (F^T H) F
    t00 = F[0, 0] * h00 + F[1, 0] * h01
    t01 = F[0, 0] * h01 + F[1, 0] * h11
    t10 = F[0, 1] * h00 + F[1, 1] * h01
    t11 = F[0, 1] * h01 + F[1, 1] * h11
    k00 = t00 * F[0, 0] + t01 * F[1, 0]
    k01 = t00 * F[0, 1] + t01 * F[1, 1]
    k10 = t10 * F[0, 0] + t11 * F[1, 0]
    k11 = t10 * F[0, 1] + t11 * F[1, 1]
    return k00, k01, k10, k11, t00, t01, t10, t11


@njit(cache=True)
def assemble(F, pi, pj, lx, ly, d, e, R, K, use, exact, diag_slot, pair_slot, values):
    """The relaxed RVE's stiffness d2W/dw2 over the contacts ``use`` (m,) bool straight into
    ``values`` (n_values, 2, 2) of a pattern analysed on the candidates (pi, pj) (slots
    ``diag_slot``, ``pair_slot``), zeroed first: for each contact +F^T H_c F on the diagonal
    blocks of its disks and -F^T H_c F on their pair's block (the pinned disk's and a disk's
    pair with its own image skipped). Contacts not ``exact`` (m,) bool contribute their
    positive part only (:func:`_contact_hessian`). The off-diagonal block is symmetric, so a
    slot holding A[j, i] takes it as it is."""
    values[:] = 0.0
    for c in range(e.shape[0]):
        i = pi[c]
        j = pj[c]
        if not use[c] or i == j:
            continue
        k00, k01, k10, k11, _, _, _, _ = _contact_hessian(F, lx, ly, d, e, R, K, c, exact[c])
        for s in (diag_slot[i], diag_slot[j]):
            if s >= 0:
                values[s, 0, 0] += k00
                values[s, 0, 1] += k01
                values[s, 1, 0] += k10
                values[s, 1, 1] += k11
        s = pair_slot[c]
        if s >= 0:
            values[s, 0, 0] -= k00
            values[s, 0, 1] -= k01
            values[s, 1, 0] -= k10
            values[s, 1, 1] -= k11
    return values


@njit(cache=True)
def mixed(F, pi, pj, qx, qy, lx, ly, d, e, R, K, use, dof, n_unknowns):
    """d2W / dw dF over the contacts ``use``: (n_unknowns, 4), F flattened row-major."""
    B = np.zeros((n_unknowns, 4))
    for c in range(e.shape[0]):
        i = pi[c]
        j = pj[c]
        if not use[c] or i == j:
            continue
        _, _, _, _, t00, t01, t10, t11 = _contact_hessian(F, lx, ly, d, e, R, K, c, True)
        s = K * e[c] / d[c]
        g0 = -s * lx[c]
        g1 = -s * ly[c]
        q = (qx[c], qy[c])
        g = (g0, g1)
        T = ((t00, t01), (t10, t11))
        for p in range(2):
            disk = i if p == 0 else j
            if dof[disk] < 0:
                continue
            sign = -1.0 if p == 0 else 1.0
            for k in range(2):
                row = 2 * dof[disk] + k
                for a in range(2):
                    for b in range(2):
                        v = T[k][a] * q[b]
                        if b == k:
                            v += g[a]
                        B[row, 2 * a + b] += sign * v
    return B
