"""The acoustic-tensor test of strong ellipticity: analytic cases and the Taylor RVE."""

from dolfinx_granular import TaylorRVE, generate_packing
from dolfinx_granular.io.postprocess import min_acoustic_eigenvalue

import numpy as np
import pytest

I2 = np.eye(2)


def isotropic(lam, mu):
    """A_iJkL of small-strain isotropic elasticity (n = 1)."""
    return (
        lam * np.einsum("ij,kl->ijkl", I2, I2)
        + mu * (np.einsum("ik,jl->ijkl", I2, I2) + np.einsum("il,jk->ijkl", I2, I2))
    )[None]


def test_isotropic_minimum_is_the_shear_modulus():
    # Q(N) = mu I + (lam + mu) N N: eigenvalues mu and lam + 2 mu for every N
    for lam, mu in [(2.0, 1.0), (-0.9, 1.0), (5.0, 0.25)]:
        assert min_acoustic_eigenvalue(isotropic(lam, mu), 7)[0] == pytest.approx(
            min(mu, lam + 2 * mu), rel=1e-14
        )
    # lam + 2 mu < 0: the longitudinal wave speed is imaginary, ellipticity is lost
    assert min_acoustic_eigenvalue(isotropic(-3.0, 1.0))[0] == pytest.approx(-1.0, rel=1e-14)


def test_geometric_stiffness_gives_the_smallest_stress_eigenvalue():
    """A_iJkL = delta_ik S_JL alone: Q(N) = (N.S.N) I, smallest over N = the least eigenvalue of
    S, reached at its eigenvector (on the direction grid here)."""
    R = np.array([[np.cos(0.3), -np.sin(0.3)], [np.sin(0.3), np.cos(0.3)]])
    S = R @ np.diag([-2.0, 0.5]) @ R.T
    A = np.einsum("ik,JL->iJkL", I2, S)[None]
    assert min_acoustic_eigenvalue(A, n_directions=1800)[0] == pytest.approx(-2.0, rel=1e-6)
    # a coarse grid can only overestimate the minimum
    assert min_acoustic_eigenvalue(A, n_directions=4)[0] >= -2.0


def test_taylor_rve_matches_dense_eigenvalues():
    rve = TaylorRVE(generate_packing(70, seed=3), 2.8e7)
    F = np.array([I2, [[1.02, 0.05], [0.0, 0.9]], [[0.85, 0.1], [-0.05, 1.1]]])
    _, _, A = rve.evaluate(F)
    got = min_acoustic_eigenvalue(A, n_directions=360)
    for q in range(len(F)):
        lowest = min(
            np.linalg.eigvalsh(np.einsum("iJkL,J,L->ik", A[q], N, N))[0]
            for N in (np.array([np.cos(t), np.sin(t)]) for t in np.pi * np.arange(360) / 360)
        )
        assert got[q] == pytest.approx(lowest, rel=1e-12, abs=1e-9 * np.abs(A[q]).max())
    # the stress-free packing under no load is elliptic
    assert got[0] > 0


def test_a_non_symmetric_tangent_gives_its_symmetric_parts_eigenvalue():
    """A frictional law's A lacks major symmetry where contacts slide: the least m . Q(N) m over
    unit m is the least eigenvalue of Q's symmetric part."""
    A = isotropic(2.0, 1.0) + 0.4 * np.random.default_rng(7).standard_normal((1, 2, 2, 2, 2))
    t = np.pi * np.arange(90) / 90
    N = np.stack([np.cos(t), np.sin(t)], axis=1)
    Q = np.einsum("iJkL,nJ,nL->nik", A[0], N, N)
    assert np.abs(Q - Q.transpose(0, 2, 1)).max() > 0.1  # (not symmetric)
    lowest = np.linalg.eigvalsh(0.5 * (Q + Q.transpose(0, 2, 1)))[:, 0].min()
    assert min_acoustic_eigenvalue(A, n_directions=90)[0] == pytest.approx(lowest, rel=1e-12)


def test_bad_shapes():
    with pytest.raises(ValueError, match="shape"):
        min_acoustic_eigenvalue(np.zeros((3, 4, 4)))
    with pytest.raises(ValueError, match="n_directions"):
        min_acoustic_eigenvalue(np.zeros((1, 2, 2, 2, 2)), 0)
