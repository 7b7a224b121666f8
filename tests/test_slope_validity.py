"""The slope model's validity entry for summary.json (marked ``mpi``: the same on 2 ranks)."""

import numpy as np
import pytest

dolfinx = pytest.importorskip("dolfinx")
from dolfinx_granular import TaylorRVE, generate_packing  # noqa: E402
from dolfinx_granular.linear import LinearElasticMaterial, lame_from_young  # noqa: E402
from dolfinx_granular.slope.model import SlopeModel  # noqa: E402

from mpi4py import MPI  # noqa: E402


@pytest.mark.mpi
def test_overlap_validity_of_the_slope_under_gravity():
    comm = MPI.COMM_WORLD
    packing = generate_packing(70, seed=0)
    model = SlopeModel(comm, TaylorRVE(packing, 2.8e7))
    model.set_gravity(1.0)
    assert model.solver.solve().converged
    entry = model.overlap_validity(threshold=0.05)
    # independently: the contact sets of every point, overlap over the smaller radius
    r = packing.radii
    ratios = []
    for F in model.material.F:
        c = model.law.contacts(F)
        ratios.append((c.overlap / np.minimum(r[c.pairs[:, 0]], r[c.pairs[:, 1]])).max(initial=0))
    ratios = np.array(ratios)
    assert entry["points"] == comm.allreduce(len(ratios)) == 1520
    assert entry["points_above"] == comm.allreduce(int((ratios > 0.05).sum()))
    assert 0 < entry["points_above"] < entry["points"]
    assert entry["max_ratio"] == pytest.approx(comm.allreduce(ratios.max(), op=MPI.MAX), rel=1e-13)
    assert entry["fraction_above"] == entry["points_above"] / entry["points"]
    assert entry["threshold"] == 0.05 and len(entry["at"]) == 2
    assert comm.allgather(entry) == [entry] * comm.size


def test_overlap_validity_is_none_without_a_packing_law():
    model = SlopeModel(
        MPI.COMM_SELF,
        None,
        material_factory=lambda law, u: LinearElasticMaterial(u, *lame_from_young(5e7, 0.3)),
    )
    assert model.overlap_validity() is None
