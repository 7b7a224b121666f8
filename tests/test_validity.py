"""The validity measure: overlap of the active contacts over the smaller disk radius.

Known overlaps (two disks, a compressed triangular lattice) give the exact ratio for every law;
the gathered summary is the same serial and on 2 ranks (marked ``mpi``).
"""

import warnings

from dolfinx_granular import (
    OVERLAP_THRESHOLD,
    AdaptiveRVE,
    FrictionalRVE,
    OverlapMonitor,
    Packing,
    SmallStrainRVE,
    TaylorRVE,
    UnsupportedDeformationError,
    ValidityWarning,
    generate_packing,
)
from dolfinx_granular.laws.validity import summarise

import numpy as np
import pytest
from mpi4py import MPI

from helpers import hex_lattice

K_N = 2.8e7


def two_disks():
    """Radii 0.5 and 1 touching along x (centre distance 1.5, exact in binary) in a cell wide
    enough that no periodic image comes near."""
    return Packing([[2.0, 5.0], [3.5, 5.0]], [0.5, 1.0], [10.0, 10.0])


def laws(packing):
    taylor = TaylorRVE(packing, K_N)
    return [
        taylor,
        FrictionalRVE(packing, K_N, K_N, 0.3),
        SmallStrainRVE(taylor),
        AdaptiveRVE(taylor, 1e-3),
    ]


@pytest.mark.parametrize("law", laws(two_disks()), ids=lambda law: type(law).__name__)
def test_two_disks_give_the_exact_ratio(law):
    # stretch 0.9 along the branch: overlap 1.5 * 0.1, over the smaller radius 0.5
    lam = np.array([0.9, 0.96, 1.0, 1.01])
    F = np.zeros((4, 2, 2))
    F[:, 0, 0], F[:, 1, 1] = lam, 1.0
    ratio, contacts = law.overlap_statistics(F)
    expected = np.maximum(1.5 * (1.0 - lam), 0.0) / 0.5
    np.testing.assert_allclose(ratio, expected, rtol=1e-13, atol=1e-15)
    np.testing.assert_array_equal(contacts, [1, 1, 1, 0])  # touching (eps = 0) counts as active


def test_compressed_triangular_lattice_gives_the_exact_ratio():
    packing = hex_lattice(6, 6, overlap=0.0)
    rve = TaylorRVE(packing, K_N)
    lam = 0.97
    ratio, contacts = rve.overlap_statistics(lam * np.eye(2))
    # every lattice contact: radius sum 1, branch 1 -> lam, overlap 1 - lam, smaller radius 1/2
    assert ratio == pytest.approx((1.0 - lam) / 0.5, rel=1e-12)
    assert contacts == 3 * packing.n_particles  # 6 neighbours per disk, each contact once


def test_it_matches_the_contact_sets():
    packing = generate_packing(70, seed=2)
    rve = TaylorRVE(packing, K_N)
    rng = np.random.default_rng(5)
    F = np.eye(2) + 0.03 * rng.standard_normal((20, 2, 2))
    ratio, contacts = rve.overlap_statistics(F)
    r = packing.radii
    for q in range(F.shape[0]):
        c = rve.contacts(F[q])
        smaller = np.minimum(r[c.pairs[:, 0]], r[c.pairs[:, 1]])
        assert contacts[q] == len(c.overlap)
        assert ratio[q] == pytest.approx((c.overlap / smaller).max(initial=0.0), rel=1e-13)
    single = rve.overlap_statistics(F[0])
    assert single.max_ratio == ratio[0] and single.contacts == contacts[0]


def test_unsupported_deformation_is_refused():
    rve = TaylorRVE(two_disks(), K_N)
    with pytest.raises(UnsupportedDeformationError, match="det F <= 0"):
        rve.overlap_statistics(np.array([[[1.0, 0.0], [0.0, 1.0]], [[-1.0, 0.0], [0.0, 1.0]]]))
    with pytest.raises(ValueError, match=r"shape \(n, 2, 2\)"):
        rve.overlap_statistics(np.eye(3))


@pytest.mark.mpi
def test_summary_is_gathered_alike_on_every_rank():
    comm = MPI.COMM_WORLD
    # 10 points split over the ranks, ratios k / 20 for k = 0..9: 0.45 at x = 9, 4 above 0.25
    k = np.arange(10)[comm.rank :: comm.size]
    points = np.stack([k, np.zeros_like(k)], axis=1).astype(float)
    s = summarise(comm, k / 20.0, points, threshold=0.25)
    assert (s.max_ratio, s.at, s.points_above, s.points) == (0.45, [9.0, 0.0], 4, 10)
    assert s.fraction_above == 0.4 and s.exceeded
    assert s.as_dict()["fraction_above"] == 0.4
    assert comm.allgather(s.as_dict()) == [s.as_dict()] * comm.size
    assert summarise(comm, k / 20.0, points).threshold == OVERLAP_THRESHOLD == 0.10


def test_summary_rejects_a_bad_threshold():
    with pytest.raises(ValueError, match="threshold must be a finite number >= 0"):
        summarise(MPI.COMM_SELF, [0.1], [[0.0, 0.0]], threshold=-1)


def test_the_monitor_warns_once():
    comm = MPI.COMM_SELF
    monitor = OverlapMonitor()
    low = summarise(comm, [0.01, 0.05], [[0.0, 0.0], [1.0, 0.0]])
    high = summarise(comm, [0.01, 0.3], [[0.0, 0.0], [1.0, 0.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert not monitor.check(low, "step 1")
    with pytest.warns(ValidityWarning, match=r"step 2: contact overlaps reach 30 % .* beyond 10 %"):
        assert monitor.check(high, "step 2")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert not monitor.check(high, "step 3")
    assert monitor.warned and issubclass(ValidityWarning, UserWarning)
