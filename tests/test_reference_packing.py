"""The shipped default packing of the slope: what it claims to be, on every stack."""

from dolfinx_granular import TaylorRVE, generate_packing
from dolfinx_granular.packings.generation import network_stats
from dolfinx_granular.packings.reference_packing import (
    MADE_WITH,
    PARTICLES,
    SEED,
    reference_packing,
)

import numba
import numpy as np
import pytest


def _numpy_avx512f():
    """Whether numpy dispatches its AVX-512 loops here (float64 exp and log among them)."""
    try:
        from numpy.core._multiarray_umath import __cpu_features__
    except ImportError:  # (numpy 2 moved it: not the numpy that wrote the file anyway)
        return False
    return bool(__cpu_features__.get("AVX512F"))


@pytest.mark.skipif(
    (np.__version__, numba.__version__, _numpy_avx512f())
    != (MADE_WITH["numpy"], MADE_WITH["numba"], MADE_WITH["avx512f"]),
    reason="generate_packing reproduces the shipped file bit for bit only with the numpy and "
    "numba that wrote it (Debian bookworm's), on a CPU with AVX-512 as it was written on",
)
def test_reference_packing_is_the_generated_one():
    shipped, generated = reference_packing(), generate_packing(PARTICLES, seed=SEED)
    np.testing.assert_array_equal(shipped.centers, generated.centers)
    np.testing.assert_array_equal(shipped.radii, generated.radii)
    np.testing.assert_array_equal(shipped.box, generated.box)


def test_reference_packing_is_jammed_and_stress_free():
    packing = reference_packing()
    stats = network_stats(packing)
    assert packing.n_particles == PARTICLES
    assert stats.rattler_fraction <= 0.15 and stats.coordination >= 3.8
    assert 0.0 < stats.max_overlap <= 2e-11
    assert TaylorRVE(packing, normal_stiffness=2.8e7).prestress_ratio < 1e-10


def test_the_slope_takes_the_shipped_packing_for_its_defaults():
    from dolfinx_granular.slope.cli import make_packing

    default, shipped = make_packing(PARTICLES, SEED), reference_packing()
    np.testing.assert_array_equal(default.centers, shipped.centers)
    np.testing.assert_array_equal(default.radii, shipped.radii)
    other, generated = make_packing(70, SEED), generate_packing(70, seed=SEED)
    np.testing.assert_array_equal(other.centers, generated.centers)
