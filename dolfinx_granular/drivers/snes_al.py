"""PETSc's own arc length (SNESNEWTONAL, PETSc >= 3.23) as a driver of a granular problem.

:class:`SNESArcLength` solves ``R(u) - lam * target * f = 0`` for lam from 0 to 1 with
SNESNEWTONAL: PETSc follows the path by itself, through limit points, and ends where lam reaches
1. The residual and the Jacobian are the :class:`~dolfinx_granular.GranularProblem`'s, the
load Constant is set to ``lam * target`` before each residual. Unlike
:class:`~dolfinx_granular.ArcLength`, PETSc decides the increments and their
convergence (its ``snes_rtol``): the package's convergence test does not apply, and the run
records one increment, the whole solve. Where the PETSc has no SNESNEWTONAL (PETSc 3.18 of
Debian's DOLFINx 0.5.2), constructing the driver raises a one-line error.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from petsc4py import PETSc

from .protocol import ASKED_TO_STOP, LoadPathWarning, failure, warn_failure

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

    import ufl
    from dolfinx import fem

    from .newton import NewtonSolver
    from .problem import GranularProblem

_REASONS = {v: k for k, v in vars(PETSc.SNES.ConvergedReason).items() if isinstance(v, int)}


def has_newtonal() -> bool:
    """True if this petsc4py's PETSc has SNESNEWTONAL."""
    return hasattr(PETSc.SNES.Type, "NEWTONAL")


@dataclass
class SNESIncrement:
    """The record of a :class:`SNESArcLength` run (an
    :class:`~dolfinx_granular.drivers.protocol.IncrementRecord`): the whole solve to lam = 1."""

    step: int
    t: float  # lam at the end (1: the target load)
    iterations: int  # Newton steps over all of PETSc's continuation steps
    residual_norm: float
    reason_name: str
    history: list = field(default_factory=list)  # (PETSc keeps no per-step energy norms)
    converged_by: str = "snes_rtol"


class SNESArcLength:
    """SNESNEWTONAL on a problem R(u) - lam * target * f (the
    :class:`~dolfinx_granular.drivers.protocol.Driver` protocol).

    Args:
        problem: a :class:`~dolfinx_granular.GranularProblem`, or a
            :class:`~dolfinx_granular.NewtonSolver` (its problem is used).
        load: the Constant that scales ``external`` in the residual.
        external: the load pattern f (UFL linear form).
        target: the load value reached at lam = 1.
        step_size: PETSc's arc length per continuation step (``snes_newtonal_step_size``).
        prefix: PETSc options prefix.
        petsc_options: more options under ``prefix`` (they override the defaults: ``psisq``
            0, ``lambda_min`` -2, 500 continuation steps, 30 Newton steps, rtol 1e-12, LU).
        warn: a failed run issues one :class:`~dolfinx_granular.LoadPathWarning` naming the
            reason and a remedy (False: the caller reports :attr:`failed` itself).

    Attributes:
        failed: None, or a :func:`~dolfinx_granular.drivers.protocol.failure` dict.
        stopped: None, or :data:`~dolfinx_granular.drivers.protocol.ASKED_TO_STOP`.
        lam: the load parameter PETSc reached.

    Raises:
        RuntimeError: this PETSc has no SNESNEWTONAL.
    """

    def __init__(
        self,
        problem: GranularProblem | NewtonSolver,
        load: fem.Constant,
        external: ufl.Form,
        target: float,
        *,
        step_size: float = 0.05,
        prefix: str = "granular_al_",
        petsc_options: Mapping[str, Any] | None = None,
        warn: bool = True,
    ) -> None:
        if not has_newtonal():
            version = ".".join(str(v) for v in PETSc.Sys.getVersion())
            raise RuntimeError(
                f"SNESNEWTONAL needs PETSc >= 3.23 (this is PETSc {version}): use "
                "dolfinx_granular.ArcLength for path following here"
            )
        self.problem = getattr(problem, "problem", problem)
        self.load, self.target = load, float(target)
        self.f = self.problem.load_vector(external)
        self.failed, self.stopped, self.lam = None, None, 0.0
        self.warn = bool(warn)
        opts = {
            "snes_type": "newtonal",
            "snes_newtonal_step_size": step_size,
            "snes_newtonal_psisq": 0.0,
            "snes_newtonal_lambda_min": -2.0,
            "snes_newtonal_max_continuation_steps": 500,
            "snes_max_it": 30,
            "snes_rtol": 1e-12,
            "ksp_type": "preonly",
            "pc_type": "lu",
        }
        opts.update(petsc_options or {})
        self.b = self.problem.u_vec.duplicate()
        self.snes = self._create(prefix, opts)

    def _create(self, prefix, opts):
        snes = PETSc.SNES().create(self.problem.comm)
        snes.setOptionsPrefix(prefix)
        db = PETSc.Options()
        for key, value in opts.items():
            db[prefix + key] = value
        snes.setFunction(self._residual, self.b)
        snes.setJacobian(
            lambda snes_, x, A, P: self.problem.assemble_jacobian(x, A), self.problem.A
        )
        snes.setFromOptions()
        snes.setNewtonALFunction(self._tangent_load)
        for key in opts:
            db.delValue(prefix + key)
        return snes

    def _residual(self, snes, x, out):
        self.load.value = snes.getNewtonALLoadParameter() * self.target
        self.problem.residual(x, out)

    def _jacobian(self, snes, x, A, P):
        self.problem.assemble_jacobian(x, A)

    def _tangent_load(self, snes, x, q):  # Q = -dR/dlam = target f
        q.set(0.0)
        q.axpy(self.target, self.f)

    def run(self, on_converged: Callable[[SNESIncrement], bool | None] | None = None) -> bool:
        """Solve to lam = 1 from the current u; True unless PETSc failed. Converged: u and the
        materials at the end state, their history committed, ``on_converged(record)`` called;
        failed: u and the materials restored."""
        start = self.problem.u.x.array.copy()
        x = self.problem.u_vec.copy()
        try:
            self.snes.solve(None, x)
            reason = int(self.snes.getConvergedReason())
            self.lam = float(self.snes.getNewtonALLoadParameter())
            if reason <= 0:
                self.problem.restore(start)
                why = f"SNESNEWTONAL: {_REASONS.get(reason, reason)} at lam = {self.lam:.6g}"
                self._give_up(why)
                return False
            self.problem.residual(x, self.b)  # u = x, the materials there
            self.problem.commit()
        finally:
            x.destroy()
        record = SNESIncrement(
            1, self.lam, self.snes.getIterationNumber(), self.b.norm(), _REASONS.get(reason, "")
        )
        if on_converged is not None and on_converged(record) is False:
            self.stopped = ASKED_TO_STOP
        return True

    def _give_up(self, why):
        """Record the failure, and warn once."""
        self.failed = failure("path", 1, 0.0, why)
        if self.warn:
            warn_failure(
                f"path following stopped: {why}; u and the materials are back at the start",
                LoadPathWarning,
                "a smaller step_size, or ArcLength (cut-backs of failed increments)",
            )

    def destroy(self) -> None:
        """Free the PETSc objects (collective)."""
        for obj in (self.snes, self.b, self.f):
            obj.destroy()
