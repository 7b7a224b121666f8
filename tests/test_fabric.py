"""Contact-normal density (angle of influence), fabric tensor and anisotropy."""

from dolfinx_granular import TaylorRVE, generate_packing
from dolfinx_granular.packings.fabric import (
    anisotropy,
    contact_angles,
    density_deviation,
    fabric_tensor,
    normal_density,
)

import numpy as np
import pytest

from helpers import hex_lattice, square_lattice

DEG = np.pi / 180


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
    ],
)
def test_bad_input(call, message):
    with pytest.raises(ValueError, match=message):
        call()
