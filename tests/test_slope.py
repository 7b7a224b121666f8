"""The slope demo at reduced size: its files, and serial and ``mpirun -n 2`` runs agreeing."""

import numpy as np
import pytest

pytest.importorskip("dolfinx")
from helpers import XDMF_FIELDS, is_png, read_outputs, run_slope_demo  # noqa: E402


@pytest.mark.mpi
def test_mesh_and_footing_load():
    """380 structured Q1 cells on the reconstructed geometry; the footing pressure has the
    resultant -4e7 N/m at e = B/6 toward the slope, 0 at the heel and 2P/B at the edge."""
    from dolfinx_granular.slope.geometry import (
        BOTTOM,
        FOOTING,
        LEFT,
        RIGHT,
        SURFACE,
        SlopeGeometry,
        create_mesh,
    )

    import ufl
    from dolfinx import fem
    from mpi4py import MPI

    g = SlopeGeometry()
    msh, _, facets = create_mesh(MPI.COMM_WORLD, g)
    comm = msh.comm
    assert (
        msh.topology.index_map(2).size_global == 380 and msh.topology.cell_name() == "quadrilateral"
    )
    assert msh.geometry.index_map().size_global == 420
    ds = ufl.Measure("ds", domain=msh, subdomain_data=facets)
    x = ufl.SpatialCoordinate(msh)
    integral = lambda form: comm.allreduce(fem.assemble_scalar(fem.form(form)), op=MPI.SUM)  # noqa: E731
    area = 38.75 * 58.125 + 19.375 * (58.125 + 38.75) / 2 + 19.375 * 38.75
    assert np.isclose(integral(1.0 * ufl.dx(domain=msh)), area, rtol=1e-12)
    for tag, length in [
        (BOTTOM, 77.5),
        (LEFT, 58.125),
        (RIGHT, 38.75),
        (FOOTING, 23.25),
        (SURFACE, 77.5 - 23.25 - 19.375 + 19.375 * np.sqrt(2)),
    ]:
        assert np.isclose(integral(1.0 * ds(tag)), length, rtol=1e-10), tag
    q = g.footing_pressure_on_strip(x[0])
    P = integral(q * ds(FOOTING))
    assert np.isclose(P, -4.0e7, rtol=1e-12)
    assert np.isclose(integral(q * x[0] * ds(FOOTING)) / P, 23.25 + 3.875, rtol=1e-12)
    assert np.isclose(g.footing_pressure(11.625), 0.0, atol=1e-6)
    assert np.isclose(g.footing_pressure(34.875), -2 * 4.0e7 / 23.25, rtol=1e-12)
    assert g.footing_pressure(40.0) == 0.0
    # rows evenly spaced between the bottom and the surface, columns 3.875 m wide
    X = msh.geometry.x
    rows = X[:, 1] / g.surface_height(X[:, 0]) * g.rows
    assert np.abs(rows - np.round(rows)).max() < 1e-9
    cols = X[:, 0] / g.column_width
    assert np.abs(cols - np.round(cols)).max() < 1e-9


def test_geometry_rejects_off_grid_dimensions():
    from dolfinx_granular.slope.geometry import SlopeGeometry

    with pytest.raises(ValueError, match="column boundary"):
        SlopeGeometry(footing_start=12.0)
    with pytest.raises(ValueError, match="B/6"):
        SlopeGeometry(eccentricity=5.0)


SMALL = ("--particles", "70", "--seed", "1", "--steps", "2")

read = read_outputs


@pytest.fixture(scope="module")
def serial_run(tmp_path_factory):
    """The reduced slope on one rank, figure included: its folder and stdout (shared by the
    tests of its files and of the serial/parallel agreement)."""
    out = tmp_path_factory.mktemp("np1")
    return out, run_slope_demo(out, *SMALL)[0].stdout


@pytest.mark.slow
def test_demo_reduced_size_writes_everything(serial_run):
    tmp_path, stdout = serial_run
    summary, rows = read(tmp_path)
    assert "step  3 (footing, t = 1): gravity x1.00, footing -4.000e+07 N/m" in stdout
    assert summary["ranks"] == 1 and summary["steps"] == 3 and summary["converged"]
    assert len(summary["iterations"]) == 3 and all(i >= 1 for i in summary["iterations"])
    for key in (
        "footing_settlement",
        "max_von_mises",
        "min_von_mises",
        "wall_time",
        "time_rve",
        "time_assembly",
        "time_solve",
    ):
        assert np.isfinite(summary[key]), key
    assert (
        len(summary["max_von_mises_location"]) == 2 and len(summary["min_von_mises_location"]) == 2
    )
    assert summary["footing_settlement"] < 0  # the footing goes down
    assert 0 <= summary["min_von_mises"] < summary["max_von_mises"]
    assert summary["min_singular_value_F"] >= 0.5
    assert list(rows[0]) == ["step", "iterate", "residual_norm", "energy_norm_rel", "converged_by"]
    assert sorted({int(r["step"]) for r in rows}) == [1, 2, 3]
    assert sum(summary["iterations"]) + 3 == len(rows)  # iterates 0 .. n of each step
    with open(tmp_path / "slope.xdmf") as f:
        xdmf = f.read()
    for step in (1, 2, 3):
        assert xdmf.count(f'<Time Value="{step}"') == XDMF_FIELDS
    assert (tmp_path / "slope.h5").stat().st_size > 0
    png = tmp_path / "slope.png"
    assert is_png(png)
    import matplotlib.image as mpimg

    img = mpimg.imread(png)
    assert img.shape[0] > 400 and img.shape[1] > 800 and img[..., :3].std() > 0.05
    # the colour bar spans the Gauss-point extremes that the figure's markers name
    lo, hi = summary["figure_colour_range"]
    assert (lo, hi) == (summary["min_von_mises"] / 1e6, summary["max_von_mises"] / 1e6)


@pytest.mark.slow
def test_serial_and_two_ranks_agree(tmp_path, serial_run):
    proc, _ = run_slope_demo(tmp_path / "np2", *SMALL, "--no-figure", ranks=2)
    s1, r1 = read(serial_run[0])
    s2, r2 = read(tmp_path / "np2")
    assert s1["ranks"] == 1 and s2["ranks"] == 2
    # each rank's RVE seconds, and how evenly they divide: in summary.json and the last line
    for s in (s1, s2):
        assert len(s["time_rve_ranks"]) == len(s["time_rve_ranks_cpu"]) == s["ranks"]
        assert s["time_rve_kernel"] == max(s["time_rve_ranks"])
        for key in ("rve_imbalance", "rve_imbalance_cpu", "rve_imbalance_per_update"):
            assert s[key] >= 1.0, key
    assert s1["rve_imbalance"] == s1["rve_imbalance_per_update"] == 1.0
    assert s2["rve_imbalance_per_update"] >= s2["rve_imbalance"] * (1 - 1e-12)
    last = proc.stdout.strip().splitlines()[-1]
    assert last.startswith("slope: RVE seconds per rank ") and "max / mean" in last, last
    assert s1["converged"] and s2["converged"]
    # A step may stop one iteration apart when its last residual sits at the round-off threshold.
    assert all(abs(a - b) <= 1 for a, b in zip(s1["iterations"], s2["iterations"]))
    rel = lambda a, b: abs(a - b) / max(abs(a), abs(b))  # noqa: E731
    for key in ("footing_settlement", "max_von_mises"):
        assert rel(s1[key], s2[key]) <= 1e-10, (key, s1[key], s2[key])
    assert abs(s1["min_von_mises"] - s2["min_von_mises"]) <= 1e-10 * s1["max_von_mises"]
    assert np.allclose(
        s1["max_von_mises_location"], s2["max_von_mises_location"], rtol=0, atol=1e-12
    )
    for lab in s1["probes"]:
        F1, F2 = np.array(s1["probes"][lab]["F"]), np.array(s2["probes"][lab]["F"])
        assert np.abs(F1 - F2).max() <= 1e-10, lab
    # Residual norms above round-off and the energy norms of the first Newton steps agree too.
    rows2 = {(b["step"], b["iterate"]): b for b in r2}
    for a in r1:
        if 1 <= int(a["iterate"]) <= 2:
            b = rows2[(a["step"], a["iterate"])]
            assert rel(float(a["residual_norm"]), float(b["residual_norm"])) <= 1e-10
            assert rel(float(a["energy_norm_rel"]), float(b["energy_norm_rel"])) <= 1e-8


@pytest.mark.slow
def test_tangential_stiffness_without_friction_is_the_frictionless_run(tmp_path, serial_run):
    """--friction 0 with a k_t (a parameter sweep's first point) runs the frictionless model."""
    _, summary = run_slope_demo(
        tmp_path, *SMALL, "--no-figure", "--friction", "0", "--tangential-stiffness", "1e7"
    )
    reference, _ = read(serial_run[0])
    assert summary["friction"] == 0.0 and summary["iterations"] == reference["iterations"]
    assert summary["footing_settlement"] == reference["footing_settlement"]


def test_prestressed_packing_is_reported(tmp_path):
    """Radii x 1.02: the run warns, logs P(I) and records it in summary.json."""
    from dolfinx_granular import Packing, TaylorRVE, generate_packing
    from dolfinx_granular.laws.taylor import PrestressWarning
    from dolfinx_granular.slope import SlopeOptions

    p = generate_packing(70, seed=1)
    Packing(p.centers, 1.02 * p.radii, p.box).save(tmp_path / "swollen.npz")
    proc, summary = run_slope_demo(
        tmp_path / "out", "--packing", tmp_path / "swollen.npz", "--steps", "1", "--no-figure"
    )
    # the reference state of the demo's RVE, computed here from the same file and stiffness
    with pytest.warns(PrestressWarning):
        rve = TaylorRVE(Packing.load(tmp_path / "swollen.npz"), SlopeOptions().normal_stiffness)
    logged = f"reference state of the RVE: P(I) = {np.array2string(rve.prestress, precision=3)}"
    assert "PrestressWarning" in proc.stderr and logged in proc.stdout, proc.stdout[-3000:]
    assert np.allclose(summary["prestress"], rve.prestress, rtol=1e-12, atol=0)
    assert summary["prestress_ratio"] == pytest.approx(rve.prestress_ratio, rel=1e-12)
    assert 1e-3 < summary["prestress_ratio"] < 0.1 and summary["prestress"][0][0] < -1e5


def test_rve_imbalance_of_the_ranks_and_of_every_update():
    """max / mean of the ranks' RVE seconds, and summed over the updates, where every rank
    waits for the slowest: two ranks that take turns being slow balance in total only."""
    from dolfinx_granular.slope.summary import rve_imbalance, rve_imbalance_per_update

    assert rve_imbalance([3.0, 1.0]) == 1.5 and rve_imbalance([0.0, 0.0]) == 1.0
    assert rve_imbalance([2.0]) == 1.0
    turns = [[3.0, 1.0], [1.0, 3.0]]
    assert rve_imbalance([sum(t) for t in turns]) == 1.0
    assert rve_imbalance_per_update(turns) == 1.5
    assert rve_imbalance_per_update([[], []]) == 1.0
    assert rve_imbalance_per_update([[1.0], [1.0, 2.0]]) is None  # counted differently
