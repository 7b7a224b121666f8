"""Sieve curves: the shipped CEN sand, validation, interpolation and diameter sampling."""

import decimal
import math
from decimal import Decimal

from dolfinx_granular.packings import portable
from dolfinx_granular.packings.gsd import (
    DEFAULT_D_MIN,
    SieveCurve,
    as_sieve_curve,
    cen_standard_sand,
)

import numpy as np
import pytest

CEN = {2.00: 100, 1.60: 93, 1.00: 67, 0.50: 33, 0.16: 13, 0.08: 1}


def test_shipped_cen_curve_matches_the_standard_table_and_names_its_source():
    c = cen_standard_sand()
    assert dict(zip(c.aperture.tolist(), c.passing.tolist())) == CEN
    assert "EN 196-1" in c.source and "normensand" in c.source


def test_passing_is_log_linear_between_sieves_and_diameter_at_inverts_it():
    c = cen_standard_sand()
    np.testing.assert_allclose(c.passing_at(c.aperture), c.passing)
    d = np.sqrt(0.5 * 1.0)  # geometric midpoint of the 0.5-1.0 class
    assert c.passing_at(d) == pytest.approx(0.5 * (33 + 67))
    assert c.passing_at(0.01) == 0.0 and c.passing_at(5.0) == 100.0
    for pct in (5.0, 33.0, 50.0, 80.0, 99.0):
        assert c.passing_at(c.diameter_at(pct)) == pytest.approx(pct)
    assert c.diameter_at(50.0) == pytest.approx(0.5 * 2 ** (17 / 34))  # d50 ~ 0.71 mm


def test_classes_above_the_cut_are_renormalised():
    lo, hi, share = cen_standard_sand().classes(d_min=0.3)
    assert lo[0] == 0.3 and share.sum() == pytest.approx(1.0)
    # the straddling class keeps the log-fraction of its share above the cut
    part = 20 * np.log(0.5 / 0.3) / np.log(0.5 / 0.16)
    np.testing.assert_allclose(share, np.array([part, 34, 26, 7]) / (part + 67))


@pytest.mark.parametrize("d_min", [DEFAULT_D_MIN, 0.16, None])
def test_sampled_area_fractions_follow_the_curve(d_min):
    c = cen_standard_sand()
    d = c.sample_diameters(20000, np.random.default_rng(5), d_min=d_min)
    lo = c.aperture[0] if d_min is None else d_min
    assert d.min() >= lo and d.max() <= 2.0
    base = c.passing_at(lo)
    for x in (0.2, 0.3, 0.5, 0.7, 1.0, 1.3, 1.6, 1.8):
        if x <= lo:
            continue
        expected = 100 * (c.passing_at(x) - base) / (100 - base)
        assert SieveCurve.area_passing(d, x) == pytest.approx(expected, abs=0.5)


def test_small_samples_are_stratified_and_deterministic():
    c = cen_standard_sand()
    a = c.sample_diameters(70, 3, d_min=0.5)
    b = c.sample_diameters(70, 3, d_min=0.5)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c.sample_diameters(70, 4, d_min=0.5))
    # stratification: 70 grains already carry the class shares to within a few grains' area
    assert SieveCurve.area_passing(a, 1.0) == pytest.approx(100 * 34 / 67, abs=6.0)


@pytest.mark.parametrize(
    "aperture, passing, message",
    [
        ([0.1, 0.5, 1.0], [10, 5, 100], "must not decrease"),
        ([0.1, 0.5, 1.0], [10, 50, 90], "reach 100"),
        ([0.0, 0.5, 1.0], [0, 50, 100], "must be > 0"),
        ([-1.0, 0.5, 1.0], [0, 50, 100], "must be > 0"),
        ([1.0, 0.5, 2.0], [0, 50, 100], "strictly increasing"),
        ([0.5, 0.5, 2.0], [0, 50, 100], "strictly increasing"),
        ([0.5, 1.0], [0, 50, 100], "same length"),
        ([1.0], [100], "at least 2"),
        ([0.5, 1.0], [-5, 100], r"\[0, 100\]"),
        ([0.5, 1.0], [0, 120], r"\[0, 100\]"),
        ([0.5, np.nan], [0, 100], "non-finite"),
        ([0.5, 1.0], [100, 100], "no size class"),
    ],
)
def test_bad_curves_are_rejected_with_the_reason(aperture, passing, message):
    with pytest.raises(ValueError, match=message):
        SieveCurve(aperture, passing)


def test_bad_cut_and_sample_size():
    c = cen_standard_sand()
    with pytest.raises(ValueError, match="cuts off the whole curve"):
        c.classes(d_min=2.0)
    with pytest.raises(ValueError, match="positive"):
        c.classes(d_min=-1.0)
    with pytest.raises(ValueError, match="n must be"):
        c.sample_diameters(0)


def test_csv_round_trip_and_bad_rows(tmp_path):
    f = tmp_path / "sand.csv"
    f.write_text("# my sand, lab sheet 7\naperture,passing\n0.3,0\n0.6,50\n1.18,100\n")
    c = SieveCurve.from_csv(f)
    np.testing.assert_array_equal(c.aperture, [0.3, 0.6, 1.18])
    assert "lab sheet 7" in c.source
    f.write_text("aperture,passing\n0.3,0\n0.6,x\n1.18,100\n")
    with pytest.raises(ValueError, match="row"):
        SieveCurve.from_csv(f)


def test_as_sieve_curve_accepts_pairs_and_rejects_junk():
    assert as_sieve_curve(None).name.startswith("CEN")
    c = as_sieve_curve(([0.3, 0.6, 1.18], [0, 50, 100]))
    assert c.passing_at(0.6) == 50
    with pytest.raises(ValueError, match="pair"):
        as_sieve_curve(3.0)


def _correctly_rounded(value, x):
    """Whether the float ``value`` is the nearest float to the decimal ``x`` (60 digits)."""
    below, above = np.nextafter(value, 0.0), np.nextafter(value, np.inf)
    with decimal.localcontext(decimal.Context(prec=60)):
        err = abs(Decimal(value) - x)
        return err <= abs(Decimal(float(below)) - x) and err <= abs(Decimal(float(above)) - x)


def test_cube_roots_are_correctly_rounded():
    """The generator's cube roots come from decimal arithmetic, not from a C library's pow:
    the nearest float to the exact root, whatever the CPU."""
    xs = np.random.default_rng(0).random(300) * 10.0 + 1e-3
    with decimal.localcontext(decimal.Context(prec=60)) as ctx:
        for x in xs.tolist():
            exact = ctx.exp(ctx.ln(Decimal(x)) / 3)
            assert _correctly_rounded(portable.root(x, 3), exact)
            assert _correctly_rounded(float(portable.inverse_roots([x], 3)[0]), 1 / exact)
    assert [portable.root(v, 3) for v in (27.0, 0.125, 1.0)] == [3.0, 0.5, 1.0]


def test_class_weights_are_correctly_rounded_sums():
    """Shares and number fractions are normalised by correctly rounded sums (math.fsum)."""
    for dim in (2, 3):
        lo, hi, nfrac = cen_standard_sand().number_fractions(DEFAULT_D_MIN, dim)
        assert math.fsum(nfrac.tolist()) == pytest.approx(1.0, abs=4e-16)
        assert np.all(nfrac > 0.0) and lo[0] == DEFAULT_D_MIN


#: sha256 of ``cen_standard_sand().sample_diameters(1000, 0, d_min=0.5, dim=k)`` (float64 bytes):
#: the same on every CPU and numpy release (recorded with numpy 1.24.2 and 2.5.5)
DIAMETERS = {
    2: "590d3c2b94138ec5ca5e4e1d764f09c381da16f405e522a949608e5b5ad22533",
    3: "f6eb5d8a52136c0db8c3726565543a35bb6052a3ac8caf9ed6a3e69794e6f0e9",
}


@pytest.mark.parametrize("dim", [2, 3])
def test_sampled_diameters_have_the_recorded_bits(dim):
    d = cen_standard_sand().sample_diameters(1000, 0, d_min=DEFAULT_D_MIN, dim=dim)
    assert portable.digest(d) == DIAMETERS[dim]
