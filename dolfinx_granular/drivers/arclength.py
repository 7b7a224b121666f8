"""Path following past limit points: arc-length continuation of R(u) - lam f = 0.

Load control stops at a limit point (the largest load the structure carries): beyond it no
equilibrium exists at a larger load. :class:`ArcLength` follows the equilibrium path instead,
with the load parameter lam as an unknown beside u, constrained per increment by (Crisfield)

    |Du|^2 + psi^2 |f|^2 Dlam^2 = ds^2      (psi = 0: cylindrical, the default; > 0: spherical)

or, with ``control=``, by the increment of one displacement dof (displacement control). Each
corrector iteration factorises the tangent K once and solves it for two right-hand sides,
``K a = -R`` and ``K b = f``; the correction ``du = a + dlam b`` satisfies the linearised
equilibrium for any dlam, which the constraint then fixes (the bordered system, without a new
matrix). Of the constraint's two roots the one that keeps going forward is taken: the smaller
angle between the new increment and the last one. The predictor follows the previous increment's
direction (the sign of ``Du_prev . b``), so the path turns round limit points by itself.

The corrector's convergence test is the solver's :class:`~dolfinx_granular.drivers.convergence.
ConvergenceTest` with its thresholds (``energy_rtol``, round-off tests, ``stagnation_it``), in its
``corrector`` variant. The increments act on the solver's
:class:`~dolfinx_granular.GranularProblem` through its public methods, and use the LU
solver (KSP) of the solver's SNES. Its work is timed on the solver's clock as SNES solves
are (``"snes"``, with the residuals, Jacobians and convergence tests under ``"callbacks"``), so
that the solver's :attr:`~dolfinx_granular.NewtonSolver.timings` split the path's time
as a load-controlled run's.

Increments adapt to the Newton iterations they take; a failed increment (no real root, Newton
divergence, an RVE outside its range, a singular tangent) is restored and halved; a path that
ends early warns once (:class:`~dolfinx_granular.LoadPathWarning`). The sign of
det K (MUMPS computes the determinant with the factorisation) is watched along the path: where it
changes between two converged states the path has crossed a critical point; a limit point where
the load turns back, a bifurcation point where it does not. Laws with history are committed only
at converged increments.

The residual must have the form R(u) - lam f with lam a :class:`dolfinx.fem.Constant` (``load``)
and f a linear form (``external``, the load pattern); this is checked once at construction.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from petsc4py import PETSc

from .convergence import CONVERGED, NAN, STAGNATION, ConvergenceTest
from .pathrecords import CriticalPoint, Increment, control_reaches, load_reaches, unloaded_to
from .protocol import (
    ASKED_TO_STOP,
    UNCONFINED_RELAXED,
    LoadPathWarning,
    failure,
    unconfined_relaxed,
    warn_failure,
)

if TYPE_CHECKING:
    from collections.abc import Callable

    import ufl
    from dolfinx import fem

    from .newton import NewtonSolver
    from .problem import GranularProblem

__all__ = [
    "ASKED_TO_STOP",
    "ArcLength",
    "CriticalPoint",
    "Increment",
    "control_reaches",
    "load_reaches",
    "unloaded_to",
]


class ArcLength:
    """Arc-length continuation on top of a :class:`~dolfinx_granular.NewtonSolver`.

    Args:
        solver: the Newton solver of R(u) - lam f (its problem, convergence thresholds and LU
            solver are used; converged increments commit the materials' history), or a bare
            :class:`~dolfinx_granular.GranularProblem` (default thresholds, an LU
            solver of its own).
        load: the Constant lam in the residual.
        external: the load pattern f (UFL linear form; the residual is ``... - lam * f``).
        ds: first arc length (m of |Du|, plus psi-weighted load); or None with ``dlam``: the
            arc of a first load increment ``dlam`` (its linearised |Du| at the start).
        psi: load weight of the constraint (0: cylindrical).
        control: ``(dof, sign)``: constrain the increment of this local dof (owned by one rank,
            -1 on the others) instead of |Du|; its increment has the sign of ``sign``.
        direction: sign of the first increment of lam.
        max_it: most corrector iterations per increment.
        target_iterations: the iterations an increment should take; ds grows or shrinks by
            sqrt(target / iterations), within a factor 2.
        ds_max, ds_min: bounds of ds; an increment below ds_min that fails ends the path.
        peak_refinement: near a limit point the arc shrinks with the load's rate, to
            ``ds_max / peak_refinement`` at most (1: off).
        max_cutbacks: most halvings of one increment in a row.
        log: callable taking one progress line, or None.
        max_increments: the increments :meth:`run` takes at most by default.
        stop: the default ``stop`` of :meth:`run`.
        warn: a path that ends early issues one :class:`~dolfinx_granular.LoadPathWarning`
            naming the reason and a remedy (False: the caller reports :attr:`failed` itself).

    Attributes:
        path: the converged :class:`Increment` s.
        critical: the :class:`CriticalPoint` s crossed.
        lam: load parameter of the converged state.
        failed: None, or a :func:`~dolfinx_granular.drivers.protocol.failure` dict once the path
            ended early (``phase`` "path", ``t`` the load parameter lam of the last converged
            state).
        stopped: None, or why :meth:`run` stopped (its ``stop`` reason, ``"N increments"``,
            :data:`~dolfinx_granular.drivers.protocol.ASKED_TO_STOP`).
        problem: the solver's :class:`~dolfinx_granular.GranularProblem`.
    """

    def __init__(
        self,
        solver: NewtonSolver | GranularProblem,
        load: fem.Constant,
        external: ufl.Form,
        ds: float | None = None,
        *,
        dlam: float | None = None,
        psi: float = 0.0,
        control: tuple[int, float] | None = None,
        direction: float = 1.0,
        max_it: int = 15,
        target_iterations: int = 5,
        ds_max: float | None = None,
        ds_min: float | None = None,
        max_cutbacks: int = 8,
        peak_refinement: float = 1.0,
        log: Callable[[str], object] | None = None,
        max_increments: int = 100,
        stop: Callable[[ArcLength], str | None] | None = None,
        warn: bool = True,
    ) -> None:
        if getattr(solver, "linear_solver", "direct") != "direct":
            raise ValueError(
                "path following factorises the tangent and reads the sign of det K from its "
                "LU factors: build the NewtonSolver with linear_solver='direct'"
            )
        self.solver, self.load = solver, load
        # a NewtonSolver lends its problem, thresholds and LU solver; a bare problem gets its own
        self.problem = getattr(solver, "problem", solver)
        self.clock = self.problem.clock  # (a NewtonSolver's clock is its problem's)
        self._thresholds = getattr(solver, "test", None) or ConvergenceTest(self.problem)
        self.ksp = solver.snes.getKSP() if hasattr(solver, "snes") else _lu(self.problem.comm)
        self.max_increments, self.stop = int(max_increments), stop
        self.warn = bool(warn)
        self.psi = float(psi)
        self.control = control
        self.direction = 1.0 if direction >= 0 else -1.0
        self.max_it, self.target_iterations = int(max_it), int(target_iterations)
        self.max_cutbacks = int(max_cutbacks)
        self.peak_refinement = float(peak_refinement)
        self.log = log or (lambda line: None)
        self.lam = float(load.value)
        self.path: list[Increment] = []
        self.critical: list[CriticalPoint] = []
        self.failed = self.stopped = None
        self._du_prev = None  # the last converged increment Du (a vector) and Dlam
        self._dlam_prev = 0.0
        self._det_sign = 0
        if ds is None and dlam is None:
            raise ValueError("give the first arc length ds or the first load increment dlam")
        self.f = self._load_vector(external)
        # the load's share psi^2 |f|^2 of the constraint: f and psi are fixed, one reduction
        self._load_weight = self.psi**2 * self.f.dot(self.f)
        with self.clock("snes"):  # (timed as the increments are: see the module doc)
            self._check_form()
            if ds is None:
                ds = self._arc_of(float(dlam))
        self.ds = float(ds)
        self.ds_max = float(ds_max) if ds_max else 10.0 * self.ds
        self.ds_min = float(ds_min) if ds_min else 1e-4 * self.ds

    # -- set-up ----------------------------------------------------------------------------------

    def _load_vector(self, external):
        """f assembled once (dead load), zero in the Dirichlet rows."""
        return self.problem.load_vector(external)

    def _check_form(self):
        """R(u, lam + 1) - R(u, lam) must be -f: the residual is R(u) - lam f."""
        x = self.problem.u_vec.copy()
        r0, r1 = x.duplicate(), x.duplicate()
        lam = float(self.load.value)
        try:
            with self.clock("callbacks"):
                self.load.value = lam + 1.0
                # with the tangent: the first factorisation, at this u, evaluates nothing again
                error = self.problem.residual(x, r1)
                self.load.value = lam
                if error:
                    raise ValueError(f"the start state cannot be evaluated: {error}")
                # the material data do not depend on lam: R at lam needs no evaluation
                self.problem.assemble_residual(x, r0)
            r1.axpy(-1.0, r0)
            r1.axpy(1.0, self.f)
            scale = max(self.f.norm(), 1e-300)
            if not r1.norm() <= 1e-8 * max(scale, r0.norm()):
                raise ValueError(
                    "the residual is not R(u) - lam * external with lam = load: "
                    f"dR/dlam differs from -external by {r1.norm():.3g} (|f| = "
                    f"{scale:.3g}); pass the load pattern that the load Constant scales"
                )
        finally:
            for v in (x, r0, r1):
                v.destroy()

    def _arc_of(self, dlam):
        """The arc of a load increment dlam from the current state: |dlam| |K^-1 f| (+ psi)."""
        x = self.problem.u_vec.copy()
        b = x.duplicate()
        try:
            self._factorise(x)
            self._solve(self.f, b)
            ds = abs(dlam) * np.sqrt(b.dot(b) + self._load_weight)
        finally:
            for v in (x, b):
                v.destroy()
        return float(ds)

    # -- restarts ------------------------------------------------------------------------------

    def state(self) -> dict:
        """What continues the path after a restart (JSON), beside u and the last increment Du."""
        return {
            "lam": self.lam,
            "ds": self.ds,
            "ds_max": self.ds_max,
            "ds_min": self.ds_min,
            "dlam_prev": self._dlam_prev,
            "det_sign": self._det_sign,
            "path": [p.as_dict() for p in self.path],
            "critical": [c.as_dict() for c in self.critical],
            "stopped": self.stopped,
        }

    def resume(self, state: dict, du_prev: PETSc.Vec | None) -> None:
        """Continue from :meth:`state` at the converged state in ``solver.u``; ``du_prev``: its
        last increment Du (a vector like u's; None at the start of the path)."""
        self.lam = float(state["lam"])
        self.load.value = self.lam
        self.ds, self._dlam_prev = float(state["ds"]), float(state["dlam_prev"])
        self.ds_max, self.ds_min = float(state["ds_max"]), float(state["ds_min"])
        self._det_sign = int(state["det_sign"])
        self.path = [Increment(**p) for p in state["path"]]
        self.critical = [CriticalPoint(**c) for c in state["critical"]]
        self.stopped = state.get("stopped")
        self._du_prev = du_prev

    # -- linear algebra ------------------------------------------------------------------------

    def _factorise(self, x):
        """Assemble K at x and factorise it; the sign of det K (0 where the LU solver does not
        give it). Raises RuntimeError if the factorisation fails."""
        with self.clock("callbacks"):  # (as SNES's Jacobian callback; the LU is not)
            A = self.problem.assemble_jacobian(x)
        ksp = self.ksp
        ksp.setOperators(A)
        pc = ksp.getPC()
        mumps = pc.getFactorSolverType() == "mumps"
        try:
            if mumps:
                pc.setFactorSetUpSolverType()
                pc.getFactorMatrix().setMumpsIcntl(33, 1)  # the determinant, with the factors
            ksp.setUp()
        except PETSc.Error as err:
            pc.reset()
            raise RuntimeError(
                f"factorisation failed (PETSc error {err.ierr}): a singular tangent"
            ) from None
        if not mumps:
            return 0
        return int(np.sign(pc.getFactorMatrix().getMumpsRinfog(12)))

    def _solve(self, rhs, out):
        ksp = self.ksp
        ksp.solve(rhs, out)
        if ksp.getConvergedReason() < 0:
            ksp.getPC().reset()
            raise RuntimeError("linear solve failed (singular tangent or zero pivot)")

    def _control_value(self, vec):
        """The control dof's entry of ``vec`` (every rank gets it)."""
        return self._control_values(vec)[0]

    def _control_values(self, *vecs):
        """The control dof's entries of ``vecs`` (every rank gets them), in one reduction."""
        dof = self.control[0]
        local = np.array([float(v.array_r[dof]) if dof >= 0 else 0.0 for v in vecs])
        # (one rank holds the dof, the others add zeros: the sum is exact)
        return [float(c) for c in self.problem.comm.allreduce(local)]

    # -- one increment -------------------------------------------------------------------------

    def _predictor(self, x):
        """Du and Dlam of the predictor from the converged state x (K factorised there)."""
        sign = self._factorise(x)
        b = x.duplicate()
        try:
            self._solve(self.f, b)
        except RuntimeError:
            b.destroy()
            raise
        if self.control is not None:
            bc = self._control_value(b)
            dlam = self.control[1] * self.ds / bc if bc != 0 else 0.0
        else:
            dlam = self.ds / np.sqrt(b.dot(b) + self._load_weight)
        if self._du_prev is None:
            dlam = abs(dlam) * self.direction
        else:  # keep going forward: the previous increment's direction
            forward = self._du_prev.dot(b) + self._load_weight * self._dlam_prev
            dlam = abs(dlam) * (1.0 if forward >= 0 else -1.0)
        b.scale(dlam)
        return b, dlam, sign

    def _constraint_root(self, du, dlam, a, b):
        """dlam correction that keeps the constraint with ``du + a + dlam' b``; None if no real
        root (the arc does not meet the linearised equilibrium)."""
        if self.control is not None:
            bc, c_du, c_a = self._control_values(b, du, a)
            target = self.control[1] * self.ds - c_du - c_a
            return target / bc if bc != 0 else None
        w = self._load_weight
        ua = du.copy()
        ua.axpy(1.0, a)
        c1 = b.dot(b) + w
        c2 = 2.0 * (ua.dot(b) + w * dlam)
        c3 = ua.dot(ua) + w * dlam**2 - self.ds**2
        disc = c2 * c2 - 4.0 * c1 * c3
        if disc < 0.0:
            ua.destroy()
            return None
        roots = [(-c2 + s * np.sqrt(disc)) / (2.0 * c1) for s in (1.0, -1.0)]
        # forward: the smaller angle between the new increment and the current one
        score = [ua.dot(du) + r * b.dot(du) + w * dlam * (dlam + r) for r in roots]
        ua.destroy()
        return roots[int(np.argmax(score))]

    def _corrector(self, x0, du, dlam):
        """Newton on (u, lam) under the constraint from x0 + du, lam + dlam. Returns the state x,
        the increment (du, dlam) and the :class:`~dolfinx_granular.ConvergenceTest`
        record; raises _Failed with the reason (no convergence, stagnation, no real root, an
        RVE outside its range); x is freed then."""
        x = x0.copy()
        x.axpy(1.0, du)
        R, a, b = (x.duplicate() for _ in range(3))
        test, energy = self._new_test(), None
        converged = False
        try:
            for it in range(self.max_it + 1):
                self.load.value = self.lam + dlam
                with self.clock("callbacks"):  # (as SNES's residual and convergence test)
                    converged = self._converged(test, it, x, R, energy)
                if converged:
                    return x, du, dlam, test
                if it == self.max_it:
                    raise _Failed(
                        f"no convergence in {self.max_it} corrector iterations "
                        f"(|R| = {test.rnorm:.3e} N)"
                    )
                r = self._correction(x, R, a, b, du, dlam)
                energy = abs(R.dot(a))  # (R is -R here: the step's energy |R . du|)
                du.axpy(1.0, a)
                x.axpy(1.0, a)
                dlam += r
        finally:
            for v in (R, a, b):
                v.destroy()
            if not converged:
                x.destroy()

    def _new_test(self):
        """The corrector's convergence test: the solver's thresholds, its corrector variant."""
        t = self._thresholds
        return ConvergenceTest(
            self.problem,
            energy_rtol=t.energy_rtol,
            residual_rtol=t.residual_rtol,
            residual_atol=t.residual_atol,
            roundoff_energy=t.roundoff_energy,
            stagnation_it=t.stagnation_it,
            corrector=True,
            stall_rtol=t.stall_rtol,
        )

    def _converged(self, test, it, x, R, energy):
        """R at x and the test's verdict there: True if converged; raises _Failed where the
        state cannot be evaluated, on a NaN residual or on stagnation."""
        error = self.problem.residual(x, R)
        if error:
            raise _Failed(error)
        verdict = test.check(it, R.norm(), R, energy)
        if verdict == NAN:
            raise _Failed("NaN residual")
        if verdict == STAGNATION:
            raise _Failed(f"stagnation: {test.error}")
        return verdict == CONVERGED

    def _correction(self, x, R, a, b, du, dlam):
        """The correction of the bordered system at x into a (``a + r b`` with ``K a = -R``,
        ``K b = f``; R is negated) and its dlam correction r; raises _Failed without a root."""
        self._factorise(x)
        R.scale(-1.0)
        self._solve(R, a)
        self._solve(self.f, b)
        r = self._constraint_root(du, dlam, a, b)
        if r is None:
            raise _Failed(
                "the arc does not meet the linearised equilibrium path (no "
                "real root of the constraint)"
            )
        a.axpy(r, b)  # the correction du = a + r b
        return r

    def advance(self) -> Increment | None:
        """One converged increment (cut back and retried as needed); the :class:`Increment`, or
        None once the path cannot go on (:attr:`failed` says why)."""
        x0 = self.problem.u_vec.copy()  # the converged state a failed attempt returns to
        try:
            cuts = 0
            while True:
                try:
                    x, du, dlam, test, sign = self._attempt(x0)
                except (_Failed, RuntimeError) as err:
                    with self.clock("after"):
                        self._restore(x0)
                    cuts += 1
                    if cuts > self.max_cutbacks or self.ds / 2.0 < self.ds_min:
                        reason = (
                            f"increment {len(self.path) + 1} failed at ds = {self.ds:.3g} "
                            f"after {cuts - 1} cut-backs: {err}"
                        )
                        self._give_up(reason)
                        return None
                    self.log(
                        f"path: increment {len(self.path) + 1} failed ({err}); ds "
                        f"{self.ds:.3g} -> {self.ds / 2:.3g}"
                    )
                    self.ds /= 2.0
                    continue
                with self.clock("after"):  # (as NewtonSolver's commit)
                    return self._accept(x, du, dlam, test, sign)
        finally:
            x0.destroy()

    def _give_up(self, reason):
        """Record that the path ended early, and warn once (a failed attempt it cuts back does
        not)."""
        self.failed = failure("path", len(self.path) + 1, self.lam, reason)
        self.log(f"path: {reason}; stopping")
        if not self.warn:
            return
        remedy = (
            "a shorter smallest arc (ds_min, now "
            f"{self.ds_min:.3g}), more cut-backs in a row (max_cutbacks, now {self.max_cutbacks}) "
            f"or more corrector iterations (max_it, now {self.max_it})"
        )
        if unconfined_relaxed(self.problem.materials):
            remedy = UNCONFINED_RELAXED
        warn_failure(
            f"path following stopped: {reason.rstrip('.')}; u and the materials are at the last "
            f"converged state, lam = {self.lam:.6g}",
            LoadPathWarning,
            remedy,
        )

    def _attempt(self, x0):
        """Predictor and corrector from the converged state x0 (timed as a SNES solve): the state
        x, the increment (du, dlam), the convergence test's record and the sign of det K at x0.
        Raises as :meth:`_corrector` does, with the attempt's vectors freed."""
        with self.clock("snes"):
            du, dlam, sign = self._predictor(x0)
            try:
                x, du, dlam, test = self._corrector(x0, du, dlam)
            except BaseException:
                du.destroy()
                raise
        return x, du, dlam, test, sign

    def _restore(self, x0):
        self.load.value = self.lam
        self.problem.restore(x0)

    def _accept(self, x, du, dlam, test, sign):
        """Commit a converged increment: history, path record, critical points, next ds."""
        self.problem.commit()
        self.lam += dlam
        self.load.value = self.lam
        if self._det_sign and sign and sign != self._det_sign and self.path:
            self._critical_point(dlam)
        elif self.path and np.sign(dlam) != np.sign(self.path[-1].dlam):
            cp = CriticalPoint("limit", len(self.path) + 1, self.path[-1].lam, self.lam, False)
            self.critical.append(cp)
            self.log(
                f"path: the load turned back in increment {cp.step} (from lam = "
                f"{cp.lam_before:.6g}) with det K keeping its sign: a non-smooth limit point"
            )
        self._det_sign = sign or self._det_sign
        if self._du_prev is not None:
            self._du_prev.destroy()
        self._du_prev, self._dlam_prev = du, dlam
        its = len(test.history)
        inc = Increment(
            len(self.path) + 1,
            self.lam,
            dlam,
            self.ds,
            its,
            sign,
            du.norm(),
            self._control_value(x) if self.control is not None else None,
            test.rnorm,
            test.history,
            test.stopped_by,
        )
        self.path.append(inc)
        x.destroy()
        self.ds = self._next_ds(its)
        return inc

    def _next_ds(self, iterations):
        """The next arc: grown or shrunk by sqrt(target / iterations) (within a factor 2), and
        on the way to the first limit point, where the load levels off, at most ds_max times the
        load's rate |dlam / ds| relative to the first increment's (down to ds_max /
        peak_refinement): finer increments sample the peak."""
        grow = np.sqrt(self.target_iterations / max(iterations, 1))
        ds = self.ds * float(np.clip(grow, 0.5, 2.0))
        rates = [abs(inc.dlam) / inc.ds for inc in self.path]
        cap = self.ds_max
        before_peak = not any(c.kind == "limit" for c in self.critical)
        if self.peak_refinement > 1 and before_peak and len(rates) > 1 and rates[0] > 0:
            cap *= float(np.clip(rates[-1] / rates[0], 1.0 / self.peak_refinement, 1.0))
        return min(ds, cap)

    def _critical_point(self, dlam):
        """det K changed sign between the last two converged states: a critical point inside
        the last increment; a limit point if the load turned back there (the increments before
        and after it, or the last one itself, go opposite ways), else a bifurcation point."""
        last = self.path[-1]
        before = self.path[-2].dlam if len(self.path) > 1 else last.dlam
        turned = np.sign(before) != np.sign(last.dlam) or np.sign(last.dlam) != np.sign(dlam)
        lam_before = self.path[-2].lam if len(self.path) > 1 else last.lam - last.dlam
        cp = CriticalPoint("limit" if turned else "bifurcation", last.step, lam_before, last.lam)
        if self.critical and self.critical[-1].step == cp.step and not self.critical[-1].det_change:
            self.critical.pop()  # the turn of the load reported there is this one
        self.critical.append(cp)
        self.log(
            f"path: det K changed sign in increment {cp.step}: a {cp.kind} point between "
            f"lam = {cp.lam_before:.6g} and {cp.lam_after:.6g}"
        )

    # -- the path ------------------------------------------------------------------------------

    def run(
        self,
        max_steps: int | None = None,
        stop: Callable[[ArcLength], str | None] | None = None,
        on_converged: Callable[[Increment], bool | None] | None = None,
    ) -> bool:
        """Follow the path for at most ``max_steps`` increments (default ``max_increments``);
        True unless it failed (the :class:`~dolfinx_granular.drivers.protocol.Driver` protocol).

        Args:
            stop: ``stop(self) -> str | None``: a reason to stop after a converged increment
                (see :func:`load_reaches`, :func:`unloaded_to`, :func:`control_reaches`);
                default: the ``stop`` given at construction.
            on_converged: ``on_converged(increment)`` after each converged increment, with u
                and the materials at the converged state; returning False stops the run
                (:attr:`stopped` is then :data:`~dolfinx_granular.drivers.protocol.ASKED_TO_STOP`).
        """
        max_steps = self.max_increments if max_steps is None else max_steps
        stop = self.stop if stop is None else stop
        self.stopped = None
        for _ in range(int(max_steps)):
            inc = self.advance()
            if inc is None:
                return False
            self.stopped = stop(self) if stop is not None else None  # (known to on_converged)
            if on_converged is not None and on_converged(inc) is False:
                self.stopped = self.stopped or ASKED_TO_STOP
                return True
            if self.stopped:
                self.log(f"path: {self.stopped}")
                return True
        self.stopped = f"{max_steps} increments"
        return True

    @property
    def peak(self) -> Increment | None:
        """The converged increment with the largest |lam| so far (None before the first)."""
        return max(self.path, key=lambda inc: abs(inc.lam), default=None)

    def peak_estimate(self) -> float | None:
        """The largest |lam| of the parabola through the sampled maximum and its neighbours
        (lam against the cumulative arc length): where the true peak lies between samples.
        None unless the maximum has a converged increment on each side."""
        k = max(range(len(self.path)), key=lambda i: abs(self.path[i].lam), default=None)
        if k is None or not 0 < k < len(self.path) - 1:
            return None
        s = np.cumsum([inc.ds for inc in self.path])[k - 1 : k + 2]
        lam = np.array([inc.lam for inc in self.path[k - 1 : k + 2]])
        a, b, _ = np.polyfit(s, lam, 2)
        if a * np.sign(lam[1]) >= 0:  # not a maximum of |lam|
            return None
        s_top = float(np.clip(-b / (2 * a), s[0], s[2]))
        return float(np.polyval([a, b, _], s_top))

    def destroy(self) -> None:
        for v in (self.f, self._du_prev):
            if v is not None:
                v.destroy()
        if not hasattr(self.solver, "snes"):  # (the LU solver of its own)
            self.ksp.destroy()


def _lu(comm):
    """A KSP of its own: LU (MUMPS where PETSc has it), as a NewtonSolver's default."""
    ksp = PETSc.KSP().create(comm)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    if PETSc.Sys.hasExternalPackage("mumps"):
        ksp.getPC().setFactorSolverType("mumps")
    return ksp


class _Failed(Exception):
    """An increment that did not converge (the reason in words)."""
