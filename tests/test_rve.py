"""The Taylor RVE against the paper's formulas: reference sums, derivatives, symmetries, limits."""

from dolfinx_granular import Packing, TaylorRVE, UnsupportedDeformationError

import numpy as np
import pytest

from helpers import hex_lattice, random_packing, square_lattice
from reference import central_differences, reference, reference_modulus

# these tests use prestressed (overlapping) packings on purpose
pytestmark = pytest.mark.filterwarnings("ignore::dolfinx_granular.laws.taylor.PrestressWarning")

K_N = 2.8e7


def rotation(theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def random_F(rng, n, smin=0.9, smax=1.1):
    """n deformation gradients Q1 diag(s) Q2 with singular values in [smin, smax]."""
    out = np.empty((n, 2, 2))
    for q in range(n):
        s = rng.uniform(smin, smax, 2)
        out[q] = (
            rotation(rng.uniform(0, 2 * np.pi)) @ np.diag(s) @ rotation(rng.uniform(0, 2 * np.pi))
        )
    return out


def rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


@pytest.fixture(scope="module")
def packing():
    return random_packing(40, seed=3)


@pytest.fixture(scope="module")
def rve(packing):
    return TaylorRVE(packing, K_N, allow_overlaps=True)  # prestressed on purpose


def test_matches_reference(packing, rve, rng):
    F = np.concatenate([random_F(rng, 6), random_F(rng, 4, 0.5, 1.3), np.eye(2)[None]])
    W, P, A = rve.evaluate(F)
    sigma = rve.cauchy(F)
    a = rve.spatial_tangent(F)
    for q in range(len(F)):
        W_r, P_r, A_r, s_r, a_r = reference(packing, K_N, F[q])
        assert abs(W[q] - W_r) <= 1e-12 * W_r
        assert rel(P[q], P_r) <= 1e-12
        assert rel(A[q], A_r) <= 1e-12
        assert rel(sigma[q], s_r) <= 1e-12
        assert rel(a[q], a_r) <= 1e-12


def test_candidates_complete_at_min_stretch(packing, rng):
    """At the supported bound the pruned kernel still finds every contact the brute force finds."""
    for smin in (0.5, 0.7):
        rve = TaylorRVE(packing, K_N, min_stretch=smin, allow_overlaps=True)
        for _ in range(3):
            F = rotation(rng.uniform(0, 6.3)) @ np.diag([smin, 1.2]) @ rotation(rng.uniform(0, 6.3))
            _, P, A = rve.evaluate(F)
            _, P_r, A_r, _, _ = reference(packing, K_N, F)
            assert rel(P, P_r) <= 1e-12 and rel(A, A_r) <= 1e-12


def test_self_image_contact():
    """A disk wider than the compressed cell touches its own periodic image."""
    packing = Packing([[0.5, 0.5], [0.5, 3.0]], [0.45, 0.45], (1.0, 6.0))
    rve = TaylorRVE(packing, K_N, allow_overlaps=True)
    F = np.diag([0.8, 1.0])
    _, P, A = rve.evaluate(F)
    _, P_r, A_r, _, _ = reference(packing, K_N, F)
    assert P[0, 0] < 0.0  # the image contact is active and compressive
    assert rel(P, P_r) <= 1e-12 and rel(A, A_r) <= 1e-12


def _safe_points(rve, F, h):
    """Keep points whose contact set does not change within +-h in any F component."""
    keep = []
    for q in range(len(F)):
        _, eps = rve.candidates.overlaps(F[q])
        margin = h * 4.0 * np.abs(rve.candidates.branch).max(axis=1).max()
        keep.append(np.min(np.abs(eps)) > margin)
    return F[np.array(keep)]


def _changes_contacts(rve, F):
    _, eps0 = rve.candidates.overlaps(np.eye(2))
    return any(np.any((rve.candidates.overlaps(f)[1] >= 0) != (eps0 >= 0)) for f in F)


def test_finite_differences(rve, rng):
    h = 1e-6
    F = _safe_points(rve, random_F(rng, 12, 0.93, 1.07), h)
    assert len(F) >= 6 and _changes_contacts(rve, F)
    W, P, A = rve.evaluate(F)
    P_fd, A_fd = central_differences(rve, F, h)
    for q in range(len(F)):
        assert rel(P_fd[q], P[q]) <= 1e-6
        assert rel(A_fd[q], A[q]) <= 1e-6


def test_major_symmetry(rve, rng):
    A = rve.evaluate(random_F(rng, 8))[2]
    assert rel(A, A.transpose(0, 3, 4, 1, 2)) <= 1e-14


def test_cauchy_symmetric_and_push_forward(rve, rng):
    F = random_F(rng, 8)
    _, P, A = rve.evaluate(F)
    sigma = rve.cauchy(F)
    J = np.linalg.det(F)
    assert rel(sigma, sigma.transpose(0, 2, 1)) <= 1e-14
    assert rel(sigma, np.einsum("qab,qcb->qac", P, F) / J[:, None, None]) <= 1e-13
    # eq. 14 is the push-forward of eq. 12: a_abcd = F_bB F_dD A_aBcD / J
    a_push = np.einsum("qbB,qdD,qaBcD->qabcd", F, F, A) / J[:, None, None, None, None]
    assert rel(rve.spatial_tangent(F), a_push) <= 1e-13


def test_objectivity(rve, rng):
    F = random_F(rng, 6)
    W, P, A = rve.evaluate(F)
    for theta in (0.3, 2.0, -1.1):
        Q = rotation(theta)
        W2, P2, A2 = rve.evaluate(np.einsum("ab,qbc->qac", Q, F))
        assert rel(W2, W) <= 1e-13
        assert rel(P2, np.einsum("ab,qbc->qac", Q, P)) <= 1e-13
        assert rel(A2, np.einsum("ae,cf,qebfd->qabcd", Q, Q, A)) <= 1e-13


def test_small_strain_modulus_equals_tangent_at_identity_without_prestress():
    packing = square_lattice(6)
    rve = TaylorRVE(packing, K_N)
    W, P, A = rve.evaluate(np.eye(2))
    C = rve.small_strain_modulus()
    assert W == 0.0 and np.all(P == 0.0)
    assert rel(A, C) <= 1e-14
    assert rel(C, reference_modulus(packing, K_N)) <= 1e-14
    # one contact per disk and direction: C_1111 = C_2222 = k_n (sum |L|^2 per direction) / V
    assert C[0, 0, 0, 0] == pytest.approx(K_N, rel=1e-14)


def test_cauchy_relation_and_exact_bulk_modulus(packing, rve):
    C = rve.small_strain_modulus()
    assert rel(C, reference_modulus(packing, K_N)) <= 1e-13
    # central forces: C is fully symmetric, so lambda = C_1122 equals mu = C_1212 for any packing
    assert C[0, 0, 1, 1] == pytest.approx(C[0, 1, 0, 1], rel=1e-13)
    L, R = rve.candidates.branch, rve.candidates.radius_sum
    on = R - np.sqrt(L[:, 0] ** 2 + L[:, 1] ** 2) >= 0
    bulk = K_N / (4 * packing.area) * np.sum(L[on] ** 2)
    assert np.einsum("iikk", C) / 4.0 == pytest.approx(bulk, rel=1e-13)


def test_isotropic_lattice_has_lame_constants_equal():
    packing = hex_lattice(6, 6)
    C = TaylorRVE(packing, K_N).small_strain_modulus()
    lam, mu = C[0, 0, 1, 1], C[0, 1, 0, 1]
    assert lam == pytest.approx(mu, rel=1e-12)
    assert C[0, 0, 0, 0] == pytest.approx(lam + 2 * mu, rel=1e-12)
    assert C[1, 1, 1, 1] == pytest.approx(lam + 2 * mu, rel=1e-12)
    assert abs(C[0, 0, 0, 1]) <= 1e-12 * mu
    # bulk modulus K = (k_n / 4V) sum |L|^2 with 3 contacts per disk of length 1
    assert (lam + mu) == pytest.approx(K_N * 3 * 36 / (4 * packing.area), rel=1e-8)


def test_all_contacts_open_gives_exact_zero():
    rve = TaylorRVE(hex_lattice(6, 6), K_N)
    assert rve.evaluate(np.eye(2))[0] > 0.0  # closed at F = I
    F = np.array([1.2 * np.eye(2), [[1.5, 0.3], [0.0, 1.4]]])
    W, P, A = rve.evaluate(F)
    assert np.all(W == 0.0) and np.all(P == 0.0) and np.all(A == 0.0)
    assert np.all(rve.cauchy(F) == 0.0) and np.all(rve.spatial_tangent(F) == 0.0)


def test_stress_only_matches_full_evaluation(rve, rng):
    F = random_F(rng, 5)
    W, P, _ = rve.evaluate(F)
    W2, P2 = rve.stress(F)
    # equal to round-off: the vectorised sums associate differently with and without the tangent
    assert rel(W2, W) <= 1e-14 and rel(P2, P) <= 1e-14


def test_out_arrays_are_written(rve, rng):
    F = random_F(rng, 3)
    out = (np.empty(3), np.empty((3, 2, 2)), np.empty((3, 2, 2, 2, 2)))
    res = rve.evaluate(F, out=out)
    assert all(r is o for r, o in zip(res, out))
    assert rel(out[1], rve.stress(F)[1]) <= 1e-14


def test_contact_set_reproduces_stress(packing, rve, rng):
    F = random_F(rng, 1)[0]
    cs = rve.contacts(F)
    _, P = rve.stress(F)
    L = np.linalg.solve(F, cs.branch.T).T
    n = cs.branch / np.linalg.norm(cs.branch, axis=1)[:, None]
    P_c = -np.einsum("m,ma,mb->ab", cs.force, n, L) / packing.area
    assert rel(P_c, P) <= 1e-12
    assert np.all(cs.overlap >= 0) and cs.pairs.shape == (len(cs.force), 2)


@pytest.mark.parametrize(
    "F, words",
    [
        (np.array([[np.nan, 0.0], [0.0, 1.0]]), "NaN or inf"),
        (np.array([[np.inf, 0.0], [0.0, 1.0]]), "NaN or inf"),
        (np.array([[1.0, 0.0], [0.0, -1.0]]), "det F <= 0"),
        (np.zeros((2, 2)), "det F <= 0"),
        (np.diag([0.45, 1.0]), "min_stretch=0.5"),
        (rotation(0.4) @ np.diag([1.3, 0.3]), "min_stretch=0.5"),
    ],
)
def test_unsupported_F_raises(rve, F, words):
    batch = np.stack([np.eye(2), F, np.eye(2)])
    with pytest.raises(UnsupportedDeformationError, match=words) as info:
        rve.evaluate(batch)
    assert info.value.points.tolist() == [1]
    with pytest.raises(UnsupportedDeformationError, match=words):
        rve.stress(F)


def test_min_stretch_bound_itself_is_supported(rve):
    rve.evaluate(rotation(0.7) @ np.diag([0.5, 1.0]))


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"normal_stiffness": 0.0}, "normal_stiffness"),
        ({"normal_stiffness": -1.0}, "normal_stiffness"),
        ({"normal_stiffness": float("nan")}, "normal_stiffness"),
        ({"normal_stiffness": 1.0, "min_stretch": 0.0}, "min_stretch"),
        ({"normal_stiffness": 1.0, "min_stretch": 1.5}, "min_stretch"),
    ],
)
def test_bad_rve_arguments(packing, kwargs, words):
    with pytest.raises(ValueError, match=words):
        TaylorRVE(packing, **kwargs)


def test_bad_F_shape(rve):
    with pytest.raises(ValueError, match=r"shape \(n, 2, 2\)"):
        rve.evaluate(np.eye(3))


def test_coincident_centres_are_refused():
    packing = Packing([[1.0, 1.0], [1.0, 1.0], [3.0, 3.0]], [0.5, 0.4, 0.5], (5.0, 5.0))
    with pytest.raises(ValueError, match="disks 0 and 1 have the same centre"):
        TaylorRVE(packing, K_N)


def test_reference_state_is_explicit():
    """A generated packing is stress-free (P(I) ~ 1e-11 of the modulus, no warning); radii x 1.02
    prestress it (warning naming P(I)); radii x 1.1 are refused unless asked for."""
    import warnings

    from dolfinx_granular import generate_packing
    from dolfinx_granular.laws.taylor import PrestressWarning

    packing = generate_packing(40, seed=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PrestressWarning)
        rve = TaylorRVE(packing, K_N)
    assert rve.prestress.shape == (2, 2) and rve.prestress_ratio < 1e-9
    assert rve.max_reference_overlap < 1e-9
    swollen = Packing(packing.centers, 1.02 * packing.radii, packing.box)
    with pytest.warns(PrestressWarning, match=r"P\(I\) = \[\[-\d.*dolfinx_granular relax"):
        rve = TaylorRVE(swollen, K_N)
    assert 1e-3 < rve.prestress_ratio < 0.1 and np.all(np.linalg.eigvalsh(rve.prestress) < 0)
    assert np.array_equal(rve.prestress, rve.stress(np.eye(2))[1])
    overlapping = Packing(packing.centers, 1.1 * packing.radii, packing.box)
    # every remedy the message names works from where the user is: API, relax, the slope
    remedies = r"overlap by up to .*relax_overlaps.*dolfinx_granular relax .*--allow-overlaps"
    with pytest.raises(ValueError, match=remedies):
        TaylorRVE(overlapping, K_N)
    with pytest.warns(PrestressWarning):
        TaylorRVE(overlapping, K_N, allow_overlaps=True)
    with pytest.raises(ValueError, match="normal_stiffness must be a number, got 'stiff'"):
        TaylorRVE(packing, "stiff")
