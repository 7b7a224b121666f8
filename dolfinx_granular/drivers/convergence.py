"""The one convergence test of every driver: Newton through SNES and the arc-length corrector.

After Newton step k the relative energy norm ``|R_k . du_k| / |R_0 . du_0|`` is recorded (table 2
of the paper); the iteration has converged when it is <= ``energy_rtol``, or when the residual is
at round-off: ``|R| <= residual_rtol * scale`` (scale: the force scale of
:meth:`~dolfinx_granular.GranularProblem.force_scale`), or the energy norm is below
``roundoff_energy`` while |R| no longer halves. SNES's Newton also stops at ``|R| <=
residual_atol`` and under no load on stress-free materials (the residual and the external forces
both within twice the forces of the materials' reference stress). It fails on a NaN residual,
at ``max_it`` steps, or on stagnation: |R| has not gone below its best value for
``stagnation_it`` steps (Newton cycling between contact sets). With ``stall_rtol`` > 0 an
iterate whose |R| Newton no longer halves is accepted when ``|R| <= stall_rtol * scale``: an
out-of-balance force tolerated where Newton stalls, while a converging Newton still goes on to
round-off (``stopped_by`` ``tolerance``, as for a ``residual_rtol`` above round-off).

``corrector=True`` is the arc-length corrector's variant, kept as the paths traced so far depend
on it: iterate 1 does not reset the best |R| to its own, the force scale is that of iterate 0
only, the stalled round-off test comes before the energy norm, and there are no absolute and
no-load tests.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from petsc4py import PETSc

    from .problem import GranularProblem

ROUNDOFF = 1e-12  # the default residual_rtol: |R| at round-off of the force scale
ITERATING, CONVERGED, NAN, MAX_IT, STAGNATION = (
    "iterating",
    "converged",
    "nan",
    "max_it",
    "stagnation",
)


class ConvergenceTest:
    """Convergence of one Newton iteration on a :class:`~dolfinx_granular.drivers.problem.
    GranularProblem`; :meth:`reset` before each solve, :meth:`check` at each iterate.

    Attributes:
        history: one ``(iteration, |R| at its start (N), relative energy norm)`` per step.
        rnorm: |R| at the last iterate checked (N); scale: the force scale (N) compared with it.
        stopped_by: the test that ended a converged iteration (``energy norm``, ``round-off``,
            ``tolerance`` (the residual test with a ``residual_rtol`` above round-off),
            ``residual_atol``, ``no load``), else ''.
        error: what the stagnation test measured, else None.
        best_within: the iterate last checked (a Newton iterate, not the start) has the
            smallest |R| so far, within ``stall_rtol`` (a Newton that then stagnates may go
            back to it).
    """

    def __init__(
        self,
        problem: GranularProblem,
        *,
        energy_rtol: float = 1e-20,
        residual_rtol: float = ROUNDOFF,
        residual_atol: float = 0.0,
        roundoff_energy: float = 1e-14,
        stagnation_it: int = 4,
        max_it: int | None = None,
        corrector: bool = False,
        stall_rtol: float = 0.0,
    ) -> None:
        self.problem = problem
        self.energy_rtol, self.residual_rtol = float(energy_rtol), float(residual_rtol)
        self.stall_rtol = float(stall_rtol)
        self.residual_atol, self.roundoff_energy = float(residual_atol), float(roundoff_energy)
        self.stagnation_it = int(stagnation_it)
        self.max_it = None if max_it is None else int(max_it)
        self.corrector = bool(corrector)
        self.reset()

    def reset(self) -> None:
        """Forget the last iteration."""
        self.history: list = []
        self.e0 = None
        self.rnorm = self.scale = self.best = float("nan")
        self.no_progress, self.stopped_by, self.error = 0, "", None
        self.best_within = False

    def relative(self, energy: float) -> float:
        """The energy |R . du| of a step relative to the first step's (which it is, before any
        step is recorded)."""
        if not self.history:
            self.e0 = energy
        return energy / self.e0 if self.e0 > 0 else 0.0

    def check(self, it: int, fnorm: float, R: PETSc.Vec, energy: float | None = None) -> str:
        """The verdict at iterate ``it`` (0: the start) with residual R of norm ``fnorm``;
        ``energy``: |R_(it-1) . du_it| of the step that led here (ignored at it = 0). One of
        ``"iterating"``, ``"converged"`` (:attr:`stopped_by` says which test), ``"nan"``,
        ``"max_it"``, ``"stagnation"`` (:attr:`error` says what it measured)."""
        rel = None
        if it > 0:
            rel = self.relative(energy)
            self.history.append((it, self.rnorm, rel))
        stalled = it > 0 and fnorm > 0.5 * self.rnorm
        # the first Newton step may well overshoot the starting residual: count from iterate
        # 1 (not the corrector's rule: there the best |R| of iterate 0 stands)
        if it == 0 or (it == 1 and not self.corrector) or fnorm < self.best:
            self.best, self.no_progress = fnorm, 0
        elif it == 1:
            self.no_progress = 0
        else:
            self.no_progress += 1
        self.rnorm = fnorm
        if not np.isfinite(fnorm):
            return NAN
        if it == 0 or (stalled and not self.corrector):  # (dead loads: once is enough)
            self.scale = self.problem.force_scale(R)
        # (not the start: a step that went back to it would accept its imbalance and not move)
        self.best_within = it > 0 and fnorm == self.best and fnorm <= self.stall_rtol * self.scale
        test = self._converged_by(it, fnorm, rel, stalled)
        if test:
            self.stopped_by = test
            return CONVERGED
        if self.max_it is not None and it >= self.max_it:
            return MAX_IT
        if 0 < self.stagnation_it <= self.no_progress:
            steps = "corrector" if self.corrector else "Newton"
            share = f" ({self.best / self.scale:.1e} of the force scale)" if self.scale > 0 else ""
            self.error = (
                f"|R| = {fnorm:.3e} N has not gone below its best value "
                f"{self.best:.3e} N{share} for {self.no_progress} {steps} steps"
            )
            return STAGNATION
        return ITERATING

    def _converged_by(self, it, fnorm, rel, stalled):
        """The name of the test that fnorm and rel meet, or ''."""
        roundoff = stalled and rel <= self.roundoff_energy
        if not self.corrector and (fnorm == 0.0 or fnorm <= self.residual_atol):
            return "residual_atol"
        if fnorm <= self.residual_rtol * self.scale:
            # a residual_rtol above round-off is a tolerated out-of-balance force
            return "round-off" if self.residual_rtol <= ROUNDOFF else "tolerance"
        if self.corrector and roundoff:
            return "round-off"
        if stalled and fnorm <= self.stall_rtol * self.scale:
            # Newton no longer halves |R| (it cycles as RVEs rearrange within an iterate): the
            # out-of-balance force tolerated
            return "tolerance"
        if not self.corrector and self._no_load(fnorm):
            # no load and a stress-free material: R is the forces of its reference stress
            # (contacts overlapping by 1e-11), which Newton cannot remove without opening them
            return "no load"
        if it > 0 and rel <= self.energy_rtol:
            return "energy norm"
        return "round-off" if roundoff else ""

    def _no_load(self, fnorm):
        floor = self.problem.floor
        return fnorm <= 2.0 * floor and self.problem.external <= 2.0 * floor
