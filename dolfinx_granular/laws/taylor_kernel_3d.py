"""Numba kernel of the Taylor RVE in 3-D: spheres in a periodic box under a macroscopic F (3, 3).

The formulas are the 2-D kernel's (:mod:`~dolfinx_granular.laws.taylor_kernel`) with every index
running over 3: a candidate contact c has reference branch vector L and radius sum R, current
branch vector l = F L, d = |l| and overlap eps = R - d (active when eps >= 0), and every output
is a contraction of the moment sums over the active contacts

    S_bd   = sum_c (eps/d)  L_b L_d              (6 distinct entries)
    T_efbd = sum_c (R/d^3)  L_e L_f L_b L_d      (15 distinct entries, fully symmetric)

with K = k_n / V (k_n in N/m, V the box volume):

    W = K/2 sum eps^2,   P = -K F S,   A_abcd = K [F_ae F_cf T_efbd - delta_ac S_bd].

Candidates are pruned as in 2-D: a point visits the prefix rho = |L| / R <= 1 / s_min(F), with
s_min(F) from the eigenvalues of C = F^T F. The branch vectors are computed without fast-math
(:func:`branch`), so that the active set is the one of
:meth:`~dolfinx_granular.ContactCandidates.overlaps` to the last bit.
"""

from __future__ import annotations

from itertools import combinations_with_replacement

import numpy as np
from numba import njit

from .taylor_kernel import (
    BELOW_MIN_STRETCH,
    FASTMATH,
    NOT_FINITE,
    NOT_ORIENTATION_PRESERVING,
    OK,
)

_STRETCH_RTOL = 1e-12  # as in 2-D: F = min_stretch * Q passes despite rounding
_PRUNE_MARGIN = 1e-12  # the eigenvalue formula's rounding must not prune an active contact


def _symmetric_index(order):
    """Table (3,) * order -> position of the index tuple's sorted form among the sorted tuples
    (the distinct entries of a fully symmetric tensor of that order)."""
    tuples = list(combinations_with_replacement(range(3), order))
    table = np.empty((3,) * order, np.int64)
    for idx in np.ndindex(*table.shape):
        table[idx] = tuples.index(tuple(sorted(idx)))
    return table


#: S_bd = S[SYM2[b, d]] (6 entries), T_efbd = T[SYM4[e, f, b, d]] (15 entries)
SYM2 = _symmetric_index(2)
SYM4 = _symmetric_index(4)


@njit(cache=True)
def stretch_bound(F, min_stretch):
    """Status code of one F (3, 3) and, when valid, 1 / s_min(F) (a hair above it): the
    kernels' rule for F, as :func:`taylor_kernel.check_F` in 2-D."""
    for a in range(3):
        for b in range(3):
            if not np.isfinite(F[a, b]):
                return NOT_FINITE, 0.0
    J = det(F)
    # C = F^T F (scalars: no allocation per point)
    c00, c01, c02 = _ctc(F, 0, 0), _ctc(F, 0, 1), _ctc(F, 0, 2)
    c11, c12, c22 = _ctc(F, 1, 1), _ctc(F, 1, 2), _ctc(F, 2, 2)
    finite = np.isfinite(c00) and np.isfinite(c01) and np.isfinite(c02) and np.isfinite(c11)
    if not (np.isfinite(J) and finite and np.isfinite(c12) and np.isfinite(c22)):
        return NOT_FINITE, 0.0  # entries so large that F^T F overflows
    if not J > 0.0:
        return NOT_ORIENTATION_PRESERVING, 0.0
    lam1, lam3 = _extreme_eigenvalues(c00, c01, c02, c11, c12, c22)
    lam2 = max(c00 + c11 + c22 - lam1 - lam3, lam3)
    # lam3 = J^2 / (lam1 lam2) is accurate where lam3 itself (a difference) is not
    smin = J / np.sqrt(lam1 * lam2) if lam2 > 0.0 else 0.0
    if smin < min_stretch * (1.0 - _STRETCH_RTOL):
        return BELOW_MIN_STRETCH, 0.0
    return OK, (1.0 + _PRUNE_MARGIN) / smin


@njit(cache=True, inline="always")
def _ctc(F, a, b):
    """(F^T F)_ab of F (3, 3)."""
    return F[0, a] * F[0, b] + F[1, a] * F[1, b] + F[2, a] * F[2, b]


@njit(cache=True)
def det(M):
    """Determinant of a (3, 3) matrix (cofactors of the first row)."""
    return (
        M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1])
        - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
        + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0])
    )


@njit(cache=True)
def _extreme_eigenvalues(c00, c01, c02, c11, c12, c22):
    """Largest and smallest eigenvalue of the symmetric matrix C (3, 3) with those entries (the
    trigonometric formula)."""
    q = (c00 + c11 + c22) / 3.0
    a, b, c = c00 - q, c11 - q, c22 - q  # the deviator C - q I
    p2 = a * a + b * b + c * c + 2.0 * (c01 * c01 + c02 * c02 + c12 * c12)
    if p2 <= 0.0:
        return q, q
    p = np.sqrt(p2 / 6.0)
    detB = a * (b * c - c12 * c12) - c01 * (c01 * c - c12 * c02) + c02 * (c01 * c12 - b * c02)
    r = 0.5 * detB / (p * p * p)
    phi = np.arccos(min(max(r, -1.0), 1.0)) / 3.0
    return q + 2.0 * p * np.cos(phi), q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)


@njit(cache=True, error_model="numpy")
def branch(F, x, y, z):
    """Current branch vector l = F L and its length, rounded as NumPy rounds ``F @ L`` summed
    left to right (no fast-math: the active set must not depend on the compiler)."""
    lx = F[0, 0] * x + F[0, 1] * y + F[0, 2] * z
    ly = F[1, 0] * x + F[1, 1] * y + F[1, 2] * z
    lz = F[2, 0] * x + F[2, 1] * y + F[2, 2] * z
    return np.sqrt(lx * lx + ly * ly + lz * lz)


@njit(cache=True, fastmath=FASTMATH | {"contract"}, error_model="numpy")
def stress_sums(F, X, Y, Z, R, n_visit, G, acc):
    """Accumulate sum eps^2 (acc[0]) and S (acc[1:7]) over the active contacts among the first
    ``n_visit`` candidates (X, Y, Z, R of shape (M,)), and write each one's weight of T,
    g = R / d^3 (0 where inactive), into G (M,)."""
    e2 = s0 = s1 = s2 = s3 = s4 = s5 = 0.0
    for c in range(n_visit):
        x = X[c]
        y = Y[c]
        z = Z[c]
        r = R[c]
        d = branch(F, x, y, z)
        eps = r - d
        on = 1.0 if eps >= 0.0 else 0.0  # selects vectorise; see taylor_kernel.moment_sums
        ee = eps if eps >= 0.0 else 0.0
        inv = on / d
        b = ee * inv
        G[c] = r * inv * inv * inv
        e2 += ee * ee
        s0 += b * x * x
        s1 += b * x * y
        s2 += b * x * z
        s3 += b * y * y
        s4 += b * y * z
        s5 += b * z * z
    acc[0] = e2
    acc[1], acc[2], acc[3], acc[4], acc[5], acc[6] = s0, s1, s2, s3, s4, s5


@njit(cache=True, fastmath=FASTMATH | {"contract"}, error_model="numpy")
def tangent_sums(X, Y, Z, G, n_visit, acc):
    """Accumulate T (acc[7:22]) = sum g L L L L over the first ``n_visit`` candidates with the
    weights G of :func:`stress_sums`: the 15 monomials of degree 4 in the order of SYM4.

    A loop of its own: without square roots and divisions, and with 15 accumulators instead of
    22, it vectorises without spilling registers (1.5x faster P + A)."""
    t0 = t1 = t2 = t3 = t4 = t5 = t6 = t7 = t8 = t9 = t10 = t11 = t12 = t13 = t14 = 0.0
    for c in range(n_visit):
        x = X[c]
        y = Y[c]
        z = Z[c]
        g = G[c]
        xx = x * x
        xy = x * y
        xz = x * z
        yy = y * y
        yz = y * z
        zz = z * z
        gxx = g * xx
        gxy = g * xy
        gxz = g * xz
        gyy = g * yy
        gyz = g * yz
        gzz = g * zz
        t0 += gxx * xx
        t1 += gxx * xy
        t2 += gxx * xz
        t3 += gxx * yy
        t4 += gxx * yz
        t5 += gxx * zz
        t6 += gxy * yy
        t7 += gxy * yz
        t8 += gxy * zz
        t9 += gxz * zz
        t10 += gyy * yy
        t11 += gyy * yz
        t12 += gyy * zz
        t13 += gyz * zz
        t14 += gzz * zz
    acc[7], acc[8], acc[9], acc[10], acc[11] = t0, t1, t2, t3, t4
    acc[12], acc[13], acc[14], acc[15], acc[16] = t5, t6, t7, t8, t9
    acc[17], acc[18], acc[19], acc[20], acc[21] = t10, t11, t12, t13, t14


@njit(cache=True)
def piola(F, S, K, P):
    """P (3, 3) = -K F S from the moment sum S (6,)."""
    for a in range(3):
        for b in range(3):
            val = 0.0
            for e in range(3):
                val += F[a, e] * S[SYM2[e, b]]
            P[a, b] = -K * val


@njit(cache=True)
def tangent_of(F, S, T, K, A, G):
    """A (3, 3, 3, 3) = K [F_ae F_cf T_efbd - delta_ac S_bd] from the moment sums S (6,) and
    T (15,); G (3, 3, 3, 3) is scratch."""
    # G_afbd = F_ae T_efbd
    for a in range(3):
        for f in range(3):
            for b in range(3):
                for d in range(3):
                    val = 0.0
                    for e in range(3):
                        val += F[a, e] * T[SYM4[e, f, b, d]]
                    G[a, f, b, d] = val
    for a in range(3):
        for b in range(3):
            for c in range(3):
                for d in range(3):
                    val = 0.0
                    for f in range(3):
                        val += F[c, f] * G[a, f, b, d]
                    if a == c:
                        val -= S[SYM2[b, d]]
                    A[a, b, c, d] = K * val


@njit(cache=True)
def cauchy_in_place(F, P):
    """P (3, 3) -> sigma = P F^T / J (eq. 11)."""
    J = det(F)
    sigma = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            sigma[a, b] = (P[a, 0] * F[b, 0] + P[a, 1] * F[b, 1] + P[a, 2] * F[b, 2]) / J
    P[:, :] = sigma


@njit(cache=True)
def spatial_in_place(F, A, H):
    """A (3, 3, 3, 3) -> a_abcd = F_bB F_dD A_aBcD / J (eq. 14); H (3, 3, 3, 3) is scratch."""
    J = det(F)
    # H_abcD = F_bB A_aBcD
    for a in range(3):
        for b in range(3):
            for c in range(3):
                for D in range(3):
                    val = 0.0
                    for B in range(3):
                        val += F[b, B] * A[a, B, c, D]
                    H[a, b, c, D] = val
    for a in range(3):
        for b in range(3):
            for c in range(3):
                for d in range(3):
                    val = 0.0
                    for D in range(3):
                        val += F[d, D] * H[a, b, c, D]
                    A[a, b, c, d] = val / J


@njit(cache=True)
def evaluate_batch(F, X, Y, Z, R, rho, K, min_stretch, spatial, tangent, W, P, A, status):
    """Energy, stress and (optionally) tangent at n points, as the 2-D
    :func:`taylor_kernel.evaluate_batch`.

    Args:
        F: (n, 3, 3) deformation gradients.
        X, Y, Z, R, rho: (M,) candidate arrays (L = (X, Y, Z)), sorted by rho.
        K: k_n / V (N/m / m³).
        min_stretch: smallest supported singular value of F.
        spatial: False -> P and A = dP/dF; True -> Cauchy stress and spatial tangent.
        tangent: compute A (else A is not touched and may have length 0).
        W: (n,) out, energy per reference volume (Pa). P: (n, 3, 3) out (Pa).
        A: (n, 3, 3, 3, 3) out (Pa). status: (n,) int8 out, OK or why F was rejected (W, P,
        A then zero).
    """
    acc = np.empty(22)
    G = np.empty(X.shape[0])
    scratch = np.empty((3, 3, 3, 3))
    for q in range(F.shape[0]):
        code, limit = stretch_bound(F[q], min_stretch)
        status[q] = code
        if code != OK:
            W[q] = 0.0
            P[q] = 0.0
            if tangent:
                A[q] = 0.0
            continue
        n_visit = np.searchsorted(rho, limit, side="right")
        stress_sums(F[q], X, Y, Z, R, n_visit, G, acc)
        W[q] = 0.5 * K * acc[0]
        if tangent:  # before P turns into sigma: A is dP/dF at the material sums
            tangent_sums(X, Y, Z, G, n_visit, acc)
            tangent_of(F[q], acc[1:7], acc[7:22], K, A[q], scratch)
            if spatial:
                spatial_in_place(F[q], A[q], scratch)
        piola(F[q], acc[1:7], K, P[q])
        if spatial:
            cauchy_in_place(F[q], P[q])
