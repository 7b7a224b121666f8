"""Public contact geometry (ContactCandidates), the laws' shared helpers (lawtools), and the rule
that the law modules read no other module's private names."""

import ast
from pathlib import Path

import dolfinx_granular
from dolfinx_granular import (
    AdaptiveRVE,
    FrictionalRVE,
    SmallStrainRVE,
    TaylorRVE,
    UnsupportedDeformationError,
    generate_packing,
)
from dolfinx_granular.laws import levels
from dolfinx_granular.laws import taylor as rve
from dolfinx_granular.laws import taylor_kernel as kernel
from dolfinx_granular.laws import tools as lawtools
from dolfinx_granular.laws.contacts import ContactCandidates

import numpy as np
import pytest

K_N = 2.8e7
LAW_MODULES = (
    "contacts",
    "friction",
    "friction_kernel",
    "taylor_kernel",
    "tools",
    "levels",
    "taylor",
    "validity",
    "relaxed/errors",
    "relaxed/settings",
    "relaxed/cell",
    "relaxed/block_ldlt",
    "relaxed/contact_state",
    "relaxed/assembly",
    "relaxed/newton",
    "relaxed/fire",
    "relaxed/tangent",
    "relaxed/equilibrium",
    "relaxed/path",
    "relaxed/batch",
    "relaxed/law",
)


@pytest.fixture(scope="module")
def packing():
    return generate_packing(70, seed=5)


@pytest.fixture(scope="module")
def cands(packing):
    return ContactCandidates.from_packing(packing, 0.6)


def test_layout_units_and_order(packing, cands):
    m = len(cands)
    assert m > 70 and cands.dim == 2 and cands.min_stretch == 0.6
    assert cands.branch.shape == (m, 2) and cands.shift.shape == (m, 2)
    assert cands.pairs.shape == (m, 2) and cands.pairs.dtype == np.int64
    assert cands.shift.dtype == np.int64
    i, j = cands.pairs.T
    box = np.asarray(packing.box)
    L = packing.centers[j] + cands.shift * box - packing.centers[i]
    assert np.allclose(cands.branch, L, rtol=0, atol=1e-12 * box.max())
    r = packing.radii
    assert np.array_equal(cands.radius_sum, r[i] + r[j])
    assert np.array_equal(cands.smaller_radius, np.minimum(r[i], r[j]))
    assert np.array_equal(cands.inverse_smaller_radius, 1.0 / np.minimum(r[i], r[j]))
    assert np.all(np.diff(cands.ratio) >= 0) and cands.ratio[-1] <= 1.0 / 0.6
    assert np.allclose(cands.ratio, np.linalg.norm(L, axis=1) / cands.radius_sum, rtol=1e-12)
    X, Y = cands.components
    assert X.flags.c_contiguous and np.array_equal(X, cands.branch[:, 0])
    assert Y.flags.c_contiguous and np.array_equal(Y, cands.branch[:, 1])
    assert cands.max_branch_length2 == np.max(X**2 + Y**2)
    assert "m=" in repr(cands) and "dim=2" in repr(cands)


def test_arrays_are_read_only(cands):
    for a in (cands.branch, cands.radius_sum, cands.ratio, cands.pairs, cands.shift):
        with pytest.raises(ValueError, match="read-only"):
            a[0] = 0
    with pytest.raises(ValueError, match="read-only"):
        cands.components[0][0] = 0.0


def test_every_law_builds_on_one_candidate_list(packing):
    taylor = TaylorRVE(packing, K_N, min_stretch=0.6)
    ref = ContactCandidates.from_packing(packing, 0.6)
    for name in ("branch", "radius_sum", "ratio", "pairs", "shift"):
        assert np.array_equal(getattr(taylor.candidates, name), getattr(ref, name))
    assert taylor.n_candidates == len(ref)
    # the levels wrap the same RVE: no second candidate search
    assert AdaptiveRVE(taylor, 0.01).taylor.candidates is taylor.candidates
    assert SmallStrainRVE(taylor).taylor.candidates is taylor.candidates
    friction = FrictionalRVE(packing, K_N, 1e7, 0.3, min_stretch=0.6)
    assert np.array_equal(friction.candidates.ratio, ref.ratio)
    assert friction.n_candidates == len(ref)


def test_overlaps_decide_the_kernels_active_set(packing, cands, rng):
    taylor = TaylorRVE(packing, K_N, min_stretch=0.6)
    for _ in range(5):
        F = 0.98 * np.eye(2) + rng.normal(0.0, 0.01, (2, 2))
        branch, eps = cands.overlaps(F)
        assert branch.shape == (len(cands), 2) and eps.shape == (len(cands),)
        on = eps >= 0.0
        contacts = taylor.contacts(F)
        assert np.array_equal(contacts.pairs, cands.pairs[on])
        assert np.array_equal(contacts.overlap, eps[on])
        assert np.array_equal(contacts.branch, branch[on])
        assert np.allclose(branch, cands.branch @ F.T, rtol=1e-14, atol=0)


def test_visited_is_the_prefix_a_stretch_can_reach(cands):
    assert cands.visited(np.array([0.6]))[0] == len(cands)
    n1 = cands.visited(np.array([1.0]))[0]
    assert n1 == np.count_nonzero(cands.ratio <= 1.0)
    assert np.all(np.diff(cands.visited(np.linspace(0.6, 1.2, 7))) <= 0)


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda p: ContactCandidates.from_packing(np.zeros((3, 2))), TypeError, "Packing"),
        (lambda p: ContactCandidates.from_packing(p, 0.0), ValueError, r"min_stretch .*\(0, 1\]"),
        (lambda p: ContactCandidates.from_packing(p, 1.5), ValueError, r"min_stretch .*\(0, 1\]"),
        (lambda p: ContactCandidates.from_packing(p).overlaps(np.eye(3)), ValueError, r"\(2, 2\)"),
    ],
)
def test_bad_input_is_named(packing, call, error, match):
    with pytest.raises(error, match=match):
        call(packing)


def test_rows_must_agree(cands):
    with pytest.raises(ValueError, match=r"pairs has shape \(3, 2\), expected one row per"):
        ContactCandidates(
            cands.branch,
            cands.radius_sum,
            cands.ratio,
            np.zeros((3, 2), np.int64),
            cands.shift,
            cands.smaller_radius,
            0.6,
        )


def test_lawtools_shapes_and_errors(rng):
    F, single = lawtools.as_batch(np.eye(3), dim=3)
    assert single and F.shape == (1, 3, 3)
    with pytest.raises(ValueError, match=r"F must have shape \(n, 2, 2\) or \(2, 2\)"):
        lawtools.as_batch(np.zeros((4, 3, 3)))
    W, P, A = lawtools.output_buffers(4, True, dim=3)
    assert W.shape == (4,) and P.shape == (4, 3, 3) and A.shape == (4, 3, 3, 3, 3)
    assert lawtools.output_buffers(4, False)[2] is None
    # push-forward in 3-D: sigma = P F^T / J and a = F_bB F_dD A_aBcD / J
    F = np.eye(3) + rng.normal(0.0, 0.1, (5, 3, 3))
    P, A = rng.normal(size=(5, 3, 3)), rng.normal(size=(5, 3, 3, 3, 3))
    sigma, a = lawtools.push_forward(F, P, A)
    J = np.linalg.det(F)
    assert np.allclose(sigma, P @ np.swapaxes(F, 1, 2) / J[:, None, None], rtol=1e-13)
    assert np.allclose(a, np.einsum("qbB,qdD,qaBcD->qabcd", F, F, A) / J[:, None, None, None, None])


def test_status_becomes_the_named_error():
    F = np.stack([np.eye(2), 0.3 * np.eye(2), np.diag([1.0, -1.0])])
    status = np.array([kernel.OK, kernel.BELOW_MIN_STRETCH, kernel.NOT_ORIENTATION_PRESERVING])
    err = lawtools.unsupported_deformation(F, status, 0.5)
    assert isinstance(err, UnsupportedDeformationError)
    assert err.points.tolist() == [1, 2] and err.status is status
    assert "F at 2 of 3 points" in str(err) and "0.3 < min_stretch=0.5" in str(err)


def test_moved_names_stay_where_users_find_them():
    assert rve.UnsupportedDeformationError is lawtools.UnsupportedDeformationError
    assert dolfinx_granular.UnsupportedDeformationError is lawtools.UnsupportedDeformationError
    assert levels.isotropic_lame is lawtools.isotropic_lame
    assert levels.singular_values_2x2 is lawtools.singular_values_2x2


def _private_reads(tree, own):
    """``(line, text)`` of every name ``_x`` imported from another module, and of every
    attribute ``obj._x`` read on anything but ``self``, ``cls``, ``sys`` or a class of ``own``."""
    hits = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            hits += [(node.lineno, a.name) for a in node.names if a.name.startswith("_")]
        elif isinstance(node, ast.Attribute) and node.attr.startswith("_"):
            if node.attr.startswith("__"):
                continue
            base = node.value
            if isinstance(base, ast.Name) and base.id in {"self", "cls", "sys"} | own:
                continue
            hits.append((node.lineno, ast.unparse(node)))
    return hits


@pytest.mark.parametrize("module", LAW_MODULES)
def test_law_modules_read_no_private_names_of_others(module):
    path = Path(dolfinx_granular.__file__).parent / "laws" / f"{module}.py"
    tree = ast.parse(path.read_text())
    own = {n.name for n in tree.body if isinstance(n, ast.ClassDef)}
    assert _private_reads(tree, own) == []
