"""generate_packing: jammed, stress-free, rigid, periodic, deterministic; bad input."""

from dolfinx_granular import Packing, TaylorRVE, generate_packing, network_stats
from dolfinx_granular.packings import cholesky, fire, generation, neighbours, portable
from dolfinx_granular.packings.gsd import SieveCurve, cen_standard_sand

import numpy as np
import pytest

# (70, 68): the first jammed state has 17 % rattlers and is rejected
CASES = [(70, 0), (70, 1), (70, 2), (70, 68), (350, 1), (700, 3)]


@pytest.fixture(scope="module")
def packings():
    return {case: generate_packing(case[0], seed=case[1]) for case in CASES}


def mandel(A):
    """3x3 matrix of a 4th-order tensor on symmetric 2x2 tensors (Mandel basis)."""
    s = np.sqrt(2.0)
    idx = [(0, 0), (1, 1), (0, 1)]
    w = [1.0, 1.0, s]
    return np.array([[A[a + b] * wa * wb for b, wb in zip(idx, w)] for a, wa in zip(idx, w)])


def brute_force_overlaps(p):
    """Overlap eps of every pair at every periodic image within one cell, independent of the
    kernel: (i, j, sx, sy, eps) rows for eps > -1e-3 * mean diameter."""
    rows = []
    c, r, L = p.centers, p.radii, p.box
    for i in range(p.n_particles):
        for j in range(i + 1, p.n_particles):
            for sx in (-1, 0, 1):
                for sy in (-1, 0, 1):
                    d = np.hypot(c[j, 0] + sx * L[0] - c[i, 0], c[j, 1] + sy * L[1] - c[i, 1])
                    eps = r[i] + r[j] - d
                    if eps > -2e-3 * r.mean():
                        rows.append((i, j, sx, sy, eps))
    return rows


@pytest.mark.parametrize("case", CASES)
def test_jammed_rigid_network(packings, case):
    s = network_stats(packings[case])
    assert s.volume_fraction >= 0.82
    assert s.rattler_fraction <= 0.15
    assert s.min_coordination >= 3
    assert s.coordination >= 3.8
    # the statistics are those of the kernel's contacts at F = I, recounted here: the same
    # contacts, rattlers (fewer than 3 contacts with the other non-rattlers; every non-rattler
    # has 3 or more) and the mean coordination of the non-rattlers
    p = packings[case]
    pairs = TaylorRVE(p, 1.0, min_stretch=0.99).contacts(np.eye(2)).pairs
    assert len(pairs) == s.n_contacts
    rattler = np.isin(np.arange(p.n_particles), s.rattlers)
    assert s.rattler_fraction == rattler.mean()
    backbone = pairs[~(rattler[pairs[:, 0]] | rattler[pairs[:, 1]])]
    counts = np.bincount(backbone.ravel(), minlength=p.n_particles)[~rattler]
    mixed = pairs[rattler[pairs[:, 0]] != rattler[pairs[:, 1]]]  # rattler - non-rattler
    rattler_end = np.where(rattler[mixed[:, 0]], mixed[:, 0], mixed[:, 1])
    to_backbone = np.bincount(rattler_end, minlength=p.n_particles)[rattler]
    assert counts.min() == s.min_coordination and np.all(to_backbone < 3)
    assert counts.mean() == pytest.approx(s.coordination, rel=1e-15)
    assert 0.0 < s.max_overlap <= 1e-9


@pytest.mark.parametrize("case", CASES)
def test_nearly_stress_free_with_positive_definite_tangent(packings, case):
    rve = TaylorRVE(packings[case], 2.8e7)
    s0 = np.abs(rve.cauchy(np.eye(2))).max()
    s1 = np.abs(rve.cauchy(0.99 * np.eye(2))).max()
    assert s0 < 1e-6 * s1
    A = rve.evaluate(np.eye(2))[2]
    assert np.linalg.eigvalsh(mandel(A)).min() > 0.0
    # stress-free reference: the tangent at I equals the small-strain modulus (eq. 15)
    C = rve.small_strain_modulus()
    np.testing.assert_allclose(A, C, rtol=0, atol=1e-6 * np.abs(C).max())
    # and the modulus is a physical Taylor modulus: isotropic-ish, K ~ k_n phi Z / (2 pi)
    s = network_stats(packings[case])
    K = np.einsum("iikk", C) / 4
    assert 0.7 < K / (2.8e7 * s.volume_fraction * s.coordination / (2 * np.pi)) < 1.3


def test_deterministic_and_seed_dependent(packings):
    again = generate_packing(70, seed=1)
    ref = packings[(70, 1)]
    np.testing.assert_array_equal(again.centers, ref.centers)
    np.testing.assert_array_equal(again.radii, ref.radii)
    np.testing.assert_array_equal(again.box, ref.box)
    assert not np.array_equal(packings[(70, 0)].radii, ref.radii)


@pytest.mark.parametrize("case", [(70, 2), (350, 1)])
def test_periodic_overlaps_are_consistent_across_the_boundary(packings, case):
    p = packings[case]
    rows = brute_force_overlaps(p)
    eps = np.array([row[4] for row in rows])
    # no deep overlap anywhere, across the boundary included
    assert eps.max() <= 1e-9 * 2 * p.radii.mean()
    active = sorted((i, j) for i, j, sx, sy, e in rows if e >= 0.0)
    cs = TaylorRVE(p, 1.0, min_stretch=0.99).contacts(np.eye(2))
    assert sorted(map(tuple, np.sort(cs.pairs, axis=1).tolist())) == active
    crossing = [row for row in rows if row[4] >= 0.0 and (row[2] or row[3])]
    assert crossing, "a periodic jammed packing has contacts across the boundary"
    # moving the origin of the cell turns boundary contacts into inner ones and vice versa; a
    # consistent periodic packing has the same contact network and overlaps (to rounding)
    moved = Packing(p.centers + 0.37 * p.box, p.radii, p.box)
    rows2 = brute_force_overlaps(moved)
    act2 = sorted((i, j) for i, j, sx, sy, e in rows2 if e >= 0.0)
    assert act2 == active
    e1 = np.sort([e for *_, e in rows if e >= 0.0])
    e2 = np.sort([e for *_, e in rows2 if e >= 0.0])
    np.testing.assert_allclose(e1, e2, rtol=0, atol=1e-13 * p.box.max())
    s1, s2 = network_stats(p), network_stats(moved)
    assert (s1.n_contacts, s1.coordination) == (s2.n_contacts, s2.coordination)


def test_sizes_follow_the_sieve_curve_and_keep_the_span(packings):
    p = packings[(700, 3)]
    d = 2 * p.radii
    assert d.min() >= 0.5 * (1 - 1e-3) and d.max() <= 2.0 * (1 + 1e-3)
    c = cen_standard_sand()
    for x in (0.7, 1.0, 1.6):
        expected = 100 * (c.passing_at(x) - 33) / 67
        assert SieveCurve.area_passing(d, x) == pytest.approx(expected, abs=3.0)


def test_user_curve_and_aspect():
    p = generate_packing(120, ([0.3, 0.6, 1.18], [0, 50, 100]), seed=4, d_min=None, aspect=2.0)
    assert p.box[1] / p.box[0] == pytest.approx(2.0)
    assert 0.3 * (1 - 1e-3) <= 2 * p.radii.min() and 2 * p.radii.max() <= 1.18 * (1 + 1e-3)
    s = network_stats(p)
    assert s.volume_fraction >= 0.82 and s.min_coordination >= 3


@pytest.mark.slow
def test_700_particles_jammed_and_stress_free():
    # its time is a figure of benchmarks/generation.py, not an assert (a loaded CI machine)
    p = generate_packing(700, seed=11)
    s = network_stats(p)
    assert p.n_particles == 700 and s.volume_fraction >= 0.82 and s.rattler_fraction <= 0.15
    assert s.min_coordination >= 3 and TaylorRVE(p, 1.0).prestress_ratio < 1e-6


def _median_hop(p):
    """Median distance (mm) between the centres of disks k and k + 1, over the diameter."""
    return np.median(np.linalg.norm(np.diff(p.centers, axis=0), axis=1)) / (2 * p.radii.mean())


@pytest.mark.slow
def test_large_packings_are_numbered_along_the_cells():
    # above CELL_ORDER_ABOVE disks, neighbours in the array are neighbours in space (FIRE's
    # memory access); a smaller packing keeps the random order of its drawn centres
    large = generate_packing(generation.CELL_ORDER_ABOVE + 1, seed=5)
    small = generate_packing(700, seed=5)
    width = large.box[0] / (2 * large.radii.mean())  # the cell in diameters (~100)
    assert _median_hop(large) < 4.0 < 0.1 * width
    assert _median_hop(small) > 0.2 * small.box[0] / (2 * small.radii.mean())
    s = network_stats(large)  # as jammed and stress-free as a small one
    assert s.rattler_fraction <= 0.15 and s.coordination >= 3.8 and s.min_coordination >= 3
    assert TaylorRVE(large, 1.0).prestress_ratio < 1e-6


def test_rejected_networks_are_jammed_again_and_the_best_attempt_is_returned():
    lines = []
    p = generate_packing(70, seed=0, max_rattlers=0.0, max_attempts=3, progress=lines.append)
    assert sum("attempt" in s for s in lines) == 3
    assert network_stats(p).rattler_fraction > 0  # no 70-disk network without rattlers here
    first = generate_packing(70, seed=0, max_attempts=1)
    assert network_stats(p).rattler_fraction <= network_stats(first).rattler_fraction


def test_progress_reports_stages():
    lines = []
    generate_packing(70, seed=0, progress=lines.append)
    assert any("jammed" in s for s in lines) and lines[-1].startswith("done")


@pytest.mark.parametrize(
    "args, kwargs, message",
    [
        ((1,), {}, "n_particles"),
        ((0,), {}, "n_particles"),
        ((-5,), {}, "n_particles"),
        ((2.5,), {}, "n_particles"),
        (("many",), {}, "n_particles"),
        ((70, ([0.5, 1.0, 2.0], [10, 5, 100])), {}, "must not decrease"),
        ((70, ([0.5, 1.0, 2.0], [10, 50, 90])), {}, "reach 100"),
        ((70, ([0.0, 1.0, 2.0], [0, 50, 100])), {}, "must be > 0"),
        ((70,), {"aspect": 0.0}, "aspect"),
        ((70,), {"pressure": 0.5}, "pressure"),
        ((70,), {"contact_overlap": 1e-3}, "contact_overlap"),
        ((70,), {"d_min": 3.0}, "d_min"),
        ((70,), {"max_rattlers": -0.1}, "max_rattlers"),
        ((70,), {"max_attempts": 0}, "max_attempts"),
        ((2,), {}, "too few"),  # two disks of the CEN sand span most of their cell
    ],
)
def test_bad_input_raises_a_clear_error(args, kwargs, message):
    with pytest.raises(ValueError, match=message):
        generate_packing(*args, **kwargs)


# -- neighbour search, FIRE chunks, progress, benchmark --------------------------------------------


def brute_force_pairs(x, r, box, ratio, skin, with_self):
    """{(i, j, sx, sy)} with |x_j + s * box - x_i| < ratio (r_i + r_j) + skin, j > i (or j == i
    with s > 0 lexicographically), over every image that can be within reach: O(N² K²)."""
    reach = ratio * 2.0 * r.max() + skin
    kx, ky = (int(np.ceil(reach / b)) + 1 for b in box)
    found = set()
    for sx in range(-kx, kx + 1):
        for sy in range(-ky, ky + 1):
            dx = x[None, :, 0] - x[:, None, 0] + sx * box[0]
            dy = x[None, :, 1] - x[:, None, 1] + sy * box[1]
            rc = ratio * (r[:, None] + r[None, :]) + skin
            hit = dx * dx + dy * dy < rc * rc
            upper = np.triu(np.ones_like(hit), 1)
            if with_self and (sx > 0 or (sx == 0 and sy > 0)):
                upper |= np.eye(len(r), dtype=bool)
            found |= {(i, j, sx, sy) for i, j in zip(*np.nonzero(hit & upper))}
    return found


@pytest.mark.parametrize(
    "n, aspect, cells, skin, with_self",
    [
        (400, 1.0, 12.0, 0.3, False),  # many cells per side: the FIRE case
        (300, 4.0, 6.0, 0.0, True),  # elongated cell
        (60, 1.0, 2.5, 0.3, False),  # two cells per side: left and right neighbour coincide
        (40, 0.5, 1.2, 0.3, True),  # one cell per side
        (12, 1.0, 0.4, 0.1, True),  # cell narrower than the reach: images two cells away
        (2, 1.0, 0.6, 0.0, True),
    ],
)
def test_cell_list_finds_exactly_the_brute_force_pairs(n, aspect, cells, skin, with_self):
    rng = np.random.default_rng(n)
    for _ in range(3):
        r = rng.uniform(0.25, 1.0, n)
        reach = 2.0 * r.max() + skin
        box = cells * reach * np.array([1.0, aspect])  # `cells` cells on the short side
        x = rng.random((n, 2)) * box
        m, pi, pj, ps = neighbours.find_pairs(x, r, box, 1.0, skin, with_self)
        found = list(zip(pi[:m].tolist(), pj[:m].tolist(), *ps[:m].T.tolist()))
        assert len(found) == len(set(found)), "a pair listed twice"
        assert set(found) == brute_force_pairs(x, r, box, 1.0, skin, with_self)


@pytest.mark.parametrize("case", [(70, 2), (700, 3)])
def test_linear_candidates_equal_the_brute_force_scan(packings, case):
    """neighbours.candidate_pairs (a cell list) lists the pairs of the O(N^2) scan, in its order and
    with its arithmetic (so the active contacts are the same), and the generator's overlaps
    are those of the Taylor RVE."""
    from reference import brute_force_candidates

    p = packings[case]
    for ratio in (1.02, 2.0) if case[0] > 100 else (1.02, 1.0 / 0.99, 1.3, 2.0):
        got = neighbours.candidate_pairs(p.centers, p.radii, p.box, ratio)
        for a, b in zip(got, brute_force_candidates(p.centers, p.radii, p.box, ratio)):
            np.testing.assert_array_equal(a, b)  # same pairs, same order, same values
        L, R = got[0], got[1]
        ij2, shift2, eps2 = fire.candidates(p.centers, p.radii, p.box, ratio)
        np.testing.assert_array_equal(eps2, R - np.sqrt(L[:, 0] ** 2 + L[:, 1] ** 2))
    # network_stats sees the contacts of the Taylor RVE
    cs = TaylorRVE(p, 1.0, min_stretch=0.99).contacts(np.eye(2))
    s = network_stats(p)
    assert s.n_contacts == cs.pairs.shape[0]
    assert s.max_overlap == cs.overlap.max() / (2 * p.radii.mean())


def test_fire_in_chunks_follows_the_same_trajectory():
    rng = np.random.default_rng(3)
    n = 70
    r = rng.uniform(0.25, 1.0, n)
    box = np.full(2, np.sqrt(np.pi * np.sum(r**2) / 0.86))
    x0 = rng.random((n, 2)) * box
    skin, ftol, dt0, dt_max = 0.2, 1e-8, 0.03, 0.3
    ends = []
    for chunk in (10**9, 1, 37):
        x = x0.copy()
        fire.wrap(x, box)
        nl = neighbours.find_pairs(x, r, box, 1.0, skin, False)
        v, f, x_ref = np.zeros((n, 2)), np.empty((n, 2)), x.copy()
        st = np.array([dt0, 0.1, 0.0, 0.0, 0.0, np.inf])
        st[4] = fire.forces(x, r, box, *nl, f)
        done = False
        while not done and st[3] < 100_000:
            nl, done = fire.fire_steps(
                x, r, box, skin, ftol, dt_max, int(st[3]) + chunk, st, v, f, x_ref, nl
            )
        assert done
        ends.append((x, st))
    for x, st in ends[1:]:
        np.testing.assert_array_equal(x, ends[0][0])
        np.testing.assert_array_equal(st, ends[0][1])


def network(p):
    """The contacts (M, 2) of a packing at F = I and their unit normals (M, d)."""
    ij, shift, eps = fire.candidates(p.centers, p.radii, p.box, 1.0 / 0.99)
    ij, shift = ij[eps >= 0.0], shift[eps >= 0.0]
    L = p.centers[ij[:, 1]] + shift * p.box - p.centers[ij[:, 0]]
    return ij, L / np.linalg.norm(L, axis=1)[:, None]


def test_the_minimum_norm_step_is_the_least_squares_one(packings):
    """The Numba Cholesky step of the stress-free correction equals the minimum-norm solution of
    J dz = -g (a dense SVD), with J's rows n at x_i, -n at x_j, 1 at r_i and r_j."""
    p = packings[(350, 1)]
    ij, nv = network(p)
    n, m = p.n_particles, ij.shape[0]
    g = np.random.default_rng(0).standard_normal(m) * 1e-4
    dx, dr = cholesky.minimum_norm_step(ij, nv, g, cholesky.nested_dissection(p.centers, ij), n)
    J = np.zeros((m, 3 * n))
    rows = np.arange(m)
    for a in range(2):
        np.add.at(J, (rows, 2 * ij[:, 0] + a), nv[:, a])
        np.add.at(J, (rows, 2 * ij[:, 1] + a), -nv[:, a])
    np.add.at(J, (rows, 2 * n + ij[:, 0]), 1.0)
    np.add.at(J, (rows, 2 * n + ij[:, 1]), 1.0)
    expected = np.linalg.lstsq(J, -g, rcond=None)[0]
    dz = np.concatenate([dx.ravel(), dr])
    np.testing.assert_allclose(dz, expected, rtol=0, atol=1e-9 * np.abs(expected).max())


def test_nested_dissection_orders_every_contact_and_saves_fill(packings):
    p = packings[(700, 3)]
    ij, nv = network(p)
    order = cholesky.nested_dissection(p.centers, ij)
    np.testing.assert_array_equal(np.sort(order), np.arange(ij.shape[0]))

    def fill(order):
        rp, ri, rx = cholesky._normal_rows(ij, nv, order, p.n_particles)
        lp, _, _, ok = cholesky._cholesky(rp, ri, rx)
        assert ok
        return lp[-1]

    # the contacts come sorted by |L| / R, scattered over the cell: 3x the fill
    assert 3 * fill(order) < fill(np.arange(ij.shape[0]))


def test_an_indefinite_normal_matrix_is_refused(packings):
    p = packings[(70, 0)]
    ij, nv = network(p)
    nv[3] = np.nan
    with pytest.raises(ValueError, match="not definite"):
        cholesky.minimum_norm_step(ij, nv, np.zeros(ij.shape[0]), np.arange(ij.shape[0]), 70)


def test_progress_fractions_increase_to_one(monkeypatch):
    monkeypatch.setattr(generation, "PROGRESS_INTERVAL", 0.0)  # a heartbeat after every chunk
    lines = []
    p = generate_packing(350, seed=1, progress=lines.append)
    assert all(isinstance(s, generation.ProgressLine) for s in lines)
    fractions = [s.fraction for s in lines]
    assert all(0.0 <= a <= b <= 1.0 for a, b in zip(fractions, fractions[1:]))
    assert fractions[-1] == 1.0 and max(fractions[:-1]) < 1.0
    assert lines[-1].stage == "done" and lines[-1].startswith("done")
    assert {s.stage for s in lines} <= {"jamming", "stress-free", "checking", "done"}
    assert any(s.startswith("jamming:") for s in lines)  # heartbeats inside the minimisations
    running = ("jamming:", "stress-free", "checking the contact network")  # still running
    assert all(s.heartbeat == s.startswith(running) for s in lines)
    assert any(s.startswith("stress-free") for s in lines)
    assert p == generate_packing(350, seed=1)  # reporting does not change the result


def test_progress_heartbeats_respect_the_interval(monkeypatch):
    monkeypatch.setattr(generation, "PROGRESS_INTERVAL", 3600.0)
    lines = []
    generate_packing(350, seed=1, progress=lines.append)
    assert not any(s.startswith(("jamming:", "stress-free")) for s in lines)  # no heartbeats
    assert [s.stage for s in lines][-2:] == ["jamming", "done"]


def test_generation_benchmark_runs(capsys):
    # benchmarks/generation.py, not dolfinx_granular.packings.generation
    import generation as benchmark

    sizes = ["70", "140"]
    benchmark.main(["--sizes", *sizes])
    out = capsys.readouterr().out
    rows = [row for row in map(str.split, out.splitlines()) if row[:1] and row[0] in sizes]
    assert [row[0] for row in rows] == sizes and len(rows[1]) == 7
    # the FIRE steps are read from the progress lines: a search takes hundreds at least
    assert all(int(row[3]) >= 100 and float(row[4]) > 0 for row in rows)
    # the packing's digest, as tests/test_reference_packing.py computes it
    p = generate_packing(140, seed=0)
    assert rows[1][5] == portable.digest(p.centers, p.radii, p.box)[:12]
    assert "log-log slope over all sizes" in out


def test_bad_seed_names_the_parameter():
    for seed in ("x", -1, 1.5, True):
        with pytest.raises(ValueError, match="seed must be an integer >= 0"):
            generate_packing(20, seed=seed)


def test_relax_overlaps_makes_a_prestressed_packing_stress_free():
    """Radii x 1.02 prestress a generated packing (a PrestressWarning); relaxed, it is stress-free
    as a generated one, its disks moved by a few % of a radius."""
    import warnings

    from dolfinx_granular import relax_overlaps
    from dolfinx_granular.laws.taylor import PrestressWarning

    p = generate_packing(70, seed=1)
    swollen = Packing(p.centers, 1.02 * p.radii, p.box)
    with pytest.warns(PrestressWarning):
        TaylorRVE(swollen, 2.8e7)
    relaxed = relax_overlaps(swollen)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PrestressWarning)
        rve = TaylorRVE(relaxed, 2.8e7)
    assert rve.prestress_ratio < 1e-9 and np.array_equal(relaxed.box, swollen.box)
    assert 0 < np.abs(relaxed.radii / swollen.radii - 1).max() < 0.1
    stats = network_stats(relaxed)
    assert stats.max_overlap < 1e-9 and stats.coordination > 3
    with pytest.raises(ValueError, match="contact_overlap"):
        relax_overlaps(swollen, contact_overlap=0.1)


# these failed with "the stress-free correction ... did not converge": a disk crossed the cell
# boundary during the correction, so its contacts changed their image shift (their keys) and the
# network never matched again; pairs are keyed between unwrapped centres now
@pytest.mark.parametrize("seed, pressure", [(20, 3e-3), (6, 1e-2), (10, 1e-2)])
def test_high_pressure_packings_are_jammed_and_stress_free(seed, pressure):
    p = generate_packing(150, seed=seed, pressure=pressure)
    s = network_stats(p)
    assert s.volume_fraction >= 0.82 and s.rattler_fraction <= 0.15 and s.min_coordination >= 3
    assert s.max_overlap < 1e-9 and TaylorRVE(p, 1.0).prestress_ratio < 1e-9


@pytest.mark.slow
def test_the_seeds_of_the_issue_give_700_disk_packings_at_pressure_3e_3():
    # seeds 2, 4, 5, 7 and 104 were reported failing; seed 5 failed on this machine too
    for seed in (2, 4, 5, 7, 104):
        p = generate_packing(700, seed=seed, pressure=3e-3)
        s = network_stats(p)
        assert s.rattler_fraction <= 0.15 and s.min_coordination >= 3 and s.max_overlap < 1e-9


def test_relax_overlaps_follows_disks_across_the_cell_boundary():
    """Radii x 1.2 (overlaps of up to ~20 %, beyond TaylorRVE's 5 % limit): the minimal moves take
    some disks across the cell boundary; they keep their contacts and the result is stress-free."""
    from dolfinx_granular import relax_overlaps

    p = generate_packing(70, seed=4)
    swollen = Packing(p.centers, 1.2 * p.radii, p.box)
    lines = []
    relaxed = relax_overlaps(swollen, progress=lines.append)
    assert not any("afresh" in line for line in lines)  # the minimal correction sufficed
    step = relaxed.centers - swollen.centers
    assert np.any(np.abs(step) > 0.5 * p.box)  # a disk was wrapped to the other side
    step -= np.rint(step / p.box) * p.box
    assert np.abs(step).max() < p.radii.mean()
    assert (
        TaylorRVE(relaxed, 1.0).prestress_ratio < 1e-9 and network_stats(relaxed).max_overlap < 1e-9
    )


def test_relax_overlaps_jams_afresh_when_the_overlaps_are_too_large():
    """Radii x 1.5: the minimal correction diverges; the disks are jammed again in the same cell
    at radii scaled by one factor (here back to ~1 / 1.5) and the result is stress-free."""
    from dolfinx_granular import relax_overlaps

    p = generate_packing(70, seed=0)
    swollen = Packing(p.centers, 1.5 * p.radii, p.box)
    lines = []
    relaxed = relax_overlaps(swollen, progress=lines.append)
    assert any("jamming afresh" in line for line in lines)
    assert np.array_equal(relaxed.box, swollen.box)
    ratio = relaxed.radii / swollen.radii
    assert ratio.max() < 0.8 and ratio.max() / ratio.min() < 1.001
    s = network_stats(relaxed)
    assert s.volume_fraction >= 0.82 and s.min_coordination >= 3 and s.max_overlap < 1e-9
    assert TaylorRVE(relaxed, 1.0).prestress_ratio < 1e-9
