"""The minimum-norm Newton step of the stress-free correction
(:mod:`~dolfinx_granular.packings.stress_free`): a sparse Cholesky factorisation in Numba.

The step solves J J^T y = -g over the contacts of the network and moves centres and radii by
J^T y, where row c of J holds d eps_c / d(x, r): n_c at x_i, -n_c at x_j, 1 at r_i and r_j. SciPy's
SuperLU would do it, but it calls the BLAS, whose kernels (OpenBLAS's, MKL's) are chosen by the
CPU and round differently; the code here uses +, -, *, / and sqrt in a fixed order, so that the
step has the same bits on every machine. The contacts are numbered by nested dissection of the
particles' positions (comparisons only), which keeps the factor sparse: two contacts couple in
J J^T only where they share a particle.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: contacts at which the nested dissection stops splitting (a block this small is nearly dense)
LEAF = 64


def nested_dissection(x, pairs, leaf=LEAF):
    """An elimination order of the contacts: (M,) indices into ``pairs``.

    The particles are split at the median of their positions along the cell's longer side; the
    contacts between particles of one half are numbered (recursively) before those that join
    the halves, which need no other contact of the two halves.

    Args:
        x: (N, d) particle centres; pairs: (M, 2) the contacts' particles; leaf: block size.
    """
    side = np.zeros(x.shape[0], np.int8)
    order = []
    _dissect(x, pairs, np.arange(x.shape[0]), np.arange(pairs.shape[0]), side, leaf, order)
    return np.concatenate(order) if order else np.empty(0, np.int64)


def _dissect(x, pairs, particles, contacts, side, leaf, order):
    """Append the order of ``contacts`` (their particles among ``particles``) to ``order``."""
    if contacts.size <= leaf or particles.size < 2:
        order.append(contacts)
        return
    pos = x[particles]
    axis = int(np.argmax(pos.max(axis=0) - pos.min(axis=0)))
    # a stable sort: ties of positions in the same order with every numpy
    lower = particles[np.argsort(pos[:, axis], kind="stable")[: particles.size // 2]]
    side[particles] = 2
    side[lower] = 1
    a, b = side[pairs[contacts, 0]], side[pairs[contacts, 1]]
    for half, s in ((lower, 1), (np.setdiff1d(particles, lower), 2)):
        _dissect(x, pairs, half, contacts[(a == s) & (b == s)], side, leaf, order)
    order.append(contacts[a != b])


def minimum_norm_step(pairs, normals, g, order, n):
    """The least move dz of centres and radii with J dz = -g: dz = J^T y, J J^T y = -g (J J^T
    shifted by 1e-12 of its mean diagonal, as a guard against a rank-deficient network).

    Args:
        pairs: (M, 2) int64 particles i, j of each contact; normals: (M, d) unit vectors from
            i to j; g: (M,) overlap minus target; order: (M,) elimination order
            (:func:`nested_dissection`); n: number of particles.

    Returns:
        ``(dx (n, d), dr (n,))``.

    Raises:
        ValueError: J J^T not positive definite in floating point (the steps diverged).
    """
    pairs = np.ascontiguousarray(pairs, dtype=np.int64)
    normals = np.ascontiguousarray(normals, dtype=np.float64)
    order = np.ascontiguousarray(order, dtype=np.int64)
    rp, ri, rx = _normal_rows(pairs, normals, order, n)
    lp, li, lx, ok = _cholesky(rp, ri, rx)
    if not ok:
        raise ValueError("the normal equations of the stress-free correction are not definite")
    y = np.empty(g.size)
    y[:] = -g[order]
    _solve(lp, li, lx, y)
    yc = np.empty_like(y)
    yc[order] = y
    return _transpose_product(pairs, normals, yc, n)


@njit(cache=True)
def _block(pairs, c, p):
    """Row c of J at particle p: (sign of n_c, entry at r_p); a contact of a particle with its
    own image has n_c - n_c = 0 and 1 + 1 = 2 there."""
    i, j = pairs[c, 0], pairs[c, 1]
    if i == j:
        return 0.0, 2.0
    return (1.0, 1.0) if p == i else (-1.0, 1.0)


@njit(cache=True)
def _coupling(pairs, normals, c, e, p):
    """(J J^T)_ce's term of the shared particle p."""
    sc, rc = _block(pairs, c, p)
    se, re = _block(pairs, e, p)
    dot = 0.0
    for a in range(normals.shape[1]):
        dot += normals[c, a] * normals[e, a]
    return sc * se * dot + rc * re


@njit(cache=True)
def _incidence(pairs, n):
    """The contacts of each particle, CSR ``(start (n + 1,), contacts)``, in contact order."""
    m = pairs.shape[0]
    start = np.zeros(n + 1, np.int64)
    for c in range(m):
        start[pairs[c, 0] + 1] += 1
        if pairs[c, 1] != pairs[c, 0]:
            start[pairs[c, 1] + 1] += 1
    for p in range(n):
        start[p + 1] += start[p]
    fill = start[:-1].copy()
    contacts = np.empty(start[n], np.int64)
    for c in range(m):
        for k in range(2):
            p = pairs[c, k]
            if k == 1 and p == pairs[c, 0]:
                break
            contacts[fill[p]] = c
            fill[p] += 1
    return start, contacts


@njit(cache=True)
def _normal_rows(pairs, normals, order, n):
    """Rows of P (J J^T + eps I) P^T on and below the diagonal, P the ``order``: CSR
    ``(rp, ri, rx)``, column indices in the new numbering."""
    m = pairs.shape[0]
    start, inc = _incidence(pairs, n)
    pos = np.empty(m, np.int64)
    for k in range(m):
        pos[order[k]] = k
    diag = 0.0
    for c in range(m):
        for k in range(2):
            p = pairs[c, k]
            if k == 0 or p != pairs[c, 0]:
                diag += _coupling(pairs, normals, c, c, p)
    shift = 1e-12 * diag / max(m, 1)
    rp = np.zeros(m + 1, np.int64)
    ri = np.empty(16 * m + 16, np.int64)
    rx = np.empty(16 * m + 16)
    w = np.zeros(m)
    seen = np.full(m, -1, np.int64)
    found = np.empty(m, np.int64)
    for k in range(m):
        c = order[k]
        nf = 0
        for side in range(2):
            p = pairs[c, side]
            if side == 1 and p == pairs[c, 0]:
                break
            for q in range(start[p], start[p + 1]):
                e = inc[q]
                if pos[e] > k:
                    continue
                if seen[e] != k:
                    seen[e] = k
                    w[e] = 0.0
                    found[nf] = e
                    nf += 1
                w[e] += _coupling(pairs, normals, c, e, p)
        if rp[k] + nf > ri.shape[0]:
            ri = _grow_int(ri, rp[k] + nf)
            rx = _grow_float(rx, rp[k] + nf)
        for f in range(nf):
            e = found[f]
            ri[rp[k] + f] = pos[e]
            rx[rp[k] + f] = w[e] + shift if e == c else w[e]
        rp[k + 1] = rp[k] + nf
    return rp, ri, rx


@njit(cache=True)
def _grow_int(a, need):
    b = np.empty(max(2 * a.shape[0], need), np.int64)
    b[: a.shape[0]] = a
    return b


@njit(cache=True)
def _grow_float(a, need):
    b = np.empty(max(2 * a.shape[0], need))
    b[: a.shape[0]] = a
    return b


@njit(cache=True)
def elimination_tree(rp, ri):
    """Parent (M,) of each column of L in the elimination tree (-1: a root), from the rows on
    and below the diagonal, (M + 1,) pointers ``rp`` into column indices ``ri`` (Liu's
    algorithm with path compression; also the block L D L^T's, laws/relaxed/block_ldlt.py)."""
    m = rp.shape[0] - 1
    parent = np.full(m, -1, np.int64)
    ancestor = np.full(m, -1, np.int64)
    for k in range(m):
        for q in range(rp[k], rp[k + 1]):
            i = ri[q]
            while i != -1 and i < k:
                nxt = ancestor[i]
                ancestor[i] = k
                if nxt == -1:
                    parent[i] = k
                i = nxt
    return parent


@njit(cache=True)
def _row_pattern(rp, ri, k, parent, mark, stack, path):
    """Columns of row k of L (below the diagonal) in topological order: ``stack[top:]``;
    returns top. ``mark`` (M,) holds k for the columns visited."""
    m = rp.shape[0] - 1
    top = m
    mark[k] = k
    for q in range(rp[k], rp[k + 1]):
        i = ri[q]
        length = 0
        while mark[i] != k:
            path[length] = i
            length += 1
            mark[i] = k
            i = parent[i]
        while length > 0:
            length -= 1
            top -= 1
            stack[top] = path[length]
    return top


@njit(cache=True)
def _cholesky(rp, ri, rx):
    """L L^T of the symmetric matrix given by its rows on and below the diagonal, row by row
    (up-looking, as CSparse's cs_chol): CSC ``(lp, li, lx, ok)``, the diagonal first in each
    column; ok False where a pivot is not positive."""
    m = rp.shape[0] - 1
    parent = elimination_tree(rp, ri)
    mark = np.full(m, -1, np.int64)
    stack = np.empty(m, np.int64)
    path = np.empty(m, np.int64)
    count = np.ones(m, np.int64)
    for k in range(m):
        top = _row_pattern(rp, ri, k, parent, mark, stack, path)
        for t in range(top, m):
            count[stack[t]] += 1
    lp = np.zeros(m + 1, np.int64)
    for k in range(m):
        lp[k + 1] = lp[k] + count[k]
    nxt = lp[:-1].copy()
    li = np.empty(lp[m], np.int64)
    lx = np.empty(lp[m])
    x = np.zeros(m)
    mark[:] = -1
    for k in range(m):
        top = _row_pattern(rp, ri, k, parent, mark, stack, path)
        for q in range(rp[k], rp[k + 1]):
            x[ri[q]] = rx[q]
        d = x[k]
        x[k] = 0.0
        for t in range(top, m):
            i = stack[t]
            lki = x[i] / lx[lp[i]]
            x[i] = 0.0
            for q in range(lp[i] + 1, nxt[i]):
                x[li[q]] -= lx[q] * lki
            d -= lki * lki
            li[nxt[i]] = k
            lx[nxt[i]] = lki
            nxt[i] += 1
        if not d > 0.0:
            return lp, li, lx, False
        li[nxt[k]] = k
        lx[nxt[k]] = np.sqrt(d)
        nxt[k] += 1
    return lp, li, lx, True


@njit(cache=True)
def _solve(lp, li, lx, y):
    """y := (L L^T)^-1 y in place."""
    m = lp.shape[0] - 1
    for j in range(m):
        y[j] /= lx[lp[j]]
        for q in range(lp[j] + 1, lp[j + 1]):
            y[li[q]] -= lx[q] * y[j]
    for j in range(m - 1, -1, -1):
        for q in range(lp[j] + 1, lp[j + 1]):
            y[j] -= lx[q] * y[li[q]]
        y[j] /= lx[lp[j]]


@njit(cache=True)
def _transpose_product(pairs, normals, y, n):
    """J^T y as ``(dx (n, d), dr (n,))``, summed in contact order."""
    d = normals.shape[1]
    dx = np.zeros((n, d))
    dr = np.zeros(n)
    for c in range(pairs.shape[0]):
        i, j = pairs[c, 0], pairs[c, 1]
        if i == j:
            dr[i] += 2.0 * y[c]
            continue
        for a in range(d):
            dx[i, a] += normals[c, a] * y[c]
            dx[j, a] -= normals[c, a] * y[c]
        dr[i] += y[c]
        dr[j] += y[c]
    return dx, dr
