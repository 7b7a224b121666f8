"""Newton solver for a quadrature-point material: petsc4py SNES (newtonls + LU).

The material is evaluated at exactly the state SNES hands to the residual callback (line searches
write trial points there); the Jacobian callback reuses that tangent only if SNES asks for the
Jacobian at the same x and re-evaluates otherwise, so the tangent is always consistent.

Convergence follows table 2 of the paper: after Newton step k the relative energy norm
``|R_k . du_k| / |R_0 . du_0|`` is logged (R_k residual at iterate k, du_k the increment actually
applied, 0-based), and the solve stops when it is <= ``energy_rtol``, when the residual norm is <=
``residual_atol``, or at round-off: the energy norm is below ``roundoff_energy`` and the residual no
longer halves.

Failures never raise: an RVE outside its range, a singular Jacobian (zero pivot in LU, e.g. where
every contact has opened), a PETSc error, the iteration limit or stagnation (the residual has not
gone below its best value for ``stagnation_it`` Newton steps, typically Newton cycling between
contact sets) all return ``converged=False`` with a readable :attr:`SolveResult.why`, so that a load
stepper (:mod:`dolfinx_granular.loading`) can cut the step back.
"""

from __future__ import annotations

import gc
import time
from dataclasses import dataclass, field

import numpy as np
from dolfinx import fem
from dolfinx.fem.petsc import apply_lifting, assemble_matrix, assemble_vector, create_matrix, set_bc
from petsc4py import PETSc

from ._dolfinx import SNES_NAN_REASON, petsc_vec


@dataclass
class SolveResult:
    """Outcome of one :meth:`NewtonSolver.solve`.

    Attributes:
        converged: SNES converged.
        reason: SNES converged reason (> 0 converged, < 0 diverged) and its name.
        iterations: Newton steps taken.
        history: one ``(iteration, residual_norm, energy_norm_rel)`` per Newton step, iteration
            1-based; residual_norm is ||R|| (N) at the iterate the step started from.
        residual_norm: ||R|| at the final iterate (N).
        error: message of an exception raised while evaluating the material (e.g. F outside the
            RVE's range), else None.
    """

    converged: bool
    reason: int
    reason_name: str
    iterations: int
    history: list = field(default_factory=list)
    residual_norm: float = float("nan")
    error: str | None = None

    @property
    def why(self) -> str:
        """One-line reason of a failure ('' if converged): the error message if there is one,
        else the SNES reason in words."""
        if self.converged:
            return ""
        words = _FAILURE_WORDS.get(self.reason_name, self.reason_name)
        return f"{words}: {self.error}" if self.error else words


STAGNATION = "DIVERGED_STAGNATION"  # reason_name of a solve stopped by the stagnation test
_FAILURE_WORDS = {
    STAGNATION: "stagnation (contact set cycling)",
    "DIVERGED_LINEAR_SOLVE": "linear solve failed (singular Jacobian or zero pivot)",
    "DIVERGED_FNORM_NAN": "NaN residual",
    "DIVERGED_FUNCTION_NANORINF": "NaN residual",
    "DIVERGED_MAX_IT": "no convergence within the Newton iteration limit",
    "DIVERGED_LINE_SEARCH": "line search failed",
    "DIVERGED_PETSC_ERROR": "PETSc error",
}


_REASON_NAMES = {v: k for k, v in vars(PETSc.SNES.ConvergedReason).items() if isinstance(v, int)}
_KSP_REASONS = {v: k for k, v in vars(PETSc.KSP.ConvergedReason).items() if isinstance(v, int)}


class NewtonSolver:
    """Solve R(u) = 0 with SNES; R and its Jacobian read quadrature data written by ``material``.

    Args:
        residual: UFL linear form R(u; v) (e.g. ``material.residual_form(v) - f_ext``).
        jacobian: UFL bilinear form dR/du (e.g. ``material.jacobian_form(du, v)``).
        u: the displacement Function; holds the initial guess and receives the solution.
        bcs: Dirichlet conditions (values are imposed on the first iterate).
        material: object with ``update(tangent=True)`` that refreshes the quadrature data from
            ``u`` (a :class:`~dolfinx_granular.material.GranularMaterial`).
        energy_rtol: relative energy norm that counts as converged.
        residual_atol: residual norm (N) that counts as converged (round-off level); 0 disables.
        roundoff_energy: below this relative energy norm a residual that fails to halve in one
            Newton step is taken as round-off (converged).
        max_it: most Newton steps per solve.
        prefix: PETSc options prefix of this solver.
        petsc_options: options set under ``prefix`` (defaults: newtonls, ``basic`` line search,
            preonly + LU with MUMPS).
        verbose: print one line per Newton step on rank 0.
        stagnation_it: fail the solve (reason ``DIVERGED_STAGNATION``) when the residual norm has
            not gone below its smallest value since the first Newton step for this many
            consecutive Newton steps
            (Newton cycling between contact sets); 0 disables the test.
        skip_final_tangent: evaluate only the stress (no tangent) for a residual that ends the
            solve whatever its value: the energy norm of the step that led to it is already
            converged, so SNES asks for no Jacobian there. The material's tangent then belongs
            to the previous iterate.

    Attributes:
        timings: seconds spent in ``"rve"`` (material updates), ``"assembly"`` and ``"solve"``
            (everything else in SNES: essentially the LU factorisation and solve).
    """

    def __init__(self, residual, jacobian, u, bcs=(), material=None, *, energy_rtol=1e-20,
                 residual_atol=0.0, roundoff_energy=1e-14, max_it=20, prefix="granular_",
                 petsc_options=None, verbose=False, skip_final_tangent=False, stagnation_it=4):
        self.u = u
        self.stagnation_it = int(stagnation_it)
        self.skip_final_tangent = bool(skip_final_tangent)
        self._have_tangent = False
        self.bcs = list(bcs)
        self.material = material
        self.energy_rtol = float(energy_rtol)
        self.residual_atol = float(residual_atol)
        self.roundoff_energy = float(roundoff_energy)
        self.max_it = int(max_it)
        self.verbose = verbose
        self.L = fem.form(residual)
        self.a = fem.form(jacobian)
        V = u.function_space
        comm = V.mesh.comm
        self.comm = comm
        self._u_vec = petsc_vec(u)
        self.b = self._u_vec.duplicate()
        self.A = create_matrix(self.a)
        self.x = self._u_vec.duplicate()  # SNES's own vector: line searches write trial points
        self._x_eval = self.x.duplicate()
        self._have_eval = False
        self._x_prev = self.x.duplicate()
        self._R_prev = self.x.duplicate()
        opts = {
            "snes_type": "newtonls",
            "snes_linesearch_type": "basic",
            "ksp_type": "preonly",
            "pc_type": "lu",
        }
        if PETSc.Sys.hasExternalPackage("mumps"):
            opts["pc_factor_mat_solver_type"] = "mumps"  # PETSc's own LU is serial only
        opts.update(petsc_options or {})
        self.snes = PETSc.SNES().create(comm)
        self.snes.setOptionsPrefix(prefix)
        db = PETSc.Options()
        for key, val in opts.items():
            db[prefix + key] = val
        self.snes.setFunction(self._residual, self.b)
        self.snes.setJacobian(self._jacobian, self.A)
        self.snes.setConvergenceTest(self._converged)
        # Only this solver's test decides convergence: no step-length test of PETSc's, and a failed
        # line search is judged by that test too (PETSc >= 3.20 would otherwise stop there).
        self.snes.setTolerances(max_it=self.max_it, stol=0.0)
        self.snes.setMaxStepFailures(self.max_it)
        self.snes.setFromOptions()
        self.snes.getKSP().setFromOptions()
        for key in opts:
            db.delValue(prefix + key)
        self.timings = {"rve": 0.0, "assembly": 0.0, "solve": 0.0}

    # -- SNES callbacks ----------------------------------------------------------------------------

    def _evaluate(self, x, tangent=True):
        x.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        x.copy(self._u_vec)
        self._u_vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        if self.material is not None:
            t = time.perf_counter()
            try:
                self.material.update(tangent=tangent)
            finally:
                self.timings["rve"] += time.perf_counter() - t
        x.copy(self._x_eval)
        self._have_eval = True
        self._have_tangent = tangent

    def _tangent_needed(self, x):
        """False if the energy norm of the step to x (what ``_converged`` will compute) already
        meets ``energy_rtol``: the solve ends at x and no Jacobian is assembled there."""
        if not (self.skip_final_tangent and self.history):
            return True
        du = x.copy()
        du.axpy(-1.0, self._x_prev)
        energy = abs(self._R_prev.dot(du))
        du.destroy()
        rel = energy / self._energy0 if self._energy0 > 0 else 0.0
        return not rel <= self.energy_rtol

    def _residual(self, snes, x, b):
        error = None
        try:
            self._evaluate(x, self._tangent_needed(x))
        except ValueError as err:  # UnsupportedDeformationError
            error = str(err)
        errors = [e for e in self.comm.allgather(error) if e]
        if errors:  # every rank takes this branch: a NaN residual makes SNES stop (or cut back)
            self._error = errors[0]
            self._have_eval = False
            with b.localForm() as b_local:
                b_local.set(np.nan)
            return
        t = time.perf_counter()
        with b.localForm() as b_local:
            b_local.set(0.0)
        assemble_vector(b, self.L)
        apply_lifting(b, [self.a], [self.bcs], [x], -1.0)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        set_bc(b, self.bcs, x, -1.0)
        self.timings["assembly"] += time.perf_counter() - t

    def _same_as_evaluated(self, x):
        same = self._have_eval and np.array_equal(x.array_r, self._x_eval.array_r)
        return self.comm.allreduce(bool(same), op=_MPI_LAND())

    def _jacobian(self, snes, x, A, P):
        if not (self._same_as_evaluated(x) and self._have_tangent):
            self._evaluate(x)
        t = time.perf_counter()
        A.zeroEntries()
        assemble_matrix(A, self.a, self.bcs)
        A.assemble()
        self.timings["assembly"] += time.perf_counter() - t

    def _converged(self, snes, it, norms):
        self._verdict = int(self._test(snes, it, norms))
        return self._verdict

    def _test(self, snes, it, norms):
        fnorm = norms[2]
        x = snes.getSolution()
        R = snes.getFunction()[0]
        if it > 0:
            du = x.copy()
            du.axpy(-1.0, self._x_prev)
            energy = abs(self._R_prev.dot(du))
            du.destroy()
            if it == 1:
                self._energy0 = energy
            rel = energy / self._energy0 if self._energy0 > 0 else 0.0
            self.history.append((it, self._rnorm_prev, rel))
            if self.verbose and self.comm.rank == 0:
                print(f"    Newton {it:2d}: |R| = {self._rnorm_prev:.3e} N, energy norm (rel) = "
                      f"{rel:.3e}", flush=True)
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
        if fnorm <= self.residual_atol or fnorm == 0.0:
            return PETSc.SNES.ConvergedReason.CONVERGED_FNORM_ABS
        if it > 0 and self.history[-1][2] <= self.energy_rtol:
            return PETSc.SNES.ConvergedReason.CONVERGED_SNORM_RELATIVE
        if stalled and self.history[-1][2] <= self.roundoff_energy:
            return PETSc.SNES.ConvergedReason.CONVERGED_FNORM_ABS
        if it >= self.max_it:
            return PETSc.SNES.ConvergedReason.DIVERGED_MAX_IT
        if self.stagnation_it > 0 and self._no_progress >= self.stagnation_it:
            self._stagnated = True
            return PETSc.SNES.ConvergedReason.DIVERGED_DTOL
        return PETSc.SNES.ConvergedReason.ITERATING

    # -- driver ------------------------------------------------------------------------------------

    def solve(self) -> SolveResult:
        """Newton solve from the current u (Dirichlet values imposed first); u gets the result.

        A failed solve leaves u at the last iterate and returns ``converged=False``; it does not
        raise, so a load-step driver can cut back.
        """
        self.history = []
        self._error = None
        self._stagnated = False
        self._rnorm_prev = float("nan")
        self._have_eval = False
        self._verdict = 0
        set_bc(self._u_vec, self.bcs)
        self._u_vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        self._u_vec.copy(self.x)
        t = time.perf_counter()
        spent = self.timings["rve"] + self.timings["assembly"]
        petsc_error = None
        try:
            self.snes.solve(None, self.x)
        except PETSc.Error as err:  # e.g. a factorisation error PETSc raises instead of reporting
            petsc_error = f"PETSc error {err.ierr} in SNES solve"
        self.timings["solve"] += (time.perf_counter() - t) - (
            self.timings["rve"] + self.timings["assembly"] - spent)
        # The material data must belong to the returned u (the last residual was at x if basic).
        if not self._same_as_evaluated(self.x):
            error = None
            try:
                self._evaluate(self.x)
            except ValueError as err:
                error = str(err)
            self._error = self._error or next((e for e in self.comm.allgather(error) if e), None)
        else:
            self.x.copy(self._u_vec)
            self._u_vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        reason = int(self.snes.getConvergedReason())
        if reason > 0 and self._verdict <= 0 and self._error:
            # PETSc >= 3.20 ends a Newton step whose line search met a NaN residual (an RVE
            # outside its range) without asking the convergence test, and may call it
            # CONVERGED_SNORM_RELATIVE at the unchanged iterate: that is a failure.
            reason = SNES_NAN_REASON
        if reason <= 0 or petsc_error is not None:
            # A failed factorisation is sticky in PETSc: every later solve would stop at once
            # with the same error. Drop the factor so that a cut-back starts afresh.
            self.snes.getKSP().getPC().reset()
        name = _REASON_NAMES.get(reason, str(reason))
        if self._stagnated:
            name = STAGNATION
        elif self.comm.allreduce(petsc_error is not None, op=_MPI_LOR()):
            reason, name = min(reason, -1), "DIVERGED_PETSC_ERROR"
            self._error = self._error or petsc_error or "PETSc error on another rank"
        elif reason == PETSc.SNES.ConvergedReason.DIVERGED_LINEAR_SOLVE:
            ksp = self.snes.getKSP()
            self._error = self._error or f"KSP reason {_KSP_REASONS.get(ksp.getConvergedReason())}"
        return SolveResult(
            converged=reason > 0, reason=reason, reason_name=name,
            iterations=len(self.history), history=list(self.history),
            residual_norm=float(self._rnorm_prev), error=self._error,
        )

    def destroy(self):
        """Free the PETSc objects (collective: call it on every rank at the same point)."""
        # petsc4py >= 3.18 defers the release of garbage-collected wrappers to a collective
        # clean-up. Flush that first on every rank, or a rank whose Python GC ran at another
        # moment destroys the MUMPS factor while the other waits elsewhere: a hang at exit.
        gc.collect()
        if hasattr(PETSc, "garbage_cleanup"):
            PETSc.garbage_cleanup(self.comm)
        for obj in (self.snes, self.A, self.b, self.x, self._x_eval, self._x_prev, self._R_prev):
            obj.destroy()
        if hasattr(PETSc, "garbage_cleanup"):
            PETSc.garbage_cleanup(self.comm)


def _MPI_LAND():
    from mpi4py import MPI

    return MPI.LAND


def _MPI_LOR():
    from mpi4py import MPI

    return MPI.LOR
