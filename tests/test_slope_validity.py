"""The slope model's validity entry for summary.json (marked ``mpi``: the same on 2 ranks)."""

import numpy as np
import pytest

dolfinx = pytest.importorskip("dolfinx")
from dolfinx_granular import TaylorRVE, generate_packing  # noqa: E402
from dolfinx_granular.fem.linear import LinearElasticMaterial, lame_from_young  # noqa: E402
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


def test_the_slope_run_reports_its_validity_and_writes_the_cauchy_stress(tmp_path):
    """The demo's log, summary.json and XDMF: the overlaps per step, one ValidityWarning when
    they first pass the threshold, the final summary, and the cell-mean Cauchy stress."""
    import json
    import re

    from helpers import run_slope_demo

    out = tmp_path / "run"
    proc, summary = run_slope_demo(out, "--particles", "40", "--steps", "2", "--no-figure")
    steps = summary["step_info"]
    beyond = [s["step"] for s in steps if s["overlap_points_above"] > 0]
    entry = summary["overlap_validity"]
    assert entry["first_step_beyond"] == (beyond[0] if beyond else None)
    assert entry["max_ratio"] == steps[-1]["overlap_max_ratio"] > 0.0
    assert entry["points_above"] == steps[-1]["overlap_points_above"]
    assert entry["points"] == summary["rves"] and entry["threshold"] == 0.10
    logged = re.findall(r"overlaps <= ([\d.]+) % of r \(([\d.]+) % of points > 10 %\)", proc.stdout)
    assert logged == [
        (f"{100 * s['overlap_max_ratio']:.3g}", f"{100 * s['overlap_fraction_above']:.3g}")
        for s in steps
    ]
    warned = (proc.stdout + proc.stderr).count("ValidityWarning")
    assert warned == (1 if beyond else 0), proc.stderr[-2000:]
    assert beyond, "the paper's parameters overlap beyond 10 % under gravity already"
    with open(out / "slope.xdmf") as f:
        xdmf = f.read()
    assert xdmf.count('<Attribute Name="cauchy" AttributeType="Tensor"') == len(steps)
    assert json.loads((out / "summary.json").read_text())["overlap_validity"] == entry
