"""Arc-length path following (dolfinx_granular.drivers.arclength) on the von Mises truss with a soft
spring (tests/truss.py): the traced path lies on the exact equilibrium path through both load
limit points and the snap-back, the limit points are found by the sign of det K, and failed
increments leave the converged state as it was."""

from dolfinx_granular.drivers.arclength import ArcLength, control_reaches, load_reaches, unloaded_to

import numpy as np
import pytest
from mpi4py import MPI

from truss import P_MAX, H, deflections, load_of_apex, spring_compression, truss


def trace(model, ds=0.02, steps=200, stop=None, **kwargs):
    """The converged states (lam, w, v) along the path."""
    al = ArcLength(model.solver, model.load, model.external, ds, **kwargs)
    states = []
    al.run(steps, stop=stop, on_converged=lambda inc: states.append((inc.lam, *deflections(model))))
    return al, np.array(states)


@pytest.mark.mpi
def test_truss_path_through_both_limit_points_and_the_snap_back():
    model = truss(prefix="al_truss_")
    al, s = trace(
        model,
        ds=0.02,
        ds_max=0.05,
        stop=lambda a: "past" if deflections(model)[0] > 2.2 * H else None,
    )
    lam, w, v = s.T
    assert al.failed is None and al.stopped == "past"
    # every converged state is on the exact path: P(w), and the spring's compression at that P
    assert np.abs(lam - load_of_apex(w)).max() <= 1e-9 * P_MAX
    c = np.array([spring_compression(p) for p in lam])
    assert np.abs(v - w - c).max() <= 1e-9 * H
    # the whole path: the peak, the valley (negative load), beyond the snap-through
    assert lam[w < H].max() > 0.99 * P_MAX and lam.min() < -0.99 * P_MAX and w[-1] > 2 * H
    # peak load to 1 % (the sampled maximum of an exact path: a step-size question); beyond the
    # snap-through (w > 2 h) the bars are stretched and the load rises again
    assert 0.99 * P_MAX <= lam[w < H].max() <= P_MAX * (1 + 1e-9)
    # snap-back: the load point's deflection v turns back while the path goes on
    dv = np.diff(v)
    assert (dv < 0).any() and (dv > 0).any()
    # det K changes sign at the two load limit points, not at the snap-back's turning points
    kinds = [cp.kind for cp in al.critical]
    assert kinds == ["limit", "limit"], al.critical
    # ... inside the increments that hold the exact limit points w = h (1 -+ 1 / sqrt 3)
    for cp, w_limit in zip(al.critical, H * (1 + np.array([-1, 1]) / np.sqrt(3))):
        w_before = w[cp.step - 2] if cp.step > 1 else 0.0
        assert w_before <= w_limit <= w[cp.step - 1], (cp, w_before, w[cp.step - 1])
        assert (cp.lam_before, cp.lam_after) == (lam[cp.step - 2], lam[cp.step - 1])
    model.solver.destroy()


def test_cylindrical_and_spherical_and_dof_control_trace_the_same_curve():
    """psi > 0 (spherical) and displacement control of the apex give states on the same exact
    path; dof control stops where asked."""
    for kwargs in ({"psi": 1.0}, {"control": "apex"}):
        model = truss(prefix=f"al_{list(kwargs)[0]}_")
        if kwargs.get("control"):
            kwargs = {"control": (model.apex_dof, -1.0)}  # the apex moves down: u_y decreases
        al, s = trace(
            model,
            ds=0.01 if "control" in kwargs else 0.02,
            steps=80,
            stop=load_reaches(-0.5 * P_MAX) if "psi" in kwargs else control_reaches(-1.5 * H),
            **kwargs,
        )
        lam, w, v = s.T
        assert al.failed is None, al.failed
        assert np.abs(lam - load_of_apex(w)).max() <= 1e-9 * P_MAX
        assert lam.max() > 0.95 * P_MAX
        if "control" in kwargs:  # each increment moved the apex by its ds exactly
            ds = np.array([inc.ds for inc in al.path])
            assert np.allclose(np.diff(np.concatenate([[0.0], w])), ds, rtol=1e-9, atol=0)
        model.solver.destroy()


def test_unloaded_to_stops_after_the_peak():
    model = truss(prefix="al_unload_")
    al, s = trace(model, ds=0.02, stop=unloaded_to(0.5))
    lam = s[:, 0]
    peak = int(np.argmax(lam))
    assert 0 < peak < len(lam) - 1 and lam[-1] <= 0.5 * lam[peak] < lam[-2]
    assert "fell to" in al.stopped
    model.solver.destroy()


def test_a_failed_increment_is_cut_back_from_the_converged_state():
    """An arc far too long for Newton: the increment fails, the state is restored exactly and
    the halved arcs reach the same path."""
    model = truss(prefix="al_cut_")
    al = ArcLength(model.solver, model.load, model.external, 0.02)
    assert al.advance() is not None
    u0, lam0 = model.u.x.array.copy(), al.lam
    al.ds, al.max_it = 5.0, 6  # a jump over the whole path
    before = len(al.path)
    inc = al.advance()
    assert inc is not None and al.ds < 5.0 and len(al.path) == before + 1
    w = deflections(model)[0]
    assert abs(inc.lam - load_of_apex(w)) <= 1e-9 * P_MAX
    # and an increment that can never converge restores the state it started from
    al2 = ArcLength(model.solver, model.load, model.external, 1.0, max_it=0, max_cutbacks=2)
    u1 = model.u.x.array.copy()
    assert al2.advance() is None and "failed" in al2.failed["reason"]
    assert np.array_equal(model.u.x.array, u1) and float(model.load.value) == inc.lam
    assert lam0 != inc.lam and not np.array_equal(u0, u1)
    model.solver.destroy()


def test_residual_must_be_linear_in_the_load():
    model = truss(prefix="al_bad_")
    with pytest.raises(ValueError, match="not R\\(u\\) - lam"):
        ArcLength(model.solver, model.load, 2.0 * model.external, 0.02)
    model.solver.destroy()


@pytest.mark.mpi
def test_serial_path_is_reproduced_on_every_rank_count():
    """The traced states do not depend on the partition: under mpirun the distributed truss
    traces, step for step, the path of a serial copy on each rank (to round-off)."""
    model = truss(MPI.COMM_WORLD, prefix="al_mpi_")
    _, s = trace(model, ds=0.05, steps=12)
    assert np.abs(s[:, 0] - load_of_apex(s[:, 1])).max() <= 1e-9 * P_MAX
    serial = truss(MPI.COMM_SELF, prefix="al_self_")
    _, s1 = trace(serial, ds=0.05, steps=12)
    assert s.shape == s1.shape == (12, 3)
    assert np.abs(s - s1).max() <= 1e-10 * np.abs(s1).max(), np.abs(s - s1).max()
    serial.solver.destroy()
    model.solver.destroy()


def snes_newtonal_final_state(model, target, step_size):
    """PETSc's own arc length (SNESNEWTONAL, in recent PETSc) through the package's driver on the
    same problem: lam from 0 to 1 of the load ``target``, through every limit point; (w, v)."""
    from dolfinx_granular.drivers.snes_al import SNESArcLength

    driver = SNESArcLength(
        model.solver, model.load, model.external, target, step_size=step_size, prefix="t_al_"
    )
    records = []
    assert driver.run(on_converged=records.append) and driver.failed is None
    assert driver.lam == 1.0 and [r.t for r in records] == [1.0]
    assert float(model.load.value) == target  # u and the load at the end state
    driver.destroy()
    return deflections(model)


def test_same_far_branch_as_petsc_snes_newtonal():
    """Where PETSc has SNESNEWTONAL: 1.5 x the peak load is carried only on the far branch, past
    both limit points; PETSc's arc length and this package's reach the same state there."""
    from dolfinx_granular.drivers.snes_al import has_newtonal

    if not has_newtonal():
        pytest.skip("this PETSc has no SNESNEWTONAL (PETSc < 3.23): nothing to compare with")

    target = 1.5 * P_MAX
    theirs = snes_newtonal_final_state(truss(prefix="al_petsc_"), target, 0.05)
    model = truss(prefix="al_ours_")
    al, s = trace(model, ds=0.02, stop=load_reaches(target))
    assert al.stopped and s[-1, 1] > 2 * H  # on the far branch
    model.load.value = target  # from the path's last state, Newton at exactly the target load
    assert model.solver.solve().converged
    ours = deflections(model)
    assert np.allclose(ours, theirs, rtol=1e-10, atol=0), (ours, theirs)
    assert abs(load_of_apex(ours[0]) - target) <= 1e-9 * P_MAX


def test_snes_newtonal_driver_refused_without_it():
    """Where PETSc lacks SNESNEWTONAL (Debian's 0.5.2: PETSc 3.18) the driver says so and
    names the alternative, in one line."""
    from dolfinx_granular.drivers.snes_al import SNESArcLength, has_newtonal

    if has_newtonal():
        pytest.skip("this PETSc has SNESNEWTONAL (tested above)")
    model = truss(prefix="al_none_")
    with pytest.raises(RuntimeError, match="needs PETSc >= 3.23.*ArcLength"):
        SNESArcLength(model.solver, model.load, model.external, 1.0)
    model.solver.destroy()


def test_both_drivers_follow_the_driver_protocol():
    """ArcLength is a Driver: run(on_converged) with one record per increment (an
    IncrementRecord, t the load parameter), failed/stopped of one type each."""
    from dolfinx_granular.drivers.protocol import ASKED_TO_STOP, Driver, IncrementRecord

    model = truss(prefix="al_proto_")
    al = ArcLength(model.solver, model.load, model.external, 0.02, max_increments=3)
    assert isinstance(al, Driver)
    records = []
    assert al.run(on_converged=lambda inc: records.append(inc) or len(records) < 2)
    assert al.stopped == ASKED_TO_STOP and al.failed is None and len(records) == 2
    assert all(isinstance(r, IncrementRecord) for r in records)
    assert [r.t for r in records] == [r.lam for r in records] and records[-1].step == 2
    assert al.run() and al.stopped == "3 increments" and len(al.path) == 5
    model.solver.destroy()


def test_arc_length_on_the_bare_problem_is_the_path_on_the_solver():
    """ArcLength acts on the GranularProblem: given the problem alone (default thresholds, an LU
    solver of its own) it traces, increment for increment, the path it traces on the solver."""
    on_solver, on_problem = truss(prefix="al_solver_"), truss(prefix="al_problem_")
    _, s = trace(on_solver, ds=0.05, steps=8)
    al = ArcLength(on_problem.solver.problem, on_problem.load, on_problem.external, 0.05)
    states = []
    al.run(8, on_converged=lambda inc: states.append((inc.lam, *deflections(on_problem))))
    assert np.array_equal(np.array(states), s) and al.failed is None
    al.destroy()
    on_solver.solver.destroy()
    on_problem.solver.destroy()
