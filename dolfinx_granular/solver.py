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
Jacobian singular (:mod:`dolfinx_granular.diagnose`).

A solve is a transaction. Converged: the materials commit their history (laws with history).
Failed: u and the material data return to the state the solve started from, and the result says
why (an RVE outside its range, a singular Jacobian where every contact has opened, a PETSc error,
the iteration limit, or stagnation: the residual has not gone below its best value for
``stagnation_it`` Newton steps, typically Newton cycling between contact sets); nothing raises, so
that a load stepper (:mod:`dolfinx_granular.loading`) can cut the step back.
"""

from __future__ import annotations

import gc
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import apply_lifting, assemble_matrix, assemble_vector, create_matrix, set_bc
from mpi4py import MPI
from petsc4py import PETSc

from ._dolfinx import SNES_NAN_REASON, petsc_vec
from .diagnose import check_wiring, singular_jacobian
from .law import LawEvaluationError
from .quadrature import derivative
from .timing import Stopwatch

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence

    from .quadrature import QuadratureMaterial

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
    def why(self) -> str:
        """One-line reason of a failure ('' if converged)."""
        if self.converged:
            return ""
        words = _FAILURE_WORDS.get(self.reason_name, self.reason_name)
        return f"{words}: {self.error}" if self.error else words


class NewtonSolver:
    """Solve R(u) = 0 with SNES; R and its Jacobian read quadrature data written by materials.

    Args:
        residual: UFL linear form R(u; v) (e.g. ``material.residual_form(v) - f_ext``).
        jacobian: UFL bilinear form dR/du, or None: the consistent Jacobian
            :func:`~dolfinx_granular.quadrature.derivative` of ``residual`` and the materials.
        u: the displacement Function; holds the initial guess and receives the solution.
        bcs: Dirichlet conditions (values are imposed on the first iterate).
        materials: one material or a sequence of them (objects with ``update(tangent)`` that
            refresh their data from ``u``, ``commit()`` and ``residual_form(v)``: a
            :class:`~dolfinx_granular.material.GranularMaterial`, a
            :class:`~dolfinx_granular.linear.LinearElasticMaterial`, ...).
        energy_rtol: relative energy norm that counts as converged.
        residual_rtol: residual norm relative to the force scale that counts as converged
            (round-off); 0 disables.
        residual_atol: residual norm (N) that counts as converged; 0 disables.
        roundoff_energy: below this relative energy norm a residual that fails to halve in one
            Newton step is taken as round-off (converged).
        max_it: most Newton steps per solve.
        prefix: PETSc options prefix of this solver.
        petsc_options: options set under ``prefix`` (defaults: newtonls, ``basic`` line search,
            preonly + LU with MUMPS).
        verbose: print one line per Newton step on rank 0.
        stagnation_it: fail the solve (reason ``DIVERGED_STAGNATION``) when the residual norm has
            not gone below its smallest value since the first Newton step for this many
            consecutive Newton steps (Newton cycling between contact sets); 0 disables the test.
        skip_final_tangent: evaluate only the stress (no tangent) for a residual that ends the
            solve whatever its value: the energy norm of the step that led to it is already
            converged, so SNES asks for no Jacobian there.

    Attributes:
        materials: the materials, a tuple.
        clock: :class:`~dolfinx_granular.timing.Stopwatch` of ``"snes"`` (whole SNES solves,
            and the increments of an :class:`~dolfinx_granular.arclength.ArcLength` on this
            solver, which factorises and solves by itself), ``"callbacks"`` (this solver's
            callbacks inside them: residuals, Jacobians, convergence tests), ``"after"`` (its
            work after them: the final evaluation, a commit or restore), ``"rve"`` (material
            updates),
            ``"residual"``, ``"jacobian"`` and ``"scale"`` (assembly: residuals, Jacobians, the
            internal forces of the round-off test); ``clock.calls`` counts them.

    Raises:
        ValueError: a wiring mistake (:func:`~dolfinx_granular.diagnose.check_wiring`): the
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
        residual_rtol: float = 1e-12,
        residual_atol: float = 0.0,
        roundoff_energy: float = 1e-14,
        max_it: int = 20,
        prefix: str = "granular_",
        petsc_options: Mapping[str, Any] | None = None,
        verbose: bool = False,
        skip_final_tangent: bool = False,
        stagnation_it: int = 4,
    ) -> None:
        self.u = u
        self.bcs = list(bcs)
        self.materials = _as_tuple(materials)
        self.energy_rtol = float(energy_rtol)
        self.residual_rtol = float(residual_rtol)
        self.residual_atol = float(residual_atol)
        self.roundoff_energy = float(roundoff_energy)
        self.max_it = int(max_it)
        self.stagnation_it = int(stagnation_it)
        self.skip_final_tangent = bool(skip_final_tangent)
        self.verbose = verbose
        check_wiring(residual, jacobian, u, self.materials)
        if jacobian is None:
            jacobian = derivative(residual, u, ufl.TrialFunction(u.function_space), self.materials)
        self.L = fem.form(residual)
        self.a = fem.form(jacobian)
        self._f_int = None  # the materials' internal forces, for the round-off scale
        if self.materials and self.residual_rtol > 0.0:
            v = residual.arguments()[0]
            self._f_int = fem.form(sum(m.residual_form(v) for m in self.materials))
        self.comm = u.function_space.mesh.comm
        self._u_vec = petsc_vec(u)
        self.A = create_matrix(self.a)
        # SNES's own vector x (line searches write trial points there) and work vectors
        self.b, self.x, self._x_eval, self._x_prev, self._R_prev, self._f = (
            self._u_vec.duplicate() for _ in range(6)
        )
        self._have_eval = self._have_tangent = False
        # forces of the materials' reference stress, for the no-load test (0: no such test)
        self._floor = 0.0 if self._f_int is None else self._stress_floor(residual.arguments()[0])
        self.snes = self._create_snes(prefix, petsc_options)
        self.clock = Stopwatch()

    def _stress_floor(self, v):
        """|f| (N) of the materials' reference stress where they count as stress-free (a
        generated packing's P(I) ~ 1e-11 of its modulus), Dirichlet rows left out; 0 if none."""
        forms = [f for m in self.materials if (f := m.stress_floor_form(v)) is not None]
        if not forms:
            return 0.0
        f = self._f
        self.assemble_forces(f, fem.form(sum(forms[1:], forms[0])))
        set_bc(f, self.bcs, None, 0.0)
        return f.norm()

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
        opts = {
            "snes_type": "newtonls",
            "snes_linesearch_type": "basic",
            "ksp_type": "preonly",
            "pc_type": "lu",
        }
        if PETSc.Sys.hasExternalPackage("mumps"):
            opts["pc_factor_mat_solver_type"] = "mumps"  # PETSc's own LU is serial only
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
        for key in opts:
            db.delValue(prefix + key)
        return snes

    # -- SNES callbacks ----------------------------------------------------------------------------

    def _evaluate(self, x, tangent=True):
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        x.copy(self._u_vec)
        self._u_vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        with self.clock("rve"):
            for m in self.materials:
                m.update(tangent=tangent)
        x.copy(self._x_eval)
        self._have_eval = True
        self._have_tangent = tangent

    def _energy_rel(self, x):
        """|R_prev . (x - x_prev)| relative to the first Newton step's."""
        du = x.copy()
        du.axpy(-1.0, self._x_prev)
        energy = abs(self._R_prev.dot(du))
        du.destroy()
        if not self.history:
            self._energy0 = energy
        return energy / self._energy0 if self._energy0 > 0 else 0.0

    def _tangent_needed(self, x):
        """False if the energy norm of the step to x (what ``_converged`` will compute) already
        meets ``energy_rtol``: the solve ends at x and no Jacobian is assembled there."""
        if not (self.skip_final_tangent and self.history):
            return True
        return not self._energy_rel(x) <= self.energy_rtol

    def _residual(self, snes, x, b):
        with self.clock("callbacks"):
            error = self.residual(x, b, self._tangent_needed(x))
            if error:
                self._error = error

    def residual(self, x: PETSc.Vec, b: PETSc.Vec, tangent: bool = True) -> str | None:
        """Evaluate the materials at the state x (a vector like u's) and assemble R(x) into b,
        Dirichlet rows ``x - g`` (collective). Returns None, or the message of a material that
        could not be evaluated (an RVE outside its range; b is NaN then, on every rank)."""
        error = None
        try:
            self._evaluate(x, tangent)
        except LawEvaluationError as err:  # e.g. UnsupportedDeformationError; bugs propagate
            error = str(err)
        errors = [e for e in self.comm.allgather(error) if e]
        if errors:  # every rank takes this branch: a NaN residual makes SNES stop
            self._have_eval = False
            with b.localForm() as b_local:
                b_local.set(np.nan)
            return errors[0]
        self.assemble_residual(x, b)
        return None

    def assemble_residual(self, x: PETSc.Vec, b: PETSc.Vec) -> None:
        """Assemble R(x) into b with the material data as they are (those of the last
        evaluation, which must have been at x), Dirichlet rows ``x - g`` (collective): R again
        after a change of the loads alone, without evaluating the materials again."""
        with self.clock("residual"):
            self._assemble(b, self.L)
            apply_lifting(b, [self.a], [self.bcs], [x], -1.0)
            b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            set_bc(b, self.bcs, x, -1.0)

    @staticmethod
    def _assemble(b, form):
        with b.localForm() as b_local:
            b_local.set(0.0)
        assemble_vector(b, form)

    @classmethod
    def assemble_forces(cls, b: PETSc.Vec, form: fem.Form) -> None:
        """Assemble the compiled linear form ``form`` (no Dirichlet lifting: internal forces, a
        load pattern) into b, ghost contributions added to their owners; Dirichlet rows as
        assembled."""
        cls._assemble(b, form)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)

    def _same_as_evaluated(self, x):
        same = self._have_eval and np.array_equal(x.array_r, self._x_eval.array_r)
        return self.comm.allreduce(bool(same), op=MPI.LAND)

    def _jacobian(self, snes, x, A, P):
        with self.clock("callbacks"):
            self.jacobian(x, A)

    def jacobian(self, x: PETSc.Vec, A: PETSc.Mat | None = None) -> PETSc.Mat:
        """Assemble dR/du at x into A (default: the solver's matrix), with the materials' tangent
        at x (re-evaluated unless the last evaluation was at x with a tangent); returns A."""
        A = self.A if A is None else A
        if not (self._same_as_evaluated(x) and self._have_tangent):
            self._evaluate(x)
        with self.clock("jacobian"):
            A.zeroEntries()
            assemble_matrix(A, self.a, self.bcs)
            A.assemble()
        return A

    def force_scale(self, R: PETSc.Vec) -> float:
        """The magnitude of the forces in balance (N): max(|f_int|, |f_ext|) at the current
        iterate, f_int the materials' internal forces (reactions included), f_ext = f_int - R on
        the free dofs. Round-off in R is a small multiple of eps times it."""
        if self._f_int is None:
            return 0.0
        f = self._f
        with self.clock("scale"):
            self.assemble_forces(f, self._f_int)
        internal = f.norm()
        f.axpy(-1.0, R)
        set_bc(f, self.bcs, None, 0.0)
        self._external = f.norm()
        return max(internal, self._external)

    def _converged(self, snes, it, norms):
        with self.clock("callbacks"):
            self._verdict = int(self._test(snes, it, norms[2]))
        return self._verdict

    def _test(self, snes, it, fnorm):
        x, R = snes.getSolution(), snes.getFunction()[0]
        rel = None
        if it > 0:
            rel = self._energy_rel(x)
            self.history.append((it, self._rnorm_prev, rel))
        if self.verbose and self.comm.rank == 0:
            # iterate k: the residual after Newton step k (that of the start for k = 0) and the
            # energy norm of step k, as the rows of the slope's convergence.csv
            energy = "" if rel is None else f", energy norm (rel) = {rel:.3e}"
            print(f"    Newton {it:2d}: |R| = {fnorm:.3e} N{energy}", flush=True)
        stalled = it > 0 and fnorm > 0.5 * self._rnorm_prev
        # the first Newton step may well overshoot the starting residual: count from iterate 1
        if it <= 1 or fnorm < self._rnorm_best:
            self._rnorm_best, self._no_progress = fnorm, 0
        else:
            self._no_progress += 1
        x.copy(self._x_prev)
        R.copy(self._R_prev)
        self._rnorm_prev = fnorm
        if not np.isfinite(fnorm):
            return SNES_NAN_REASON
        if it == 0 or stalled:  # (dead loads: |f_ext| is that of the start; once is enough)
            self._scale = self.force_scale(R)
        if fnorm == 0.0 or fnorm <= self.residual_atol:
            return self._stop_as("residual_atol", _CR.CONVERGED_FNORM_ABS)
        if fnorm <= self.residual_rtol * self._scale:
            return self._stop_as("round-off", _CR.CONVERGED_FNORM_ABS)
        if fnorm <= 2.0 * self._floor and self._external <= 2.0 * self._floor:
            # no load and a stress-free material: R is the forces of its reference stress
            # (contacts overlapping by 1e-11), which Newton cannot remove without opening them
            return self._stop_as("no load", _CR.CONVERGED_FNORM_ABS)
        if it > 0 and self.history[-1][2] <= self.energy_rtol:
            return self._stop_as("energy norm", _CR.CONVERGED_SNORM_RELATIVE)
        if stalled and self.history[-1][2] <= self.roundoff_energy:
            return self._stop_as("round-off", _CR.CONVERGED_FNORM_ABS)
        if it >= self.max_it:
            return _CR.DIVERGED_MAX_IT
        if self.stagnation_it > 0 and self._no_progress >= self.stagnation_it:
            self._error = (
                f"|R| = {fnorm:.3e} N has not gone below its best value "
                f"{self._rnorm_best:.3e} N for {self._no_progress} Newton steps"
            )
            self._stagnated = True
            return _CR.DIVERGED_DTOL
        return _CR.ITERATING

    def _stop_as(self, test, reason):
        self._stop = test
        return reason

    # -- driver ------------------------------------------------------------------------------------

    def solve(self) -> SolveResult:
        """Newton solve from the current u (Dirichlet values imposed first).

        Converged: u holds the solution, the material data belong to it and the materials'
        history is committed. Failed: u and the material data are those the solve started from;
        the result says why.
        """
        self.history, self._error, self._stagnated, self._stop = [], None, False, ""
        self._rnorm_prev = self._scale = self._external = float("nan")
        self._have_eval, self._verdict = False, 0
        start = self.u.x.array.copy()
        set_bc(self._u_vec, self.bcs)
        self._u_vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        self._u_vec.copy(self.x)
        petsc_error = self._run_snes()
        with self.clock("after"):
            self._error = self._error or self._final_evaluation()
        reason, name = self._outcome(petsc_error)
        result = SolveResult(
            converged=reason > 0,
            reason=reason,
            reason_name=name,
            iterations=len(self.history),
            history=list(self.history),
            residual_norm=float(self._rnorm_prev),
            force_scale=float(self._scale),
            error=self._error,
            stopped_by=self._stop if reason > 0 else "",
        )
        with self.clock("after"):
            if result.converged:
                for m in self.materials:
                    m.commit()
            else:
                self._restore(start)
        return result

    def _run_snes(self):
        """``snes.solve``; a PETSc error message or None."""
        try:
            with self.clock("snes"):
                self.snes.solve(None, self.x)
        except PETSc.Error as err:  # e.g. a factorisation error PETSc raises instead of reporting
            return f"PETSc error {err.ierr} in SNES solve"
        return None

    def _final_evaluation(self):
        """Make u and the material data those of SNES's x (the last residual was at x with
        full Newton steps); an evaluation error message or None."""
        if self._same_as_evaluated(self.x):
            self.x.copy(self._u_vec)
            self._u_vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
            return None
        error = None
        try:
            self._evaluate(self.x)
        except LawEvaluationError as err:
            error = str(err)
        return next((e for e in self.comm.allgather(error) if e), None)

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

    def _restore(self, start):
        """u and the material data back at the start of a failed solve."""
        self.u.x.array[:] = start
        self.refresh_materials()

    def refresh_materials(self) -> None:
        """Evaluate the materials' stress (no tangent) at the current u, after u was set from
        outside (a restore): their data belong to u again, and the next Jacobian evaluates them
        afresh. A u outside a law's range leaves the data as far as they got."""
        self._have_eval = False
        try:
            for m in self.materials:
                m.update(tangent=False)
        except LawEvaluationError:
            pass  # u itself (the start of a failed solve) is outside a law's range: nothing to do

    def destroy(self) -> None:
        """Free the PETSc objects (collective: call it on every rank at the same point)."""
        # petsc4py >= 3.18 defers the release of garbage-collected wrappers to a collective
        # clean-up. Flush that first on every rank, or a rank whose Python GC ran at another
        # moment destroys the MUMPS factor while the other waits elsewhere: a hang at exit.
        gc.collect()
        if hasattr(PETSc, "garbage_cleanup"):
            PETSc.garbage_cleanup(self.comm)
        for obj in (
            self.snes,
            self.A,
            self.b,
            self.x,
            self._x_eval,
            self._x_prev,
            self._R_prev,
            self._f,
        ):
            obj.destroy()
        if hasattr(PETSc, "garbage_cleanup"):
            PETSc.garbage_cleanup(self.comm)


def _as_tuple(materials):
    if materials is None:
        return ()
    if isinstance(materials, (list, tuple)):
        return tuple(materials)
    return (materials,)
