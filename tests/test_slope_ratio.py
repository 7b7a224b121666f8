"""Slopes of other ratios (run over rise): ``SlopeGeometry.with_slope_ratio`` keeps the crest with
the footing, the rise and the ground past the toe and widens the domain; its mesh follows the
ground; ``--slope-ratio`` reaches the run, its summary and its restart."""

import dataclasses
import json
import math

from dolfinx_granular.slope.geometry import SlopeGeometry

import numpy as np
import pytest

from helpers import run_slope_demo

RISE = 58.125 - 38.75


def test_ratio_1_is_the_default_geometry():
    default, made = SlopeGeometry(), SlopeGeometry.with_slope_ratio(1)
    for field in dataclasses.fields(SlopeGeometry):
        assert getattr(made, field.name) == getattr(default, field.name), field.name
    assert default.slope_ratio == 1.0 and default.slope_angle == 45.0


@pytest.mark.parametrize(
    "ratio, angle, width", [(2, 26.565, 96.875), (3, 18.435, 116.25), (4, 14.036, 135.625)]
)
def test_flatter_slopes_keep_crest_rise_and_toe(ratio, angle, width):
    g, default = SlopeGeometry.with_slope_ratio(ratio), SlopeGeometry()
    assert g.slope_end - g.slope_start == ratio * RISE and g.width == width
    assert g.slope_ratio == ratio and round(g.slope_angle, 3) == angle
    assert math.isclose(math.tan(math.radians(g.slope_angle)), 1 / ratio, rel_tol=1e-12)
    for name in ("slope_start", "crest_height", "toe_height", "footing_start", "footing_end"):
        assert getattr(g, name) == getattr(default, name), name
    assert g.width - g.slope_end == default.width - default.slope_end  # the ground past the toe
    assert g.columns == 20 + 5 * (ratio - 1) and g.refined(2).slope_ratio == ratio
    steep = SlopeGeometry.with_slope_ratio(0.4, rows=2)  # steeper, with a field overridden
    assert steep.slope_end - steep.slope_start == 2 * 3.875 and steep.rows == 2


@pytest.mark.parametrize(
    "ratio, words",
    [
        (1.5, ["1.5", "29.0625 m", "multiple of column_width / rise = 0.2", "1.4 or 1.6"]),
        (0.1, ["multiple of", "e.g. 0.2"]),
        (0.0, ["finite number > 0"]),
        (-2.0, ["finite number > 0"]),
        (float("nan"), ["finite number > 0"]),
    ],
)
def test_ratios_off_the_columns_are_refused(ratio, words):
    with pytest.raises(ValueError) as info:
        SlopeGeometry.with_slope_ratio(ratio)
    for w in words:
        assert w in str(info.value)


def test_width_and_slope_end_follow_from_the_ratio():
    with pytest.raises(ValueError, match="follow from the slope ratio: drop width"):
        SlopeGeometry.with_slope_ratio(2, width=100.75)


@pytest.mark.mpi
def test_mesh_of_a_ratio_2_slope_follows_its_ground():
    """475 cells; every boundary facet of the ground lies on y = y_s(x), the slope's part is
    hypot(run, rise) long, the area that of the wider section, rows evenly spaced."""
    pytest.importorskip("dolfinx")
    from dolfinx_granular.slope.geometry import FOOTING, RIGHT, SURFACE, create_mesh

    import ufl
    from dolfinx import fem
    from mpi4py import MPI

    g = SlopeGeometry.with_slope_ratio(2)
    msh, _, facets = create_mesh(MPI.COMM_WORLD, g)
    assert msh.topology.index_map(2).size_global == 25 * 19 == g.n_cells
    assert msh.geometry.index_map().size_global == 26 * 20
    ds = ufl.Measure("ds", domain=msh, subdomain_data=facets)
    x = ufl.SpatialCoordinate(msh)

    def integral(form):
        return msh.comm.allreduce(fem.assemble_scalar(fem.form(form)), op=MPI.SUM)

    run = 2 * RISE
    along = ufl.min_value(ufl.max_value(x[0] - g.slope_start, 0.0), run)  # m into the slope
    ground = g.crest_height - along / 2  # y_s(x): the crest, 1 down in 2 along, the toe
    assert integral((x[1] - ground) ** 2 * ds((SURFACE, FOOTING))) < 1e-20
    on_slope = ufl.conditional(ufl.And(x[0] > g.slope_start, x[0] < g.slope_end), 1.0, 0.0)
    assert np.isclose(integral(on_slope * ds(SURFACE)), math.hypot(run, RISE), rtol=1e-12)
    assert np.isclose(integral(1.0 * ds(RIGHT)), g.toe_height, rtol=1e-12)
    area = g.slope_start * g.crest_height + run * (g.crest_height + g.toe_height) / 2
    area += (g.width - g.slope_end) * g.toe_height
    assert np.isclose(integral(1.0 * ufl.dx(domain=msh)), area, rtol=1e-12)
    X = msh.geometry.x
    rows = X[:, 1] / g.surface_height(X[:, 0]) * g.rows
    assert np.abs(rows - np.round(rows)).max() < 1e-9


def test_command_line_builds_the_slope():
    pytest.importorskip("dolfinx")
    from dolfinx_granular.slope.cli import UserError, build_parser, options_of

    def geometry(*args):
        return options_of(build_parser().parse_args(list(args))).geometry

    assert geometry() == SlopeGeometry()
    assert geometry("--slope-ratio", "2") == SlopeGeometry.with_slope_ratio(2)
    refined = geometry("--slope-ratio", "3", "--refine", "2")
    assert refined == SlopeGeometry.with_slope_ratio(3).refined(2) and refined.slope_ratio == 3
    with pytest.raises(UserError, match=r"--slope-ratio 2.5: .* e\.g\. 2\.4 or 2\.6"):
        geometry("--slope-ratio", "2.5")


SMALL = ("--particles", "70", "--seed", "1", "--steps", "2", "--no-figure")


@pytest.mark.slow
def test_small_run_at_ratio_2_records_and_resumes_its_slope(tmp_path):
    """Stopped after the gravity step and one footing step, resumed to the end: the 1:2 slope
    in the log, summary.json and restart.npz, and kept by --resume."""
    out = tmp_path / "ratio2"
    proc, summary = run_slope_demo(out, *SMALL, "--slope-ratio", "2", "--stop-after", "2")
    assert "slope: 1:2 slope (26.6°), 475 cells, 1900 RVEs" in proc.stdout
    assert summary["status"] == "stopped" and summary["slope_ratio"] == 2.0
    with np.load(out / "restart.npz") as f:
        stored = json.loads(str(f["options"]))["geometry"]
    assert SlopeGeometry(**stored) == SlopeGeometry.with_slope_ratio(2)
    proc, _ = run_slope_demo(None, "--resume", out, "--no-figure")
    with open(out / "summary.json") as f:
        summary = json.load(f)
    assert summary["status"] == "converged" and summary["resumed_from"] == 2
    assert summary["completed_steps"] == 3 and summary["footing_settlement"] < 0
    assert summary["slope_ratio"] == 2.0 and round(summary["slope_angle"], 3) == 26.565
    assert "1:2 slope (26.6°), 475 cells" in proc.stdout
