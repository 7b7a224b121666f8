"""A packing confined by the relaxed RVE: in equilibrium at its pressure, the reference state of
the relaxed and the Taylor law alike; and the slope options that use it."""

import warnings

from dolfinx_granular import LawEvaluationError, RelaxedRVE, TaylorRVE, generate_packing
from dolfinx_granular.drivers.confinement import MAX_HALVINGS, compress, confined_packing, ramp
from dolfinx_granular.drivers.material_point import MaterialPoint
from dolfinx_granular.laws.relaxed import newton, relax
from dolfinx_granular.laws.relaxed.contact_state import ContactState
from dolfinx_granular.slope.options import SlopeOptions

import numpy as np
import pytest

from helpers import net_forces

K_N = 2.8e7
PRESSURE = 1e-3


@pytest.fixture(scope="module")
def packings():
    packing = generate_packing(70, seed=1, pressure=PRESSURE)
    return packing, confined_packing(packing, K_N, PRESSURE)


def test_the_confined_packing_is_in_equilibrium_at_its_pressure(packings):
    packing, confined = packings
    np.testing.assert_array_equal(confined.radii, packing.radii)
    assert confined.area < packing.area  # (one side may lengthen: a small cell is anisotropic)
    f, mean = net_forces(confined, confined.centers, np.eye(2))
    assert np.linalg.norm(f, axis=1).max() <= 1e-9 * mean
    rve = RelaxedRVE(confined, K_N)
    sigma = rve.cauchy(np.eye(2), rve.initial_state(1))
    np.testing.assert_allclose(np.diag(sigma), -PRESSURE * K_N, rtol=1e-9)
    assert abs(sigma[0, 1]) <= 0.1 * PRESSURE * K_N


def test_relaxing_the_confined_packing_moves_nothing(packings):
    """A strain of 1e-12 from its reference state: the relaxation starts in equilibrium."""
    _, confined = packings
    rve = RelaxedRVE(confined, K_N)
    F = np.eye(2) * (1.0 - 1e-12)
    _, P, _, state = rve.evaluate(F, rve.initial_state(1))
    _, P0 = rve.stress(np.eye(2), rve.initial_state(1))[:2]
    np.testing.assert_allclose(P, P0, atol=1e-8 * PRESSURE * K_N)
    assert state.fluctuation[0] < 1e-6


def test_taylor_reads_the_same_reference_stress(packings):
    _, confined = packings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        taylor = TaylorRVE(confined, K_N, allow_overlaps=True)
    relaxed = RelaxedRVE(confined, K_N)
    _, P_taylor = taylor.stress(np.eye(2))
    _, P_relaxed, _ = relaxed.stress(np.eye(2), relaxed.initial_state(1))
    np.testing.assert_allclose(P_taylor, P_relaxed, atol=1e-12 * PRESSURE * K_N)


@pytest.mark.parametrize("pressure", [0.0, -1e-3, 0.02, float("nan")])
def test_a_pressure_out_of_range_is_refused(packings, pressure):
    with pytest.raises(ValueError, match="pressure"):
        confined_packing(packings[0], K_N, pressure)


@pytest.mark.parametrize(
    "options, words",
    [
        (dict(rve="relaxed"), ("confining pressure", "--confinement")),
        (dict(rve="relaxed", friction=0.5), ("confining pressure", "--confinement")),
        (dict(confinement=1e6), ("confinement", "280000")),
        (dict(rve="dem"), ("rve", "taylor")),
    ],
)
def test_slope_options_refuse_what_has_no_meaning(options, words):
    with pytest.raises(ValueError) as err:
        SlopeOptions(**options)
    assert all(w in str(err.value) for w in words), str(err.value)


def test_the_slope_law_is_built_on_the_confined_packing(packings):
    packing, confined = packings
    law = SlopeOptions(rve="relaxed", confinement=PRESSURE * K_N).law(packing)
    assert isinstance(law, RelaxedRVE)
    np.testing.assert_array_equal(law.packing.centers, confined.centers)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the intended prestress gives no PrestressWarning
        taylor = SlopeOptions(confinement=PRESSURE * K_N).law(packing)
    np.testing.assert_allclose(
        taylor.stress(np.eye(2))[1], law.stress(np.eye(2), law.initial_state(1))[1], rtol=1e-12
    )


@pytest.mark.mpi
def test_the_holding_traction_keeps_the_confined_column_at_rest(packings):
    """The README's column of a confined packing under no load: with holding_traction(material)
    on its boundary the reference state is in equilibrium (0 Newton steps, u = 0); without it
    the confinement pushes the free top and the walls' shear out of equilibrium."""
    pytest.importorskip("dolfinx")
    import dolfinx_granular
    from dolfinx_granular import GranularMaterial, NewtonSolver, holding_traction, vector_space

    import ufl
    from dolfinx import fem, mesh
    from mpi4py import MPI

    assert dolfinx_granular.confined_packing is confined_packing  # public from the package
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (the prestress is the confinement)
        law = TaylorRVE(packings[1], K_N, allow_overlaps=True)
    msh = mesh.create_rectangle(MPI.COMM_WORLD, [[0, 0], [10, 10]], [2, 2])
    V = vector_space(msh)
    u, v, du = fem.Function(V), ufl.TestFunction(V), ufl.TrialFunction(V)
    material = GranularMaterial(law, u)
    bottom = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 0))
    bcs = [fem.dirichletbc(np.zeros(2), fem.locate_dofs_topological(V, 1, bottom), V)]
    t = holding_traction(material)
    assert t.ufl_shape == (2,)
    results = []
    for hold in (ufl.dot(t, v) * ufl.ds, None):
        u.x.array[:] = 0.0
        residual = material.residual_form(v) - (hold if hold is not None else 0)
        solver = NewtonSolver(residual, material.jacobian_form(du, v), u, bcs, material)
        results.append(solver.solve(warn=False))
        solver.destroy()
    held, free = results
    assert held.converged and held.iterations == 0 and held.stopped_by == "round-off", held
    assert free.iterations > 0 or not free.converged, free


def test_isotropic_compression_near_jamming_ends_in_equilibrium():
    # jammed at p / k_n = 1e-4, compressed along F = lam I to it: the mean pressure is met and
    # the disks are at rest there (net forces <= 1e-9 of the mean contact force)
    p = 1e-4
    rve = RelaxedRVE(generate_packing(70, seed=1, pressure=p), K_N)
    point = MaterialPoint(rve)
    result = compress(point, p * K_N, max_increment=10 * p, isotropic=True)
    assert result.F[0, 0] == result.F[1, 1] and result.F[0, 1] == result.F[1, 0] == 0.0
    assert -np.trace(result.sigma) / 2 == pytest.approx(p * K_N, rel=1e-8)
    x = rve.positions(result.F, point.state)[0]
    f, mean = net_forces(rve.packing, x, result.F)
    assert np.linalg.norm(f, axis=1).max() <= 1e-9 * mean


def test_equilibrium_is_judged_against_the_round_off_of_tiny_overlaps():
    # at 1e-7 compression the overlaps are ~1e-7 of the radii, so the contact forces carry a
    # round-off of ~eps R / e of themselves: the solver stops there, not at force_tol
    rve = RelaxedRVE(generate_packing(70, seed=1, pressure=1e-3), K_N)
    F = (1.0 - 1e-7) * np.eye(2)
    eq = relax(rve.cell, F, rve.initial_state(1).w[0], False, rve.settings)
    s = ContactState(rve.cell, F, eq.w)
    on = s.on
    expected = np.finfo(float).eps * rve.cell.R[: s.m][on].mean() / s.e[on].mean()
    assert s.resolution(rve.cell) == pytest.approx(expected, rel=1e-12)
    assert 1e-10 < expected and eq.residual <= newton.RESOLVED * expected


class FailsAtTheEnd:
    """Linear law that fails at F_11 <= 0.98 and nowhere short of it; counts its calls."""

    def __init__(self):
        self.calls = 0

    def evaluate(self, F):
        self.calls += 1
        F = np.asarray(F)
        if F[0, 0] <= 0.98:
            raise LawEvaluationError("fails at the end")
        return 0.0, 1e6 * (F - np.eye(2)), np.zeros((2, 2, 2, 2))


def test_a_load_value_gets_its_halvings_in_all():
    # every point short of the value converges, the value never does: the halvings stop after
    # MAX_HALVINGS in all (reset at every reached midpoint they would creep up on it for long)
    law = FailsAtTheEnd()
    point = MaterialPoint(law)
    with pytest.raises(LawEvaluationError, match="fails at the end"):
        ramp(point, [0.02], lambda v, F: (np.diag([1.0 - v, 1.0]), {}), 0.1)
    assert law.calls == 2 * MAX_HALVINGS + 1
    assert 0.98 < point.F[0, 0] < 0.99  # the last midpoint reached is committed
