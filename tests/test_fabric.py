"""Contact-normal density (angle of influence), fabric tensor and anisotropy."""

from dolfinx_granular import TaylorRVE, generate_packing
from dolfinx_granular.packings.fabric import (
    anisotropy,
    anisotropy_3d,
    contact_angles,
    contact_normals,
    density_deviation,
    fabric_tensor,
    normal_density,
    normal_density_sphere,
)

import numpy as np
import pytest

from helpers import hex_lattice, square_lattice

DEG = np.pi / 180


def _unit(v):
    return v / np.linalg.norm(v, axis=1)[:, None]


def _fibonacci_sphere(n):
    """n nearly uniform unit vectors (Fibonacci lattice, a low-discrepancy point set)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + np.sqrt(5.0)) * i
    s = np.sqrt(1.0 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def _sphere_integral(lat, lon, rho):
    return np.sum(rho * np.cos(lat)[:, None]) * (np.pi / lat.size) * (2 * np.pi / lon.size)


@pytest.fixture(scope="module")
def packing_3d():
    return generate_packing(200, seed=0, dim=3)


@pytest.mark.parametrize("delta_deg", [5, 10, 20, 30, 90])
def test_density_integrates_to_one(rng, delta_deg):
    angles = rng.uniform(-np.pi, np.pi, 37)
    m = 72000
    theta, rho = normal_density(angles, delta_deg * DEG, n_theta=m)
    assert rho.min() >= 0
    # Riemann sum of box windows: exact up to one grid cell per window edge
    assert np.sum(rho) * 2 * np.pi / m == pytest.approx(
        1.0, abs=2 * (2 * np.pi / m) / (2 * delta_deg * DEG)
    )


def test_uniform_set_gives_one_over_two_pi_everywhere():
    angles = (np.arange(180) + 0.5) * DEG  # one normal per degree on [0, pi)
    theta = (np.arange(1440) + 0.25) * 0.25 * DEG  # grid never on a window edge
    for delta in (10, 20, 30):
        _, rho = normal_density(angles, delta * DEG, theta=theta)
        np.testing.assert_allclose(rho, 1 / (2 * np.pi), rtol=1e-12)


def test_each_contact_counts_at_theta_and_theta_plus_pi():
    delta = 10 * DEG
    theta, rho = normal_density([0.3], delta, n_theta=3600)
    on = (
        np.minimum(
            np.abs(np.angle(np.exp(1j * (theta - 0.3)))),
            np.abs(np.angle(np.exp(1j * (theta - 0.3 - np.pi)))),
        )
        < delta - 1e-9
    )
    off = (
        np.minimum(
            np.abs(np.angle(np.exp(1j * (theta - 0.3)))),
            np.abs(np.angle(np.exp(1j * (theta - 0.3 - np.pi)))),
        )
        > delta + 1e-9
    )
    np.testing.assert_allclose(rho[on], 1 / (4 * delta))
    assert np.all(rho[off] == 0)
    # a normal and its opposite are the same contact orientation; vectors work like angles
    a = np.array([0.1, 1.0, 2.5, -2.0])
    t1, r1 = normal_density(a, delta)
    _, r2 = normal_density(a + np.pi, delta)
    _, r3 = normal_density(np.stack([np.cos(a), np.sin(a)], axis=1), delta)
    np.testing.assert_allclose(r1, r2)
    np.testing.assert_allclose(r1, r3)


def test_sliding_window_not_fixed_bins():
    # the density moves continuously with the contacts; fixed bins would not
    _, r1 = normal_density([0.0], 10 * DEG, theta=np.array([9.5 * DEG]))
    _, r2 = normal_density([1 * DEG], 10 * DEG, theta=np.array([10.5 * DEG]))
    assert r1[0] == r2[0] > 0


def test_fabric_of_known_sets():
    np.testing.assert_allclose(fabric_tensor([0.0]), [[1, 0], [0, 0]], atol=1e-15)
    np.testing.assert_allclose(fabric_tensor([0.0, np.pi / 2]), 0.5 * np.eye(2), atol=1e-15)
    F = fabric_tensor([0.0, 0.0, np.pi / 2, np.pi])
    np.testing.assert_allclose(F, [[0.75, 0], [0, 0.25]], atol=1e-15)
    a, th = anisotropy(F)
    assert a == pytest.approx(1.0) and th == pytest.approx(0.0)
    rot = fabric_tensor(np.array([0.0, 0.0, np.pi / 2]) + 30 * DEG)
    a, th = anisotropy(rot)
    assert a == pytest.approx(2 / 3) and th == pytest.approx(30 * DEG)
    assert np.trace(fabric_tensor(np.random.default_rng(0).uniform(0, 7, 50))) == pytest.approx(1.0)


def test_fabric_from_density_moments(rng):
    # int rho_delta n (x) n = I/2 + (F - I/2) sin(2 delta) / (2 delta) for the box window
    angles = rng.vonmises(0.4, 2.0, 300)
    delta = 25 * DEG
    m = 72000
    theta, rho = normal_density(angles, delta, n_theta=m)
    c, s = np.cos(theta), np.sin(theta)
    M = (
        np.array(
            [[np.sum(rho * c * c), np.sum(rho * c * s)], [np.sum(rho * c * s), np.sum(rho * s * s)]]
        )
        * 2
        * np.pi
        / m
    )
    expected = 0.5 * np.eye(2) + (fabric_tensor(angles) - 0.5 * np.eye(2)) * np.sin(2 * delta) / (
        2 * delta
    )
    np.testing.assert_allclose(M, expected, atol=2e-3)


def test_lattices():
    a, _ = anisotropy(fabric_tensor(contact_angles(hex_lattice(6, 6))))
    assert a == pytest.approx(0.0, abs=1e-12)  # hexagonal fabric is isotropic
    ang = contact_angles(square_lattice(4))
    assert ang.size == 2 * 16
    np.testing.assert_allclose(fabric_tensor(ang), 0.5 * np.eye(2), atol=1e-15)
    assert density_deviation(ang, 10 * DEG) > 1.0  # four spikes, far from isotropic


def test_generated_packing_angles_are_the_kernel_contacts():
    p = generate_packing(70, seed=2)
    ang = contact_angles(p)
    cs = TaylorRVE(p, 1.0).contacts(np.eye(2))
    assert ang.size == cs.pairs.shape[0] > 100
    np.testing.assert_allclose(np.cos(ang), cs.branch[:, 0] / np.hypot(*cs.branch.T))


def test_isotropy_improves_with_particle_count_on_average():
    dev, ani = {}, {}
    for n in (70, 700):
        angles = [contact_angles(generate_packing(n, seed=s)) for s in range(5)]
        dev[n] = np.mean([density_deviation(a, 20 * DEG) for a in angles])
        ani[n] = np.mean([anisotropy(fabric_tensor(a))[0] for a in angles])
    assert dev[700] < dev[70]
    assert ani[700] < ani[70]


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: normal_density([], 0.1), "no contacts"),
        (lambda: normal_density([0.1], 0.0), "angle of influence"),
        (lambda: normal_density([0.1], 2.0), "angle of influence"),
        (lambda: normal_density([[0.1, 0.2, 0.3]], 0.1), "1-D"),
        (lambda: fabric_tensor([np.nan]), "NaN"),
        (lambda: anisotropy(np.eye(3)), "shape"),
        (lambda: fabric_tensor(np.zeros((0, 3))), "no contacts"),
        (lambda: fabric_tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]), "row 1 is zero"),
        (lambda: fabric_tensor([[1.0, np.inf, 0.0]]), "NaN or inf"),
        (lambda: anisotropy_3d(np.eye(2) / 2), r"shape \(3, 3\)"),
        (lambda: anisotropy_3d(np.eye(3)), "trace 1"),
        (lambda: anisotropy_3d(np.full((3, 3), np.nan)), "NaN"),
        (lambda: normal_density_sphere([[0.0, 0.0, 1.0]], 0.0), "half-angle"),
        (lambda: normal_density_sphere([[0.0, 0.0, 1.0]], 1.6), "half-angle"),
        (lambda: normal_density_sphere([[0.0, 1.0]], 0.1), r"\(N_c, 3\)"),
        (lambda: normal_density_sphere([[0.0, 0.0, 1.0]], 0.1, n_lat=0), "n_lat"),
    ],
)
def test_bad_input(call, message):
    with pytest.raises(ValueError, match=message):
        call()


# --- 3-D: sphere packings -------------------------------------------------------------------


def test_fabric_3d_of_known_sets():
    axes = np.array([[1.0, 0, 0], [0, -2.0, 0], [0, 0, 0.5]])  # lengths and signs do not matter
    np.testing.assert_allclose(fabric_tensor(axes), np.eye(3) / 3, atol=1e-15)
    a, _ = anisotropy_3d(fabric_tensor(axes))
    assert a == pytest.approx(0.0, abs=1e-14)
    # all normals along one axis: A = e (x) e, a_ij = (15/2)(A - I/3), a = (15/2)(1 - 0) = 7.5
    a, axis = anisotropy_3d(fabric_tensor([[0.0, -3.0, 0.0]] * 4))
    assert a == pytest.approx(7.5)
    np.testing.assert_array_equal(axis, [0.0, 1.0, 0.0])  # sign: first nonzero component > 0
    # vectors in the plane z = 0: the 3-D fabric embeds the 2-D one
    ang = np.random.default_rng(3).uniform(-np.pi, np.pi, 25)
    v3 = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1)
    A3 = fabric_tensor(3.0 * v3)
    np.testing.assert_allclose(A3[:2, :2], fabric_tensor(ang), atol=1e-15)
    np.testing.assert_allclose(A3[2], 0.0, atol=1e-15)
    # axisymmetric with a_ij = diag(2, -1, -1) s / 3: a = sqrt(3/2 * 6 s^2 / 9) = s
    s = 0.7
    a, axis = anisotropy_3d(np.eye(3) / 3 + 2 / 15 * s / 3 * np.diag([-1.0, -1.0, 2.0]))
    assert a == pytest.approx(s, rel=1e-12)
    np.testing.assert_allclose(axis, [0.0, 0.0, 1.0], atol=1e-12)


def test_isotropic_vectors_have_small_anisotropy():
    n = 200_000
    # Gaussian vectors of random length: isotropic directions once normalised
    v = np.random.default_rng(11).normal(size=(n, 3))
    A = fabric_tensor(v)
    assert np.trace(A) == pytest.approx(1.0, abs=1e-12)
    a, axis = anisotropy_3d(A)
    assert np.linalg.norm(axis) == pytest.approx(1.0)
    # For isotropic normals dev(n (x) n) has E|.|^2 = 2/3 over 5 independent components, so
    # N a^2 / 56.25 ~ chi^2_5 / 5; chi^2_5 > 25.7 has probability 1e-4: a < 7.5 sqrt(25.7/5/N).
    # (A wrongly normalised fabric, or a missing 15/2, fails by orders of magnitude.)
    bound = 7.5 * np.sqrt(25.7 / 5 / n)
    assert bound < 0.04
    assert a < bound


def test_axisymmetric_sample_gives_back_its_anisotropy():
    # rho(n) = (1/4pi)(1 + a_ij n_i n_j), a_ij = (3/2) alpha (e (x) e - I/3): eigenvalues alpha,
    # -alpha/2, -alpha/2, scalar a = sqrt(3/2 a_ij a_ij) = 3 alpha / 2
    e = np.array([2.0, -1.0, 2.0]) / 3
    alpha = 0.6
    a_ij = 1.5 * alpha * (np.outer(e, e) - np.eye(3) / 3)
    rng = np.random.default_rng(2024)
    cand = _unit(rng.normal(size=(400_000, 3)))
    dens = 1.0 + np.einsum("ci,ij,cj->c", cand, a_ij, cand)  # in [1 - alpha/2, 1 + alpha]
    n = cand[rng.uniform(0.0, 1.0 + alpha, cand.shape[0]) < dens][:200_000]
    assert n.shape[0] == 200_000
    A = fabric_tensor(n)
    a, axis = anisotropy_3d(A)
    # Statistical tolerance: every quantity is a smooth function of the sample mean of n (x) n,
    # so its standard error is (delta method) std(g : n (x) n) / sqrt(N) with g its gradient in
    # A at the true fabric A0 = I/3 + (2/15) a_ij; we allow 5 standard errors (~6e-7 two-sided).
    A0 = np.eye(3) / 3 + 2 / 15 * a_ij
    N = n.shape[0]
    nn = np.einsum("ci,cj->cij", n, n)
    se_A = nn.std(axis=0) / np.sqrt(N)
    assert np.all(np.abs(A - A0) < 5 * se_A)
    a0 = 1.5 * alpha
    dev0 = 7.5 * (A0 - np.eye(3) / 3)
    g = 1.5 * 7.5 * dev0 / a0  # d a / d A
    se_a = np.einsum("cij,ij->c", nn, g).std() / np.sqrt(N)
    assert se_a < 0.01  # ~0.008: the check has teeth (a is 0.9)
    assert abs(a - a0) < 5 * se_a
    # major axis: first-order perturbation e' = e + sum_k (v_k . dA e) / (A_1 - A_k) v_k, the two
    # components independent-ish normal; the angle is below 6 of their largest standard error
    w, v = np.linalg.eigh(A0)
    se_axis = max(
        (np.einsum("ci,i,cj,j->c", n, v[:, k], n, e)).std() / np.sqrt(N) / (w[2] - w[k])
        for k in (0, 1)
    )
    assert se_axis < 0.01
    np.testing.assert_allclose(np.linalg.norm(axis), 1.0)
    assert axis[0] > 0  # sign convention; e has e_0 > 0 too
    assert np.linalg.norm(axis - e) < 6 * se_axis


@pytest.mark.parametrize("delta_deg", [20, 30, 45, 90])
def test_sphere_density_integrates_to_one(delta_deg):
    v = np.random.default_rng(5).normal(size=(400, 3))
    lat, lon, rho = normal_density_sphere(v, delta_deg * DEG, n_lat=36, n_lon=72)  # 5 deg cells
    assert lat.shape == (36,) and lon.shape == (72,) and rho.shape == (36, 72)
    assert -np.pi / 2 < lat.min() and lat.max() < np.pi / 2
    assert 0 <= lon.min() and lon.max() < 2 * np.pi
    assert rho.min() >= 0
    # Midpoint rule on 5 deg cells: one cap's count of cell centres misses its area by a boundary
    # term of standard deviation <= 0.022 (measured, delta >= 20 deg) that averages out over 400
    # randomly placed caps (-> ~1e-3); the smooth part errs by ~dlat^2/24 = 3e-4.
    assert _sphere_integral(lat, lon, rho) == pytest.approx(1.0, abs=1e-2)


def test_sphere_density_of_isotropic_sets():
    # delta = pi/2: the two hemispheres of every contact cover the sphere, rho = 1/(4 pi) exactly
    v = np.random.default_rng(6).normal(size=(50, 3))
    _, _, rho = normal_density_sphere(v, np.pi / 2, n_lat=20, n_lon=40)
    np.testing.assert_allclose(rho, 1 / (4 * np.pi), rtol=1e-12)
    # a Fibonacci lattice restricted to z > 0: +n and -n together cover the sphere uniformly; the
    # low-discrepancy lattice misses N (1 - cos delta) per cap pair by a few boundary points
    # (random normals would scatter by sqrt(cos d / (N (1 - cos d))) = 3.3 % at each point)
    f = _fibonacci_sphere(12_000)
    half = f[f[:, 2] > 0]
    lat, lon, rho = normal_density_sphere(half, 30 * DEG, n_lat=45, n_lon=90)
    assert np.max(np.abs(4 * np.pi * rho - 1)) < 0.03
    assert _sphere_integral(lat, lon, rho) == pytest.approx(1.0, abs=1e-3)
    # random isotropic normals: binomial count, relative standard deviation s at every point
    N, d = 6000, 30 * DEG
    s = np.sqrt(np.cos(d) / (N * (1 - np.cos(d))))
    _, _, rho = normal_density_sphere(np.random.default_rng(7).normal(size=(N, 3)), d, 45, 90)
    # 4050 grid points, P(|Z| > 5.5) = 4e-8 each: the union bound keeps the max below 5.5 s
    assert np.max(np.abs(4 * np.pi * rho - 1)) < 5.5 * s


def test_sphere_density_of_one_contact():
    n = np.array([0.3, -0.5, 0.8])
    delta = 20 * DEG
    lat, lon, rho = normal_density_sphere(5 * n[None], delta, n_lat=60, n_lon=120)
    m = np.stack(
        [
            np.cos(lat)[:, None] * np.cos(lon)[None, :],
            np.cos(lat)[:, None] * np.sin(lon)[None, :],
            np.broadcast_to(np.sin(lat)[:, None], rho.shape),
        ],
        axis=-1,
    )
    # angle to the nearer of +n and -n
    ang = np.arccos(np.clip(np.abs(m @ (n / np.linalg.norm(n))), 0, 1))
    inside, outside = ang < delta - 1e-9, ang > delta + 1e-9
    assert inside.sum() > 50
    np.testing.assert_allclose(rho[inside], 1 / (4 * np.pi * (1 - np.cos(delta))), rtol=1e-12)
    assert np.all(rho[outside] == 0)
    # the sign of a normal does not matter; chunking does not change the result
    _, _, r2 = normal_density_sphere(-n[None], delta, n_lat=60, n_lon=120)
    np.testing.assert_array_equal(rho, r2)
    many = np.random.default_rng(8).normal(size=(5000, 3))  # > 2^22 / 5000 grid points a chunk
    _, _, r3 = normal_density_sphere(many, delta, n_lat=60, n_lon=120)
    _, _, r4 = normal_density_sphere(many[:2500], delta, n_lat=60, n_lon=120)
    _, _, r5 = normal_density_sphere(many[2500:], delta, n_lat=60, n_lon=120)
    np.testing.assert_allclose(r3, 0.5 * (r4 + r5), rtol=1e-12)


def test_contact_normals_of_a_3d_packing(packing_3d):
    p = packing_3d
    n = contact_normals(p)
    cs = TaylorRVE(p, 1.0).contacts(np.eye(3))
    assert n.shape == (len(cs.force), 3)
    assert n.shape[0] > 200
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, rtol=1e-14)
    np.testing.assert_allclose(n, _unit(cs.branch), rtol=1e-14)
    A = fabric_tensor(n)
    assert np.trace(A) == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(A, A.T)
    a, axis = anisotropy_3d(A)
    assert 0 <= a < 1.0 and np.linalg.norm(axis) == pytest.approx(1.0)
    # a compressed F: the kernel's contacts at that F, with the same min_stretch handling
    F = np.diag([1.0, 1.0, 0.99])
    n_F = contact_normals(p, F)
    cs_F = TaylorRVE(p, 1.0, min_stretch=0.99).contacts(F)
    np.testing.assert_allclose(n_F, _unit(cs_F.branch), rtol=1e-14)
    assert n_F.shape[0] > n.shape[0]


def test_contact_normals_in_2d_match_contact_angles():
    p = generate_packing(70, seed=2)
    ang = contact_angles(p)
    n = contact_normals(p)
    assert n.shape == (ang.size, 2)
    np.testing.assert_allclose(n, np.stack([np.cos(ang), np.sin(ang)], axis=1), atol=1e-15)
    np.testing.assert_allclose(fabric_tensor(n), fabric_tensor(ang), atol=1e-15)


def test_3d_bad_input(packing_3d):
    with pytest.raises(ValueError, match="disks"):
        contact_angles(packing_3d)
    with pytest.raises(ValueError, match=r"shape \(3, 3\)"):
        contact_normals(packing_3d, np.eye(2))
