"""Limit equilibrium of the slope benchmark (dolfinx_granular.slope.limit_equilibrium): the
infinite slope FS = tan φ / tan β, Bishop's simplified method on one circle against a slice
loop written out here, and the search for the critical circle (shallow slips tend to the
infinite slope, trends with φ, slope and footing, convergence, repeatability, bad input)."""

import dataclasses
import functools
import math

from dolfinx_granular.slope import (
    SlipCircle,
    SlopeGeometry,
    bishop_factor_of_safety,
    infinite_slope_factor_of_safety,
)
from dolfinx_granular.slope.limit_equilibrium import circle_factor_of_safety

import numpy as np
import pytest

DEFAULT = SlopeGeometry()
#: a circle from the crest (x = 30 m, under the footing) through the toe (58.125, 38.75)
ENTRY, EXIT, RADIUS = (30.0, 58.125), (58.125, 38.75), 25.0


@functools.cache
def search(ratio=1, phi=30.0, scale=0.0, **options):
    return bishop_factor_of_safety(SlopeGeometry.with_slope_ratio(ratio), phi, scale, **options)


def through(a, b, radius):
    """The centre (x, y) of the circle of ``radius`` through a and b, above the chord."""
    (xa, ya), (xb, yb) = a, b
    chord = math.hypot(xb - xa, yb - ya)
    lift = math.sqrt(radius**2 - chord**2 / 4) / chord
    return (0.5 * (xa + xb) - lift * (yb - ya), 0.5 * (ya + yb) + lift * (xb - xa))


def hand_methods(g, phi, centre, radius, xa, xb, n, scale=0.0, sub=40, c=0.0):
    """Fellenius's and Bishop's FS of the slip mass over [xa, xb], one slice at a time: the
    slice's weight from the trapezoidal rule on ``sub`` intervals, the footing's surcharge
    from the finite-element pressure (geometry.footing_pressure) integrated the same way;
    cohesion ``c`` (Pa) on each slice's base, c b / cos α long."""
    xc, yc = centre
    tan_phi, gamma, b = math.tan(math.radians(phi)), g.density * g.gravity, (xb - xa) / n
    W, sin_a = [], []
    for i in range(n):
        xs = np.linspace(xa + i * b, xa + (i + 1) * b, sub + 1)
        depth = g.surface_height(xs) - (yc - np.sqrt(radius**2 - (xs - xc) ** 2))
        load = gamma * np.maximum(depth, 0.0) - scale * g.footing_pressure(xs)
        W.append(float(np.sum(0.5 * (load[1:] + load[:-1]) * np.diff(xs))))
        sin_a.append((xc - (xa + (i + 0.5) * b)) / radius)
    W, sin_a = np.array(W), np.array(sin_a)
    cos_a, driving = np.sqrt(1.0 - sin_a**2), float(np.sum(W * sin_a))
    fellenius = bishop = float(np.sum(c * b / cos_a + tan_phi * W * cos_a)) / driving
    for _ in range(200):
        m = cos_a + sin_a * tan_phi / bishop
        bishop = float(np.sum((c * b + tan_phi * W) / m)) / driving
    return fellenius, bishop


# -- the infinite slope ---------------------------------------------------------------------


def test_infinite_slope_formula():
    assert infinite_slope_factor_of_safety(DEFAULT, 30) == pytest.approx(0.57735, abs=1e-5)
    assert infinite_slope_factor_of_safety(DEFAULT, 45) == pytest.approx(1.0, rel=1e-12)
    for ratio in (2, 3, 4):  # tan β = 1 / ratio
        g = SlopeGeometry.with_slope_ratio(ratio)
        value = infinite_slope_factor_of_safety(g, 25)
        assert value == pytest.approx(ratio * math.tan(math.radians(25)), rel=1e-12)
    flat = SlopeGeometry(toe_height=DEFAULT.crest_height)
    assert infinite_slope_factor_of_safety(flat, 30) == math.inf


# -- one circle: the method of slices ------------------------------------------------------


def test_bishop_on_a_toe_circle_matches_the_slices_by_hand():
    centre = through(ENTRY, EXIT, RADIUS)
    fs = circle_factor_of_safety(DEFAULT, 30, centre, RADIUS)
    fellenius, bishop = hand_methods(DEFAULT, 30, centre, RADIUS, ENTRY[0], EXIT[0], 100)
    assert fs == pytest.approx(bishop, rel=1e-3)
    # Bishop's normal forces (horizontal interslice forces) carry more than Fellenius's
    # (none): for this cohesionless circle Bishop's FS is the larger, by less than 15 %
    assert fellenius < bishop < 1.15 * fellenius


def test_cohesion_on_a_toe_circle_matches_the_slices_by_hand():
    """c = 50 kPa on the same circle: Bishop's FS as the slice loop's; it exceeds the
    cohesionless one by about the cohesion's share of the resisting moment."""
    centre = through(ENTRY, EXIT, RADIUS)
    fs = circle_factor_of_safety(DEFAULT, 30, centre, RADIUS, cohesion=5e4)
    _, bishop = hand_methods(DEFAULT, 30, centre, RADIUS, ENTRY[0], EXIT[0], 100, c=5e4)
    assert fs == pytest.approx(bishop, rel=1e-3)
    assert fs > 1.2 * circle_factor_of_safety(DEFAULT, 30, centre, RADIUS)


def test_with_cohesion_fs_depends_on_c_over_the_unit_weight():
    """c / (γ H) and φ set FS (Taylor's stability number): c and γ doubled together give the
    same critical circle; c alone doubled raises FS, and the critical circle goes deeper than
    the cohesionless slope's shallow slip."""
    g = SlopeGeometry.with_slope_ratio(2)
    base = bishop_factor_of_safety(g, 30, cohesion=2e4)
    heavy = dataclasses.replace(g, density=2 * g.density)
    twice = bishop_factor_of_safety(heavy, 30, cohesion=4e4)
    assert twice.factor_of_safety == pytest.approx(base.factor_of_safety, rel=1e-12)
    assert bishop_factor_of_safety(g, 30, cohesion=4e4).factor_of_safety > base.factor_of_safety
    assert base.depth > 2 * bishop_factor_of_safety(g, 30).depth


@pytest.mark.parametrize("eccentricity", [3.875, 0.0, -3.875])
def test_the_footing_surcharge_is_the_finite_element_pressure(eccentricity):
    g = dataclasses.replace(DEFAULT, eccentricity=eccentricity)
    centre = through((10.0, g.crest_height), EXIT, 45.0)  # the whole footing on the slip mass
    for scale in (0.05, 0.5):
        fs = circle_factor_of_safety(g, 30, centre, 45.0, footing_scale=scale, n_slices=400)
        _, bishop = hand_methods(g, 30, centre, 45.0, 10.0, EXIT[0], 400, scale=scale)
        assert fs == pytest.approx(bishop, rel=2e-4)


def test_slices_converge_on_a_fixed_circle():
    centre = through(ENTRY, EXIT, RADIUS)
    fs = [circle_factor_of_safety(DEFAULT, 30, centre, RADIUS, 0.2, n) for n in (25, 50, 100, 800)]
    errors = np.abs(np.array(fs[:3]) - fs[3])
    assert errors[2] < 1e-3 * fs[3] and errors[0] > errors[1] > errors[2]


def test_a_fixed_circle_does_not_depend_on_the_unit_weight():
    centre = through(ENTRY, EXIT, RADIUS)
    fs = circle_factor_of_safety(DEFAULT, 30, centre, RADIUS)
    for density, gravity in ((1000.0, 9.81), (2500.0, 1.62), (7.0, 100.0)):
        g = dataclasses.replace(DEFAULT, density=density, gravity=gravity)
        assert circle_factor_of_safety(g, 30, centre, RADIUS) == pytest.approx(fs, rel=1e-12)
    # with the footing only the surcharge over the unit weight counts
    heavy = dataclasses.replace(DEFAULT, density=3 * DEFAULT.density)
    loaded = circle_factor_of_safety(DEFAULT, 30, centre, RADIUS, footing_scale=0.1)
    assert circle_factor_of_safety(heavy, 30, centre, RADIUS, 0.3) == pytest.approx(loaded)
    assert loaded < fs  # this circle's slip mass carries the footing's loaded edge


# -- the critical circle ------------------------------------------------------------------


@pytest.mark.parametrize(
    "ratio, phi", [(1, 25.0), (1, 30.0), (1, 35.0), (2, 25.0), (2, 30.0), (3, 30.0), (4, 30.0)]
)
def test_a_shallow_slip_gives_the_infinite_slope(ratio, phi):
    g = SlopeGeometry.with_slope_ratio(ratio)
    found, infinite = search(ratio, phi), infinite_slope_factor_of_safety(g, phi)
    assert isinstance(found, SlipCircle)
    assert infinite <= found.factor_of_safety < 1.01 * infinite
    # the shallowest admissible slip (5 % of the 19.375 m rise) along the slope's face
    assert found.depth == pytest.approx(0.05 * 19.375, rel=0.01)
    assert found.entry_x > g.slope_start - 1.0 and found.exit_x < g.slope_end + 2.0
    assert found.radius > 5 * (g.slope_end - g.slope_start)  # a flat circle
    xc, yc, R = found.circle
    for x in (found.entry_x, found.exit_x):  # the circle meets the ground there
        y = yc - math.sqrt(R**2 - (x - xc) ** 2)
        assert y == pytest.approx(float(g.surface_height(x)), abs=1e-6)


def test_the_flatter_the_circle_the_closer_to_the_infinite_slope():
    infinite, depths = infinite_slope_factor_of_safety(DEFAULT, 30), (2.0, 0.96875, 0.25)
    excess = np.array([search(min_depth=d).factor_of_safety / infinite - 1 for d in depths])
    assert 0 < excess[2] < 0.001 and excess[1] < 0.01 and excess[0] < 0.05
    # the excess over tan φ / tan β falls as the depth squared (the arc's spread of α)
    ratios = excess[:-1] / excess[1:]
    assert ratios == pytest.approx((np.array(depths[:-1]) / depths[1:]) ** 2, rel=0.2)


def test_fs_grows_with_phi_and_with_a_flatter_slope():
    by_phi = [search(1, phi).factor_of_safety for phi in (25.0, 30.0, 35.0)]
    by_ratio = [search(ratio, 30.0).factor_of_safety for ratio in (1, 2, 3, 4)]
    assert np.all(np.diff(by_phi) > 0) and np.all(np.diff(by_ratio) > 0)


def test_fs_is_proportional_to_tan_phi():
    # c = 0: FS / tan φ solves Σ W / m_α = Σ W sin α FS / tan φ, m_α a function of tan φ / FS
    centre, tan = through(ENTRY, EXIT, RADIUS), lambda phi: math.tan(math.radians(phi))
    fs = [circle_factor_of_safety(DEFAULT, phi, centre, RADIUS, 0.5) for phi in (20, 40)]
    assert fs[1] / fs[0] == pytest.approx(tan(40) / tan(20), rel=1e-9)
    low, high = search(1, 30.0, 1.0), search(1, 40.0, 1.0)  # the same critical circle
    assert high.factor_of_safety / low.factor_of_safety == pytest.approx(tan(40) / tan(30))
    assert high.circle == pytest.approx(low.circle, rel=1e-6)


def test_the_footing_lowers_fs_and_its_circle_passes_under_it():
    free, part, full = (search(1, 30.0, scale) for scale in (0.0, 0.3, 1.0))
    assert full.factor_of_safety < part.factor_of_safety <= free.factor_of_safety
    assert full.factor_of_safety < 0.9 * free.factor_of_safety
    g = DEFAULT
    assert g.footing_start <= full.entry_x < g.footing_end < g.slope_start < full.exit_x
    assert full.centre_y - full.radius >= 0.0  # above the base
    # the search's circle on its own gives the same FS
    again = circle_factor_of_safety(g, 30, full.circle[:2], full.radius, footing_scale=1.0)
    assert again == pytest.approx(full.factor_of_safety, rel=1e-6)


def test_footing_scale_zero_ignores_the_footing():
    free = search(1, 30.0, n_grid=11)
    other = dataclasses.replace(DEFAULT, footing_load=-1e9, eccentricity=-3.0)
    assert bishop_factor_of_safety(other, 30.0, 0.0, n_grid=11) == free
    none = dataclasses.replace(DEFAULT, footing_load=0.0)
    assert bishop_factor_of_safety(none, 30.0, 1.0, n_grid=11) == free


def test_the_search_is_repeatable_and_converged():
    full = search(1, 30.0, 1.0)
    assert bishop_factor_of_safety(DEFAULT, 30.0, 1.0) == full  # deterministic
    for options in ({"n_grid": 41}, {"n_slices": 300}):
        other = search(1, 30.0, 1.0, **options).factor_of_safety
        assert other == pytest.approx(full.factor_of_safety, rel=3e-3), options


def test_flat_ground_has_no_failing_circle():
    flat = SlopeGeometry(toe_height=DEFAULT.crest_height)
    found = bishop_factor_of_safety(flat, 30.0, n_grid=11)
    assert found.factor_of_safety == math.inf and math.isnan(found.radius)


# -- bad input ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"phi_degrees": 0}, "phi_degrees"),
        ({"phi_degrees": 90}, "phi_degrees"),
        ({"phi_degrees": -30}, "phi_degrees"),
        ({"phi_degrees": math.nan}, "phi_degrees"),
        ({"phi_degrees": "30"}, "phi_degrees"),
        ({"footing_scale": -0.5}, "footing_scale"),
        ({"footing_scale": math.inf}, "footing_scale"),
        ({"n_slices": 1}, "n_slices"),
        ({"n_slices": 50.0}, "n_slices"),
        ({"min_depth": -1.0}, "min_depth"),
        ({"min_depth": 100.0}, "min_depth"),
        ({"n_grid": 2}, "n_grid"),
        ({"tolerance": 0.0}, "tolerance"),
        ({"cohesion": -1.0}, "cohesion must be a finite stress"),
    ],
)
def test_bad_input_raises(kwargs, match):
    arguments = {"phi_degrees": 30.0, **kwargs}
    with pytest.raises(ValueError, match=match):
        bishop_factor_of_safety(DEFAULT, **arguments)


def test_bad_circles_and_geometry_raise():
    with pytest.raises(ValueError, match="phi_degrees"):
        infinite_slope_factor_of_safety(DEFAULT, 0.5 * math.pi * 60)  # 94.2°
    with pytest.raises(ValueError, match="cuts the ground 0 times"):
        circle_factor_of_safety(DEFAULT, 30, (40.0, 100.0), 10.0)  # in the air
    with pytest.raises(ValueError, match="cuts the ground 1 times"):
        circle_factor_of_safety(DEFAULT, 30, (0.0, 70.0), 20.0)  # leaves through x = 0
    low = dataclasses.replace(DEFAULT, crest_height=8.0, toe_height=4.0)
    with pytest.raises(ValueError, match="below the base"):  # enters at 27.8, leaves at 58.6
        circle_factor_of_safety(low, 30, (45.0, 20.0), 21.0)
    with pytest.raises(ValueError, match="radius > 0"):
        circle_factor_of_safety(DEFAULT, 30, (40.0, 60.0), -1.0)
    weightless = dataclasses.replace(DEFAULT, gravity=0.0)
    with pytest.raises(ValueError, match="unit weight"):
        bishop_factor_of_safety(weightless, 30.0)
