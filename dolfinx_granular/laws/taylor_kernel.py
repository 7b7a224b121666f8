"""Numba kernels of the Taylor RVE: candidate contacts and the per-point contact sums.

Notation (paper, sections 2-3): a candidate contact c is a pair of disks (i, j), j possibly a
periodic image, with reference branch vector L = X_j + shift - X_i and R = r_i + r_j. Under the
Taylor assumption its current branch vector is l = F L, with d = |l| and overlap eps = R - d; it is
active when eps >= 0.

Every output of the material is a contraction of two moment sums over the active contacts,

    S_bd   = sum_c (eps/d)      v_b v_d                 (3 distinct entries)
    T_efbd = sum_c (R/d^3)      v_e v_f v_b v_d         (5 distinct entries, fully symmetric)

with v = L (material, eqs. 10 and 12-13) or v = l (spatial, eqs. 11 and 14). With K = k_n / V:

    W = K/2 sum eps^2                       (eq. 7, each contact counted once)
    P = -K F S(L)                           (eq. 10)
    A_abcd = K [F_ae F_cf T_efbd(L) - delta_ac S_bd(L)]      (eqs. 12-13)
    sigma = -K/J S(l),  a_abcd = K/J [T_acbd(l) - delta_ac S_bd(l)]   (eqs. 11, 14)

The 4th-order term follows from
n_a n_c L_b L_d = l_a l_c L_b L_d / d^2 = F_ae F_cf L_e L_f L_b L_d / d^2.
Accumulating 8 scalars per contact instead of the 16 entries of A is what makes the kernel fast.

Contacts can only be active where |F L| <= R, and |F L| >= s_min(F) |L| with s_min the smallest
singular value of F. Candidates are therefore all pairs with rho = |L| / R <= 1 / min_stretch,
sorted by rho; a point with s_min(F) >= min_stretch visits only the prefix rho <= 1 / s_min(F).
They are found with a cell list (:mod:`~dolfinx_granular.packings.neighbours`, O(N)).
"""

from __future__ import annotations

import numpy as np
from numba import njit

# Status codes written per point by the batch kernels.
OK = 0
NOT_FINITE = 1
NOT_ORIENTATION_PRESERVING = 2
BELOW_MIN_STRETCH = 3

# Tolerance on the singular-value test: F built as exactly min_stretch * Q must pass despite
# rounding in the 2x2 singular-value formula.
_STRETCH_RTOL = 1e-12


@njit(cache=True, inline="always")
def check_F(F00, F01, F10, F11, min_stretch):
    """Status code of one F and, when valid, the number-independent bound 1 / s_min(F).

    The one rule of every kernel (stress, friction, validity): they accept the same F."""
    if not (np.isfinite(F00) and np.isfinite(F01) and np.isfinite(F10) and np.isfinite(F11)):
        return NOT_FINITE, 0.0
    J = F00 * F11 - F01 * F10
    # s_max^2 = (tr C + sqrt(tr C^2 - 4 J^2)) / 2 with C = F^T F; s_min = J / s_max is stable.
    trC = F00 * F00 + F01 * F01 + F10 * F10 + F11 * F11
    if not (np.isfinite(J) and np.isfinite(trC * trC)):
        return NOT_FINITE, 0.0  # entries so large that F^T F overflows
    if not J > 0.0:
        return NOT_ORIENTATION_PRESERVING, 0.0
    disc = max(trC * trC - 4.0 * J * J, 0.0)
    smax = np.sqrt(0.5 * (trC + np.sqrt(disc)))
    smin = J / smax
    if smin < min_stretch * (1.0 - _STRETCH_RTOL):
        return BELOW_MIN_STRETCH, 0.0
    return OK, 1.0 / smin


# Fast-math flags of every kernel that must find the same active set, without 'nnan'/'ninf'
# (inputs are validated finite, d > 0) and without 'contract', so that l = F L rounds exactly as
# in NumPy and the active set matches TaylorRVE.contacts(). error_model="numpy" drops the
# ZeroDivisionError check, which would otherwise stop LLVM from vectorising the loop.
FASTMATH = {"reassoc", "nsz", "arcp"}


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def moment_sums(F00, F01, F10, F11, X, Y, R, n_visit, tangent, acc):
    """Accumulate sum eps^2, S(L) (3) and, if ``tangent``, T(L) (5) into ``acc`` (9,) over the
    active contacts among the first ``n_visit`` candidates (X, Y, R of shape (M,))."""
    e2 = 0.0
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    t0 = 0.0
    t1 = 0.0
    t2 = 0.0
    t3 = 0.0
    t4 = 0.0
    for c in range(n_visit):
        x = X[c]
        y = Y[c]
        r = R[c]
        lx = F00 * x + F01 * y
        ly = F10 * x + F11 * y
        d = np.sqrt(lx * lx + ly * ly)
        eps = r - d
        # Heaviside with H(0) = 1, as selects (they vectorise); selecting eps itself rather than
        # multiplying by 0 keeps an overflowed d = inf from turning into 0 * inf = NaN.
        on = 1.0 if eps >= 0.0 else 0.0
        ee = eps if eps >= 0.0 else 0.0
        inv = on / d
        xx = x * x
        xy = x * y
        yy = y * y
        b = ee * inv
        e2 += ee * ee
        s0 += b * xx
        s1 += b * xy
        s2 += b * yy
        if tangent:
            g = r * inv * inv * inv
            t0 += g * xx * xx
            t1 += g * xx * xy
            t2 += g * xx * yy
            t3 += g * xy * yy
            t4 += g * yy * yy
    acc[0] = e2
    acc[1] = s0
    acc[2] = s1
    acc[3] = s2
    acc[4] = t0
    acc[5] = t1
    acc[6] = t2
    acc[7] = t3
    acc[8] = t4


@njit(cache=True)
def evaluate_batch(
    F, X, Y, R, rho, stiffness_per_area, min_stretch, spatial, tangent, W, P, A, status
):
    """Energy, stress and (optionally) tangent at n points.

    Args:
        F: (n, 2, 2) deformation gradients.
        X, Y, R, rho: (M,) candidate arrays from :func:`candidate_pairs` (L = (X, Y)).
        stiffness_per_area: k_n / V_rve.
        min_stretch: smallest supported singular value of F.
        spatial: False -> P (eq. 10) and A = dP/dF (eqs. 12-13);
            True -> Cauchy stress (eq. 11) and spatial tangent (eq. 14), pushed forward from the
            material sums (S(l) = F S(L) F^T, since l = F L with the same weights).
        tangent: compute A (else A is not touched and may have length 0).
        W: (n,) out, energy density per reference area (eq. 7).
        P: (n, 2, 2) out, stress.
        A: (n, 2, 2, 2, 2) out, tangent.
        status: (n,) int8 out, OK or the reason F was rejected (W, P, A then zero).
    """
    K = stiffness_per_area
    acc = np.empty(9)
    Am = np.empty((2, 2, 2, 2))
    for q in range(F.shape[0]):
        F00 = F[q, 0, 0]
        F01 = F[q, 0, 1]
        F10 = F[q, 1, 0]
        F11 = F[q, 1, 1]
        code, limit = check_F(F00, F01, F10, F11, min_stretch)
        status[q] = code
        if code != OK:
            W[q] = 0.0
            P[q, :, :] = 0.0
            if tangent:
                A[q, :, :, :, :] = 0.0
            continue
        n_visit = np.searchsorted(rho, limit, side="right")
        moment_sums(F00, F01, F10, F11, X, Y, R, n_visit, tangent, acc)
        S = acc[1:4]  # S[b + d] = S_bd
        T = acc[4:9]  # T[e + f + b + d] = T_efbd
        W[q] = 0.5 * K * acc[0]
        J = F00 * F11 - F01 * F10
        for a in range(2):
            for b in range(2):
                Pab = -K * (F[q, a, 0] * S[b] + F[q, a, 1] * S[1 + b])
                P[q, a, b] = Pab
        if spatial:  # sigma = P F^T / J
            for a in range(2):
                s0 = (P[q, a, 0] * F[q, 0, 0] + P[q, a, 1] * F[q, 0, 1]) / J
                s1 = (P[q, a, 0] * F[q, 1, 0] + P[q, a, 1] * F[q, 1, 1]) / J
                P[q, a, 0] = s0
                P[q, a, 1] = s1
        if not tangent:
            continue
        for a in range(2):
            for b in range(2):
                for c in range(2):
                    for d in range(2):
                        val = 0.0
                        for e in range(2):
                            for f in range(2):
                                val += F[q, a, e] * F[q, c, f] * T[e + f + b + d]
                        if a == c:
                            val -= S[b + d]
                        Am[a, b, c, d] = K * val
        if spatial:  # a_abcd = F_bB F_dD A_aBcD / J
            for a in range(2):
                for b in range(2):
                    for c in range(2):
                        for d in range(2):
                            val = 0.0
                            for B in range(2):
                                for D in range(2):
                                    val += F[q, b, B] * F[q, d, D] * Am[a, B, c, D]
                            A[q, a, b, c, d] = val / J
        else:
            A[q] = Am
