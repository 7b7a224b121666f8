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
They are found with a cell list (:func:`find_pairs`, O(N); the packing generator uses it too).
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


@njit(cache=True)
def _append_pair(m, pi, pj, ps, i, j, sx, sy):
    """Store pair number m (i, j, shift (sx, sy)), doubling the buffers when full; returns them."""
    if m == pi.shape[0]:
        pi2 = np.empty(2 * m, np.int32)
        pj2 = np.empty(2 * m, np.int32)
        ps2 = np.empty((2 * m, 2), np.int32)
        pi2[:m] = pi
        pj2[:m] = pj
        ps2[:m] = ps
        pi, pj, ps = pi2, pj2, ps2
    pi[m] = i
    pj[m] = j
    ps[m, 0] = sx
    ps[m, 1] = sy
    return pi, pj, ps


@njit(cache=True)
def cell_list(x, box, cut):
    """Sort the centres x (N, 2), inside [0, box), into a grid of cells at least ``cut`` wide
    (a single cell per side where the box is narrower).

    Returns:
        ``(ncx, ncy, start, order)``: grid size; the disks of cell c = cx * ncy + cy are
        ``order[start[c]:start[c + 1]]``, by descending index.
    """
    n = x.shape[0]
    ncx = max(int(box[0] / cut), 1)
    ncy = max(int(box[1] / cut), 1)
    cell = np.empty(n, np.int64)
    start = np.zeros(ncx * ncy + 1, np.int64)
    for i in range(n):
        cx = min(max(int(x[i, 0] / box[0] * ncx), 0), ncx - 1)
        cy = min(max(int(x[i, 1] / box[1] * ncy), 0), ncy - 1)
        cell[i] = cx * ncy + cy
        start[cell[i] + 1] += 1
    for c in range(ncx * ncy):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n - 1, -1, -1):
        order[fill[cell[i]]] = i
        fill[cell[i]] += 1
    return ncx, ncy, start, order


@njit(cache=True)
def find_pairs(x, r, box, ratio, skin, with_self):
    """All pairs (i, j, image shift s) with |x_j + s * box - x_i| < ratio (r_i + r_j) + skin.

    A cell list: O(N) for cells wider than a few diameters, and exact for any cell (narrow cells
    scan more neighbour cells, so every periodic image within reach is found once).

    Args:
        x: (N, 2) centres inside [0, box) (mm); r: (N,) radii (mm); box: (2,) cell lengths (mm).
        ratio, skin: reach factor (>= 0) and added distance (mm, >= 0).
        with_self: also list a disk and its own images (j == i, one of each +-s).

    Returns:
        ``(m, pi, pj, ps)``: the count and int32 arrays of capacity >= m: pi, pj (cap,) with
        j > i (or j == i), ps (cap, 2) integer shifts in cells.
    """
    n = r.shape[0]
    cut = ratio * 2.0 * r.max() + skin
    ncx, ncy, start, order = cell_list(x, box, cut)
    kx = int(np.ceil(cut * ncx / box[0]))  # neighbour cells to scan on each side (1 normally)
    ky = int(np.ceil(cut * ncy / box[1]))
    xs = np.empty((n, 2))  # centres and radii in cell order: contiguous loads
    rs = np.empty(n)
    for a in range(n):
        xs[a] = x[order[a]]
        rs[a] = r[order[a]]
    cap = 16 * n + 16
    pi = np.empty(cap, np.int32)
    pj = np.empty(cap, np.int32)
    ps = np.empty((cap, 2), np.int32)
    m = 0
    for c in range(ncx * ncy):
        cx, cy = c // ncy, c % ncy
        for a in range(start[c], start[c + 1]):
            i = order[a]
            for ux in range(cx - kx, cx + kx + 1):
                sx = ux // ncx  # floor: the image of the unwrapped cell column ux
                for uy in range(cy - ky, cy + ky + 1):
                    sy = uy // ncy
                    c2 = (ux - sx * ncx) * ncy + uy - sy * ncy
                    for b in range(start[c2], start[c2 + 1]):
                        j = order[b]
                        if j > i or (with_self and j == i and (sx > 0 or (sx == 0 and sy > 0))):
                            dx = xs[b, 0] - xs[a, 0] + sx * box[0]
                            dy = xs[b, 1] - xs[a, 1] + sy * box[1]
                            rc = ratio * (rs[a] + rs[b]) + skin
                            if dx * dx + dy * dy < rc * rc:
                                pi, pj, ps = _append_pair(m, pi, pj, ps, i, j, sx, sy)
                                m += 1
    return m, pi, pj, ps


def candidate_pairs(centers, radii, box, max_ratio):
    """All pairs (i, j, image) with |L| <= max_ratio * (r_i + r_j), sorted by |L| / (r_i + r_j);
    O(N) (a cell list).

    Args:
        centers: (N, 2) centres inside the cell.
        radii: (N,) radii.
        box: (2,) cell lengths.
        max_ratio: 1 / min_stretch, >= 1.

    Returns:
        ``(L, R, rho, ij, shift)``: L (M, 2) reference branch vectors, R (M,) radius sums, rho (M,)
        = |L|/R ascending, ij (M, 2) disk indices, shift (M, 2) integer image offsets in cells.
        A disk paired with its own image appears once per pair of opposite shifts.
    """
    centers = np.ascontiguousarray(centers, dtype=np.float64)
    radii = np.ascontiguousarray(radii, dtype=np.float64)
    box = np.ascontiguousarray(box, dtype=np.float64)
    # every pair within reach from a cell list (a hair wider than max_ratio, then the exact cut)
    m, pi, pj, ps = find_pairs(centers, radii, box, max_ratio * (1.0 + 1e-9), 0.0, True)
    i, j, s = pi[:m].astype(np.int64), pj[:m].astype(np.int64), ps[:m].astype(np.int64)
    lx = centers[j, 0] + s[:, 0] * box[0] - centers[i, 0]
    ly = centers[j, 1] + s[:, 1] * box[1] - centers[i, 1]
    d2 = lx * lx + ly * ly
    rsum = radii[i] + radii[j]
    keep = np.flatnonzero(d2 <= (max_ratio * rsum) ** 2)
    # ties of |L| / R in a fixed order (i, j, shift): the same list on every rank and platform
    keep = keep[np.lexsort((s[keep, 1], s[keep, 0], j[keep], i[keep]))]
    L, R, rho = np.stack([lx[keep], ly[keep]], axis=1), rsum[keep], np.sqrt(d2[keep]) / rsum[keep]
    ij, shift = np.stack([i[keep], j[keep]], axis=1), s[keep]
    if m and np.any(rho == 0.0):
        c = int(np.flatnonzero(rho == 0.0)[0])
        raise ValueError(
            f"disks {ij[c, 0]} and {ij[c, 1]} have the same centre, so their contact normal is "
            "undefined; move one of them"
        )
    order = np.argsort(rho, kind="stable")
    return L[order], R[order], rho[order], ij[order], shift[order]


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
