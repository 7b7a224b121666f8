"""Jammed, stress-free sphere packings from a sieve curve (generate_packing with dim=3)."""

from dolfinx_granular import SieveCurve, TaylorRVE, generate_packing
from dolfinx_granular.packings import portable
from dolfinx_granular.packings.generation import network_stats
from dolfinx_granular.packings.gsd import DEFAULT_D_MIN, as_sieve_curve

import numpy as np
import pytest


@pytest.fixture(scope="module")
def spheres():
    return generate_packing(200, seed=0, dim=3)


def test_a_jammed_stress_free_sphere_packing(spheres):
    p = spheres
    assert p.dim == 3 and p.n_particles == 200 and p.box.shape == (3,)
    stats = network_stats(p)
    assert stats.volume_fraction >= 0.60
    assert stats.coordination >= 5.5  # isostatic: 6; rattlers (< 4 contacts) left out
    assert stats.rattler_fraction <= 0.15
    assert stats.min_coordination >= 4
    # every network contact overlaps by 1e-11 of the mean diameter: P(I) ~ 1e-11 of C
    assert 0.0 < stats.max_overlap <= 2e-11
    assert TaylorRVE(p, 1e5).prestress_ratio < 1e-9


def test_deterministic(spheres):
    again = generate_packing(200, seed=0, dim=3)
    assert again == spheres
    assert generate_packing(200, seed=1, dim=3) != spheres


def test_the_same_bits_on_every_machine(spheres):
    """sha256 of the centres, radii and box (little-endian float64) of 200 spheres, seed 0: the
    same on every CPU and numpy release (the generator's arithmetic is correctly rounded).
    Recorded with numpy 1.24.2 / numba 0.56.4 and checked with numpy 2.5.5 / numba 0.68.1, on an
    Intel Xeon with AVX-512; tests/test_reference_packing.py checks it without numpy's SIMD."""
    assert portable.digest(spheres.centers, spheres.radii, spheres.box) == (
        "e97351e0546cbfa97e919d8e3e9f4bbff7e627955c87da265cc47df52cc81c1c"
    )


def test_rattlers_are_force_free_and_apart(spheres):
    stats = network_stats(spheres)
    cs = TaylorRVE(spheres, 1e5).contacts(np.eye(3))
    touching = np.isin(cs.pairs, stats.rattlers).any(axis=1)
    assert not touching.any()  # the correction opens every rattler contact


def test_sizes_follow_the_sieve_curve_by_volume():
    curve = as_sieve_curve(None)
    d = curve.sample_diameters(20000, np.random.default_rng(0), d_min=DEFAULT_D_MIN, dim=3)
    lo, hi, share = curve.classes(DEFAULT_D_MIN)
    passing = SieveCurve.area_passing(d, hi, dim=3)
    assert np.allclose(passing, 100.0 * np.cumsum(share), atol=1.5)
    # read by area (2-D) the same diameters would miss the curve: the reading matters
    assert not np.allclose(SieveCurve.area_passing(d, hi), 100.0 * np.cumsum(share), atol=1.5)


def test_bad_dimension_is_refused():
    with pytest.raises(ValueError, match="dim must be 2 .* or 3"):
        generate_packing(20, dim=4)
    with pytest.raises(ValueError, match="dim must be 2 .* or 3"):
        as_sieve_curve(None).sample_diameters(10, 0, dim=1)
