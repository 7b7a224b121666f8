"""The nonlinear problem R(u) = 0 of quadrature-point materials, apart from any driver.

:class:`GranularProblem` owns the compiled forms, the Dirichlet conditions and the materials. It
evaluates the materials at a state x, assembles the residual and the Jacobian there, gives the
force scale of the round-off test, and commits or restores the materials. The drivers act on it
through these public methods only: Newton through SNES (:class:`~dolfinx_granular.drivers.newton.
NewtonSolver`), load stepping (:mod:`~dolfinx_granular.drivers.loading`), arc length
(:mod:`~dolfinx_granular.drivers.arclength`) and PETSc's SNESNEWTONAL
(:mod:`~dolfinx_granular.drivers.snes_al`).

The materials are evaluated at exactly the state a driver hands over; :meth:`assemble_jacobian`
reuses that tangent only at the same x and re-evaluates otherwise, so the tangent is always
consistent. A law that cannot be evaluated raises
:class:`~dolfinx_granular.LawEvaluationError`; :meth:`residual` turns it into a NaN residual
on every rank and its message (any other exception propagates with its traceback).
"""

from __future__ import annotations

import gc
from typing import TYPE_CHECKING, Any

import numpy as np
import ufl
from dolfinx import fem
from dolfinx.fem.petsc import apply_lifting, assemble_matrix, assemble_vector, create_matrix, set_bc
from mpi4py import MPI
from petsc4py import PETSc

from ..fem.compat import petsc_vec
from ..fem.diagnose import check_wiring
from ..fem.quadrature import derivative
from ..laws.protocol import LawEvaluationError
from ..timing import Stopwatch

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    from ..fem.quadrature import QuadratureMaterial

_FORWARD = {"addv": PETSc.InsertMode.INSERT, "mode": PETSc.ScatterMode.FORWARD}


class GranularProblem:
    """R(u; v) = 0 with quadrature-point materials: forms, boundary conditions, materials.

    Args:
        residual: UFL linear form R(u; v) (e.g. ``material.residual_form(v) - f_ext``).
        jacobian: UFL bilinear form dR/du, or None: the consistent Jacobian
            :func:`~dolfinx_granular.derivative` of ``residual`` and the materials.
        u: the displacement Function (the state the materials read).
        bcs: Dirichlet conditions.
        materials: one material or a sequence of them (``update(tangent)``, ``commit()``,
            ``residual_form(v)``, ``stress_floor_form(v)``).
        roundoff_scale: compile the materials' internal forces for :meth:`force_scale`.

    Attributes:
        L, a: the compiled residual and Jacobian forms.
        A: the Jacobian matrix.
        materials: the materials, a tuple.
        comm: the mesh's communicator.
        clock: :class:`~dolfinx_granular.timing.Stopwatch`: ``"rve"`` (material updates),
            ``"residual"``, ``"jacobian"``, ``"scale"`` (assembly).
        floor: |f| (N) of the materials' reference stress, Dirichlet rows left out (0: none).
        external: |f_ext| (N) of the last :meth:`force_scale`.

    Raises:
        ValueError: a wiring mistake (:func:`~dolfinx_granular.fem.diagnose.check_wiring`).
    """

    def __init__(
        self,
        residual: ufl.Form,
        jacobian: ufl.Form | None,
        u: fem.Function,
        bcs: Iterable[Any] = (),
        materials: QuadratureMaterial | Sequence[QuadratureMaterial] | None = (),
        *,
        roundoff_scale: bool = True,
    ) -> None:
        self.u, self.bcs, self.materials = u, list(bcs), as_tuple(materials)
        check_wiring(residual, jacobian, u, self.materials)
        if jacobian is None:
            jacobian = derivative(residual, u, ufl.TrialFunction(u.function_space), self.materials)
        self.L, self.a = fem.form(residual), fem.form(jacobian)
        v = residual.arguments()[0]
        self._f_int = None  # the materials' internal forces, for the round-off scale
        if self.materials and roundoff_scale:
            self._f_int = fem.form(sum(m.residual_form(v) for m in self.materials))
        self.comm = u.function_space.mesh.comm
        self.u_vec = petsc_vec(u)
        self.A = create_matrix(self.a)
        self._x_eval, self._f = self.u_vec.duplicate(), self.u_vec.duplicate()
        self._have_eval = self._have_tangent = False
        self.clock = Stopwatch()
        self.external = float("nan")
        self.floor = 0.0 if self._f_int is None else self._stress_floor(v)

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

    # -- the materials -------------------------------------------------------------------------

    def evaluate(self, x: PETSc.Vec, tangent: bool = True) -> None:
        """u = x, and the materials' data at u (their tangent too if ``tangent``); raises
        :class:`~dolfinx_granular.LawEvaluationError` where a law cannot be evaluated."""
        x.ghostUpdate(**_FORWARD)
        x.copy(self.u_vec)
        self.u_vec.ghostUpdate(**_FORWARD)
        with self.clock("rve"):
            for m in self.materials:
                m.update(tangent=tangent)
        x.copy(self._x_eval)
        self._have_eval = True
        self._have_tangent = tangent

    def try_evaluate(self, x: PETSc.Vec, tangent: bool = True) -> str | None:
        """:meth:`evaluate` (collective); None, or the message of a law that could not be
        evaluated on any rank (the material data are stale then)."""
        error = None
        try:
            self.evaluate(x, tangent)
        except LawEvaluationError as err:  # e.g. UnsupportedDeformationError; bugs propagate
            error = str(err)
        errors = [e for e in self.comm.allgather(error) if e]
        if errors:
            self._have_eval = False
            return errors[0]
        return None

    def evaluated_at(self, x: PETSc.Vec) -> bool:
        """Collective: the material data are those of state x (the last evaluation was at x)."""
        same = self._have_eval and np.array_equal(x.array_r, self._x_eval.array_r)
        return self.comm.allreduce(bool(same), op=MPI.LAND)

    def invalidate(self) -> None:
        """Forget the last evaluation: the next Jacobian evaluates the materials afresh."""
        self._have_eval = False

    def set_state(self, x: PETSc.Vec) -> None:
        """u = x without evaluating the materials (their data must be those of x)."""
        x.copy(self.u_vec)
        self.u_vec.ghostUpdate(**_FORWARD)

    def commit(self) -> None:
        """The materials commit their history at the current (converged) state."""
        for m in self.materials:
            m.commit()

    def restore(self, u0: np.ndarray | PETSc.Vec) -> None:
        """u = u0 (an array like ``u.x.array``, or a vector like u's) and the materials' stress
        at it: the state a failed solve or increment returns to."""
        if isinstance(u0, PETSc.Vec):
            self.set_state(u0)
        else:
            self.u.x.array[:] = u0
        self.refresh_materials()

    def refresh_materials(self) -> None:
        """Evaluate the materials' stress (no tangent) at the current u, after u was set from
        outside (a restore): their data belong to u again, and the next Jacobian evaluates them
        afresh. A u outside a law's range leaves the data as far as they got."""
        self.invalidate()
        try:
            for m in self.materials:
                m.update(tangent=False)
        except LawEvaluationError:
            pass  # u itself (the start of a failed solve) is outside a law's range: nothing to do

    # -- assembly ------------------------------------------------------------------------------

    def residual(self, x: PETSc.Vec, b: PETSc.Vec, tangent: bool = True) -> str | None:
        """Evaluate the materials at the state x (a vector like u's) and assemble R(x) into b,
        Dirichlet rows ``x - g`` (collective). Returns None, or the message of a material that
        could not be evaluated (an RVE outside its range; b is NaN then, on every rank)."""
        error = self.try_evaluate(x, tangent)
        if error:  # every rank takes this branch: a NaN residual makes SNES stop
            with b.localForm() as b_local:
                b_local.set(np.nan)
            return error
        self.assemble_residual(x, b)
        return None

    def assemble_residual(self, x: PETSc.Vec, b: PETSc.Vec) -> None:
        """Assemble R(x) into b with the material data as they are (those of the last
        evaluation, which must have been at x), Dirichlet rows ``x - g`` (collective): R again
        after a change of the loads alone, without evaluating the materials again."""
        with self.clock("residual"):
            _zero_and_assemble(b, self.L)
            apply_lifting(b, [self.a], [self.bcs], [x], -1.0)
            b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            set_bc(b, self.bcs, x, -1.0)

    @staticmethod
    def assemble_forces(b: PETSc.Vec, form: fem.Form) -> None:
        """Assemble the compiled linear form ``form`` (no Dirichlet lifting: internal forces, a
        load pattern) into b, ghost contributions added to their owners; Dirichlet rows as
        assembled."""
        _zero_and_assemble(b, form)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)

    def load_vector(self, external: ufl.Form) -> PETSc.Vec:
        """The load pattern ``external`` (UFL linear form) assembled, zero in the Dirichlet
        rows: a new vector like u's."""
        f = self.u_vec.duplicate()
        self.assemble_forces(f, fem.form(external))
        set_bc(f, self.bcs, None, 0.0)
        return f

    def assemble_jacobian(self, x: PETSc.Vec, A: PETSc.Mat | None = None) -> PETSc.Mat:
        """Assemble dR/du at x into A (default: :attr:`A`), with the materials' tangent at x
        (re-evaluated unless the last evaluation was at x with a tangent); returns A."""
        A = self.A if A is None else A
        if not (self.evaluated_at(x) and self._have_tangent):
            self.evaluate(x)
        with self.clock("jacobian"):
            A.zeroEntries()
            assemble_matrix(A, self.a, self.bcs)
            A.assemble()
        return A

    def force_scale(self, R: PETSc.Vec) -> float:
        """The magnitude of the forces in balance (N): max(|f_int|, |f_ext|) at the current
        iterate, f_int the materials' internal forces (reactions included), f_ext = f_int - R on
        the free dofs (kept in :attr:`external`). Round-off in R is a small multiple of eps
        times it; 0 without materials."""
        if self._f_int is None:
            return 0.0
        f = self._f
        with self.clock("scale"):
            self.assemble_forces(f, self._f_int)
        internal = f.norm()
        f.axpy(-1.0, R)
        set_bc(f, self.bcs, None, 0.0)
        self.external = f.norm()
        return max(internal, self.external)

    def destroy(self) -> None:
        """Free the PETSc objects (collective: call it on every rank at the same point)."""
        for obj in (self.A, self._x_eval, self._f):
            obj.destroy()


def _zero_and_assemble(b, form):
    with b.localForm() as b_local:
        b_local.set(0.0)
    assemble_vector(b, form)


def collect_garbage(comm: MPI.Comm) -> None:
    """Flush petsc4py's deferred destruction on every rank (collective). petsc4py >= 3.18 defers
    the release of garbage-collected wrappers to a collective clean-up; a rank whose Python GC
    ran at another moment would otherwise destroy a MUMPS factor while the other waits: a hang."""
    gc.collect()
    if hasattr(PETSc, "garbage_cleanup"):
        PETSc.garbage_cleanup(comm)


def as_tuple(materials: Any) -> tuple:
    """``materials`` (None, one material or a sequence of them) as a tuple."""
    if materials is None:
        return ()
    if isinstance(materials, (list, tuple)):
        return tuple(materials)
    return (materials,)
