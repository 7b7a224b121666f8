"""The block LU of the frictional relaxed RVE's Jacobian (laws/relaxed_friction/block_lu.py):
its assembly against a dense one, contact by contact; its solutions against dense and SuperLU
solves, on synthetic matrices and on the Jacobian of a sheared frictional packing with slipping
contacts; a singular block pivot is refused."""

from dolfinx_granular import FrictionalRelaxedRVE, generate_packing
from dolfinx_granular.laws.relaxed import block_ldlt
from dolfinx_granular.laws.relaxed_friction import block_lu, cell_state, newton, system
from dolfinx_granular.laws.relaxed_friction.contact_law import SLIP

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.linalg import splu

N = 40


def _synthetic(seed, diagonal=8.0, self_pairs=False):
    """A random structurally symmetric, non-symmetric block matrix: its pattern, its assembled
    BlockLU, and the same matrix dense (the pinned disk 0's translation held)."""
    rng = np.random.default_rng(seed)
    pairs = [(i, j) for i in range(N) for j in range(i + 1, N) if rng.random() < 0.1]
    pairs += [(3, 7), (3, 7)]  # two periodic images of one pair: one block
    if self_pairs:
        pairs += [(5, 5)]  # a disk touching its own image
    pairs = np.array(pairs, dtype=np.int64)
    p = block_ldlt.analyse(N, pairs, -1, 3)
    lu = block_lu.BlockLU.on(p)
    K = rng.standard_normal((len(pairs), 6, 6))
    held = np.zeros(3 * N, bool)
    held[:2] = True
    diag = np.full(3 * N, diagonal)
    pi, pj = pairs[:, 0].copy(), pairs[:, 1].copy()
    contacts = np.arange(len(pairs))
    block_lu.assemble(p.n, p.diag_slot, p.pair_slot, p.pair_flip, pi, pj, contacts, K, held,
                      diag, lu.values)  # fmt: skip
    A = np.diag(diag)
    for t, (i, j) in enumerate(pairs):
        idx = np.r_[3 * i : 3 * i + 3, 3 * j : 3 * j + 3]
        keep = ~held[idx]
        np.add.at(A, np.ix_(idx[keep], idx[keep]), K[t][np.ix_(keep, keep)])  # (i = j: summed)
    return p, lu, A


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_it_solves_a_non_symmetric_block_matrix(seed):
    p, lu, A = _synthetic(seed, self_pairs=seed == 2)
    assert lu.factorise()
    assert np.abs(A - A.T).max() > 0.1
    B = np.random.default_rng(10 + seed).standard_normal((3 * N, 4))
    X = lu.solve(B)
    assert np.abs(X - np.linalg.solve(A, B)).max() <= 1e-12 * np.abs(X).max()
    assert lu.residual <= block_lu.REFINED
    x = lu.solve(B[:, 0])  # one right-hand side, in its shape
    assert x.shape == (3 * N,) and np.allclose(x, X[:, 0], rtol=0, atol=1e-14 * np.abs(x).max())


def test_a_singular_block_pivot_is_refused():
    p, lu, A = _synthetic(0)
    first = p.perm[0]  # the first block eliminated: its D block is its diagonal block
    lu.values[p.diag_slot[first]] = np.outer([1.0, 2.0, 3.0], [1.0, -1.0, 0.5])
    assert not lu.factorise()
    with pytest.raises(ValueError, match="singular"):
        lu.solve(np.ones(3 * N))


def test_the_flop_count_grows_with_the_fill():
    p, _, _ = _synthetic(0)
    dense = block_ldlt.analyse(N, np.array([(i, j) for i in range(N) for j in range(i)]), -1, 3)
    assert 0 < block_lu.flops(p) < block_lu.flops(dense)


@pytest.fixture(scope="module", params=[0.0, 0.05], ids=["sliding", "rolling"])
def slipping(request):
    """A frictional relaxed packing sheared from its compressed state: the cell, its springs
    and the CellState at the solution (contacts slipping; with rolling resistance, some
    rolling too)."""
    rve = FrictionalRelaxedRVE(
        generate_packing(70, seed=1), 1e8, 1e8, friction=0.3, rolling_friction=request.param
    )
    F1, F2 = np.diag([0.99, 0.99]), np.array([[0.99, 0.004], [0.001, 0.992]])
    committed = rve.evaluate(F1, rve.initial_state(1))[3]
    eq, _ = rve.equilibrium(F2, committed, 0)
    return rve, F2, eq.state


@pytest.mark.parametrize("tangent", [False, True])
def test_it_solves_the_frictional_jacobian_as_superlu_does(slipping, tangent):
    rve, F, s = slipping
    assert (s.status == SLIP).sum() >= 5
    lu, held = newton.factorise(rve.cell, rve.springs, F, s, tangent)
    assert isinstance(lu, block_lu.BlockLU)
    J = _superlu_matrix(rve, F, s, tangent, held)
    assert abs(J - J.T).max() > 1e-3 * abs(J).max()  # slip: not symmetric
    B = np.random.default_rng(3).standard_normal((3 * rve.cell.n_disks, 5))
    B[held] = 0.0
    X = lu.solve(B)
    Y = splu(J.tocsc()).solve(B)
    assert abs(lu.to_csc() - J).max() <= 1e-12 * abs(J).max()  # (SuperLU's fallback matrix)
    assert np.abs(X - Y).max() <= 1e-9 * np.abs(Y).max()


def _superlu_matrix(rve, F, s, tangent, held):
    """The Jacobian newton.factorise assembles, as scipy COO of the triplets."""
    cell, N = rve.cell, rve.cell.n_disks
    mode = np.full(s.m, system.EXACT, np.int8)
    if tangent:
        mode[~s.network] = system.SKIPPED
    _, _, (rows, cols, vals) = s.equations(cell, rve.springs, F, mode, True)
    use = ~(held[rows] | held[cols])
    pinned = int(np.argmax(s.keep))
    reach = cell_state.RATTLER_REACH * s.e[s.on].mean()
    sp_ = rve.springs
    diag = cell_state.diagonal(
        s.status, s.rstatus, s.network, s.keep, cell.pi[: s.m], cell.pj[: s.m], cell.radii, s.r,
        s.fstar, s.mstar, s.e, sp_.kn, sp_.kt, sp_.mu, sp_.kr, sp_.mu_r, sp_.inv_area, pinned,
        reach, cell_state.RATTLER_SHIFT, tangent, 1.0,
    )  # fmt: skip
    idx = np.arange(3 * N)
    return sp.coo_matrix(
        (np.r_[vals[use], diag], (np.r_[rows[use], idx], np.r_[cols[use], idx])), (3 * N, 3 * N)
    ).tocsr()
