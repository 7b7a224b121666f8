"""Thousands of random, hostile F through the kernel: a finite answer or a clean error, no NaN."""

from dolfinx_granular import TaylorRVE, UnsupportedDeformationError
from dolfinx_granular.laws import taylor_kernel as kernel

import numpy as np
import pytest

from helpers import random_packing

# these tests use prestressed (overlapping) packings on purpose
pytestmark = pytest.mark.filterwarnings("ignore::dolfinx_granular.laws.taylor.PrestressWarning")


def hostile_F(rng, n):
    kinds = rng.integers(0, 6, n)
    F = np.empty((n, 2, 2))
    for q, kind in enumerate(kinds):
        if kind == 0:  # near-singular
            F[q] = rng.normal(size=(2, 2)) * 1e-8
        elif kind == 1:  # inverted
            F[q] = np.diag([1.0, -1.0]) @ rng.normal(size=(2, 2))
        elif kind == 2:  # huge or tiny entries
            F[q] = rng.normal(size=(2, 2)) * 10.0 ** rng.uniform(-300, 300)
        elif kind == 3:  # NaN or inf somewhere
            F[q] = np.eye(2)
            F[q].flat[rng.integers(0, 4)] = rng.choice([np.nan, np.inf, -np.inf])
        elif kind == 4:  # moderate, near the supported bound
            F[q] = np.eye(2) + rng.normal(size=(2, 2)) * 0.3
        else:  # rank-deficient
            v = rng.normal(size=2)
            F[q] = np.outer(v, rng.normal(size=2))
    return F


@pytest.mark.parametrize("seed", range(4))
def test_fuzz_batch_gives_finite_results_or_status(seed):
    rng = np.random.default_rng(seed)
    rve = TaylorRVE(random_packing(30, seed=seed), 1e7, allow_overlaps=True)
    F = hostile_F(rng, 1000)
    W, P, A = np.empty(1000), np.empty((1000, 2, 2)), np.empty((1000, 2, 2, 2, 2))
    status = np.empty(1000, np.int8)
    c = rve.candidates
    K = rve.normal_stiffness / rve.packing.area
    X, Y = c.components
    kernel.evaluate_batch(
        F, X, Y, c.radius_sum, c.ratio, K, rve.min_stretch, False, True, W, P, A, status
    )
    assert np.isfinite(W).all() and np.isfinite(P).all() and np.isfinite(A).all()
    ok = status == kernel.OK
    # every point the kernel accepts is valid, every point it rejects is invalid
    finite = np.isfinite(F).all(axis=(1, 2))
    with np.errstate(over="ignore", invalid="ignore"):
        J = np.where(finite, np.linalg.det(np.where(finite[:, None, None], F, 0.0)), np.nan)
    smin = np.full(len(F), np.nan)
    good = finite & (J > 0)
    smin[good] = np.linalg.svd(F[good], compute_uv=False).min(axis=1)
    # entries beyond ~1e76 overflow (tr F^T F)^2 and are rejected as non-finite: not counted valid
    valid = good & (smin >= rve.min_stretch * (1 + 1e-9)) & (np.abs(F).max(axis=(1, 2)) < 1e75)
    invalid = ~good | (smin < rve.min_stretch * (1 - 1e-9))
    assert np.all(ok[valid]) and not np.any(ok[invalid])
    assert np.all(W[~ok] == 0.0) and np.all(P[~ok] == 0.0)
    assert ok.sum() > 50 and (~ok).sum() > 500  # both branches exercised
    # the public API raises for the batch and names the first bad point
    bad = np.flatnonzero(~ok)
    with pytest.raises(UnsupportedDeformationError, match=f"the first, point {bad[0]}, ") as info:
        rve.evaluate(F)
    assert info.value.points.tolist() == bad.tolist()
    # accepted points alone evaluate cleanly and identically
    W2, P2, A2 = rve.evaluate(F[ok])
    assert np.array_equal(P2, P[ok]) and np.array_equal(A2, A[ok])
