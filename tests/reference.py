"""Slow, obvious NumPy reference of the Taylor RVE, written straight from the paper's formulas.

The paper's double sums over i != j (eqs. 7, 10, 13, 14) with their factor 1/2, periodic images
included by brute force over a fixed range of image shifts. Independent of the package's kernel:
no candidate lists, no moment sums, no pruning.
"""

from itertools import product

import numpy as np


def all_branch_vectors(packing, images=3):
    """Every ordered pair (i, j, image) except a particle with itself: L (M, d), R (M,)."""
    X, r, box = packing.centers, packing.radii, packing.box
    n = len(r)
    s = range(-images, images + 1)
    shifts = np.array(list(product(s, repeat=len(box))), dtype=float) * box  # (S, d)
    i, j, k = np.meshgrid(np.arange(n), np.arange(n), np.arange(len(shifts)), indexing="ij")
    i, j, k = i.ravel(), j.ravel(), k.ravel()
    keep = ~((i == j) & np.all(shifts[k] == 0.0, axis=1))
    i, j, k = i[keep], j[keep], k[keep]
    L = X[j] + shifts[k] - X[i]
    return L, r[i] + r[j]


def reference(packing, k_n, F, images=3):
    """W, P, A, sigma, a at one F (d, d) from eqs. 7, 10, 11, 13, 14 (the 3-D ones with every
    index over 3 and V the box volume)."""
    L, R = all_branch_vectors(packing, images)
    V = packing.volume
    l = L @ F.T
    d = np.linalg.norm(l, axis=1)
    eps = R - d
    on = eps >= 0.0
    L, R, l, d, eps = L[on], R[on], l[on], d[on], eps[on]
    n = l / d[:, None]
    I = np.eye(len(F))
    W = np.sum(k_n * eps**2) / (4.0 * V)  # eq. 7
    f = -k_n * eps[:, None] * n  # eq. 5
    P = np.einsum("ma,mb->ab", f, L) / (2.0 * V)  # eq. 10
    J = np.linalg.det(F)
    sigma = np.einsum("ma,mb->ab", f, l) / (2.0 * J * V)  # eq. 11
    w = k_n / d
    LL = np.einsum("mb,md->mbd", L, L)
    A_geo = -np.einsum("m,ac,mbd->abcd", w * eps, I, LL) / (2.0 * V)  # eq. 13, geometric part
    nn = np.einsum("ma,mc->mac", n, n)
    A_mat = np.einsum("m,mac,mbd->abcd", w * R, nn, LL) / (2.0 * V)  # eq. 13, material part
    inner = R[:, None, None] * nn - eps[:, None, None] * I  # [r_i + r_j] n x n - eps 1
    a = np.einsum("m,mac,mbd->abcd", d * k_n, inner, nn) / (2.0 * J * V)  # eq. 14
    return W, P, A_geo + A_mat, sigma, a


def reference_modulus(packing, k_n, images=3):
    """Small-strain modulus of eq. 15 over the contacts touching at F = I."""
    L, R = all_branch_vectors(packing, images)
    d = np.linalg.norm(L, axis=1)
    on = R - d >= 0.0
    L, d = L[on], d[on]
    n = L / d[:, None]
    return np.einsum("m,ma,mb,mc,md->abcd", k_n * d**2, n, n, n, n) / (2.0 * packing.volume)


def central_differences(model, F, h):
    """Central differences of ``model.stress`` (any material point with ``stress(F) -> (W, P)``)
    in each component of F (n, d, d): ``(dW/dF (n, d, d), dP/dF (n, d, d, d, d))``, step h."""
    dim = F.shape[-1]
    dW = np.empty(F.shape)
    dP = np.empty(F.shape + (dim, dim))
    for c in range(dim):
        for d in range(dim):
            dF = np.zeros((dim, dim))
            dF[c, d] = h
            Wp, Pp = model.stress(F + dF)
            Wm, Pm = model.stress(F - dF)
            dW[:, c, d] = (Wp - Wm) / (2 * h)
            dP[..., c, d] = (Pp - Pm) / (2 * h)
    return dW, dP


def brute_force_candidates(centers, radii, box, max_ratio):
    """neighbours.candidate_pairs the slow way: every pair i <= j and every image within reach,
    scanned in (i, j, sx, sy) order, kept where |L| <= max_ratio (r_i + r_j), then sorted stably
    by |L| / (r_i + r_j). Returns ``(L, R, rho, ij, shift)``."""
    n = len(radii)
    k = [int(np.ceil(2.0 * radii.max() * max_ratio / b)) for b in box]
    rows = []
    for i in range(n):
        for j in range(i, n):
            rsum = radii[i] + radii[j]
            for sx in range(-k[0], k[0] + 1):
                for sy in range(-k[1], k[1] + 1):
                    if i == j and (sx < 0 or (sx == 0 and sy <= 0)):
                        continue
                    lx = centers[j, 0] + sx * box[0] - centers[i, 0]
                    ly = centers[j, 1] + sy * box[1] - centers[i, 1]
                    d2 = lx * lx + ly * ly
                    if d2 <= (max_ratio * rsum) ** 2:
                        rows.append((lx, ly, rsum, np.sqrt(d2) / rsum, i, j, sx, sy))
    a = np.array(rows)
    order = np.argsort(a[:, 3], kind="stable")
    a = a[order]
    return a[:, :2], a[:, 2], a[:, 3], a[:, 4:6].astype(np.int64), a[:, 6:8].astype(np.int64)
