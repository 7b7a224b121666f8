"""Model levels: the small-strain model of eq. 15 and the adaptive linear/Taylor choice."""

from dolfinx_granular import TaylorRVE, UnsupportedDeformationError, generate_packing
from dolfinx_granular.laws.levels import (
    AdaptiveRVE,
    SmallStrainRVE,
    isotropic_lame,
    singular_values_2x2,
)
from dolfinx_granular.laws.protocol import MaterialLaw

import numpy as np
import pytest

from helpers import random_packing
from reference import all_branch_vectors, central_differences

# these tests use prestressed (overlapping) packings on purpose
pytestmark = pytest.mark.filterwarnings("ignore::dolfinx_granular.laws.taylor.PrestressWarning")

K_N = 2.8e7


def rotation(theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def rel(a, b):
    return np.max(np.abs(a - b)) / np.max(np.abs(b))


@pytest.fixture(scope="module")
def jammed():
    """A generated packing: stress-free, touching reference contacts, gaps ~1e-6 R."""
    return TaylorRVE(generate_packing(70, seed=1), K_N)


@pytest.fixture(scope="module")
def prestressed():
    """Random centres: overlapping reference contacts (prestress), so a finite linear region."""
    return TaylorRVE(random_packing(40, seed=3), K_N, allow_overlaps=True)


def random_F(rng, n, scale):
    return np.eye(2) + rng.normal(0.0, scale, (n, 2, 2))


def near_rotations(rng, n, max_angle, stretch_lo, stretch_hi):
    """Q(theta) diag(s) Q(phi) with |theta + phi| small: F - I small, singular values in range."""
    out = np.empty((n, 2, 2))
    for q in range(n):
        phi = rng.uniform(0, 2 * np.pi)
        theta = rng.uniform(-max_angle, max_angle) - phi
        out[q] = rotation(theta) @ np.diag(rng.uniform(stretch_lo, stretch_hi, 2)) @ rotation(phi)
    return out


# -- SmallStrainRVE -------------------------------------------------------------------------------


def test_small_strain_is_C_colon_eps(jammed, rng):
    level = SmallStrainRVE(jammed)
    C_paper = jammed.small_strain_modulus()
    F = np.concatenate([random_F(rng, 20, 0.05), [rotation(0.3)], [np.eye(2)]])
    W, P, A = level.evaluate(F)
    H = F - np.eye(2)
    eps = 0.5 * (H + np.swapaxes(H, 1, 2))
    P_ref = np.einsum("abcd,qcd->qab", C_paper, eps)
    assert rel(P, P_ref) <= 1e-14
    assert np.allclose(W, 0.5 * np.einsum("qab,qab->q", P_ref, eps), rtol=1e-14, atol=0)
    assert np.array_equal(P[-1], np.zeros((2, 2))) and W[-1] == 0.0
    # tangent = C for every point, exactly; C is eq. 15 (symmetrised) and Taylor's A at I
    assert all(np.array_equal(A[q], level.C) for q in range(len(F)))
    assert rel(level.C, C_paper) <= 1e-15
    assert rel(level.C, jammed.evaluate(np.eye(2))[2]) <= 1e-9
    for perm in ("bacd", "abdc", "cdab"):
        assert np.array_equal(np.einsum(f"{perm}->abcd", level.C), level.C)
    # stress-only path, Cauchy (= P in linear theory) and spatial tangent
    W2, P2 = level.stress(F)
    assert np.array_equal(P2, P) and np.array_equal(W2, W)
    assert np.array_equal(level.cauchy(F), P)
    assert np.array_equal(level.spatial_tangent(F[:3]), A[:3])
    # a MaterialLaw by structure, wrapping (not copying) the full model
    assert isinstance(level, MaterialLaw) and not isinstance(level, TaylorRVE)
    assert level.taylor is jammed and level.packing is jammed.packing
    assert SmallStrainRVE(level).taylor is jammed  # a level of a level wraps the full model


def test_small_strain_finite_differences(jammed, rng):
    level = SmallStrainRVE(jammed)
    F = random_F(rng, 4, 0.03)
    W, P, A = level.evaluate(F)
    P_fd, A_fd = central_differences(level, F, 1e-6)
    for c in range(2):
        for d in range(2):
            assert rel(A_fd[..., c, d], A[:, :, :, c, d]) <= 1e-8
            assert np.allclose(P_fd[:, c, d], P[:, c, d], rtol=1e-7, atol=1e-7 * np.abs(P).max())


def test_small_strain_writes_out_arrays_and_rejects_nan(jammed, rng):
    level = SmallStrainRVE(jammed)
    F = random_F(rng, 5, 0.02)
    out = (np.empty(5), np.empty((5, 2, 2)), np.empty((5, 2, 2, 2, 2)))
    level.evaluate(F, out=out)
    W, P, A = level.evaluate(F)
    assert np.array_equal(out[1], P) and np.array_equal(out[2], A) and np.array_equal(out[0], W)
    F[3, 0, 1] = np.nan
    with pytest.raises(UnsupportedDeformationError, match="point 3") as info:
        level.stress(F)
    assert info.value.points.tolist() == [3]


# -- AdaptiveRVE ----------------------------------------------------------------------------------


def independent_bounds(rve):
    """Contact-test stretch limits from the reference contact set of TaylorRVE.contacts(I) and a
    brute-force search of the packing (no candidate list involved)."""
    pk = rve.packing
    ref = rve.contacts(np.eye(2))
    closed_ratio = (ref.overlap + np.linalg.norm(ref.branch, axis=1)) / np.linalg.norm(
        ref.branch, axis=1
    )
    L, R = all_branch_vectors(pk, images=1)
    ratio = R / np.linalg.norm(L, axis=1)
    gap_ratio = ratio[ratio < 1.0].max(initial=0.0)  # the closest reference gap
    return closed_ratio.min(), gap_ratio, ref


@pytest.mark.parametrize("which", ["jammed", "prestressed"])
def test_adaptive_picks_linear_only_where_provable(which, request, rng):
    rve = request.getfixturevalue(which)
    smax_ok, smin_req, ref = independent_bounds(rve)
    tol = 0.02
    level = AdaptiveRVE(rve, tol)
    # the stretch limits reproduce the brute-force ones (the class adds a 1e-12 margin)
    assert abs(level.stretch_bounds[0] / smax_ok - 1) <= 1.1e-12
    assert abs(level.stretch_bounds[1] / smin_req - 1) <= 1.1e-12
    lo, hi = smin_req + 0.3 * (1 - smin_req), 1.0 + 0.3 * (smax_ok - 1.0)
    F = np.concatenate(
        [
            near_rotations(rng, 40, tol, lo, hi),  # mostly linear
            near_rotations(rng, 10, 3 * tol, lo, hi),  # rotations too large
            near_rotations(rng, 10, tol, 0.98, 1.0),  # compressed: gaps may close
            near_rotations(rng, 10, tol, 1.0, 1.0 + 2e-3),  # stretched: contacts may open
            random_F(rng, 20, 0.01),
        ]
    )
    W, P, A = level.evaluate(F)
    lin = level.linear_mask
    s = np.linalg.svd(F, compute_uv=False)
    strain = np.linalg.svd(F - np.eye(2), compute_uv=False)[:, 0]
    expected = (strain <= tol) & (s[:, 0] <= smax_ok) & (s[:, 1] > smin_req)
    # identical to the criterion, except within the margin (none of these F is that close)
    assert np.array_equal(lin, expected)
    assert level.counts == {"linear": int(lin.sum()), "taylor": int((~lin).sum())}
    assert 30 <= lin.sum() < len(F) - 10
    # where linear, the contact set is provably the reference one: check it
    ref_keys = {(i, j, a, b) for (i, j), (a, b) in zip(ref.pairs.tolist(), ref.shift.tolist())}
    for q in np.flatnonzero(lin):
        c = rve.contacts(F[q])
        assert {
            (i, j, a, b) for (i, j), (a, b) in zip(c.pairs.tolist(), c.shift.tolist())
        } == ref_keys
    # Taylor points: bit for bit the full model
    Wt, Pt, At = rve.evaluate(F)
    full = ~lin
    assert np.array_equal(P[full], Pt[full]) and np.array_equal(A[full], At[full])
    assert np.array_equal(W[full], Wt[full])
    # linear points: tangent A(I), error within the bound (plus round-off of the kernel's P)
    assert all(np.array_equal(A[q], level.A0) for q in np.flatnonzero(lin))
    err = np.linalg.norm(P - Pt, axis=(1, 2))
    bound = level.error_bound(F)
    roundoff = 1e-14 * level.error_constant
    assert np.all(err[lin] <= bound[lin] + roundoff)
    assert np.all(
        bound[lin] <= tol / (np.sqrt(3) * (1 - tol) ** 2) * level.error_constant * strain[lin]
    )


def test_adaptive_error_bound_is_not_vacuous(prestressed, rng):
    """The bound is within a small factor of the actual error for pure rotations."""
    level = AdaptiveRVE(prestressed, 0.05)
    F = np.array([rotation(t) for t in (0.01, 0.02, 0.04)])
    W, P, A = level.evaluate(F)
    assert level.linear_mask.all()
    err = np.linalg.norm(P - prestressed.stress(F)[1], axis=(1, 2))
    ratio = err / level.error_bound(F)
    assert np.all(ratio <= 1.0) and np.all(ratio > 0.05)


def test_adaptive_strain_only_and_fd(prestressed, rng):
    level = AdaptiveRVE(prestressed, 0.01, contact_test=False)
    F = np.concatenate([random_F(rng, 10, 0.002), random_F(rng, 10, 0.05)])
    W, P, A = level.evaluate(F)
    strain = np.linalg.svd(F - np.eye(2), compute_uv=False)[:, 0]
    assert np.array_equal(level.linear_mask, strain <= 0.01)
    # the linear branch is linear in F: central differences reproduce A(I) at linear points
    q = np.flatnonzero(level.linear_mask)[:3]
    A_fd = central_differences(level, F[q], 1e-7)[1]
    for c in range(2):
        for d in range(2):
            assert rel(A_fd[..., c, d], A[q][:, :, :, c, d]) <= 1e-6
    # stress() and evaluate() agree (the kernel's sums associate differently without the
    # tangent: round-off), spatial outputs are the push-forward / the kernel's
    P2 = level.stress(F)[1]
    assert np.array_equal(P2[level.linear_mask], P[level.linear_mask]) and rel(P2, P) <= 1e-14
    sigma = level.cauchy(F)
    J = np.linalg.det(F)
    assert rel(sigma, np.einsum("qaB,qbB->qab", P, F) / J[:, None, None]) <= 1e-13
    a = level.spatial_tangent(F)
    full = ~level.linear_mask
    assert np.array_equal(a[full], prestressed.spatial_tangent(F[full]))
    assert np.array_equal(sigma[full], prestressed.cauchy(F[full]))


def test_adaptive_out_arrays_counts_and_errors(jammed, rng):
    level = AdaptiveRVE(jammed, 0.01)
    F = np.concatenate([near_rotations(rng, 3, 0.005, 1.0, 1.0), random_F(rng, 3, 0.02)])
    out = (np.empty(6), np.empty((6, 2, 2)), np.empty((6, 2, 2, 2, 2)))
    level.evaluate(F, out=out)
    W, P, A = level.evaluate(F)
    assert np.array_equal(out[1], P) and np.array_equal(out[2], A)
    assert level.counts == {"linear": 3, "taylor": 3}
    assert level.totals == {"linear": 6, "taylor": 6}
    F[4] = [[0.2, 0.0], [0.0, 1.0]]  # below min_stretch
    with pytest.raises(UnsupportedDeformationError, match="point 4") as info:
        level.evaluate(F)
    assert info.value.points.tolist() == [4]
    with pytest.raises(ValueError, match="tol"):
        AdaptiveRVE(jammed, 1.5)
    with pytest.raises(TypeError, match="rve must be a dolfinx_granular.TaylorRVE, got object"):
        AdaptiveRVE(object(), 0.1)


def test_levels_wrap_the_full_model_only(jammed):
    a = AdaptiveRVE(SmallStrainRVE(jammed), 0.01)
    assert a.taylor is jammed
    assert SmallStrainRVE(a).taylor is jammed


def test_isotropic_lame(jammed):
    I = np.eye(2)
    lam, mu = 3.0e6, 5.0e6
    C_iso = lam * np.einsum("ij,kl->ijkl", I, I) + mu * (
        np.einsum("ik,jl->ijkl", I, I) + np.einsum("il,jk->ijkl", I, I)
    )
    assert np.allclose(isotropic_lame(C_iso), (lam, mu), rtol=1e-15)
    # an anisotropic perturbation orthogonal to the isotropic part does not move the projection
    D = np.zeros((2, 2, 2, 2))
    D[0, 0, 0, 0], D[1, 1, 1, 1] = 1e6, -1e6
    assert np.allclose(isotropic_lame(C_iso + D), (lam, mu), rtol=1e-15)
    # eq. 15 (central forces): Cauchy relation, lam = mu = C_iikk / 8
    C = SmallStrainRVE(jammed).C
    lam, mu = isotropic_lame(C)
    assert abs(lam / mu - 1) <= 1e-12 and abs(mu - np.einsum("iikk->", C) / 8) <= 1e-12 * mu


def test_singular_values_2x2(rng):
    F = rng.normal(size=(50, 2, 2))
    smax, smin = singular_values_2x2(F)
    s = np.linalg.svd(F, compute_uv=False)
    assert np.allclose(smax, s[:, 0], rtol=1e-14) and np.allclose(smin, s[:, 1], atol=1e-14 * smax)
    # near-identity: no discriminant cancellation (the naive formula loses ~8 digits here)
    F = np.array([rotation(1e-9) @ np.diag([1.0 + 1e-13, 1.0])])
    smax, smin = singular_values_2x2(F)
    assert abs(smax[0] - (1.0 + 1e-13)) <= 4e-16 and abs(smin[0] - 1.0) <= 4e-16


# -- the levels and the stress-only final residual inside a Newton solve ---------------------------


def column_problem(rve, prefix, skip_final_tangent=False, n=4, pressure=2e5, **solver_kwargs):
    """The shared column (tests/helpers.py) under a top pressure (Pa), counting the material's
    stress-only and tangent updates."""
    pytest.importorskip("dolfinx")
    from helpers import granular_column

    solver, material, u, _ = granular_column(
        rve, prefix, n=n, pressure=pressure, skip_final_tangent=skip_final_tangent, **solver_kwargs
    )
    calls = {True: 0, False: 0}
    update = material.update

    def counting_update(tangent=True):
        calls[bool(tangent)] += 1
        update(tangent=tangent)

    material.update = counting_update
    return solver, material, u, calls


@pytest.mark.mpi
def test_final_residual_skips_the_tangent(jammed):
    runs = {}
    for skip in (False, True):
        # the energy-norm test alone (it, not the round-off test, is what the skip predicts)
        solver, material, u, calls = column_problem(
            jammed, f"skip{int(skip)}_", skip, residual_rtol=0.0
        )
        result = solver.solve()
        assert result.converged and result.reason_name == "CONVERGED_SNORM_RELATIVE"
        runs[skip] = (result, u.x.array.copy(), dict(calls), material.P.x.array.copy())
        solver.destroy()
    (r0, u0, c0, P0), (r1, u1, c1, P1) = runs[False], runs[True]
    # same iterates, same answer: the stress is identical with and without the tangent to round-off
    assert r1.iterations == r0.iterations
    assert np.allclose(u1, u0, rtol=0, atol=1e-12 * np.abs(u0).max())
    assert np.allclose(P1, P0, rtol=0, atol=1e-10 * np.abs(P0).max())
    # one tangent per Jacobian; the final residual (energy norm already converged) is stress only
    assert c0 == {True: r0.iterations + 1, False: 0}
    assert c1 == {True: r1.iterations, False: 1}


@pytest.mark.mpi
def test_levels_drop_into_granular_material(jammed):
    results = {}
    adaptive = AdaptiveRVE(jammed, 1e-3)
    for name, rve in (
        ("taylor", jammed),
        ("small", SmallStrainRVE(jammed)),
        ("adaptive", adaptive),
    ):
        solver, material, u, calls = column_problem(rve, f"lvl_{name}_")
        result = solver.solve()
        assert result.converged, name
        results[name] = (result, u.x.array.copy())
        solver.destroy()
    # linear model: the first Newton step lands on the solution (residual at round-off after it)
    hist = results["small"][0].history
    assert len(hist) <= 2 and (len(hist) == 1 or hist[1][1] <= 1e-12 * hist[0][1])
    u_t, u_s = results["taylor"][1], results["small"][1]
    assert 0 < np.abs(u_s - u_t).max() < 0.5 * np.abs(u_t).max()
    # adaptive with a provable test: at this load no point qualifies -> the Taylor law everywhere
    assert adaptive.counts["linear"] == 0 and adaptive.counts["taylor"] > 0  # (at the answer)
    # ... and the Taylor answer. Not bit for bit: under MPI, MUMPS sums its parallel reductions in
    # no fixed order, so two factorisations of the same matrix differ by round-off, and so do the
    # converged solutions, by about eps * cond(K) * |u| (1e-16 * 1e4 here). Measured: 0 or ~1e-15.
    u_a = results["adaptive"][1]
    assert np.abs(u_a - u_t).max() <= 1e-12 * np.abs(u_t).max()
