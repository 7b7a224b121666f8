"""Candidate contacts of a periodic packing: a cell list and the pairs within reach.

A candidate contact is a pair of particles (i, j) (disks or spheres, in 2-D or 3-D), j possibly a
periodic image shifted by whole cells,
whose centres are closer than a reach. The packing generator asks for pairs with a skin
(:func:`find_pairs`); the laws' contact geometry
(:class:`~dolfinx_granular.ContactCandidates`) asks for all pairs with
|L| <= max_ratio (r_i + r_j), sorted by |L| / (r_i + r_j) (:func:`candidate_pairs`).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _append_pair(m, pi, pj, ps, i, j, shift):
    """Store pair number m (i, j, image shift (d,)), doubling the buffers when full; returns
    them."""
    if m == pi.shape[0]:
        pi2 = np.empty(2 * m, np.int32)
        pj2 = np.empty(2 * m, np.int32)
        ps2 = np.empty((2 * m, ps.shape[1]), np.int32)
        pi2[:m] = pi
        pj2[:m] = pj
        ps2[:m] = ps
        pi, pj, ps = pi2, pj2, ps2
    pi[m] = i
    pj[m] = j
    ps[m, :] = shift
    return pi, pj, ps


@njit(cache=True)
def cell_list(x, box, cut):
    """Sort the centres x (N, d), inside [0, box), into a grid of cells at least ``cut`` wide
    (a single cell per side where the box is narrower).

    Returns:
        ``(nc, start, order)``: cells per side (d,); the particles of the cell with grid index
        (c_0, .., c_d-1), number c = sum_k c_k prod_{l>k} nc_l (the last index fastest), are
        ``order[start[c]:start[c + 1]]``, by descending index.
    """
    n, d = x.shape
    nc = np.empty(d, np.int64)
    for k in range(d):
        nc[k] = max(int(box[k] / cut), 1)
    total = 1
    for k in range(d):
        total *= nc[k]
    cell = np.empty(n, np.int64)
    start = np.zeros(total + 1, np.int64)
    for i in range(n):
        c = 0
        for k in range(d):
            c = c * nc[k] + min(max(int(x[i, k] / box[k] * nc[k]), 0), nc[k] - 1)
        cell[i] = c
        start[c + 1] += 1
    for c in range(total):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n - 1, -1, -1):
        order[fill[cell[i]]] = i
        fill[cell[i]] += 1
    return nc, start, order


@njit(cache=True)
def _neighbour_cells(nc, reach):
    """The cells to scan around a cell, as offsets (K, d) in cells, -reach..reach per side, the
    last index fastest."""
    d = nc.shape[0]
    K = 1
    for k in range(d):
        K *= 2 * reach[k] + 1
    offsets = np.empty((K, d), np.int64)
    for o in range(K):
        rest = o
        for k in range(d - 1, -1, -1):
            width = 2 * reach[k] + 1
            offsets[o, k] = rest % width - reach[k]
            rest //= width
    return offsets


@njit(cache=True)
def _positive(shift):
    """The first non-zero entry of an image shift (d,) is positive: one of each pair +-s."""
    for k in range(shift.shape[0]):
        if shift[k] != 0:
            return shift[k] > 0
    return False


@njit(cache=True)
def find_pairs(x, r, box, ratio, skin, with_self):
    """All pairs (i, j, image shift s) with |x_j + s * box - x_i| < ratio (r_i + r_j) + skin.

    A cell list: O(N) for cells wider than a few diameters, and exact for any cell (narrow cells
    scan more neighbour cells, so every periodic image within reach is found once).

    Args:
        x: (N, d) centres inside [0, box) (mm), d = 2 or 3; r: (N,) radii (mm); box: (d,) cell
            lengths (mm).
        ratio, skin: reach factor (>= 0) and added distance (mm, >= 0).
        with_self: also list a particle and its own images (j == i, one of each +-s).

    Returns:
        ``(m, pi, pj, ps)``: the count and int32 arrays of capacity >= m: pi, pj (cap,) with
        j > i (or j == i), ps (cap, d) integer shifts in cells.
    """
    n, d = x.shape
    cut = ratio * 2.0 * r.max() + skin
    nc, start, order = cell_list(x, box, cut)
    reach = np.empty(d, np.int64)  # neighbour cells to scan on each side (1 normally)
    for k in range(d):
        reach[k] = int(np.ceil(cut * nc[k] / box[k]))
    offsets = _neighbour_cells(nc, reach)
    xs = np.empty((n, d))  # centres and radii in cell order: contiguous loads
    rs = np.empty(n)
    for a in range(n):
        xs[a] = x[order[a]]
        rs[a] = r[order[a]]
    cap = 16 * n + 16
    pi = np.empty(cap, np.int32)
    pj = np.empty(cap, np.int32)
    ps = np.empty((cap, d), np.int32)
    home = np.empty(d, np.int64)
    shift = np.empty(d, np.int64)
    m = 0
    for c in range(start.shape[0] - 1):
        rest = c
        for k in range(d - 1, -1, -1):
            home[k] = rest % nc[k]
            rest //= nc[k]
        for a in range(start[c], start[c + 1]):
            i = order[a]
            for o in range(offsets.shape[0]):
                c2 = 0
                for k in range(d):
                    u = home[k] + offsets[o, k]
                    shift[k] = u // nc[k]  # floor: the image of the unwrapped cell index u
                    c2 = c2 * nc[k] + u - shift[k] * nc[k]
                for b in range(start[c2], start[c2 + 1]):
                    j = order[b]
                    if j > i or (with_self and j == i and _positive(shift)):
                        rc = ratio * (rs[a] + rs[b]) + skin
                        dist2 = 0.0
                        for k in range(d):
                            dk = xs[b, k] - xs[a, k] + shift[k] * box[k]
                            dist2 += dk * dk
                        if dist2 < rc * rc:
                            pi, pj, ps = _append_pair(m, pi, pj, ps, i, j, shift)
                            m += 1
    return m, pi, pj, ps


def candidate_pairs(centers, radii, box, max_ratio):
    """All pairs (i, j, image) with |L| <= max_ratio * (r_i + r_j), sorted by |L| / (r_i + r_j);
    O(N) (a cell list).

    Args:
        centers: (N, d) centres inside the cell, d = 2 or 3.
        radii: (N,) radii.
        box: (d,) cell lengths.
        max_ratio: 1 / min_stretch, >= 1.

    Returns:
        ``(L, R, rho, ij, shift)``: L (M, d) reference branch vectors, R (M,) radius sums, rho (M,)
        = |L|/R ascending, ij (M, 2) particle indices, shift (M, d) integer image offsets in
        cells. A particle paired with its own image appears once per pair of opposite shifts.
    """
    centers = np.ascontiguousarray(centers, dtype=np.float64)
    radii = np.ascontiguousarray(radii, dtype=np.float64)
    box = np.ascontiguousarray(box, dtype=np.float64)
    d = centers.shape[1]
    # every pair within reach from a cell list (a hair wider than max_ratio, then the exact cut)
    m, pi, pj, ps = find_pairs(centers, radii, box, max_ratio * (1.0 + 1e-9), 0.0, True)
    i, j, s = pi[:m].astype(np.int64), pj[:m].astype(np.int64), ps[:m].astype(np.int64)
    L = centers[j] + s * box - centers[i]
    d2 = L[:, 0] * L[:, 0]
    for k in range(1, d):
        d2 = d2 + L[:, k] * L[:, k]
    rsum = radii[i] + radii[j]
    reach = max_ratio * rsum
    keep = np.flatnonzero(d2 <= reach * reach)  # a product: no pow, whatever numpy does with ** 2
    # ties of |L| / R in a fixed order (i, j, shift): the same list on every rank and platform
    keys = tuple(s[keep, k] for k in range(d - 1, -1, -1)) + (j[keep], i[keep])
    keep = keep[np.lexsort(keys)]
    L, R, rho = L[keep], rsum[keep], np.sqrt(d2[keep]) / rsum[keep]
    ij, shift = np.stack([i[keep], j[keep]], axis=1), s[keep]
    if m and np.any(rho == 0.0):
        c = int(np.flatnonzero(rho == 0.0)[0])
        word = "disks" if d == 2 else "spheres"
        raise ValueError(
            f"{word} {ij[c, 0]} and {ij[c, 1]} have the same centre, so their contact normal is "
            "undefined; move one of them"
        )
    order = np.argsort(rho, kind="stable")
    return L[order], R[order], rho[order], ij[order], shift[order]
