"""The block LDL^T factorisation (laws/relaxed/block_ldlt.py) against SuperLU and dense
eigenvalues, on the stiffness the relaxed RVE's micro solver assembles at a relaxed state of real
packings (against an assembly in numpy, contact by contact), and on synthetic 3 x 3 block
matrices; the shift bound of the Newton loop against dense eigenvalues; the condensed tangent
against a dense condensation."""

from dolfinx_granular import generate_packing
from dolfinx_granular.laws.relaxed import RelaxedRVE, at_rest, block_ldlt, newton, relax
from dolfinx_granular.laws.relaxed.assembly import assemble, mixed
from dolfinx_granular.laws.relaxed.contact_state import ContactState
from dolfinx_granular.laws.relaxed.tangent import _affine
from dolfinx_granular.packings.reference_packing import reference_packing

import numpy as np
import pytest
from scipy.sparse import coo_matrix, diags
from scipy.sparse.linalg import splu, spsolve

K_N = 2.8e7
F0 = np.diag([0.995, 0.995])
F1 = np.array([[0.994, 0.002], [0.001, 0.996]])


class Relaxed:
    """A relaxed cell at F, its contact state, and the block pattern of its candidates with
    the first non-rattler pinned (as the micro solver pins it)."""

    def __init__(self, packing, F):
        self.rve = RelaxedRVE(packing, K_N)
        _, _, _, state = self.rve.evaluate(F[None], self.rve.initial_state(1))
        self.cell, self.F, self.w = self.rve.cell, F, state.w[0]
        self.s = ContactState(self.cell, F, self.w)
        self.pinned = int(np.argmax(self.s.keep))
        self.pattern = block_ldlt.analyse(
            self.cell.n_disks, np.c_[self.cell.pi, self.cell.pj], pinned=self.pinned
        )
        self.dof = np.arange(self.cell.n_disks, dtype=np.int64)
        self.dof[self.pinned + 1 :] -= 1
        self.dof[self.pinned] = -1
        self.n = 2 * (self.cell.n_disks - 1)

    def values(self, exact, F=None, s=None):
        """The stiffness over the contacts on (``exact`` the exact ones) in block values."""
        F, s, c = (self.F if F is None else F), (self.s if s is None else s), self.cell
        v = self.pattern.zeros()
        assemble(
            F, c.pi[: s.m], c.pj[: s.m], s.lx, s.ly, s.d, s.e, c.R[: s.m], c.K, s.on, exact,
            self.pattern.diag_slot, self.pattern.pair_slot, v,
        )  # fmt: skip
        return v

    def superlu_matrix(self, exact, F=None, s=None):
        """The same stiffness assembled in numpy, contact by contact (CSC on the unknowns
        without the pinned disk)."""
        F, s = (self.F if F is None else F), (self.s if s is None else s)
        return stiffness_matrix(self.cell, F, s, s.on, exact, self.dof, self.n)

    def gather(self, g):
        """g (N, 2) on the unknowns without the pinned disk, (n,)."""
        k = self.dof >= 0
        v = np.zeros(self.n)
        v[2 * self.dof[k]], v[2 * self.dof[k] + 1] = g[k, 0], g[k, 1]
        return v

    def scatter(self, v):
        """v (n, ...) on the unknowns as (N, 2, ...), zero at the pinned disk."""
        k = self.dof >= 0
        x = np.zeros((self.cell.n_disks, 2) + v.shape[1:])
        x[k, 0], x[k, 1] = v[2 * self.dof[k]], v[2 * self.dof[k] + 1]
        return x

    def rattler_shift(self, scale=1e-8):
        shift = np.zeros(self.cell.n_disks)
        shift[~self.s.keep] = scale * self.cell.K
        return shift


def stiffness_matrix(cell, F, s, use, exact, dof, n):
    """d2W/dw2 over the contacts ``use`` on the unknowns ``dof`` (N,) (-1: fixed), CSC (n, n),
    in numpy from the contact Hessian H_c = K [(R/d) n n^T - (e/d) I] (its positive part
    K n n^T where not ``exact``): +F^T H_c F on the blocks (i, i), (j, j), minus on (i, j)."""
    c = np.flatnonzero(use & (cell.pi[: s.m] != cell.pj[: s.m]))
    nrm = np.stack([s.lx[c], s.ly[c]], axis=1) / s.d[c, None]
    a = np.where(exact[c], cell.K * cell.R[c] / s.d[c], cell.K)
    b = np.where(exact[c], cell.K * s.e[c] / s.d[c], 0.0)
    H = a[:, None, None] * nrm[:, :, None] * nrm[:, None, :] - b[:, None, None] * np.eye(2)
    k = np.einsum("ba,cbd,de->cae", F, H, F)
    rows, cols, vals = [], [], []
    for p, q, sign in ((0, 0, 1), (1, 1, 1), (0, 1, -1), (1, 0, -1)):
        dp, dq = dof[(cell.pi, cell.pj)[p][c]], dof[(cell.pi, cell.pj)[q][c]]
        ok = (dp >= 0) & (dq >= 0)
        for r in range(2):
            for t in range(2):
                rows.append(2 * dp[ok] + r)
                cols.append(2 * dq[ok] + t)
                vals.append(sign * k[ok, r, t])
    rows, cols, vals = map(np.concatenate, (rows, cols, vals))
    return coo_matrix((vals, (rows, cols)), shape=(n, n)).tocsc()


def factorise_superlu(H):
    """SuperLU of a symmetric matrix with symmetric pivoting, and whether it is positive
    definite (every pivot > 0)."""
    lu = splu(H, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
              options={"SymmetricMode": True})  # fmt: skip
    return lu, bool(np.array_equal(lu.perm_r, lu.perm_c) and np.all(lu.U.diagonal() > 0.0))


@pytest.fixture(scope="module")
def big():
    """The shipped 700-disk packing relaxed at an isotropic compression."""
    return Relaxed(reference_packing(), F0)


@pytest.fixture(scope="module")
def small():
    """70 disks jammed at p / k_n = 1e-3, relaxed at the same compression."""
    return Relaxed(generate_packing(70, seed=0, pressure=1e-3), F0)


@pytest.fixture(scope="module")
def network_eigenvalues(big):
    """Eigenvalues of the 700-disk network's stiffness, the rattlers' unknowns at K."""
    H = big.superlu_matrix(big.s.network) + diags(unknowns_of(big.rattler_shift(1.0), big.dof))
    return np.linalg.eigvalsh(H.toarray())


def rel_err(x, ref):
    return np.abs(x - ref).max() / np.abs(ref).max()


def unknowns_of(shift_per_disk, dof):
    """A per-disk shift (N,) as a diagonal on the unknowns without the pinned disk."""
    k = dof >= 0
    return np.repeat(shift_per_disk[k], 2)


def test_assembly_writes_the_stiffness_of_the_micro_solver(big):
    for exact in (big.s.network, big.s.on):
        A = big.pattern.to_csc(big.values(exact))
        keep = np.repeat(big.dof >= 0, 2)
        A = A[keep][:, keep]
        H = big.superlu_matrix(exact)
        assert abs(A - H).max() <= 1e-14 * abs(H).max()


def residual(H, b, x):
    """Normwise relative residual |b - H x| / (|H| |x|) (max norms)."""
    return np.abs(b - H @ x).max() / (abs(H).max() * np.abs(x).max())


def superlu(H, b):
    """SuperLU's solution with one step of iterative refinement (the reference)."""
    lu = splu(H.tocsc())
    x = lu.solve(b)
    return x + lu.solve(b - H @ x)


def test_the_network_stiffness_solves_as_superlu(big):
    """The non-rattlers' exact stiffness (the tangent's condensation), the rattlers' unknowns
    on the diagonal alone: positive definite, solved as SuperLU solves it."""
    shift = big.rattler_shift(1.0)
    factor = big.pattern.new_factor()
    ok, inertia = block_ldlt.factorise(big.pattern, big.values(big.s.network), factor, shift)
    assert ok and factor.positive_definite and inertia == (big.n, 0, 0)
    H = big.superlu_matrix(big.s.network) + diags(unknowns_of(shift, big.dof))
    g = np.random.default_rng(0).normal(size=(big.cell.n_disks, 2))
    ref = big.scatter(spsolve(H.tocsc(), big.gather(g)))
    x = block_ldlt.solve(big.pattern, factor, g)
    assert rel_err(x, ref) < 1e-12
    assert np.all(x[big.pinned] == 0.0)
    assert rel_err(block_ldlt.solve(big.pattern, factor, g, refine=1), ref) < 1e-12


def test_the_newton_stiffness_with_the_rattler_shift(big):
    """Newton's stiffness: every contact, the rattlers' by their positive part, the rattlers'
    unknowns shifted by 1e-8 K (condition number ~7e8: two backward stable solvers agree to
    ~1e-10 only): backward stable, refined to SuperLU's residual."""
    shift = big.rattler_shift()
    factor = big.pattern.new_factor()
    ok, _ = block_ldlt.factorise(big.pattern, big.values(big.s.network), factor, shift)
    assert ok and factor.positive_definite
    H = (big.superlu_matrix(big.s.network) + diags(unknowns_of(shift, big.dof))).tocsc()
    g = np.random.default_rng(6).normal(size=(big.cell.n_disks, 2))
    b = big.gather(g)
    x = big.gather(block_ldlt.solve(big.pattern, factor, g))
    x1 = big.gather(block_ldlt.solve(big.pattern, factor, g, refine=1))
    assert residual(H, b, x) < 1e-15 and residual(H, b, x1) < 1e-17
    assert rel_err(x, spsolve(H, b)) < 1e-8 and rel_err(x1, superlu(H, b)) < 1e-8


def test_several_right_hand_sides_in_every_layout(big):
    shift = big.rattler_shift(1.0)
    factor = big.pattern.new_factor()
    block_ldlt.factorise(big.pattern, big.values(big.s.network), factor, shift)
    H = big.superlu_matrix(big.s.network) + diags(unknowns_of(shift, big.dof))
    B = np.random.default_rng(1).normal(size=(big.cell.n_disks, 2, 4))
    k = big.dof >= 0
    rhs = np.zeros((big.n, 4))
    rhs[2 * big.dof[k]], rhs[2 * big.dof[k] + 1] = B[k, 0], B[k, 1]
    ref = big.scatter(splu(H.tocsc()).solve(rhs))
    X = block_ldlt.solve(big.pattern, factor, B)
    assert X.shape == B.shape and rel_err(X, ref) < 1e-12
    flat = block_ldlt.solve(big.pattern, factor, B.reshape(-1, 4))
    np.testing.assert_array_equal(flat, X.reshape(-1, 4))
    one = block_ldlt.solve(big.pattern, factor, B[:, :, 0].ravel())
    np.testing.assert_array_equal(one, X[:, :, 0].ravel())


@pytest.mark.parametrize("near", [3, 100])
def test_a_negative_shift_makes_it_indefinite(big, network_eigenvalues, near):
    """The network's stiffness shifted by -mu I, mu in the widest gap of its spectrum near
    eigenvalue number ``near`` (the condition number low enough that SuperLU resolves the
    solution to 1e-12): as many negative eigenvalues as lie below mu, solved as SuperLU solves
    it once refined (without pivoting the D blocks can grow: the refinement takes that out)."""
    lam = network_eigenvalues
    lo = max(near - 3, 0)
    below = lo + 1 + int(np.argmax(np.diff(lam[lo : near + 4])))
    mu = 0.5 * (lam[below - 1] + lam[below])
    shift = big.rattler_shift(1.0) - mu
    factor = big.pattern.new_factor()
    ok, inertia = block_ldlt.factorise(big.pattern, big.values(big.s.network), factor, shift)
    assert ok and inertia == (big.n - below, below, 0) and not factor.positive_definite
    H = (big.superlu_matrix(big.s.network) + diags(unknowns_of(shift, big.dof))).tocsc()
    g = np.random.default_rng(3).normal(size=(big.cell.n_disks, 2))
    b = big.gather(g)
    x = big.gather(block_ldlt.solve(big.pattern, factor, g, refine=2))
    assert rel_err(x, superlu(H, b)) < 1e-12


def test_refactorisation_on_the_same_pattern(big):
    """The values of another relaxed state (sheared, the same candidates) factorised into the
    same arrays: no trace of the first factorisation."""
    factor = big.pattern.new_factor()
    block_ldlt.factorise(big.pattern, big.values(big.s.network), factor, big.rattler_shift())
    _, _, _, state = big.rve.evaluate(F1[None], big.rve.initial_state(1))
    s1 = ContactState(big.cell, F1, state.w[0])
    assert not np.array_equal(s1.network, big.s.network)
    shift = np.zeros(big.cell.n_disks)
    shift[~s1.keep] = big.cell.K
    ok, _ = block_ldlt.factorise(big.pattern, big.values(s1.network, F1, s1), factor, shift)
    H = big.superlu_matrix(s1.network, F1, s1) + diags(unknowns_of(shift, big.dof))
    g = np.random.default_rng(4).normal(size=(big.cell.n_disks, 2))
    ref = big.scatter(spsolve(H.tocsc(), big.gather(g)))
    assert ok and rel_err(block_ldlt.solve(big.pattern, factor, g), ref) < 1e-12


def test_inertia_is_that_of_the_dense_eigenvalues(small):
    """Shifted by -mu I across the spectrum: the counts of positive and negative eigenvalues
    of the dense matrix (pinned disk removed)."""
    shift = small.rattler_shift(1e-3)
    values = small.values(small.s.on)
    H = (small.superlu_matrix(small.s.on) + diags(unknowns_of(shift, small.dof))).toarray()
    lam = np.linalg.eigvalsh(H)
    factor = small.pattern.new_factor()
    below = np.arange(7, lam.size - 1, 14)  # (past the rattlers' 5-fold eigenvalue)
    for mu in [0.0] + list(0.5 * (lam[below] + lam[below + 1])):
        ok, inertia = block_ldlt.factorise(small.pattern, values, factor, shift - mu)
        shifted = lam - mu
        assert ok and inertia == (int((shifted > 0).sum()), int((shifted < 0).sum()), 0), mu


def test_a_singular_or_non_finite_block_is_reported(small):
    factor = small.pattern.new_factor()
    ok, inertia = block_ldlt.factorise(small.pattern, small.pattern.zeros(), factor)
    assert not ok and inertia[2] == 2 and not factor.positive_definite
    with pytest.raises(ValueError, match="singular"):
        block_ldlt.solve(small.pattern, factor, np.ones((small.cell.n_disks, 2)))
    values = small.values(small.s.network)
    values[small.pattern.diag_slot[small.pattern.perm[5]], 0, 0] = np.nan
    ok, _ = block_ldlt.factorise(small.pattern, values, factor, small.rattler_shift())
    assert not ok and not factor.positive_definite


def test_minimum_degree_fills_as_little_as_superlu(big):
    """L's blocks (in scalar entries, the diagonal blocks' lower triangles included) on the
    network's pattern against SuperLU's L of the same matrix in its own minimum-degree order;
    reverse Cuthill-McKee fills several times more."""
    s, c = big.s, big.cell
    pairs = np.c_[c.pi, c.pj].copy()
    network = np.zeros(c.pi.size, np.bool_)
    network[: s.m] = s.network
    pairs[~network, 1] = pairs[~network, 0]  # a pair of a disk with itself: no block
    fill = {}
    for ordering in ("mmd", "rcm"):
        p = block_ldlt.analyse(c.n_disks, pairs, pinned=big.pinned, ordering=ordering)
        fill[ordering] = 4 * p.nnz_L + 3 * p.n
    H = big.superlu_matrix(s.network) + diags(unknowns_of(big.rattler_shift(), big.dof))
    lu, pd = factorise_superlu(H.tocsc())
    assert pd and fill["mmd"] <= 1.1 * lu.L.nnz
    assert fill["rcm"] > 2 * fill["mmd"]


def test_the_flop_count_is_that_of_the_operations():
    """One block column on a path of 3 blocks (natural order): L has 2 blocks, each needs
    Y D^-1 and D's update (2 d^3 each), none an earlier block of its column; 3 inverses."""
    p = block_ldlt.analyse(3, np.array([[0, 1], [1, 2]]), ordering="natural")
    assert p.nnz_L == 2 and p.flops == 2 * 8 * (0 + 2 * 2) + 8 * 3


def random_blocks(n, d, pairs, rng, margin):
    """A dense symmetric matrix (n d, n d) with random (non-symmetric) off-diagonal blocks at
    ``pairs`` and diagonal blocks dominant by ``margin``; and its values on a pattern."""
    A = np.zeros((n * d, n * d))
    blocks = rng.normal(size=(len(pairs), d, d))
    for (i, j), B in zip(pairs, blocks):
        A[d * i : d * i + d, d * j : d * j + d] += B
        A[d * j : d * j + d, d * i : d * i + d] += B.T
    for i in range(n):
        S = rng.normal(size=(d, d))
        A[d * i : d * i + d, d * i : d * i + d] += S + S.T
    row = np.abs(A).sum(axis=1)
    A += np.diag(row + margin)
    return A, blocks


def values_of(pattern, A, pairs, blocks):
    """Values on ``pattern`` of the dense A: diagonal blocks, then each pair's block once
    (its slot holds A[i, j] or, flipped, A[j, i])."""
    d = pattern.d
    v = pattern.zeros()
    for b in range(pattern.n_blocks):
        if pattern.diag_slot[b] >= 0:
            v[pattern.diag_slot[b]] = A[d * b : d * b + d, d * b : d * b + d]
    for k, B in enumerate(blocks):
        if pattern.pair_slot[k] >= 0:
            v[pattern.pair_slot[k]] += B.T if pattern.pair_flip[k] else B
    return v


@pytest.mark.parametrize("pinned", [-1, 4])
def test_three_by_three_blocks(pinned):
    """d = 3 (a disk with its rotation): a random SPD block matrix on a random graph, and the
    same shifted indefinite, against numpy."""
    rng = np.random.default_rng(5)
    n, d = 60, 3
    pairs = np.unique(np.sort(rng.integers(0, n, size=(150, 2)), axis=1), axis=0)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    A, blocks = random_blocks(n, d, pairs, rng, 1.0)
    pattern = block_ldlt.analyse(n, pairs, pinned=pinned, d=3)
    values = values_of(pattern, A, pairs, blocks)
    keep = np.ones(n * d, np.bool_)
    if pinned >= 0:
        keep[d * pinned : d * pinned + d] = False
    Ak = A[keep][:, keep]
    assert np.abs(pattern.to_csc(values).toarray()[keep][:, keep] - Ak).max() == 0.0
    factor = pattern.new_factor()
    assert block_ldlt.factorise(pattern, values, factor) == (True, (keep.sum(), 0, 0))
    b = rng.normal(size=(n * d, 2))
    x = block_ldlt.solve(pattern, factor, b)
    ref = np.zeros_like(b)
    ref[keep] = np.linalg.solve(Ak, b[keep])
    assert rel_err(x, ref) < 1e-12
    lam = np.linalg.eigvalsh(Ak)
    mu = 0.5 * (lam[40] + lam[41])
    ok, inertia = block_ldlt.factorise(pattern, values, factor, -mu)
    assert ok and inertia == (int((lam > mu).sum()), int((lam < mu).sum()), 0)
    ref[keep] = np.linalg.solve(Ak - mu * np.eye(keep.sum()), b[keep])
    assert rel_err(block_ldlt.solve(pattern, factor, b, refine=1), ref) < 1e-12


def test_the_benchmark_times_the_parts():
    import relaxed as benchmark  # benchmarks/relaxed.py

    rve = RelaxedRVE(generate_packing(70, seed=0), benchmark.K_N)
    F, state = benchmark.committed(rve, 0.005, 1)
    timed = benchmark.parts(rve, F, state, repeats=2)
    solver, own = timed["solver's pattern"], timed["network's own pattern"]
    assert solver["factorisation"] > 0.0 and solver["solve"] > 0.0 and timed["SuperLU"]
    assert solver["flops"] >= own["flops"] > 0
    ms, mflop = benchmark.floor({"numeric_factorisations": 2.0, "solves": 3.0}, timed)
    assert mflop == 2.0 * solver["flops"] / 1e6
    assert ms == pytest.approx(1e3 * (2.0 * solver["factorisation"] + 3.0 * solver["solve"]))


def test_the_tangent_is_the_dense_condensation(big):
    """A = W_FF - B^T H^-1 B with B = d2W/dw dF and H the network's stiffness (the rattlers'
    and the pinned disk's unknowns out), dense in numpy, against the relaxed RVE's tangent and
    its sensitivities dw/dF = -H^-1 B at the same equilibrium."""
    c, s, F = big.cell, big.s, big.F
    eq = at_rest(c, F, big.w, True)
    free = s.keep.copy()
    free[big.pinned] = False
    dof = -np.ones(c.n_disks, np.int64)
    dof[free] = np.arange(free.sum())
    n = 2 * int(free.sum())
    H = stiffness_matrix(c, F, s, s.network, s.network, dof, n).toarray()
    B = mixed(F, c.pi[: s.m], c.pj[: s.m], s.qx, s.qy, s.lx, s.ly, s.d, s.e, c.R[: s.m], c.K,
              s.network, dof, n)  # fmt: skip
    X = np.linalg.solve(H, B)
    A = _affine(c, F, s) - (B.T @ X).reshape(2, 2, 2, 2)
    assert rel_err(eq.A, A) < 1e-10
    dw = np.zeros((c.n_disks, 2, 4))
    dw[free] = -X.reshape(-1, 2, 4)
    assert rel_err(eq.sensitivity, dw) < 1e-8


@pytest.mark.parametrize("near", [0, 2, 40])
def test_the_shift_bound_is_below_the_least_shift_that_works(big, network_eigenvalues, near):
    """The bound a failed factorisation gives (newton.shift_bound): M + t I is not positive
    definite for t at or below it (t < -lam_min(M), from dense eigenvalues), and not far below
    (within a factor 1e3 here: the ladder's rungs below it are skipped)."""
    lam = network_eigenvalues
    mu = 0.5 * (lam[near] + lam[near + 1])
    shift = big.rattler_shift(1.0) - mu
    p = big.pattern
    factor = p.new_factor()
    ok, inertia = block_ldlt.factorise(p, big.values(big.s.network), factor, shift)
    assert inertia[1] == near + 1
    pat = (p.pinned, 0, p.n, p.perm, p.Lp, p.Li, p.Rp, p.Rc, p.Rq, p.Ap, p.Ai, p.diag_slot,
           p.pair_slot)  # fmt: skip
    fac = (factor.values, factor.Lx, factor.D, factor.Dinv, factor.y)
    bound = newton.shift_bound(pat, fac)
    needed = -(lam[0] - mu)
    assert 0.0 < bound <= needed and bound > 1e-3 * needed


def test_the_pattern_serves_the_prefix_it_is_asked_for():
    """The smallest kept pattern that holds the prefix serves it, unless it reaches too far
    beyond; another pinned disk, a longer prefix get their own; the list's growth keeps them."""
    packing = generate_packing(70, seed=0)
    cell = RelaxedRVE(packing, K_N).cell
    p, _, cover = cell.block_pattern(0, 100)
    assert cover >= 100 and p.pair_slot.size == cover
    assert cell.block_pattern(0, cover)[0] is p and cell.block_pattern(3, 100)[0] is not p
    longer, _, c2 = cell.block_pattern(0, cover + 1)
    assert longer is not p and c2 > cover
    assert cell.block_pattern(0, 100)[0] is p  # (not the longer one)
    w = np.zeros((cell.n_disks, 2))
    w[0] = 0.5 * packing.box  # one disk across the cell: new pairs within reach
    n = cell.pi.size
    cell.visited(np.eye(2), w)
    assert cell.pi.size > n and cell.block_pattern(0, 100)[0] is p
    assert cell.block_pattern(0)[2] == cell.pi.size


def test_a_list_that_grows_mid_solve_gives_the_same_equilibrium():
    """A disk pushed far across the cell: the Newton loop asks for a longer candidate list and
    a pattern on it (it stops, and goes on once they are there); relaxed again from the same
    start on the grown list, the same equilibrium."""
    packing = generate_packing(70, seed=0)
    rve = RelaxedRVE(packing, K_N)
    F = np.diag([0.99, 0.995])
    w = np.zeros((rve.cell.n_disks, 2))
    w[5] = 0.3 * packing.box
    n = rve.cell.pi.size
    first = newton_relax(rve, F, w)
    assert rve.cell.pi.size > n
    again = newton_relax(rve, F, w)
    assert abs(first.W - again.W) <= 1e-12 * abs(again.W)
    assert rel_err(first.P, again.P) < 1e-10


def newton_relax(rve, F, w):
    return relax(rve.cell, F, w, False, rve.settings)
