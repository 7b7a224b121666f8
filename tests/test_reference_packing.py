"""The generator's guarantee (the same seed gives the same packing, bit for bit, on every CPU and
with every numpy release) and the shipped default packing of the slope."""

import os
import subprocess
import sys

from dolfinx_granular import Packing, TaylorRVE, generate_packing
from dolfinx_granular.packings import portable
from dolfinx_granular.packings.generation import network_stats
from dolfinx_granular.packings.reference_packing import (
    PARTICLES,
    SEED,
    reference_packing,
)

import numpy as np
import pytest

#: sha256 of ``generate_packing(700, seed=0)`` (centres, radii, box as little-endian float64).
#: The generator uses only correctly rounded arithmetic (``dolfinx_granular.packings.portable``),
#: so this must be the same on every CPU and with every numpy and Numba release. Recorded on an
#: Intel Xeon with AVX-512 (Debian bookworm: numpy 1.24.2, numba 0.56.4, glibc 2.36) and
#: checked there, identical, with numpy 2.5.5 and numba 0.68.1 (the DOLFINx 0.11 stack) and with
#: numpy's CPU dispatch and Numba's host CPU switched off (test_generation_ignores_the_cpu).
DIGEST_700 = "fce2f98a7b5e5e3c9cb7c9bc7a2ef85ae96ba57df714b0c0ba7c2cb77240be5c"

#: sha256 of the shipped file's arrays: made by the earlier generator, kept as it is
SHIPPED_DIGEST = "0ee3f637bfa8b5c8c2f350facaec46b2e002864ec566d7c9d37986d4b0a2b206"

# 700 disks and 200 spheres of seed 0, saved, in a process whose numpy must dispatch on nothing
_GENERATE = """
import sys
import dolfinx_granular
from dolfinx_granular import generate_packing
from test_reference_packing import numpy_dispatch
assert not numpy_dispatch(), f"numpy still dispatches on {numpy_dispatch()}"
generate_packing(700, seed=0).save(sys.argv[1])
generate_packing(200, seed=0, dim=3).save(sys.argv[2])
"""


def numpy_dispatch():
    """The CPU features that numpy dispatches on here (AVX512F, AVX2, FMA3, ...; numpy 2: X86_V3,
    X86_V4, ...)."""
    try:
        from numpy._core import _multiarray_umath as umath
    except ImportError:  # numpy 1
        from numpy.core import _multiarray_umath as umath
    return [f for f in umath.__cpu_dispatch__ if umath.__cpu_features__.get(f)]


def digest(packing):
    """sha256 of a packing's centres, radii and box (little-endian float64 bytes)."""
    return portable.digest(packing.centers, packing.radii, packing.box)


@pytest.fixture(scope="module")
def generated():
    return generate_packing(PARTICLES, seed=SEED)


def test_generated_packing_has_the_recorded_bits(generated):
    assert digest(generated) == DIGEST_700


@pytest.mark.slow
def test_generation_ignores_the_cpu(generated, tmp_path):
    """numpy without its SIMD loops (AVX-512, AVX2, FMA3, ...: what an older CPU takes) and Numba
    compiling for a generic x86-64 (no FMA, no AVX) give the same bits as this process."""
    env = dict(
        os.environ,
        NPY_DISABLE_CPU_FEATURES=" ".join(numpy_dispatch()),
        NUMBA_CPU_NAME="generic",
        NUMBA_CACHE_DIR=str(tmp_path / "numba"),  # compiled afresh for the generic CPU
        PYTHONPATH=os.pathsep.join([os.path.dirname(__file__), os.environ.get("PYTHONPATH", "")]),
    )
    disks, spheres = tmp_path / "disks.npz", tmp_path / "spheres.npz"
    run = subprocess.run(
        [sys.executable, "-c", _GENERATE, str(disks), str(spheres)],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr
    assert Packing.load(disks) == generated
    assert Packing.load(spheres) == generate_packing(200, seed=0, dim=3)


def test_the_shipped_packing_is_the_earlier_generators(generated):
    """The file is kept as the earlier generator wrote it (the slope's documented numbers come
    from it): the same contact network as today's packing of seed 0, centres 2.5e-4 of the mean
    radius apart."""
    shipped = reference_packing()
    assert digest(shipped) == SHIPPED_DIGEST
    r_mean = shipped.radii.mean()
    np.testing.assert_allclose(generated.radii, shipped.radii, rtol=1e-5)
    np.testing.assert_allclose(generated.box, shipped.box, rtol=1e-5)
    moved = (generated.centers - shipped.centers + 0.5 * shipped.box) % shipped.box
    assert np.abs(moved - 0.5 * shipped.box).max() < 1e-3 * r_mean
    a, b = network_stats(shipped), network_stats(generated)
    assert a.n_contacts == b.n_contacts
    np.testing.assert_array_equal(a.rattlers, b.rattlers)


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
