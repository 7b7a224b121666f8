"""Newton solver for quadrature-point materials: petsc4py SNES (newtonls + LU).

The materials are evaluated at exactly the state SNES hands to the residual callback (line
searches write trial points there); the Jacobian callback reuses that tangent only if SNES asks
for the Jacobian at the same x and re-evaluates otherwise, so the tangent is always consistent.

Convergence follows table 2 of the paper: after Newton step k the relative energy norm
``|R_k . du_k| / |R_0 . du_0|`` is logged (R_k residual at iterate k, du_k the increment actually
applied, 0-based), and the solve stops when it is <= ``energy_rtol``. It also stops, at any
iterate including the first, when the residual is at round-off: ``|R| <= residual_rtol * scale``
with scale the larger of the internal and the external force norms (the materials' ``∫ P : grad v``
and ``f_int - R``, Dirichlet rows left out), or ``|R| <= residual_atol``, or the energy norm is
below ``roundoff_energy`` while the residual no longer halves. A solve that starts converged (the
same load twice) returns at once with 0 iterations. So does one under no load on stress-free
materials ("no load": the residual and the external forces are both within twice the forces of
the materials' reference stress, e.g. a generated packing's P(I) ~ 1e-11 of its modulus from
contacts overlapping by 1e-11, which Newton could remove only by opening those contacts).

Wiring mistakes are refused when the solver is built, and a failed factorisation says what made the
Jacobian singular (:mod:`dolfinx_granular.fem.diagnose`).

A solve is a transaction. Converged: the materials commit their history (laws with history).
Failed: u and the material data return to the state the solve started from, and the result says
why (an RVE outside its range, a singular Jacobian where every contact has opened, a PETSc error,
the iteration limit, or stagnation: the residual has not gone below its best value for
``stagnation_it`` Newton steps, typically Newton cycling between contact sets); nothing raises, so
that a load stepper (:mod:`dolfinx_granular.drivers.loading`) can cut the step back. A failed
solve called by the user warns once (:class:`~dolfinx_granular.SolveFailedWarning`: the reason and
a remedy); the stepper's solves do not, the stepper warns if it gives up.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from dolfinx.fem.petsc import set_bc
from mpi4py import MPI
from petsc4py import PETSc

from ..fem.compat import SNES_NAN_REASON
from ..fem.diagnose import singular_jacobian
from . import linear_solver as linear
from .convergence import CONVERGED, MAX_IT, NAN, ROUNDOFF, ConvergenceTest
from .convergence import STAGNATION as STAGNATION_VERDICT
from .problem import GranularProblem, collect_garbage
from .protocol import UNCONFINED_RELAXED, SolveFailedWarning, unconfined_relaxed, warn_failure

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence

    import ufl
    from dolfinx import fem

    from ..fem.quadrature import QuadratureMaterial

_CR = PETSc.SNES.ConvergedReason
STAGNATION = "DIVERGED_STAGNATION"  # reason_name of a solve stopped by the stagnation test
_FAILURE_WORDS = {
    STAGNATION: "stagnation",
    "DIVERGED_LINEAR_SOLVE": "linear solve failed (singular Jacobian or zero pivot)",
    "DIVERGED_FNORM_NAN": "NaN residual",
    "DIVERGED_FUNCTION_NANORINF": "NaN residual",
    "DIVERGED_MAX_IT": "no convergence within the Newton iteration limit",
    "DIVERGED_LINE_SEARCH": "line search failed",
    "DIVERGED_PETSC_ERROR": "PETSc error",
}
_REASON_NAMES = {v: k for k, v in vars(_CR).items() if isinstance(v, int)}
_KSP_REASONS = {v: k for k, v in vars(PETSc.KSP.ConvergedReason).items() if isinstance(v, int)}


@dataclass
class SolveResult:
    """Outcome of one :meth:`NewtonSolver.solve`.

    Attributes:
        converged: the solve converged (the materials have committed their history).
        reason: SNES converged reason (> 0 converged, < 0 diverged) and its name.
        iterations: Newton steps taken (0: the start state was converged already).
        history: one ``(iteration, residual_norm, energy_norm_rel)`` per Newton step, iteration
            1-based; residual_norm is ||R|| (N) at the iterate the step started from.
        residual_norm: ||R|| at the final iterate (N) (of a failed solve: where it stopped).
        force_scale: the force norm (N) the round-off test compared it with.
        error: message of an exception raised while evaluating a material (e.g. F outside the
            RVE's range), or what the stagnation test measured; else None.
        stopped_by: the test that ended a converged solve: ``energy norm``, ``round-off``,
            ``residual_atol`` or ``no load`` ('' for a failed one).
    """

    converged: bool
    reason: int
    reason_name: str
    iterations: int
    history: list = field(default_factory=list)
    residual_norm: float = float("nan")
    force_scale: float = float("nan")
    error: str | None = None
    stopped_by: str = ""

    @property
    def converged_by(self) -> str:
        """:attr:`stopped_by`: the name of the :class:`~dolfinx_granular.drivers.protocol.
        IncrementRecord` field."""
        return self.stopped_by

    @property
    def why(self) -> str:
        """One-line reason of a failure ('' if converged)."""
        if self.converged:
            return ""
        words = _FAILURE_WORDS.get(self.reason_name, self.reason_name)
        return f"{words}: {self.error}" if self.error else words


def _threshold(name):
    """A property that reads and writes the convergence test's threshold ``name``."""
    return property(
        lambda self: getattr(self.test, name),
        lambda self, value: setattr(self.test, name, value),
        doc=f"The convergence test's ``{name}``.",
    )


class NewtonSolver:
    """Solve R(u) = 0 with SNES; R and its Jacobian read quadrature data written by materials.

    Args:
        residual: UFL linear form R(u; v) (e.g. ``material.residual_form(v) - f_ext``).
        jacobian: UFL bilinear form dR/du, or None: the consistent Jacobian
            :func:`~dolfinx_granular.derivative` of ``residual`` and the materials.
        u: the displacement Function; holds the initial guess and receives the solution.
        bcs: Dirichlet conditions (values are imposed on the first iterate).
        materials: one material or a sequence of them (objects with ``update(tangent)`` that
            refresh their data from ``u``, ``commit()`` and ``residual_form(v)``: a
            :class:`~dolfinx_granular.GranularMaterial`, a
            :class:`~dolfinx_granular.LinearElasticMaterial`, ...).
        energy_rtol: relative energy norm that counts as converged.
        residual_rtol: residual norm relative to the force scale that counts as converged
            (default: round-off; a larger one is an out-of-balance force tolerated, and the
            solve's ``converged_by`` says ``tolerance``); 0 disables.
        residual_atol: residual norm (N) that counts as converged; 0 disables.
        roundoff_energy: below this relative energy norm a residual that fails to halve in one
            Newton step is taken as round-off (converged).
        max_it: most Newton steps per solve.
        prefix: PETSc options prefix of this solver.
        linear_solver: ``"direct"`` (LU with MUMPS) or ``"iterative"`` (GMRES + GAMG with the
            rigid-body modes, the Krylov tolerance tied to the Newton residual;
            :mod:`~dolfinx_granular.drivers.linear_solver`).
        petsc_options: options set under ``prefix`` (defaults: newtonls, ``basic`` line search,
            and those of ``linear_solver``); they override the defaults.
        verbose: print one line per Newton step on rank 0.
        stagnation_it: fail the solve (reason ``DIVERGED_STAGNATION``) when the residual norm has
            not gone below its smallest value since the first Newton step for this many
            consecutive Newton steps (Newton cycling between contact sets); 0 disables the test.
        stall_rtol: where Newton no longer halves the residual (it cycles as RVEs rearrange
            within an iterate), accept an iterate whose residual is at most this times the
            force scale: an out-of-balance force tolerated (``converged_by`` ``tolerance``);
            0 (default) never.
        skip_final_tangent: evaluate only the stress (no tangent) for a residual that ends the
            solve whatever its value: the energy norm of the step that led to it is already
            converged, so SNES asks for no Jacobian there.

    Attributes:
        problem: the :class:`~dolfinx_granular.GranularProblem` this solver drives.
        test: its :class:`~dolfinx_granular.ConvergenceTest` (the thresholds above).
        materials: the materials, a tuple.
        clock: :class:`~dolfinx_granular.timing.Stopwatch` of ``"snes"`` (whole SNES solves,
            and the increments of an :class:`~dolfinx_granular.ArcLength` on this
            solver, which factorises and solves by itself), ``"callbacks"`` (this solver's
            callbacks inside them: residuals, Jacobians, convergence tests), ``"after"`` (its
            work after them: the final evaluation, a commit or restore), ``"rve"`` (material
            updates),
            ``"residual"``, ``"jacobian"`` and ``"scale"`` (assembly: residuals, Jacobians, the
            internal forces of the round-off test); ``clock.calls`` counts them.

    Raises:
        ValueError: a wiring mistake (:func:`~dolfinx_granular.fem.diagnose.check_wiring`): the
            residual reads the P of a material not in ``materials``; ``jacobian`` lacks the
            tangent A of one that is (``ufl.derivative(residual, u)``); two materials share
            cells; cells with no material and no other u-dependent term.
    """

    def __init__(
        self,
        residual: ufl.Form,
        jacobian: ufl.Form | None,
        u: fem.Function,
        bcs: Iterable[Any] = (),  # dolfinx.fem.DirichletBC (0.9+), DirichletBCMetaClass (0.5)
        materials: QuadratureMaterial | Sequence[QuadratureMaterial] | None = (),
        *,
        energy_rtol: float = 1e-20,
        residual_rtol: float = ROUNDOFF,
        residual_atol: float = 0.0,
        roundoff_energy: float = 1e-14,
        max_it: int = 20,
        prefix: str = "granular_",
        petsc_options: Mapping[str, Any] | None = None,
        verbose: bool = False,
        skip_final_tangent: bool = False,
        stagnation_it: int = 4,
        linear_solver: str = "direct",
        stall_rtol: float = 0.0,
    ) -> None:
        self.linear_solver = linear.check(linear_solver)
        self._fnorm0 = 0.0  # |R| at the start of the solve (the iterative solver's forcing)
        self.problem = GranularProblem(
            residual, jacobian, u, bcs, materials, roundoff_scale=residual_rtol > 0.0
        )
        self.test = ConvergenceTest(
            self.problem,
            energy_rtol=energy_rtol,
            residual_rtol=residual_rtol,
            residual_atol=residual_atol,
            roundoff_energy=roundoff_energy,
            stagnation_it=stagnation_it,
            max_it=max_it,
            stall_rtol=stall_rtol,
        )
        p = self.problem
        self.u, self.bcs, self.materials, self.comm = u, p.bcs, p.materials, p.comm
        self.L, self.a, self.A, self.clock = p.L, p.a, p.A, p.clock
        self.skip_final_tangent = bool(skip_final_tangent)
        self.verbose = verbose
        # SNES's own vector x (line searches write trial points there) and work vectors
        self.b, self.x, self._x_prev, self._R_prev, self._x_best = (
            p.u_vec.duplicate() for _ in range(5)
        )
        linear.prepare(self.linear_solver, self.A, u.function_space)
        self.snes = self._create_snes(prefix, petsc_options)

    # the thresholds are the convergence test's (one copy)
    energy_rtol = _threshold("energy_rtol")
    residual_rtol = _threshold("residual_rtol")
    residual_atol = _threshold("residual_atol")
    roundoff_energy = _threshold("roundoff_energy")
    stagnation_it = _threshold("stagnation_it")
    stall_rtol = _threshold("stall_rtol")
    max_it = _threshold("max_it")

    @property
    def history(self) -> list:
        """``(iteration, |R| at its start, relative energy norm)`` per step of the last solve."""
        return self.test.history

    @property
    def timings(self) -> dict:
        """Wall seconds in ``"rve"`` (material updates), ``"assembly"`` (residuals, Jacobians and
        the round-off test's internal forces), ``"solve"`` (SNES outside the callbacks: the LU
        factorisation and solve, SNES's vector work) and ``"rest"`` (the callbacks' own work and
        the work after the solves: vector copies, ghost updates, the convergence test)."""
        return self.time_split(self.clock.wall)

    @staticmethod
    def time_split(t: Mapping[str, float]) -> dict:
        """``rve``, ``assembly``, ``solve`` and ``rest`` seconds of a Stopwatch table ``t`` (wall
        or CPU; the categories of :attr:`clock`)."""
        assembly = t["residual"] + t["jacobian"] + t["scale"]
        return {
            "rve": t["rve"],
            "assembly": assembly,
            "solve": t["snes"] - t["callbacks"],
            "rest": t["callbacks"] + t["after"] - t["rve"] - assembly,
        }

    def _create_snes(self, prefix, petsc_options):
        opts = {"snes_type": "newtonls", "snes_linesearch_type": "basic"}
        opts.update(linear.options(self.linear_solver))
        opts.update(petsc_options or {})
        snes = PETSc.SNES().create(self.comm)
        snes.setOptionsPrefix(prefix)
        db = PETSc.Options()
        for key, val in opts.items():
            db[prefix + key] = val
        snes.setFunction(self._residual, self.b)
        snes.setJacobian(self._jacobian, self.A)
        snes.setConvergenceTest(self._converged)
        # Only this solver's test decides convergence: no step-length test of PETSc's, and a failed
        # line search is judged by that test too (PETSc >= 3.20 would otherwise stop there).
        snes.setTolerances(max_it=self.max_it, stol=0.0)
        snes.setMaxStepFailures(self.max_it)
        snes.setFromOptions()
        snes.getKSP().setFromOptions()
        # a multigrid preconditioner reads its options at its first set-up: keep them till then
        self._held_options = (prefix, opts) if self.linear_solver == "iterative" else None
        if self._held_options is None:
            linear.release(prefix, opts)
        return snes

    # -- the problem's methods, as before (ArcLength and users call them on the solver) --------

    def residual(self, x: PETSc.Vec, b: PETSc.Vec, tangent: bool = True) -> str | None:
        """:meth:`GranularProblem.residual <dolfinx_granular.GranularProblem.residual>`."""
        return self.problem.residual(x, b, tangent)

    def assemble_residual(self, x: PETSc.Vec, b: PETSc.Vec) -> None:
        """:meth:`~dolfinx_granular.GranularProblem.assemble_residual`."""
        self.problem.assemble_residual(x, b)

    assemble_forces = staticmethod(GranularProblem.assemble_forces)

    def jacobian(self, x: PETSc.Vec, A: PETSc.Mat | None = None) -> PETSc.Mat:
        """:meth:`~dolfinx_granular.GranularProblem.assemble_jacobian`."""
        return self.problem.assemble_jacobian(x, A)

    def force_scale(self, R: PETSc.Vec) -> float:
        """:meth:`~dolfinx_granular.GranularProblem.force_scale`."""
        return self.problem.force_scale(R)

    def refresh_materials(self) -> None:
        """:meth:`~dolfinx_granular.GranularProblem.refresh_materials`."""
        self.problem.refresh_materials()

    # -- SNES callbacks ----------------------------------------------------------------------------

    def _step_energy(self, x):
        """|R_prev . (x - x_prev)|: the energy of the Newton step to x."""
        du = x.copy()
        du.axpy(-1.0, self._x_prev)
        energy = abs(self._R_prev.dot(du))
        du.destroy()
        return energy

    def _tangent_needed(self, x):
        """False if the energy norm of the step to x (what ``_converged`` will compute) already
        meets ``energy_rtol``: the solve ends at x and no Jacobian is assembled there."""
        if not (self.skip_final_tangent and self.history):
            return True
        return not self.test.relative(self._step_energy(x)) <= self.energy_rtol

    @contextmanager
    def _callback(self):
        """Time a SNES callback and keep any exception it raises (a bug: not a
        LawEvaluationError), which petsc4py >= 3.20 would turn into a PETSc error."""
        try:
            with self.clock("callbacks"):
                yield
        except BaseException as err:
            self._raised = self._raised or err
            raise

    def _residual(self, snes, x, b):
        with self._callback():
            error = self.problem.residual(x, b, self._tangent_needed(x))
            if error:
                self._error = error

    def _jacobian(self, snes, x, A, P):
        with self._callback():
            self.problem.assemble_jacobian(x, A)
            if self.linear_solver == "iterative":
                rtol = linear.forcing(snes.getFunctionNorm(), self._fnorm0)
                snes.getKSP().setTolerances(rtol=rtol)

    def _converged(self, snes, it, norms):
        with self._callback():
            self._verdict = int(self._test(snes, it, norms[2]))
        return self._verdict

    def _test(self, snes, it, fnorm):
        x, R = snes.getSolution(), snes.getFunction()[0]
        if it == 0:
            self._fnorm0 = fnorm  # the Krylov tolerance of an iterative solver follows |R|
        verdict = self.test.check(it, fnorm, R, self._step_energy(x) if it > 0 else None)
        if self.verbose and self.comm.rank == 0:
            # iterate k: the residual after Newton step k (that of the start for k = 0) and the
            # energy norm of step k, as the rows of the slope's convergence.csv
            energy = f", energy norm (rel) = {self.history[-1][2]:.3e}" if it > 0 else ""
            print(f"    Newton {it:2d}: |R| = {fnorm:.3e} N{energy}", flush=True)
        x.copy(self._x_prev)
        R.copy(self._R_prev)
        if self.test.best_within:
            x.copy(self._x_best)
            self._have_best = True
        if verdict == CONVERGED:
            if self.test.stopped_by == "energy norm":
                return _CR.CONVERGED_SNORM_RELATIVE
            return _CR.CONVERGED_FNORM_ABS
        if verdict == STAGNATION_VERDICT:
            self._error, self._stagnated = self.test.error, True
            return _CR.DIVERGED_DTOL
        return {NAN: SNES_NAN_REASON, MAX_IT: _CR.DIVERGED_MAX_IT}.get(verdict, _CR.ITERATING)

    # -- driver ------------------------------------------------------------------------------------

    def solve(self, *, warn: bool = True) -> SolveResult:
        """Newton solve from the current u (Dirichlet values imposed first).

        Converged: u holds the solution, the material data belong to it and the materials'
        history is committed. Failed: u and the material data are those the solve started from;
        the result says why, and with ``warn`` one :class:`~dolfinx_granular.SolveFailedWarning`
        names the reason and a remedy (drivers that cut a failed solve back pass False: they
        warn once if the whole load path fails).
        """
        self.test.reset()
        self._error, self._stagnated, self._verdict, self._raised = None, False, 0, None
        self._have_best = False
        self.problem.external = float("nan")
        self.problem.invalidate()
        start = self.u.x.array.copy()
        u_vec = self.problem.u_vec
        set_bc(u_vec, self.bcs)
        u_vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        u_vec.copy(self.x)
        petsc_error = self._run_snes()
        if self._raised is not None:  # a bug in a callback reaches the user with its traceback
            raise self._raised
        with self.clock("after"):
            back = petsc_error is None and self._back_to_best()
            self._error = self._error or self._final_evaluation()
        reason, name = self._outcome(petsc_error)
        if back and not self._error:
            reason, name = int(_CR.CONVERGED_FNORM_ABS), _REASON_NAMES[_CR.CONVERGED_FNORM_ABS]
        result = SolveResult(
            converged=reason > 0,
            reason=reason,
            reason_name=name,
            iterations=len(self.history),
            history=list(self.history),
            residual_norm=float(self.test.rnorm),
            force_scale=float(self.test.scale),
            error=self._error,
            stopped_by=self.test.stopped_by if reason > 0 else "",
        )
        with self.clock("after"):
            if result.converged:
                self.problem.commit()
            else:
                self.problem.restore(start)
        if warn and not result.converged:
            self._warn_failed(result)
        return result

    def _warn_failed(self, result):
        """The one :class:`SolveFailedWarning` of a failed solve: its reason and a remedy."""
        if unconfined_relaxed(self.materials):
            remedy = UNCONFINED_RELAXED
        else:
            remedy = (
                "take the load in smaller steps: LoadStepper(solver).run(name, set_load, "
                "increment) cuts a failed step back by itself; near the largest load the "
                "structure carries, follow the path past it with ArcLength"
            )
            if result.reason_name == "DIVERGED_MAX_IT":
                remedy = f"allow more Newton steps (max_it, now {self.max_it}), or {remedy}"
        warn_failure(
            f"Newton solve failed after {result.iterations} Newton steps ({result.reason_name}): "
            f"{result.why.rstrip('.')}; u and the materials are back at the state it started from",
            SolveFailedWarning,
            remedy,
        )

    def _run_snes(self):
        """``snes.solve``; a PETSc error message or None."""
        try:
            with self.clock("snes"):
                self.snes.solve(None, self.x)
        except PETSc.Error as err:  # e.g. a factorisation error PETSc raises instead of reporting
            return f"PETSc error {err.ierr} in SNES solve"
        return None

    def _back_to_best(self) -> bool:
        """After a stagnation or the iteration limit: x = the best iterate where its |R| was
        within ``stall_rtol`` (the out-of-balance force tolerated where Newton stalls), if its
        residual, evaluated again, still is; True then (the solve converged by ``tolerance``)."""
        verdict = self.snes.getConvergedReason()
        if not (self._have_best and (self._stagnated or verdict == _CR.DIVERGED_MAX_IT)):
            return False
        self._x_best.copy(self.x)
        error = self.problem.residual(self.x, self.b, True)
        fnorm = self.b.norm()
        if error or not fnorm <= self.test.stall_rtol * self.test.scale:
            return False
        self._stagnated, self._error = False, None
        self.test.rnorm, self.test.stopped_by = fnorm, "tolerance"
        return True

    def _final_evaluation(self):
        """Make u and the material data those of SNES's x (the last residual was at x with
        full Newton steps); an evaluation error message or None."""
        if self.problem.evaluated_at(self.x):
            self.problem.set_state(self.x)
            return None
        return self.problem.try_evaluate(self.x)

    def _outcome(self, petsc_error):
        """The SNES reason and its name, corrected for what SNES does not see."""
        reason = int(self.snes.getConvergedReason())
        if reason > 0 and self._verdict <= 0 and self._error:
            # PETSc >= 3.20 ends a Newton step whose line search met a NaN residual (an RVE
            # outside its range) without asking the convergence test, and may call it
            # CONVERGED_SNORM_RELATIVE at the unchanged iterate: that is a failure.
            reason = SNES_NAN_REASON
        any_petsc_error = self.comm.allreduce(petsc_error is not None, op=MPI.LOR)
        if reason <= 0 or any_petsc_error:
            # A failed factorisation is sticky in PETSc: every later solve would stop at once
            # with the same error. Drop the factor so that a cut-back starts afresh.
            self.snes.getKSP().getPC().reset()
        name = _REASON_NAMES.get(reason, str(reason))
        if self._stagnated:
            name = STAGNATION
        elif any_petsc_error:
            reason, name = min(reason, -1), "DIVERGED_PETSC_ERROR"
            self._error = self._error or petsc_error or "PETSc error on another rank"
        elif reason == _CR.DIVERGED_LINEAR_SOLVE:
            ksp = self.snes.getKSP()
            self._error = self._error or f"KSP reason {_KSP_REASONS.get(ksp.getConvergedReason())}"
        if reason == _CR.DIVERGED_LINEAR_SOLVE or any_petsc_error:
            # (the material data are still those of the failed iterate: before the restore)
            cause = singular_jacobian(self.materials)
            self._error = f"{self._error}; {cause}" if cause else self._error
        return reason, name

    def destroy(self) -> None:
        """Free the PETSc objects (collective: call it on every rank at the same point)."""
        # (flush petsc4py's deferred destruction first on every rank: see collect_garbage)
        collect_garbage(self.comm)
        for obj in (self.snes, self.b, self.x, self._x_prev, self._R_prev, self._x_best):
            obj.destroy()
        if self._held_options is not None:
            linear.release(*self._held_options)
        self.problem.destroy()
        if hasattr(PETSc, "garbage_cleanup"):
            PETSc.garbage_cleanup(self.comm)
