"""A sparse symmetric factorisation A = L D L^T in d x d blocks, in Numba (no BLAS).

The relaxed RVE's stiffness couples the d unknowns of a disk (d = 2; 3 for a disk with its
rotation) with those of its contact partners only, so it is a sparse matrix of d x d blocks, one
block row per disk, off-diagonal blocks where two disks can touch. The factorisation works on
those blocks: L is unit lower triangular in blocks, D block diagonal with each d x d block
inverted explicitly.

* :func:`analyse` is the symbolic part, done once for a block pattern (the disk pairs of the
  candidate contacts: every pair that can be in contact) and kept while the pattern holds: a
  fill-reducing order of the blocks (minimum degree on the block graph), the elimination tree,
  the block structure of L, and for every pair and every block the slot of the values where its
  contribution goes, so that the stiffness is assembled straight into the values
  (:func:`assemble`) without COO triplets or a CSC conversion. One block (the pinned disk) can
  be left out.
* :func:`factorise` is the numeric part (up-looking, row by row of L, as CSparse's ``cs_chol``),
  into the preallocated arrays of a :class:`BlockFactor`, with per-unknown diagonal shifts added
  on the fly (the rattler shift, a Levenberg-Marquardt mu I): one assembly serves every shift.
  It returns the inertia (positive, negative, zero eigenvalues) read off the D blocks by
  Sylvester's law of inertia (A = L D L^T is a congruence): A is positive definite iff every D
  block is. A D block that is singular or not finite stops it (not positive definite).
* :func:`solve` solves for one or several right-hand sides, with optional steps of iterative
  refinement (where a small shift leaves the matrix ill-conditioned).

Without pivoting the factorisation of an indefinite matrix can be unstable where a D block is
nearly singular; the 2 x 2 (3 x 3) blocks keep a disk's unknowns together, which covers the
common case (one disk's stiffness indefinite in one direction).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.sparse import coo_matrix, diags
from scipy.sparse.linalg import splu

from ...packings.cholesky import elimination_tree

#: orderings of the blocks :func:`analyse` knows: SuperLU's multiple minimum degree on the
#: block graph, reverse Cuthill-McKee, the given order
ORDERINGS = ("mmd", "rcm", "natural")


@dataclass(eq=False)
class BlockPattern:
    """The symbolic factorisation of a block pattern (:func:`analyse`); read-only by convention.

    Attributes:
        n_blocks: blocks (disks) of the full matrix, the pinned one included. d: block size.
        pinned: the block left out (-1: none). n: blocks factorised.
        perm: (n,) the block at each position of the elimination order; iperm: (n_blocks,)
            position of each block (-1: pinned).
        Ap, Ai: block rows of A's strict lower triangle in the elimination order, CSR: row k
            has blocks in columns Ai[Ap[k]:Ap[k + 1]] < k.
        Lp, Li: L's strict lower triangle by block columns, CSC, rows increasing.
        Rp, Rc, Rq: L's rows: row k has blocks in columns Rc[Rp[k]:Rp[k + 1]] (increasing),
            stored at L's positions Rq[...].
        diag_slot: (n_blocks,) where a block's diagonal block lives in the values (-1:
            pinned). pair_slot: (n_pairs,) where a pair's off-diagonal block lives (-1: a
            pair of a block with itself, or with the pinned one); pair_flip: (n_pairs,) the
            slot holds A[j, i] = A[i, j]^T, not A[i, j].
        n_values: blocks of the values array, (n_values, d, d): the n diagonal blocks first
            (position k), then A's strict lower triangle (n + q for Ai[q]).
        flops: floating-point operations of one numeric factorisation.
    """

    n_blocks: int
    d: int
    pinned: int
    n: int
    perm: np.ndarray
    iperm: np.ndarray
    Ap: np.ndarray
    Ai: np.ndarray
    Lp: np.ndarray
    Li: np.ndarray
    Rp: np.ndarray
    Rc: np.ndarray
    Rq: np.ndarray
    diag_slot: np.ndarray
    pair_slot: np.ndarray
    pair_flip: np.ndarray
    n_values: int
    flops: int

    @property
    def dims(self) -> tuple:
        """(d,) the block size as the kernels take it (a tuple's length is a compile-time
        constant)."""
        return tuple(range(self.d))

    @property
    def nnz_L(self) -> int:
        """Blocks of L below the diagonal."""
        return int(self.Li.shape[0])

    def zeros(self) -> np.ndarray:
        """A zeroed values array (n_values, d, d)."""
        return np.zeros((self.n_values, self.d, self.d))

    def new_factor(self) -> BlockFactor:
        """Preallocated arrays of a numeric factorisation on this pattern."""
        d, n = self.d, self.n
        return BlockFactor(
            self,
            np.zeros((self.nnz_L, d, d)),
            np.zeros((n, d, d)),
            np.zeros((n, d, d)),
            np.zeros((n, d, d)),
            np.zeros((self.n_values, d, d)),
            np.zeros((self.n_blocks, d)),
        )

    def to_csc(self, values: np.ndarray, shift=None):
        """The matrix (n_blocks d, n_blocks d) of ``values`` (+ ``shift``) as scipy CSC (the
        pinned block's rows and columns empty): for tests and comparisons."""
        rows, cols, vals = _triplets(self, values, _shifts(self, shift))
        N = self.n_blocks * self.d
        return coo_matrix((vals, (rows, cols)), shape=(N, N)).tocsc()


@dataclass(eq=False)
class BlockFactor:
    """A numeric factorisation on a :class:`BlockPattern` (:func:`factorise`).

    Attributes:
        Lx: (nnz_L, d, d) L's blocks. D, Dinv: (n, d, d) D's blocks and their inverses.
        y: (n, d, d) work space. values, shift: (n_values, d, d) and (n_blocks, d) copies of
            what was factorised (for the residuals of iterative refinement).
        ok: every D block finite and invertible. inertia: (positive, negative, zero)
            eigenvalue counts of A (without the pinned block; of the D blocks up to the first
            singular one where not ok).
    """

    pattern: BlockPattern
    Lx: np.ndarray
    D: np.ndarray
    Dinv: np.ndarray
    y: np.ndarray
    values: np.ndarray
    shift: np.ndarray
    ok: bool = False
    inertia: tuple = (0, 0, 0)

    @property
    def positive_definite(self) -> bool:
        """Every D block positive definite (so A is, Sylvester's law of inertia)."""
        return self.ok and self.inertia[1] == 0 and self.inertia[2] == 0


def analyse(
    n_blocks: int,
    pairs: np.ndarray,
    pinned: int = -1,
    d: int = 2,
    ordering: str = "mmd",
) -> BlockPattern:
    """The symbolic factorisation of the block pattern of ``pairs``.

    Args:
        n_blocks: blocks (disks); pairs: (n_pairs, 2) blocks (i, j) that may couple (repeats
            and i == j allowed: one slot each, or none); pinned: a block left out of the matrix
            (its unknowns fixed), -1 for none; d: block size; ordering: one of
            :data:`ORDERINGS`.
    """
    pairs = np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2)
    i, j = pairs[:, 0], pairs[:, 1]
    active = np.ones(n_blocks, np.bool_)
    if pinned >= 0:
        active[pinned] = False
    use = (i != j) & active[i] & active[j]
    perm = _ordering(n_blocks, i[use], j[use], active, ordering)
    iperm = -np.ones(n_blocks, np.int64)
    iperm[perm] = np.arange(perm.size)
    n = perm.size
    Ap, Ai, pair_q = _lower_rows(n, iperm[i], iperm[j], use)
    Lp, Li, Rp, Rc, Rq = _symbolic(n, Ap, Ai)
    pair_slot = np.where(pair_q >= 0, n + pair_q, -1)
    pair_flip = use & (iperm[i] < iperm[j])
    diag_slot = iperm.copy()
    flops = _flop_count(Lp, Rp, Rc, Rq, d)
    return BlockPattern(
        n_blocks, d, int(pinned), n, perm, iperm, Ap, Ai, Lp, Li, Rp, Rc, Rq,
        diag_slot, pair_slot, pair_flip, n + Ai.shape[0], flops,
    )  # fmt: skip


def _ordering(n_blocks, i, j, active, method):
    """(n,) the active blocks in elimination order, a fill-reducing order of the block graph
    with edges (i, j)."""
    idx = np.flatnonzero(active)
    if method == "natural" or idx.size < 3:
        return idx
    local = -np.ones(n_blocks, np.int64)
    local[idx] = np.arange(idx.size)
    n = idx.size
    G = coo_matrix((np.ones(i.size), (local[i], local[j])), shape=(n, n)).tocsr()
    G = ((G + G.T) > 0).astype(np.float64)
    if method == "rcm":
        from scipy.sparse.csgraph import reverse_cuthill_mckee

        return idx[reverse_cuthill_mckee(G.tocsr(), symmetric_mode=True)]
    if method != "mmd":
        raise ValueError(f"unknown ordering {method!r}: one of {ORDERINGS}")
    # the graph Laplacian plus I: symmetric, diagonally dominant, the pattern of the block graph;
    # SuperLU orders it (minimum degree on A + A^T) while it factorises it once
    lap = diags(np.asarray(G.sum(axis=1)).ravel() + 1.0) - G
    lu = splu(
        lap.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )  # fmt: skip
    order = np.empty(n, np.int64)
    order[lu.perm_c] = np.arange(n)  # perm_c[k]: the position of column k
    return idx[order]


@njit(cache=True)
def _lower_rows(n, pi, pj, use):
    """A's strict lower triangle in the elimination order (positions pi, pj of the pairs'
    blocks), CSR ``(Ap, Ai, pair_q)`` with columns increasing and repeats merged; pair_q (n_pairs,)
    the entry of each pair (-1: not used)."""
    count = np.zeros(n + 1, np.int64)
    for p in range(pi.shape[0]):
        if use[p]:
            count[max(pi[p], pj[p]) + 1] += 1
    for k in range(n):
        count[k + 1] += count[k]
    fill = count[:-1].copy()
    col = np.empty(count[n], np.int64)
    who = np.empty(count[n], np.int64)
    for p in range(pi.shape[0]):
        if use[p]:
            r = max(pi[p], pj[p])
            col[fill[r]] = min(pi[p], pj[p])
            who[fill[r]] = p
            fill[r] += 1
    Ap = np.zeros(n + 1, np.int64)
    Ai = np.empty(count[n], np.int64)
    pair_q = -np.ones(pi.shape[0], np.int64)
    t = 0
    for k in range(n):
        seg = np.argsort(col[count[k] : count[k + 1]], kind="mergesort") + count[k]
        last = -1
        for s in seg:
            if col[s] != last:
                Ai[t] = col[s]
                last = col[s]
                t += 1
            pair_q[who[s]] = t - 1
        Ap[k + 1] = t
    return Ap, Ai[:t].copy(), pair_q


@njit(cache=True)
def _row_of_L(Ap, Ai, k, parent, mark, out):
    """The columns of row k of L below the diagonal, increasing, into ``out``; their count.
    ``mark`` (n,) holds k for the columns visited (the paths up the elimination tree from A's
    entries of row k, as CSparse's ``cs_ereach``)."""
    length = 0
    mark[k] = k
    for q in range(Ap[k], Ap[k + 1]):
        i = Ai[q]
        while mark[i] != k:
            out[length] = i
            length += 1
            mark[i] = k
            i = parent[i]
    out[:length].sort()
    return length


@njit(cache=True)
def _symbolic(n, Ap, Ai):
    """L's block structure: by columns ``(Lp, Li)`` and by rows ``(Rp, Rc, Rq)``."""
    parent = elimination_tree(Ap, Ai)
    mark = np.full(n, -1, np.int64)
    row = np.empty(n, np.int64)
    count = np.zeros(n, np.int64)
    Rp = np.zeros(n + 1, np.int64)
    for k in range(n):
        length = _row_of_L(Ap, Ai, k, parent, mark, row)
        for t in range(length):
            count[row[t]] += 1
        Rp[k + 1] = Rp[k] + length
    Lp = np.zeros(n + 1, np.int64)
    for k in range(n):
        Lp[k + 1] = Lp[k] + count[k]
    nxt = Lp[:-1].copy()
    Li = np.empty(Lp[n], np.int64)
    Rc = np.empty(Rp[n], np.int64)
    Rq = np.empty(Rp[n], np.int64)
    mark[:] = -1
    for k in range(n):
        length = _row_of_L(Ap, Ai, k, parent, mark, row)
        for t in range(length):
            i = row[t]
            Li[nxt[i]] = k
            Rc[Rp[k] + t] = i
            Rq[Rp[k] + t] = nxt[i]
            nxt[i] += 1
    return Lp, Li, Rp, Rc, Rq


def _flop_count(Lp, Rp, Rc, Rq, d):
    """Multiplications and additions of one numeric factorisation: per block of L, a d x d
    product for each earlier block of its column, one for L = Y D^-1 and one for D's update;
    a d x d inverse per block (~d^3)."""
    earlier = (Rq - Lp[Rc]).sum() if Rc.size else 0
    n = Lp.shape[0] - 1
    return int(2 * d**3 * (earlier + 2 * Rc.size) + d**3 * n)


def _shifts(pattern, shift):
    """The per-unknown diagonal shift (n_blocks, d) of ``shift``: None, a scalar, (n_blocks,)
    per block or (n_blocks, d) / (n_blocks d,) per unknown."""
    out = np.zeros((pattern.n_blocks, pattern.d))
    if shift is None:
        return out
    s = np.asarray(shift, dtype=np.float64)
    if s.ndim == 1 and s.shape[0] == pattern.n_blocks:
        s = s[:, None]
    out += s.reshape(out.shape) if s.size == out.size else s
    return out


def factorise(pattern: BlockPattern, values: np.ndarray, factor: BlockFactor, shift=None):
    """A + diag(shift) = L D L^T into ``factor`` (:meth:`BlockPattern.new_factor`), A the
    ``values`` (n_values, d, d) on ``pattern``: ``(ok, inertia)``, also set on the factor.

    ``shift``: see :func:`_shifts` (added to the diagonal; ``values`` stay as they are)."""
    p = pattern
    factor.values[:] = values
    factor.shift[:] = _shifts(p, shift)
    ok, pos, neg, zero = numeric_factorisation(
        p.dims, p.n, p.perm, p.Ap, p.Ai, factor.values, factor.shift, p.Lp, p.Li, p.Rp, p.Rc,
        p.Rq, factor.Lx, factor.D, factor.Dinv, factor.y,
    )  # fmt: skip
    factor.ok, factor.inertia = bool(ok), (int(pos), int(neg), int(zero))
    return factor.ok, factor.inertia


@njit(cache=True)
def numeric_factorisation(dims, n, perm, Ap, Ai, values, shift, Lp, Li, Rp, Rc, Rq, Lx, D, Dinv, y):
    """Up-looking block LDL^T: row k of L from the rows before it, Y_i = L_ki D_i solved for
    in increasing i (a topological order of the elimination tree). Returns
    ``(ok, positive, negative, zero)``. ``dims`` (d,) any tuple of the block size: its
    length is a constant of the compiled code (the d x d loops unrolled), one kernel per d;
    d = 2 (a disk) has its own kernel in scalars (a fifth faster)."""
    d = len(dims)
    if d == 2:
        return _numeric_2(n, perm, Ap, Ai, values, shift, Lp, Li, Rp, Rc, Rq, Lx, D, Dinv, y)
    Dk = np.empty((d, d))
    Yi = np.empty((d, d))
    pos = neg = zero = 0
    for k in range(n):
        for q in range(Ap[k], Ap[k + 1]):
            y[Ai[q]] = values[n + q]
        for a in range(d):
            for b in range(d):
                Dk[a, b] = values[k, a, b]
            Dk[a, a] += shift[perm[k], a]
        for t in range(Rp[k], Rp[k + 1]):
            _row_block(Lp, Li, Lx, Dinv, y, Yi, Dk, Rc[t], Rq[t], dims)
        D[k] = Dk
        good, p, m, z = _invert(Dk, Dinv[k], dims)
        pos, neg, zero = pos + p, neg + m, zero + z
        if not good:
            return False, pos, neg, zero
    return True, pos, neg, zero


@njit(cache=True)
def _numeric_2(n, perm, Ap, Ai, values, shift, Lp, Li, Rp, Rc, Rq, Lx, D, Dinv, y):
    """:func:`numeric_factorisation` for 2 x 2 blocks, every block entry a scalar."""
    pos = neg = zero = 0
    for k in range(n):
        for q in range(Ap[k], Ap[k + 1]):
            i = Ai[q]
            y[i, 0, 0], y[i, 0, 1] = values[n + q, 0, 0], values[n + q, 0, 1]
            y[i, 1, 0], y[i, 1, 1] = values[n + q, 1, 0], values[n + q, 1, 1]
        b = perm[k]
        d00, d01 = values[k, 0, 0] + shift[b, 0], values[k, 0, 1]
        d10, d11 = values[k, 1, 0], values[k, 1, 1] + shift[b, 1]
        for t in range(Rp[k], Rp[k + 1]):
            i, at = Rc[t], Rq[t]
            y00, y01, y10, y11 = y[i, 0, 0], y[i, 0, 1], y[i, 1, 0], y[i, 1, 1]
            y[i, 0, 0] = y[i, 0, 1] = y[i, 1, 0] = y[i, 1, 1] = 0.0
            for q in range(Lp[i], at):  # y[r] -= Y_i L_ri^T for the rows r before k
                r = Li[q]
                l00, l01, l10, l11 = Lx[q, 0, 0], Lx[q, 0, 1], Lx[q, 1, 0], Lx[q, 1, 1]
                y[r, 0, 0] -= y00 * l00 + y01 * l01
                y[r, 0, 1] -= y00 * l10 + y01 * l11
                y[r, 1, 0] -= y10 * l00 + y11 * l01
                y[r, 1, 1] -= y10 * l10 + y11 * l11
            e00, e01, e10, e11 = Dinv[i, 0, 0], Dinv[i, 0, 1], Dinv[i, 1, 0], Dinv[i, 1, 1]
            a00, a01 = y00 * e00 + y01 * e10, y00 * e01 + y01 * e11  # L_ki = Y_i D_i^-1
            a10, a11 = y10 * e00 + y11 * e10, y10 * e01 + y11 * e11
            Lx[at, 0, 0], Lx[at, 0, 1], Lx[at, 1, 0], Lx[at, 1, 1] = a00, a01, a10, a11
            d00 -= a00 * y00 + a01 * y01  # D_k -= L_ki Y_i^T
            d01 -= a00 * y10 + a01 * y11
            d10 -= a10 * y00 + a11 * y01
            d11 -= a10 * y10 + a11 * y11
        D[k, 0, 0], D[k, 0, 1], D[k, 1, 0], D[k, 1, 1] = d00, d01, d10, d11
        good, p, m, z = _invert(D[k], Dinv[k], (0, 1))
        pos, neg, zero = pos + p, neg + m, zero + z
        if not good:
            return False, pos, neg, zero
    return True, pos, neg, zero


@njit(cache=True, inline="always")
def _row_block(Lp, Li, Lx, Dinv, y, Yi, Dk, i, at, dims):
    """L_ki (at position ``at`` of L) from Y_i = y[i]: y[r] -= Y_i L_ri^T for the blocks of
    column i in rows r before k, L_ki = Y_i D_i^-1, D_k -= L_ki Y_i^T; y[i] zeroed."""
    d = len(dims)
    for a in range(d):
        for b in range(d):
            Yi[a, b] = y[i, a, b]
            y[i, a, b] = 0.0
    if d == 2:  # (a constant: the other branch is compiled out) as scalars
        y00, y01, y10, y11 = Yi[0, 0], Yi[0, 1], Yi[1, 0], Yi[1, 1]
        for q in range(Lp[i], at):
            r = Li[q]
            l00, l01, l10, l11 = Lx[q, 0, 0], Lx[q, 0, 1], Lx[q, 1, 0], Lx[q, 1, 1]
            y[r, 0, 0] -= y00 * l00 + y01 * l01
            y[r, 0, 1] -= y00 * l10 + y01 * l11
            y[r, 1, 0] -= y10 * l00 + y11 * l01
            y[r, 1, 1] -= y10 * l10 + y11 * l11
        _last_block(Lx, Dinv, Yi, Dk, i, at, d)
        return
    for q in range(Lp[i], at):  # the blocks of column i in rows before k
        r = Li[q]
        for a in range(d):
            for b in range(d):
                s = 0.0
                for c in range(d):
                    s += Yi[a, c] * Lx[q, b, c]
                y[r, a, b] -= s
    _last_block(Lx, Dinv, Yi, Dk, i, at, d)


@njit(cache=True, inline="always")
def _last_block(Lx, Dinv, Yi, Dk, i, at, d):
    """L_ki = Y_i D_i^-1 at L's position ``at``, D_k -= L_ki Y_i^T."""
    for a in range(d):
        for b in range(d):
            s = 0.0
            for c in range(d):
                s += Yi[a, c] * Dinv[i, c, b]
            Lx[at, a, b] = s
    for a in range(d):
        for b in range(d):
            s = 0.0
            for c in range(d):
                s += Lx[at, a, c] * Yi[b, c]
            Dk[a, b] -= s


@njit(cache=True)
def _invert(M, out, dims):
    """out = M^-1 of a symmetric d x d block (d <= 3) by its adjugate, and M's inertia:
    ``(ok, positive, negative, zero)``; ok False (out undefined) where M is singular or not
    finite. The inertia is the sign pattern of the characteristic polynomial's coefficients
    (Descartes' rule of signs, exact for a polynomial with real roots)."""
    d = len(dims)
    if d == 1:
        det, c1, c2 = M[0, 0], M[0, 0], 0.0
        if det != 0.0:
            out[0, 0] = 1.0 / det
    elif d == 2:
        det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
        c1, c2 = M[0, 0] + M[1, 1], det
        out[0, 0], out[0, 1] = M[1, 1], -M[0, 1]
        out[1, 0], out[1, 1] = -M[1, 0], M[0, 0]
    else:
        det = adjugate3(M, out)
        c1 = M[0, 0] + M[1, 1] + M[2, 2]
        c2 = out[0, 0] + out[1, 1] + out[2, 2]  # the principal 2 x 2 minors
    # det(lam I - M) = lam^d - c1 lam^(d-1) + c2 lam^(d-2) - c3 ..., c_d = det
    pos = _sign_changes(c1, c2, det, d, True)
    neg = _sign_changes(c1, c2, det, d, False)
    if not (np.isfinite(det) and np.isfinite(c1) and np.isfinite(c2)) or det == 0.0:
        return False, pos, neg, d - pos - neg
    if d > 1:
        for a in range(d):
            for b in range(d):
                out[a, b] /= det
    return True, pos, neg, d - pos - neg


@njit(cache=True)
def adjugate3(M, out):
    """out = the adjugate of a 3 x 3 block M (M^-1 det M); returns det M."""
    for a in range(3):
        for b in range(3):
            a1, a2 = (b + 1) % 3, (b + 2) % 3
            b1, b2 = (a + 1) % 3, (a + 2) % 3
            out[a, b] = M[a1, b1] * M[a2, b2] - M[a1, b2] * M[a2, b1]
    return M[0, 0] * out[0, 0] + M[0, 1] * out[1, 0] + M[0, 2] * out[2, 0]


@njit(cache=True)
def _sign_changes(c1, c2, c3, d, alternate):
    """Sign changes of (1, c1, c2, c3)[: d + 1], of (1, -c1, c2, -c3) with ``alternate``
    (positive roots), zeros skipped."""
    last, changes = 1.0, 0
    for m in range(1, d + 1):
        c = c1 if m == 1 else (c2 if m == 2 else c3)
        if alternate and m % 2 == 1:
            c = -c
        if c == 0.0:
            continue
        if (c > 0.0) != (last > 0.0):
            changes += 1
        last = c
    return changes


def solve(pattern: BlockPattern, factor: BlockFactor, b: np.ndarray, refine: int = 0):
    """x = (A + diag(shift))^-1 b on a factorisation (:func:`factorise`), the pinned block's
    unknowns zero (its entries of b ignored).

    Args:
        b: (n_blocks d,), (n_blocks d, k), (n_blocks, d) or (n_blocks, d, k), unknowns of block
            i at rows d i ... d i + d - 1. refine: steps of iterative refinement (residual in
            double precision against the factorised values).

    Returns:
        x in b's shape.
    """
    if not factor.ok:
        raise ValueError("the factorisation failed (a singular or non-finite D block)")
    p = pattern
    B = np.ascontiguousarray(np.asarray(b, dtype=np.float64).reshape(p.n_blocks, p.d, -1))
    x = np.zeros_like(B)
    substitute(p.dims, p.n, p.perm, p.Lp, p.Li, factor.Lx, factor.Dinv, B, x)
    for _ in range(refine):
        r = B - _matvec(p.dims, p.n, p.perm, p.Ap, p.Ai, factor.values, factor.shift, x)
        dx = np.zeros_like(B)
        substitute(p.dims, p.n, p.perm, p.Lp, p.Li, factor.Lx, factor.Dinv, r, dx)
        x += dx
    return x.reshape(np.shape(b))


@njit(cache=True)
def substitute(dims, n, perm, Lp, Li, Lx, Dinv, b, x):
    """x[perm] = L^-T D^-1 L^-1 b[perm] for b, x (n_blocks, d, k), d = len(dims), one
    right-hand side after the other (d = 2 in scalars: a third faster)."""
    d = len(dims)
    if d == 2:
        _substitute_2(n, perm, Lp, Li, Lx, Dinv, b, x)
        return
    z = np.empty((n, d))
    t = np.empty(d)
    for c in range(b.shape[2]):
        for r in range(n):
            for a in range(d):
                z[r, a] = b[perm[r], a, c]
        for j in range(n):  # L z = b
            for q in range(Lp[j], Lp[j + 1]):
                r = Li[q]
                for a in range(d):
                    s = 0.0
                    for e in range(d):
                        s += Lx[q, a, e] * z[j, e]
                    z[r, a] -= s
        for j in range(n):  # D z = z
            for a in range(d):
                s = 0.0
                for e in range(d):
                    s += Dinv[j, a, e] * z[j, e]
                t[a] = s
            for a in range(d):
                z[j, a] = t[a]
        for j in range(n - 1, -1, -1):  # L^T z = z
            for q in range(Lp[j], Lp[j + 1]):
                r = Li[q]
                for a in range(d):
                    s = 0.0
                    for e in range(d):
                        s += Lx[q, e, a] * z[r, e]
                    z[j, a] -= s
        for r in range(n):
            for a in range(d):
                x[perm[r], a, c] = z[r, a]


@njit(cache=True)
def _substitute_2(n, perm, Lp, Li, Lx, Dinv, b, x):
    """:func:`substitute` for 2 x 2 blocks (the same operations in the same order)."""
    z = np.empty((n, 2))
    for c in range(b.shape[2]):
        for r in range(n):
            z[r, 0], z[r, 1] = b[perm[r], 0, c], b[perm[r], 1, c]
        for j in range(n):  # L z = b
            z0, z1 = z[j, 0], z[j, 1]
            for q in range(Lp[j], Lp[j + 1]):
                r = Li[q]
                z[r, 0] -= Lx[q, 0, 0] * z0 + Lx[q, 0, 1] * z1
                z[r, 1] -= Lx[q, 1, 0] * z0 + Lx[q, 1, 1] * z1
        for j in range(n):  # D z = z
            z0, z1 = z[j, 0], z[j, 1]
            z[j, 0] = Dinv[j, 0, 0] * z0 + Dinv[j, 0, 1] * z1
            z[j, 1] = Dinv[j, 1, 0] * z0 + Dinv[j, 1, 1] * z1
        for j in range(n - 1, -1, -1):  # L^T z = z
            s0, s1 = z[j, 0], z[j, 1]
            for q in range(Lp[j], Lp[j + 1]):
                r = Li[q]
                s0 -= Lx[q, 0, 0] * z[r, 0] + Lx[q, 1, 0] * z[r, 1]
                s1 -= Lx[q, 0, 1] * z[r, 0] + Lx[q, 1, 1] * z[r, 1]
            z[j, 0], z[j, 1] = s0, s1
        for r in range(n):
            x[perm[r], 0, c], x[perm[r], 1, c] = z[r, 0], z[r, 1]


@njit(cache=True)
def _matvec(dims, n, perm, Ap, Ai, values, shift, x):
    """(A + diag(shift)) x for x (n_blocks, d, k) (zero rows at the pinned block), d =
    len(dims)."""
    d = len(dims)
    out = np.zeros_like(x)
    k = x.shape[2]
    for r in range(n):
        br = perm[r]
        for a in range(d):
            for c in range(k):
                s = shift[br, a] * x[br, a, c]
                for e in range(d):
                    s += values[r, a, e] * x[br, e, c]
                out[br, a, c] += s
        for q in range(Ap[r], Ap[r + 1]):
            bi = perm[Ai[q]]
            V = values[n + q]
            for a in range(d):
                for c in range(k):
                    s = 0.0
                    u = 0.0
                    for e in range(d):
                        s += V[a, e] * x[bi, e, c]
                        u += V[e, a] * x[br, e, c]
                    out[br, a, c] += s
                    out[bi, a, c] += u
    return out


def _triplets(pattern, values, shift):
    """COO ``(rows, cols, vals)`` of the full symmetric matrix of ``values`` + ``shift``."""
    p, d = pattern, pattern.d
    rows, cols, vals = [], [], []
    a, b = np.meshgrid(np.arange(d), np.arange(d), indexing="ij")
    for k in range(p.n):
        blk = values[k] + np.diag(shift[p.perm[k]])
        rows.append(d * p.perm[k] + a), cols.append(d * p.perm[k] + b), vals.append(blk)
    for k in range(p.n):
        for q in range(p.Ap[k], p.Ap[k + 1]):
            r, c, V = p.perm[k], p.perm[p.Ai[q]], values[p.n + q]
            rows += [d * r + a, d * c + a]
            cols += [d * c + b, d * r + b]
            vals += [V, V.T]
    if not rows:
        return np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0)
    return (np.concatenate([x.ravel() for x in rows]),
            np.concatenate([x.ravel() for x in cols]),
            np.concatenate([x.ravel() for x in vals]))  # fmt: skip
