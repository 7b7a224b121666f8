"""Adaptive load stepping and failure handling: cut-backs on RVE range errors, singular matrices and
stagnation; a failed step never leaves NaN or an unconverged state behind; the stabiliser."""

import re
import warnings

import numpy as np
import pytest

dolfinx = pytest.importorskip("dolfinx")
from dolfinx_granular import (  # noqa: E402
    LoadPathWarning,
    SolveFailedWarning,
    TaylorRVE,
    generate_packing,
)
from dolfinx_granular.drivers.arclength import ArcLength  # noqa: E402
from dolfinx_granular.drivers.loading import LoadStepper  # noqa: E402
from dolfinx_granular.drivers.newton import STAGNATION, NewtonSolver  # noqa: E402
from dolfinx_granular.fem.compat import vector_space  # noqa: E402
from dolfinx_granular.fem.material import GranularMaterial  # noqa: E402

import ufl  # noqa: E402
from dolfinx import fem, mesh  # noqa: E402
from mpi4py import MPI  # noqa: E402

from helpers import granular_column  # noqa: E402
from truss import truss  # noqa: E402


def column(prefix, n=4, stabilise=0.0, material_class=GranularMaterial, **solver_kwargs):
    """The shared column (tests/helpers.py) of a 70-particle RVE, top pressure p = 0 to start."""
    solver_kwargs.setdefault("max_it", 10)
    return granular_column(
        TaylorRVE(generate_packing(70, seed=4), 2.8e7),
        prefix,
        n=n,
        material_class=material_class,
        stabilise=stabilise,
        **solver_kwargs,
    )


def all_finite(a):
    return MPI.COMM_WORLD.allreduce(bool(np.isfinite(a).all()), op=MPI.LAND)


def failure_warnings(call):
    """``call()``'s result and the SolveFailedWarning and LoadPathWarning it issued, as
    ``(category, message)`` (every one recorded)."""
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        result = call()
    kinds = (SolveFailedWarning, LoadPathWarning)
    return result, [(w.category, str(w.message)) for w in record if issubclass(w.category, kinds)]


@pytest.mark.mpi
def test_cutback_recovers_the_same_answer():
    """6.5 MPa in one step drives Newton outside the RVE's range; the stepper halves the step and
    reaches the same state as a run with two nominal steps."""
    solver, material, u, p = column("cut_")
    stepper = LoadStepper(solver)
    ok, said = failure_warnings(
        lambda: stepper.run("press", lambda t: setattr(p, "value", 6.5e6 * t), 1.0)
    )
    assert ok and not said  # a failed solve the stepper recovers from is no failure to report
    assert len(stepper.cutbacks) == 1 and stepper.step == 2 and stepper.failed is None
    cut = stepper.cutbacks[0]
    assert (cut.phase, cut.step, cut.t_from, cut.t_to) == ("press", 1, 0.0, 1.0)
    assert "outside the Taylor RVE's range" in cut.reason
    ref_solver, _, u_ref, p_ref = column("ref_")
    ref = LoadStepper(ref_solver)
    assert ref.run("press", lambda t: setattr(p_ref, "value", 6.5e6 * t), 0.5) and not ref.cutbacks
    diff = MPI.COMM_WORLD.allreduce(np.abs(u.x.array - u_ref.x.array).max(), op=MPI.MAX)
    assert diff <= 1e-12 * MPI.COMM_WORLD.allreduce(np.abs(u_ref.x.array).max(), op=MPI.MAX)
    solver.destroy()
    ref_solver.destroy()


@pytest.mark.mpi
def test_crushing_load_fails_cleanly_at_the_last_converged_state():
    """10 MPa is beyond what the column carries: Newton's trial states leave the RVE's range
    (and invert elements), the stepper cuts back until it gives up, leaving u and the material
    data at the last converged state, finite. The stop is a limit point: near 6.9 MPa the
    load-settlement path flattens (the strongly compressed RVEs lose their shear stiffness)."""
    solver, material, u, p = column("crush_")
    converged = {}

    def remember(step, t, result):
        converged.update(step=step, t=t, u=u.x.array.copy())

    stepper = LoadStepper(solver, max_cutbacks=4)
    ok, said = failure_warnings(
        lambda: stepper.run(
            "press", lambda t: setattr(p, "value", 1e7 * t), 1.0, on_converged=remember
        )
    )
    assert not ok
    # once per failure: one LoadPathWarning for the phase, none for its failed solves
    assert [kind for kind, _ in said] == [LoadPathWarning] and len(stepper.cutbacks) > 4
    message = said[0][1]
    assert (
        message.startswith("load phase 'press' failed ")
        and stepper.failed["reason"].rstrip(".") in message
    )
    assert "a limit load, which load control cannot pass" in message and "ArcLength" in message
    assert stepper.failed["step"] == converged["step"] + 1 and stepper.failed["t"] == converged["t"]
    assert 0.5 < converged["t"] < 1.0
    reasons = " ".join(c.reason for c in stepper.cutbacks)
    assert "outside the Taylor RVE's range" in reasons
    limit = stepper.failed["limit_load"]
    assert (
        limit is not None
        and limit["t_converged"] == converged["t"]
        and limit["stiffness_ratio"] < 0.2
    )
    assert converged["t"] - 1e-3 <= limit["t_estimate"] <= limit["t_failed"]
    assert all_finite(u.x.array) and np.array_equal(u.x.array, converged["u"])
    assert p.value == 1e7 * converged["t"]
    assert np.array_equal(material.F, material.deformation_gradient())  # data belong to u
    assert all_finite(material.P.x.array[: 4 * material.n_points])
    solver.destroy()


@pytest.mark.mpi
def test_singular_matrix_is_a_failed_solve():
    """The column pulled up: the contacts of the upper cells open, the Jacobian has zero rows and
    LU fails; the solve reports it instead of raising, names the RVEs without contacts, and
    restores the state it started from."""
    solver, material, u, p = column("sing_", verbose=False)
    opened = []
    update = material.update

    def spy(tangent=True):
        update(tangent)
        opened.append(MPI.COMM_WORLD.allreduce(material.n_open))

    material.update = spy
    p.value = -2e5
    result = solver.solve()
    assert not result.converged and result.reason_name == "DIVERGED_LINEAR_SOLVE"
    assert "singular" in result.why
    assert max(opened) > 0  # the iterate where LU failed had RVEs without contacts
    # the result names the cause and the fixes
    assert f"{opened[-2]} of 64 RVE points have lost every contact" in result.why, result.why
    assert "a confining load" in result.why and "stabilise=" in result.why
    assert not u.x.array.any() and opened[-1] == 0  # restored: u = 0, data of u = 0
    solver.destroy()


class Cycling(GranularMaterial):
    """A material whose stress flips by a constant every evaluation: Newton cannot settle."""

    def update(self, tangent=True):
        super().update(tangent)
        self.P.x.array[: 4 * self.n_points] += (-1.0) ** self.n_updates * 1e3


@pytest.mark.mpi
def test_stagnation_is_detected_before_the_iteration_limit():
    solver, _, _, p = column("stag_", material_class=Cycling, max_it=40)
    p.value = 2e5
    result = solver.solve()
    assert not result.converged and result.reason_name == STAGNATION
    # the reason says what was measured
    assert (
        result.why.startswith("stagnation: |R| = ") and "has not gone below its best" in result.why
    )
    # ... and how large the stalled residual is beside the forces (what a residual tolerance
    # would have to accept)
    best, share = re.search(r"best value (\S+) N \((\S+) of the force scale\)", result.why).groups()
    assert float(share) == pytest.approx(float(best) / result.force_scale, rel=0.06)
    assert 5 <= result.iterations < 15
    solver.destroy()
    solver, _, _, p = column("nostag_", material_class=Cycling, max_it=12, stagnation_it=0)
    p.value = 2e5
    result = solver.solve()
    assert result.reason_name == "DIVERGED_MAX_IT" and result.iterations == 12
    solver.destroy()


@pytest.mark.mpi
def test_a_stall_within_the_stall_tolerance_is_accepted_and_one_above_it_is_not():
    """The cycling stress stalls Newton at a residual of some share of the force scale: a
    stall_rtol of twice that share accepts the stalled iterate (``tolerance``, its residual
    within it, the state finite and kept), half of it stagnates as without one."""
    solver, _, _, p = column("share_", material_class=Cycling, max_it=40)
    p.value = 2e5
    share = float(re.search(r"\((\S+) of the force scale\)", solver.solve().why).group(1))
    solver.destroy()
    solver, _, u, p = column("accept_", material_class=Cycling, max_it=40, stall_rtol=2 * share)
    p.value = 2e5
    result = solver.solve()
    assert result.converged and result.stopped_by == "tolerance", result
    assert result.residual_norm <= 2 * share * result.force_scale
    assert result.iterations < 15 and all_finite(u.x.array) and u.x.array.any()
    solver.destroy()
    solver, _, _, p = column("refuse_", material_class=Cycling, max_it=40, stall_rtol=share / 2)
    p.value = 2e5
    result = solver.solve()
    assert not result.converged and result.reason_name == STAGNATION
    solver.destroy()


@pytest.mark.mpi
def test_stabiliser_acts_only_where_every_contact_is_open():
    """Stretched half (x > 5: every contact open) gets alpha C : (F - I) and alpha C; the
    compressed half is bit for bit the plain material."""
    _, plain, u0, _ = column("plain_")
    _, stab, u1, _ = column("stab_", stabilise=1e-3)
    C = 1e-3 * stab.rve.small_strain_modulus()

    def field(x):  # compression for x < 5, a uniform 0.1 % stretch for x > 5
        # (the nodes on x = 5 stretch: their interpolation points may lie a round-off below 5)
        s = np.where(x[0] < 5 - 1e-9, -0.01, 0.001)
        return np.stack([s * (x[0] - 5), s * x[1]])

    for u in (u0, u1):
        u.interpolate(field)
    plain.update()
    stab.update()
    assert np.array_equal(plain.F, stab.F)
    opened = plain.W == 0.0
    assert np.array_equal(opened, plain.points[:, 0] > 5)
    assert stab.n_open == plain.n_open == opened.sum()
    P0, P1 = plain.P.x.array.reshape(-1, 2, 2), stab.P.x.array.reshape(-1, 2, 2)
    A0, A1 = plain.A.x.array.reshape(-1, 2, 2, 2, 2), stab.A.x.array.reshape(-1, 2, 2, 2, 2)
    n = plain.n_points
    assert np.array_equal(P0[:n][~opened], P1[:n][~opened])
    assert np.array_equal(A0[:n][~opened], A1[:n][~opened])
    assert np.all(P0[:n][opened] == 0.0) and np.all(A0[:n][opened] == 0.0)
    E = stab.F[opened] - np.eye(2)
    assert np.allclose(P1[:n][opened], np.einsum("abcd,qcd->qab", C, E), rtol=1e-12, atol=0)
    assert np.allclose(A1[:n][opened], C, rtol=1e-14, atol=0)
    with pytest.raises(ValueError, match="stabilise"):
        GranularMaterial(stab.rve, u0, stabilise=-1.0)


@pytest.mark.mpi
def test_block_pulled_partly_into_tension():
    """A block under its own weight, free sides, the top plate tilted: pushed down 1.4 m at the
    left, lifted 0.6 m at the right, in one nominal step. The prescribed top displacement alone
    crushes the top cells beyond the RVE's range; two cut-backs later the block is in equilibrium
    with RVEs at the lifted corner that have lost every contact."""
    msh = mesh.create_rectangle(
        MPI.COMM_WORLD, [[0, 0], [10, 10]], [6, 6], mesh.CellType.quadrilateral
    )
    V = vector_space(msh)
    u, v, du = fem.Function(V), ufl.TestFunction(V), ufl.TrialFunction(V)
    material = GranularMaterial(TaylorRVE(generate_packing(70, seed=4), 2.8e7), u)
    top = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 10))
    bottom = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 0))
    g, lam = fem.Function(V), fem.Constant(msh, 0.0)

    def set_load(t):
        g.interpolate(lambda x: np.stack([0 * x[0], 2.0 * t * (x[0] / 10 - 0.7)]))
        lam.value = t

    bcs = [
        fem.dirichletbc(np.zeros(2), fem.locate_dofs_topological(V, 1, bottom), V),
        fem.dirichletbc(g, fem.locate_dofs_topological(V, 1, top)),
    ]
    residual = material.residual_form(v) + lam * 2.5e4 * v[1] * ufl.dx  # weight 25 kN/m³
    solver = NewtonSolver(
        residual, material.jacobian_form(du, v), u, bcs, material, prefix="pull_", max_it=15
    )
    stepper = LoadStepper(solver)
    assert stepper.run("pull", set_load, 1.0)
    assert len(stepper.cutbacks) >= 1
    assert all("outside the Taylor RVE's range" in c.reason for c in stepper.cutbacks)
    assert MPI.COMM_WORLD.allreduce(material.n_open) > 0
    assert all_finite(u.x.array)
    # the open RVEs are at the lifted corner
    opened = material.points[material.W == 0.0]
    assert MPI.COMM_WORLD.allreduce(
        bool(np.all(opened[:, 0] > 5) and np.all(opened[:, 1] > 5)), op=MPI.LAND
    )
    solver.destroy()


@pytest.mark.mpi
def test_a_column_pulled_apart_says_why_it_fails():
    """The issue: a column pulled up returned False and printed nothing. One LoadPathWarning
    names the reason (RVEs without contacts) and the remedies for tension; the solves it cut
    back stay silent; warn=False leaves the report to the caller."""
    solver, _, _, p = column("apart_")
    stepper = LoadStepper(solver, max_cutbacks=1)
    ok, said = failure_warnings(
        lambda: stepper.run("pull", lambda t: setattr(p, "value", -2e5 * t), 1.0)
    )
    assert not ok and [kind for kind, _ in said] == [LoadPathWarning]
    assert "have lost every contact" in said[0][1]
    assert (
        "Remedy: the granular material carries no tension" in said[0][1]
        and "stabilise=" in said[0][1]
    )
    quiet = LoadStepper(solver, max_cutbacks=1, warn=False)
    ok, said = failure_warnings(
        lambda: quiet.run("pull", lambda t: setattr(p, "value", -2e5 * t), 1.0)
    )
    assert not ok and not said and quiet.failed is not None
    solver.destroy()


@pytest.mark.mpi
def test_a_path_that_cannot_go_on_warns_once():
    """ArcLength: the failed attempts it cuts back are silent; the path that ends warns once."""
    model = truss(prefix="al_warn_")
    al = ArcLength(model.solver, model.load, model.external, 1.0, max_it=0, max_cutbacks=2)
    inc, said = failure_warnings(al.advance)
    assert inc is None and [kind for kind, _ in said] == [LoadPathWarning]
    assert said[0][1].startswith("path following stopped: increment 1 failed")
    assert (
        al.failed["reason"].rstrip(".") in said[0][1]
        and "Remedy: a shorter smallest arc" in said[0][1]
    )
    quiet = ArcLength(model.solver, model.load, model.external, 1.0, max_it=0, warn=False)
    ok, said = failure_warnings(quiet.run)
    assert not ok and not said and quiet.failed is not None
    model.solver.destroy()


def smooth_limit_path(n, t_top=1.0, scale=3.0):
    """Increments along t(u) = t_top (2 s - s²), s = u / scale: a limit point at u = scale,
    approached with increments that shrink like the cut-back stepper's."""
    t = t_top * (1 - 0.5 ** np.arange(1, n + 1))  # 0.5, 0.75, ... t_top
    u = scale * (1 - np.sqrt(1 - t / t_top))
    t0, u0 = np.concatenate([[0.0], t]), np.concatenate([[0.0], u])
    return [
        {"phase": "p", "t": t0[k], "dt": t0[k] - t0[k - 1], "increment_norm": u0[k] - u0[k - 1]}
        for k in range(1, n + 1)
    ]


def test_limit_point_is_recognised_and_located():
    from dolfinx_granular.drivers.loading import limit_point

    path = smooth_limit_path(8, t_top=0.8)
    t_last = path[-1]["t"]
    t_failed = t_last + 0.5 * (0.8 - t_last) * 2  # the next increment, beyond the maximum
    limit = limit_point(path, t_failed)
    assert limit is not None and limit["t_converged"] == t_last and limit["t_failed"] == t_failed
    # S² is linear in t along this curve: the extrapolation is exact
    assert abs(limit["t_estimate"] - 0.8) <= 1e-12
    S = [p["dt"] / p["increment_norm"] for p in path]
    assert limit["stiffness_ratio"] == S[-1] / S[0] < 0.2
    # any scaling of the displacement norm gives the same answer
    scaled = [dict(p, increment_norm=7.0 * p["increment_norm"]) for p in path]
    assert limit_point(scaled, t_failed)["t_estimate"] == pytest.approx(0.8, abs=1e-12)


def test_limit_point_rejects_other_failures():
    from dolfinx_granular.drivers.loading import limit_point

    linear = [{"phase": "p", "t": 0.1 * k, "dt": 0.1, "increment_norm": 0.02} for k in range(1, 6)]
    assert limit_point(linear, 0.55) is None  # stiff path: the failure is not a limit point
    path = smooth_limit_path(4, t_top=1.0)  # still far from the maximum (S at 35 % of S_first)
    assert limit_point(path, path[-1]["t"] + 1e-3) is None
    assert limit_point(path[:2], 1.0) is None  # too few increments to tell
    path = smooth_limit_path(8, t_top=1.0)
    # a failure just after t_last, far before the extrapolated maximum, is something else
    assert limit_point(path, path[-1]["t"] + 1e-3 * (1 - path[-1]["t"])) is None


def test_limit_point_inside_the_failed_increment_needs_a_smaller_drop():
    """S at 35 % of its first value: no limit for a failure well before the extrapolated maximum,
    a limit when the maximum lies inside the increment that failed; S that has not halved: never."""
    from dolfinx_granular.drivers.loading import limit_point

    path = smooth_limit_path(4, t_top=1.0)
    S = [p["dt"] / p["increment_norm"] for p in path]
    assert 0.2 < S[-1] / S[0] <= 0.5
    assert limit_point(path, 0.97) is None  # t* = 1 beyond the failed target
    limit = limit_point(path, 1.01)
    assert limit is not None and limit["t_estimate"] == pytest.approx(1.0, abs=1e-12)
    mild = [
        {"phase": "p", "t": 0.1 * k, "dt": 0.1, "increment_norm": 0.1 / S_k}
        for k, S_k in enumerate([1.0, 0.9, 0.7], start=1)
    ]  # extrapolates to t* = 0.403
    assert limit_point(mild, 0.45) is None


class SevenIterationSolver:
    """A stand-in for NewtonSolver whose solves take 7 Newton steps (the count of a typical
    step to the energy norm 1e-20), except the first attempt, which fails."""

    def __init__(self, u):
        self.u, self.materials, self.calls = u, (), 0

    def solve(self, warn=True):
        from dolfinx_granular.drivers.newton import SolveResult

        self.calls += 1
        ok = self.calls > 1
        return SolveResult(
            converged=ok,
            reason=2 if ok else -5,
            reason_name="CONVERGED_FNORM_ABS" if ok else "DIVERGED_MAX_IT",
            iterations=7,
        )


def test_increment_grows_back_after_ordinary_newton_steps():
    """After a cut-back, steps of 7 Newton iterations count as easy: the increment grows back to
    the nominal one (1/4 -> 3/8 -> 1/2 capped), instead of staying at the cut-back size."""
    from dolfinx_granular import LoadStepper as exported

    assert exported is LoadStepper  # the package exports it
    msh = mesh.create_unit_square(MPI.COMM_SELF, 1, 1)
    stepper = LoadStepper(SevenIterationSolver(fem.Function(vector_space(msh))))
    assert stepper.run("p", lambda t: None, 0.5)
    assert [round(p["dt"], 12) for p in stepper.path] == [0.25, 0.375, 0.375]
    assert len(stepper.cutbacks) == 1
