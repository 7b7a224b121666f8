"""Candidate contacts of a periodic disk packing: a cell list and the pairs within reach.

A candidate contact is a pair of disks (i, j), j possibly a periodic image shifted by whole cells,
whose centres are closer than a reach. The packing generator asks for pairs with a skin
(:func:`find_pairs`); the laws' contact geometry
(:class:`~dolfinx_granular.ContactCandidates`) asks for all pairs with
|L| <= max_ratio (r_i + r_j), sorted by |L| / (r_i + r_j) (:func:`candidate_pairs`).
"""

from __future__ import annotations

import numpy as np
from numba import njit


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
