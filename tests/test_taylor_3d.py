"""The Taylor RVE of spheres (3-D): the paper's formulas with every index over 3.

Checked against the NumPy reference written from the paper (no candidate lists, no pruning), by
finite differences, symmetry and objectivity, and against the analytic moduli of the fcc
lattice.
"""

from itertools import product

from dolfinx_granular import (
    AdaptiveRVE,
    FrictionalRVE,
    Packing,
    RelaxedRVE,
    SmallStrainRVE,
    TaylorRVE,
    UnsupportedDeformationError,
)
from dolfinx_granular.packings import neighbours
from dolfinx_granular.packings.packing import LENGTH_UNIT

import numpy as np
import pytest

from helpers import fcc_lattice, random_spheres
from reference import central_differences, reference, reference_modulus

K_N = 1e5  # N/m
KN_REF = K_N / LENGTH_UNIT  # the reference reads the packing's mm as m: k_n per mm


def rel(a, b):
    return np.abs(np.asarray(a) - b).max() / np.abs(b).max()


def rotation(axis, angle):
    """Rotation (3, 3) by ``angle`` about a unit ``axis`` (Rodrigues)."""
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


@pytest.fixture(scope="module")
def packing():
    return random_spheres(40, seed=0)


@pytest.fixture(scope="module")
def rve(packing):
    # the warning points to the 3-D way to a stress-free packing (relax_overlaps is for disks)
    with pytest.warns(UserWarning, match=r"prestressed.*spheres.*generate_packing\(n, dim=3\)"):
        return TaylorRVE(packing, K_N, allow_overlaps=True)


@pytest.fixture(scope="module")
def batch():
    rng = np.random.default_rng(1)
    return np.eye(3) + 0.08 * rng.normal(size=(6, 3, 3))


def test_the_kernel_is_the_paper(rve, packing, batch):
    W, P, A = rve.evaluate(batch)
    sigma, a = rve.cauchy(batch), rve.spatial_tangent(batch)
    for q, F in enumerate(batch):
        Wr, Pr, Ar, sr, ar = reference(packing, KN_REF, F, images=1)
        assert abs(W[q] - Wr) <= 1e-12 * Wr
        assert rel(P[q], Pr) <= 1e-12 and rel(A[q], Ar) <= 1e-12
        assert rel(sigma[q], sr) <= 1e-12 and rel(a[q], ar) <= 1e-12


def test_stress_is_the_energy_derivative_and_A_the_stress_derivative(rve, batch):
    W, P, A = rve.evaluate(batch)
    dW, dP = central_differences(rve, batch, 1e-6)
    assert rel(dW, P) <= 1e-7
    assert rel(dP, A) <= 1e-7
    W2, P2 = rve.stress(batch)
    assert np.array_equal(W2, W) and np.array_equal(P2, P)


def test_symmetries_and_objectivity(rve, batch):
    W, P, A = rve.evaluate(batch)
    assert rel(A, A.transpose(0, 3, 4, 1, 2)) <= 1e-14  # major symmetry: A = d2W/dF2
    sigma = rve.cauchy(batch)
    assert rel(sigma, sigma.transpose(0, 2, 1)) <= 1e-14
    Q = rotation([1.0, 2.0, -0.5], 0.9)
    WQ, PQ, AQ = rve.evaluate(Q @ batch)
    assert rel(WQ, W) <= 1e-13
    assert rel(PQ, Q @ P) <= 1e-13
    assert rel(AQ, np.einsum("ai,ck,qibkd->qabcd", Q, Q, A)) <= 1e-13


def test_pruned_candidates_are_complete_under_strong_compression(packing):
    with pytest.warns(UserWarning, match="prestressed"):
        rve = TaylorRVE(packing, K_N, min_stretch=0.55, allow_overlaps=True)
    F = rotation([0.3, -1.0, 0.4], 0.5) @ np.diag([0.56, 1.2, 0.9])
    W, P, A = rve.evaluate(F)
    Wr, Pr, Ar, _, _ = reference(packing, KN_REF, F, images=2)
    assert abs(W - Wr) <= 1e-12 * Wr and rel(P, Pr) <= 1e-12 and rel(A, Ar) <= 1e-12


def test_candidates_are_the_brute_force_pairs(packing):
    L, R, rho, ij, shift = neighbours.candidate_pairs(
        packing.centers, packing.radii, packing.box, 1.5
    )
    X, r, box = packing.centers, packing.radii, packing.box
    rows = set()
    for i in range(len(r)):
        for j in range(i, len(r)):
            for s in product(range(-2, 3), repeat=3):
                if i == j and s <= (0, 0, 0):
                    continue
                Lv = X[j] + np.array(s) * box - X[i]
                if Lv @ Lv <= (1.5 * (r[i] + r[j])) ** 2:
                    rows.add((i, j) + s)
    assert {tuple(p) + tuple(s) for p, s in zip(ij, shift)} == rows
    assert len(rows) == len(R) and np.all(np.diff(rho) >= 0)
    assert np.allclose(np.linalg.norm(L, axis=1) / R, rho, rtol=1e-15)


def test_small_strain_modulus_of_the_fcc_lattice():
    """eq. 15 on the fcc lattice of neighbour distance a: cubic, C11 = sqrt(2) k_n / a and
    C12 = C44 = C11 / 2; its isotropic projection has Luding's bulk modulus
    K = phi Z k_n / (3 pi d) (Z = 12, phi = pi / (3 sqrt 2), d = a) and G = 3 K / 5."""
    p = fcc_lattice(3, overlap=1e-10)
    rve = TaylorRVE(p, K_N)
    C = rve.small_strain_modulus()
    assert rel(C, reference_modulus(p, KN_REF, images=1)) <= 1e-13
    C11 = np.sqrt(2.0) * KN_REF  # the neighbour distance is 1 mm
    for idx in product(range(3), repeat=4):
        a, b, c, d = idx
        want = 0.0
        if a == b == c == d:
            want = C11
        elif sorted(idx) in ([a, a, c, c] for a, c in product(range(3), repeat=2) if a != c):
            want = C11 / 2
        assert C[idx] == pytest.approx(want, rel=1e-9, abs=1e-9 * C11)
    bulk = np.einsum("iijj->", C) / 9.0
    shear = (np.einsum("ijij->", C) - np.einsum("iijj->", C) / 3.0) / 10.0
    phi, Z = np.pi / (3.0 * np.sqrt(2.0)), 12
    assert bulk == pytest.approx(phi * Z * KN_REF / (3.0 * np.pi), rel=1e-9)
    assert shear == pytest.approx(0.6 * bulk, rel=1e-12)
    # without prestress the tangent at F = I is that modulus
    assert rel(rve.evaluate(np.eye(3))[2], C) <= 1e-8


def test_contacts_carry_the_stress(rve, packing):
    F = np.eye(3) + np.array([[0.02, 0.01, 0.0], [0.0, -0.03, 0.01], [0.02, 0.0, 0.01]])
    cs = rve.contacts(F)
    assert cs.branch.shape == (len(cs.force), 3) and cs.shift.shape == (len(cs.force), 3)
    L = np.linalg.solve(F, cs.branch.T).T
    n = cs.branch / np.linalg.norm(cs.branch, axis=1)[:, None]
    P_c = -np.einsum("m,ma,mb->ab", cs.force, n, L) / (packing.volume * LENGTH_UNIT)
    assert rel(P_c, rve.stress(F)[1]) <= 1e-12
    stats = rve.overlap_statistics(F)
    assert stats.contacts == len(cs.force)
    smaller = np.minimum(*packing.radii[cs.pairs.T])
    assert stats.max_ratio == pytest.approx((cs.overlap / smaller).max(), rel=1e-14)


@pytest.mark.parametrize(
    "F, words",
    [
        (np.diag([np.nan, 1.0, 1.0]), "NaN or inf"),
        (np.diag([1.0, 1.0, -1.0]), "det F <= 0"),
        (np.zeros((3, 3)), "det F <= 0"),
        (np.diag([0.45, 1.0, 1.0]), "min_stretch=0.5"),
        (rotation([1, 1, 0], 0.4) @ np.diag([1.3, 0.3, 1.0]), "min_stretch=0.5"),
    ],
)
def test_unsupported_F_raises(rve, F, words):
    with pytest.raises(UnsupportedDeformationError, match=words) as info:
        rve.evaluate(np.stack([np.eye(3), F, np.eye(3)]))
    assert info.value.points.tolist() == [1]


def test_min_stretch_bound_itself_is_supported(rve):
    Q = rotation([0.2, 1.0, 0.3], 0.7)
    rve.evaluate(Q @ np.diag([0.5, 1.0, 0.5]) @ Q.T)


def test_F_of_the_wrong_dimension_is_refused(rve):
    with pytest.raises(ValueError, match=r"\(n, 3, 3\) or \(3, 3\)"):
        rve.evaluate(np.eye(2))
    with pytest.raises(ValueError, match=r"shape \(3, 3\)"):
        rve.contacts(np.eye(2))


def test_the_2d_laws_refuse_spheres():
    p = fcc_lattice(2)
    for make in (
        lambda: FrictionalRVE(p, K_N, K_N, 0.5),
        lambda: RelaxedRVE(p, K_N),
        lambda: SmallStrainRVE(TaylorRVE(p, K_N)),
        lambda: AdaptiveRVE(TaylorRVE(p, K_N), 1e-3),
    ):
        with pytest.raises(ValueError, match="built for disks.*3-D packings take TaylorRVE"):
            make()


def test_a_sphere_touching_its_own_image_is_refused():
    with pytest.raises(ValueError, match="own periodic image"):
        Packing([[0.5, 0.5, 0.5], [1.5, 1.5, 1.5]], [0.6, 0.4], (2.0, 2.0, 1.0))
