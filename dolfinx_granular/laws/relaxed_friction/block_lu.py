"""A sparse non-symmetric factorisation A = L D U in 3 x 3 blocks, in Numba (no BLAS), without
pivoting between blocks.

The frictional relaxed cell's Jacobian couples a disk's three unknowns (w, theta) with those of
its contact partners, both ways: it is structurally symmetric, though not symmetric where
contacts slip. So it shares the symbolic part of the symmetric factorisation
(:func:`~dolfinx_granular.laws.relaxed.block_ldlt.analyse`: the fill-reducing order of the disks,
the elimination tree, L's block structure), and U^T has L's pattern. The values hold the
diagonal blocks, A's strict lower triangle in the elimination order, and the mirror image of
each of those blocks above the diagonal.

* :func:`assemble` adds the contacts' 6 x 6 Jacobians into the blocks (held unknowns out, a
  diagonal added).
* :func:`factorise` is up-looking, as CSparse's ``cs_chol``: row k of L and column k of U from
  two block triangular solves along the same reach, D_k inverted explicitly (its adjugate). It
  fails where a D block is singular (relative to its size), as the Jacobian without pivoting
  may be where slip makes it indefinite: the caller then takes a pivoting LU.
* :meth:`BlockLU.solve` substitutes, with iterative refinement where the first solution's
  residual is large.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.sparse import coo_matrix

from ..relaxed.block_ldlt import BlockPattern, adjugate3

#: a D block counts as singular where |det| < SINGULAR * the product of its rows' norms (the
#: Hadamard bound of |det|: the test holds whatever the units of the rows, forces or moments)
SINGULAR = 1e-13
#: solutions are refined while their residual exceeds this part of |b|, at most REFINE times
REFINED, REFINE = 1e-10, 2


@dataclass(eq=False)
class BlockLU:
    """A numeric factorisation A = L D U on a 3 x 3 :class:`BlockPattern` (pinned: none).

    Attributes:
        values: (n + 2 nnz_A, 3, 3) A's blocks: the diagonal (position k), the strict lower
            triangle (n + q for the pattern's Ai[q]: A[k, Ai[q]]), the upper (n + nnz_A + q:
            A[Ai[q], k]). Lx, Ux: (nnz_L, 3, 3) L's blocks and U's (U[i, Li[q]] at L's position
            q of column i). Dinv: (n, 3, 3). ok: every D block invertible. residual: the
            relative residual of the last :meth:`solve`.
    """

    pattern: BlockPattern
    values: np.ndarray
    Lx: np.ndarray
    Ux: np.ndarray
    Dinv: np.ndarray
    ok: bool = False
    residual: float = 0.0

    @classmethod
    def on(cls, pattern: BlockPattern) -> BlockLU:
        """Zeroed values and preallocated factors on ``pattern`` (3 x 3 blocks, none pinned)."""
        if pattern.d != 3 or pattern.pinned >= 0:
            raise ValueError("the block LU takes 3 x 3 blocks with no block left out")
        nA, nL, n = pattern.Ai.shape[0], pattern.nnz_L, pattern.n
        return cls(
            pattern, np.zeros((n + 2 * nA, 3, 3)), np.empty((nL, 3, 3)),
            np.empty((nL, 3, 3)), np.empty((n, 3, 3)),
        )  # fmt: skip

    def arrays(self) -> tuple:
        """``(values, Lx, Ux, Dinv)`` as the compiled Newton loop takes them."""
        return self.values, self.Lx, self.Ux, self.Dinv

    def to_csc(self):
        """The assembled matrix (3 n_blocks, 3 n_blocks) of :attr:`values` as scipy CSC (for
        a pivoting LU where a block pivot is singular, and for tests)."""
        p = self.pattern
        row_of = np.repeat(np.arange(p.n), np.diff(p.Ap))  # (the position of each q's row)
        rows = p.perm[np.concatenate([np.arange(p.n), row_of, p.Ai])]
        cols = p.perm[np.concatenate([np.arange(p.n), p.Ai, row_of])]
        a, b = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
        N = 3 * p.n_blocks
        return coo_matrix(
            (self.values.ravel(), ((3 * rows[:, None, None] + a).ravel(),
                                   (3 * cols[:, None, None] + b).ravel())),
            shape=(N, N),
        ).tocsc()  # fmt: skip

    def factorise(self) -> bool:
        """L D U of :attr:`values`; False where a D block is singular."""
        p = self.pattern
        self.ok = bool(
            numeric(
                p.n,
                p.Ap,
                p.Ai,
                self.values,
                p.Lp,
                p.Li,
                p.Rp,
                p.Rc,
                p.Rq,
                self.Lx,
                self.Ux,
                self.Dinv,
            )  # fmt: skip
        )
        return self.ok

    def solve(self, b: np.ndarray) -> np.ndarray:
        """x = A^-1 b for b (3 n_blocks,) or (3 n_blocks, k), refined (:data:`REFINED`); sets
        :attr:`residual` (the largest over the columns of |b - A x| / |b|)."""
        if not self.ok:
            raise ValueError("the factorisation failed (a singular D block)")
        p = self.pattern
        B = np.ascontiguousarray(np.asarray(b, dtype=np.float64).reshape(p.n_blocks, 3, -1))
        x = np.zeros_like(B)
        self.residual = refined_solve(
            p.n, p.perm, p.Ap, p.Ai, p.Lp, p.Li, self.values, self.Lx, self.Ux, self.Dinv, B, x
        )
        return x.reshape(np.shape(b))


@njit(cache=True)
def refined_solve(n, perm, Ap, Ai, Lp, Li, values, Lx, Ux, Dinv, b, x):
    """x = A^-1 b (b, x (n_blocks, 3, k)) by substitution and up to :data:`REFINE` steps of
    iterative refinement while the residual exceeds :data:`REFINED` of |b| (per column);
    returns the largest relative residual."""
    scale = np.empty(b.shape[2])
    for c in range(b.shape[2]):
        scale[c] = np.sqrt((b[:, :, c] ** 2).sum())
        if scale[c] == 0.0:
            scale[c] = 1.0
    substitute(n, perm, Lp, Li, Lx, Ux, Dinv, b, x)
    worst = 0.0
    for k in range(REFINE + 1):
        r = b - matvec(n, perm, Ap, Ai, values, x)
        worst = 0.0
        for c in range(b.shape[2]):
            worst = max(worst, np.sqrt((r[:, :, c] ** 2).sum()) / scale[c])
        if worst <= REFINED or k == REFINE:
            break
        dx = np.zeros_like(b)
        substitute(n, perm, Lp, Li, Lx, Ux, Dinv, r, dx)
        x += dx
    return worst


def flops(pattern: BlockPattern) -> int:
    """Multiplications and additions of one numeric factorisation: per block of L, two 3 x 3
    products for each earlier block of its column (L's and U's), three for L_ki, U_ik and D's
    update; a 3 x 3 inverse per block."""
    p = pattern
    earlier = (p.Rq - p.Lp[p.Rc]).sum() if p.Rc.size else 0
    return int(2 * 27 * (2 * earlier + 3 * p.Rc.size) + 2 * 27 * p.n)


@njit(cache=True)
def assemble(n, diag_slot, pair_slot, pair_flip, pi, pj, contacts, K, held, diag, values):
    """values (zeroed here) = the contacts' Jacobians K (k, 6, 6) (rows and columns (w_i,
    theta_i, w_j, theta_j) of contact ``contacts[t]`` between disks pi, pj) without the rows
    and columns of the ``held`` (3N,) unknowns, plus ``diag`` (3N,) on the diagonal."""
    values[:] = 0.0
    nA = (values.shape[0] - n) // 2
    for t in range(contacts.shape[0]):
        c = contacts[t]
        i, j = pi[c], pj[c]
        for bu in range(2):
            for bv in range(2):
                a, b = (i, j)[bu], (i, j)[bv]
                if a == b:
                    slot = diag_slot[a]
                elif (bu == 0) != pair_flip[c]:  # (i, j) unflipped or (j, i) flipped: lower
                    slot = pair_slot[c]
                else:
                    slot = pair_slot[c] + nA
                for u in range(3):
                    if held[3 * a + u]:
                        continue
                    for v in range(3):
                        if not held[3 * b + v]:
                            values[slot, u, v] += K[t, 3 * bu + u, 3 * bv + v]
    for b in range(diag_slot.shape[0]):
        for u in range(3):
            values[diag_slot[b], u, u] += diag[3 * b + u]


@njit(cache=True)
def numeric(n, Ap, Ai, values, Lp, Li, Rp, Rc, Rq, Lx, Ux, Dinv):
    """Up-looking block L D U: for row k, Y_i = L_ki D_i and Z_i = D_i U_ik by two triangular
    solves along the reach of row k (increasing i, a topological order of the elimination
    tree); D_k = A_kk - sum L_ki Z_i. False where a D block is singular. The blocks travel as
    9-tuples (:func:`_load`), which Numba keeps in registers: 2.3 times the speed of loops
    over the blocks' entries, the same operations in the same order."""
    nA = Ai.shape[0]
    y = np.zeros((n, 9))
    z = np.zeros((n, 9))
    Dk = np.empty((1, 9))
    L, U, D, V = Lx.reshape(-1, 9), Ux.reshape(-1, 9), Dinv.reshape(-1, 9), values.reshape(-1, 9)
    for k in range(n):
        for q in range(Ap[k], Ap[k + 1]):
            y[Ai[q]] = V[n + q]
            z[Ai[q]] = V[n + nA + q]
        Dk[0] = V[k]
        for t in range(Rp[k], Rp[k + 1]):
            i, at = Rc[t], Rq[t]
            Yi, Zi = _load(y, i), _load(z, i)
            y[i] = 0.0
            z[i] = 0.0
            for q in range(Lp[i], at):  # the rows r < k of column i
                _subtract(y, Li[q], _product(Yi, _load(U, q)))
                _subtract(z, Li[q], _product(_load(L, q), Zi))
            Di = _load(D, i)
            Lki = _product(Yi, Di)
            _store(L, at, Lki)
            _store(U, at, _product(Di, Zi))
            _subtract(Dk, 0, _product(Lki, Zi))
        if not invert3(Dk.reshape(3, 3), Dinv[k]):
            return False
    return True


@njit(cache=True, inline="always")
def _load(a, k):
    """Row k of a (n, 9), a 3 x 3 block row-major, as a 9-tuple."""
    return (a[k, 0], a[k, 1], a[k, 2], a[k, 3], a[k, 4], a[k, 5], a[k, 6], a[k, 7], a[k, 8])


@njit(cache=True, inline="always")
def _store(a, k, t):
    """Row k of a (n, 9) = the 9-tuple t."""
    a[k, 0], a[k, 1], a[k, 2], a[k, 3], a[k, 4] = t[0], t[1], t[2], t[3], t[4]
    a[k, 5], a[k, 6], a[k, 7], a[k, 8] = t[5], t[6], t[7], t[8]


@njit(cache=True, inline="always")
def _subtract(a, k, t):
    """Row k of a (n, 9) -= the 9-tuple t."""
    for s in range(9):
        a[k, s] -= t[s]


@njit(cache=True, inline="always")
def _product(a, b):
    """a b of two 3 x 3 blocks as 9-tuples."""
    return (
        a[0] * b[0] + a[1] * b[3] + a[2] * b[6], a[0] * b[1] + a[1] * b[4] + a[2] * b[7],
        a[0] * b[2] + a[1] * b[5] + a[2] * b[8], a[3] * b[0] + a[4] * b[3] + a[5] * b[6],
        a[3] * b[1] + a[4] * b[4] + a[5] * b[7], a[3] * b[2] + a[4] * b[5] + a[5] * b[8],
        a[6] * b[0] + a[7] * b[3] + a[8] * b[6], a[6] * b[1] + a[7] * b[4] + a[8] * b[7],
        a[6] * b[2] + a[7] * b[5] + a[8] * b[8],
    )  # fmt: skip


@njit(cache=True)
def invert3(M, out):
    """out = M^-1 of a 3 x 3 block by its adjugate; False where M is singular relative to its
    rows (:data:`SINGULAR`) or not finite."""
    det = adjugate3(M, out)
    bound = 1.0
    for a in range(3):
        bound *= np.sqrt(M[a, 0] ** 2 + M[a, 1] ** 2 + M[a, 2] ** 2)
    if not np.isfinite(det) or abs(det) <= SINGULAR * bound:
        return False
    for a in range(3):
        for b in range(3):
            out[a, b] /= det
    return True


@njit(cache=True)
def substitute(n, perm, Lp, Li, Lx, Ux, Dinv, b, x):
    """x[perm] = U^-1 D^-1 L^-1 b[perm] for b, x (n_blocks, 3, k), one column after another."""
    z = np.empty((n, 3))
    t = np.empty(3)
    for col in range(b.shape[2]):
        for r in range(n):
            for a in range(3):
                z[r, a] = b[perm[r], a, col]
        for j in range(n):  # L z = b
            for q in range(Lp[j], Lp[j + 1]):
                r = Li[q]
                for a in range(3):
                    z[r, a] -= Lx[q, a, 0] * z[j, 0] + Lx[q, a, 1] * z[j, 1] + Lx[q, a, 2] * z[j, 2]
        for j in range(n):  # D z = z
            for a in range(3):
                t[a] = Dinv[j, a, 0] * z[j, 0] + Dinv[j, a, 1] * z[j, 1] + Dinv[j, a, 2] * z[j, 2]
            z[j] = t
        for j in range(n - 1, -1, -1):  # U z = z
            for q in range(Lp[j], Lp[j + 1]):
                r = Li[q]
                for a in range(3):
                    z[j, a] -= Ux[q, a, 0] * z[r, 0] + Ux[q, a, 1] * z[r, 1] + Ux[q, a, 2] * z[r, 2]
        for r in range(n):
            for a in range(3):
                x[perm[r], a, col] = z[r, a]


@njit(cache=True)
def matvec(n, perm, Ap, Ai, values, x):
    """A x for x (n_blocks, 3, k) on the block values."""
    nA = Ai.shape[0]
    out = np.zeros_like(x)
    for k in range(n):
        bk = perm[k]
        _add_product(values[k], x, bk, bk, out)
        for q in range(Ap[k], Ap[k + 1]):
            bi = perm[Ai[q]]
            _add_product(values[n + q], x, bk, bi, out)
            _add_product(values[n + nA + q], x, bi, bk, out)
    return out


@njit(cache=True, inline="always")
def _add_product(V, x, row, col, out):
    """out[row] += V x[col] (3 x 3 times (3, k))."""
    for a in range(3):
        for c in range(x.shape[2]):
            s = V[a, 0] * x[col, 0, c] + V[a, 1] * x[col, 1, c] + V[a, 2] * x[col, 2, c]
            out[row, a, c] += s
