"""Probes and per-point values of a GranularMaterial: the nearest owned quadrature point over all
ranks, the law's values there, the same on every rank and serial = distributed.

Marked ``mpi``: under ``mpirun -n 2`` each test compares the distributed mesh with the same mesh
on one rank (``COMM_SELF``) in the same process.
"""

import numpy as np
import pytest

dolfinx = pytest.importorskip("dolfinx")
from dolfinx_granular import FrictionalRVE, RelaxedRVE, TaylorRVE, generate_packing  # noqa: E402
from dolfinx_granular.fem.compat import vector_space  # noqa: E402
from dolfinx_granular.fem.material import GranularMaterial  # noqa: E402
from dolfinx_granular.fem.probing import (  # noqa: E402
    _local_nearest,
    _winners,
    point_values,
    probe,
)
from dolfinx_granular.laws.validity import validity_summary  # noqa: E402

from dolfinx import fem, mesh  # noqa: E402
from mpi4py import MPI  # noqa: E402

K_N = 2.8e7
PACKING = generate_packing(70, seed=1)
TARGETS = [[0.3, 0.2], [1.9, 0.9], [1.0, 0.5], [0.25, 1 / 6], [5.0, -3.0]]


def loaded_material(comm, law, cells=None):
    """A 2 m x 1 m rectangle of 4 x 3 skewed Q1 cells under a non-homogeneous compression."""
    msh = mesh.create_rectangle(comm, [[0, 0], [2, 1]], [4, 3], mesh.CellType.quadrilateral)
    x = msh.geometry.x
    x[:, 0] += 0.1 * np.sin(3 * x[:, 1]) * x[:, 0]  # non-affine cells
    u = fem.Function(vector_space(msh))
    u.interpolate(
        lambda x: np.stack([-0.01 * x[0] * x[1], -0.02 * x[0] * x[1] + 0.003 * x[0] ** 2])
    )
    if cells is not None:
        cells = mesh.locate_entities(msh, 2, cells)
    material = GranularMaterial(law, u, cells=cells)
    material.update(tangent=False)
    material.commit()
    return material


@pytest.mark.mpi
def test_probe_is_the_same_serial_and_distributed_on_every_rank():
    law = TaylorRVE(PACKING, K_N)
    here = probe(loaded_material(MPI.COMM_WORLD, law), TARGETS)
    serial_material = loaded_material(MPI.COMM_SELF, law)
    alone = probe(serial_material, TARGETS)
    for name, value in here.__dict__.items():
        np.testing.assert_allclose(value, getattr(alone, name), rtol=1e-12, atol=1e-6, err_msg=name)
        gathered = MPI.COMM_WORLD.allgather(np.asarray(value))
        assert all(np.array_equal(g, value, equal_nan=True) for g in gathered), name
    # the nearest of all points (brute force over the one-rank material)
    X = serial_material.points
    d = np.linalg.norm(X[None] - np.asarray(TARGETS)[:, None], axis=2)
    np.testing.assert_array_equal(here.points, X[d.argmin(axis=1)])
    np.testing.assert_allclose(here.distance, d.min(axis=1), rtol=1e-14)


@pytest.mark.mpi
def test_probe_values_are_the_laws_at_that_point_on_a_subdomain():
    law = TaylorRVE(PACKING, K_N)
    material = loaded_material(MPI.COMM_WORLD, law, cells=lambda x: x[0] >= 0.9)
    result = probe(material, TARGETS)
    assert (result.points[:, 0] > 0.9).all()  # material points only, wherever the target is
    _, P = law.stress(result.F)
    np.testing.assert_allclose(result.P, P, rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(result.cauchy, law.cauchy(result.F), rtol=1e-12, atol=1e-6)
    ratio, contacts = law.overlap_statistics(result.F)
    np.testing.assert_array_equal(result.max_overlap_ratio, ratio)
    np.testing.assert_array_equal(result.contacts, contacts)
    np.testing.assert_allclose(result.coordination, 2 * contacts / PACKING.n_particles)
    assert result.F[:, 1, 1].max() < 1.0  # compressed: the test reads a loaded state
    assert result.as_dict()["points"] == result.points.tolist()


@pytest.mark.mpi
def test_point_values_follow_the_points_on_a_subdomain():
    law = TaylorRVE(PACKING, K_N)
    material = loaded_material(MPI.COMM_WORLD, law, cells=lambda x: x[1] <= 0.7)
    values = point_values(material)
    np.testing.assert_array_equal(values.points, material.points)
    np.testing.assert_array_equal(values.F, material.F)
    if material.n_points:
        np.testing.assert_allclose(values.P, law.stress(values.F)[1], rtol=1e-12, atol=1e-6)
        np.testing.assert_allclose(values.cauchy, law.cauchy(values.F), rtol=1e-12, atol=1e-6)
    total = MPI.COMM_WORLD.allreduce(material.n_points)
    assert total == 2 * 4 * 4  # the two bottom rows of 4 cells, 4 points each


@pytest.mark.mpi
def test_probe_reads_the_committed_history_of_a_frictional_law():
    law = FrictionalRVE(PACKING, K_N, K_N, 0.3)
    material = loaded_material(MPI.COMM_WORLD, law)
    result = probe(material, TARGETS)
    alone = probe(loaded_material(MPI.COMM_SELF, law), TARGETS)
    np.testing.assert_allclose(result.cauchy, alone.cauchy, rtol=1e-12, atol=1e-6)
    state = law.initial_state(len(TARGETS))
    sigma = law.cauchy(result.F, state)  # one step from F = I: the committed step's stress
    np.testing.assert_allclose(result.cauchy, sigma, rtol=1e-12, atol=1e-6)
    assert np.isfinite(result.max_overlap_ratio).all() and (result.contacts > 0).all()


def contact_statistics(material, points):
    """(m, 3) [contacts, coordination, largest overlap / smaller radius] of the law's own
    ``contacts(F, state)`` at the material's points ``points`` (m, 2), gathered from the ranks
    that own them."""
    law, comm = material.rve, material.mesh.comm
    rows = np.zeros((len(points), 3))
    for k, x in enumerate(points):
        for i in np.flatnonzero((material.points == x).all(axis=1))[:1]:
            c = law.contacts(material.F[i], material.state.take([i]))
            ratio = c.overlap / PACKING.radii[c.pairs].min(axis=1)
            rows[k] = len(c.overlap), 2 * len(c.overlap) / PACKING.n_particles, ratio.max()
    return comm.allreduce(rows, op=MPI.SUM)  # (a point is owned by one rank)


def probed_statistics(result):
    return np.stack([result.contacts, result.coordination, result.max_overlap_ratio], axis=1)


@pytest.mark.mpi
def test_probe_of_a_frictional_law_counts_the_contacts_of_its_state():
    law = FrictionalRVE(PACKING, K_N, K_N, 0.3)
    material = loaded_material(MPI.COMM_WORLD, law)
    result = probe(material, TARGETS)
    np.testing.assert_allclose(
        probed_statistics(result), contact_statistics(material, result.points), rtol=1e-12
    )


@pytest.mark.mpi
def test_probe_of_a_relaxed_law_counts_the_contacts_where_its_disks_moved():
    """The relaxed RVE has no overlap_statistics(F): its contacts depend on where the disks
    moved to. The probe gives those of ``contacts(F, state)`` at the point (was NaN)."""
    material = loaded_material(MPI.COMM_WORLD, RelaxedRVE(PACKING, K_N), lambda x: x[0] <= 0.6)
    result = probe(material, TARGETS[:2])
    stats = probed_statistics(result)
    assert np.isfinite(stats).all() and (result.contacts > 0).all(), stats
    np.testing.assert_allclose(stats, contact_statistics(material, result.points), rtol=1e-12)
    assert result.max_overlap_ratio.max() < 0.1  # overlaps of a small compression


@pytest.mark.mpi
def test_exact_ties_go_to_the_smaller_coordinates_whichever_rank_owns_them():
    comm = MPI.COMM_WORLD
    # (0, 0) and (2, 0) are both at distance 1 from (1, 0); the last rank holds (0, 0)
    mine = {0: [[2.0, 0.0], [5.0, 5.0]], comm.size - 1: [[0.0, 0.0], [2.0, 0.0]]}
    X = np.array(mine.get(comm.rank, np.zeros((0, 2))), dtype=float).reshape(-1, 2)
    key, index = _local_nearest(X, np.array([[1.0, 0.0]]))
    won = _winners(comm, key)
    assert comm.allreduce(int(won[0])) == 1
    if won[0]:
        assert comm.rank == comm.size - 1 and X[index[0]].tolist() == [0.0, 0.0]


def test_bad_probe_points_are_refused():
    material = loaded_material(MPI.COMM_SELF, TaylorRVE(PACKING, K_N))
    with pytest.raises(ValueError, match=r"probe points must be finite coordinates of shape"):
        probe(material, [[1.0, 2.0, 3.0]])
    with pytest.raises(ValueError, match=r"probe points must be finite"):
        probe(material, [[np.nan, 0.0]])
    one = probe(material, [0.3, 0.2])  # a single (2,) point
    assert one.points.shape == (1, 2)


@pytest.mark.mpi
def test_validity_summary_is_the_same_serial_and_distributed():
    law = TaylorRVE(PACKING, K_N)
    here = validity_summary(loaded_material(MPI.COMM_WORLD, law))
    alone = validity_summary(loaded_material(MPI.COMM_SELF, law))
    assert (here.points_above, here.points, here.fraction_above) == (
        alone.points_above,
        alone.points,
        alone.fraction_above,
    )
    assert here.max_ratio == pytest.approx(alone.max_ratio, rel=1e-13)
    np.testing.assert_allclose(here.at, alone.at, rtol=1e-13)
    assert 0 < here.points_above < here.points  # the threshold splits this state's points
    assert MPI.COMM_WORLD.allgather(here.as_dict()) == [here.as_dict()] * MPI.COMM_WORLD.size
