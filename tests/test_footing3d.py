"""The 3-D scene: its mesh and tags, its run's agreement across linear solvers and ranks, its
summary's status (the slope's schema), and its output folder: a run there is refused, and
``force`` (``overwrite``, deprecated) replaces its files and no others."""

import json

import numpy as np
import pytest

dolfinx = pytest.importorskip("dolfinx")
from dolfinx_granular.footing3d import geometry as G  # noqa: E402
from dolfinx_granular.footing3d.run import FootingOptions, run_footing  # noqa: E402
from dolfinx_granular.io.outfolder import RunExistsError  # noqa: E402
from dolfinx_granular.slope.geometry import SlopeGeometry  # noqa: E402

from mpi4py import MPI  # noqa: E402

from helpers import run_demo  # noqa: E402

TINY = G.FootingGeometry(SlopeGeometry(rows=3), depth=15.5, layers=2, footing_layers=(0, 1))


@pytest.mark.mpi
def test_the_mesh_is_the_extruded_section_with_its_tags():
    g = G.FootingGeometry()
    msh, _, facets = G.create_mesh(MPI.COMM_WORLD, g)
    assert msh.topology.index_map(3).size_global == g.n_cells == 2280
    assert msh.topology.cell_type.name == "hexahedron"
    s = g.section
    areas = {
        G.BOTTOM: s.width * g.depth,
        G.LEFT: s.crest_height * g.depth,
        G.RIGHT: s.toe_height * g.depth,
        G.FOOTING: g.footing_area,
    }
    for tag, area in areas.items():
        assert G.facet_area(msh, facets, tag) == pytest.approx(area, rel=1e-12)
    # the front and back faces are the cross-section, the ground is the surface's length x depth
    section = s.width * s.toe_height + (s.crest_height - s.toe_height) * (
        s.slope_start + 0.5 * (s.slope_end - s.slope_start)
    )
    for tag in (G.FRONT, G.BACK):
        assert G.facet_area(msh, facets, tag) == pytest.approx(section, rel=1e-12)
    ground = (
        s.width
        - (s.slope_end - s.slope_start)
        + np.hypot(s.slope_end - s.slope_start, s.crest_height - s.toe_height)
    )
    total = G.facet_area(msh, facets, G.FOOTING) + G.facet_area(msh, facets, G.SURFACE)
    assert total == pytest.approx(ground * g.depth, rel=1e-12)


def test_bad_footing_layers_are_refused():
    with pytest.raises(ValueError, match="footing_layers"):
        G.FootingGeometry(layers=4, footing_layers=(3, 5))


def stale_run(folder):
    """A killed run's summary and a user's note in ``folder`` (rank 0 writes, all wait)."""
    if MPI.COMM_WORLD.rank == 0:
        (folder / "summary.json").write_text('{"status": "running"}')
        (folder / "notes.txt").write_text("mine")
    MPI.COMM_WORLD.barrier()


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = {}
    for solver in ("direct", "iterative"):
        # one folder for all ranks (each rank's pytest has its own temporary directory)
        folder = MPI.COMM_WORLD.bcast(tmp_path_factory.mktemp(solver), root=0)
        o = FootingOptions(
            particles=100, linear_solver=solver, figure=False, geometry=TINY,
            gravity_steps=1, footing_steps=2,
        )  # fmt: skip
        if solver == "direct":
            summary = run_footing(MPI.COMM_WORLD, o, str(folder))
        else:  # into a stale run beside a user's file, by the old name of force
            stale_run(folder)
            with pytest.warns(DeprecationWarning, match="overwrite"):
                summary = run_footing(MPI.COMM_WORLD, o, str(folder), overwrite=True)
        out[solver] = (summary, folder)
    return out


@pytest.mark.mpi
def test_direct_and_iterative_solvers_agree(runs):
    direct, iterative = runs["direct"][0], runs["iterative"][0]
    assert direct["status"] == iterative["status"] == "converged"
    assert direct["completed"] and direct["failed"] is None  # (the old keys, kept)
    assert iterative["settlement_m"] == pytest.approx(direct["settlement_m"], rel=1e-10)
    # the Krylov tolerance follows the Newton residual: Newton takes the same steps
    assert [s["iterations"] for s in iterative["steps"]] == [
        s["iterations"] for s in direct["steps"]
    ]


@pytest.mark.mpi
def test_different_folders_on_the_ranks_are_refused(tmp_path):
    if MPI.COMM_WORLD.size == 1:
        pytest.skip("needs 2 ranks (mpirun -n 2 pytest -m mpi)")
    o = FootingOptions(particles=100, figure=False, geometry=TINY)
    with pytest.raises(ValueError, match="different output folders"):
        run_footing(MPI.COMM_WORLD, o, str(tmp_path / f"rank{MPI.COMM_WORLD.rank}"))


@pytest.mark.mpi
def test_an_existing_run_is_refused_before_any_work(runs):
    summary, folder = runs["direct"]
    before = (folder / "summary.json").read_text()
    o = FootingOptions(particles=100, figure=False, geometry=TINY)
    with pytest.raises(RunExistsError, match=r"holds a footing3d run \(convergence.csv, .*--force"):
        run_footing(MPI.COMM_WORLD, o, str(folder))
    assert (folder / "summary.json").read_text() == before
    assert json.loads(before)["settlement_m"] == summary["settlement_m"]


@pytest.mark.mpi
def test_force_replaces_the_run_and_keeps_the_users_files(runs):
    summary, folder = runs["iterative"]
    stored = json.loads((folder / "summary.json").read_text())
    assert stored["status"] == "converged" and stored["settlement_m"] == summary["settlement_m"]
    assert (folder / "notes.txt").read_text() == "mine"
    assert summary["completed_steps"] == len(summary["steps"]) == 3


def test_serial_and_two_ranks_agree(tmp_path):
    """The demo's small run, serially and on 2 ranks: the same settlement, stress and steps."""
    runs = {}
    for ranks in (1, 2):
        run_demo("footing3d", "--small", "--no-figure", "--out", tmp_path / str(ranks), ranks=ranks)
        runs[ranks] = json.loads((tmp_path / str(ranks) / "summary.json").read_text())
    one, two = runs[1], runs[2]
    assert two["ranks"] == 2 and one["ranks"] == 1
    assert two["settlement_m"] == pytest.approx(one["settlement_m"], rel=1e-10)
    assert two["max_von_mises_Pa"] == pytest.approx(one["max_von_mises_Pa"], rel=1e-10)
    assert [s["iterations"] for s in two["steps"]] == [s["iterations"] for s in one["steps"]]
