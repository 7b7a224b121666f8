"""The relaxed RVE's errors: a point the micro solver could not relax, a cell that lost its
rigidity (both :class:`~dolfinx_granular.LawEvaluationError`, so that load stepping cuts back),
one whose disks came apart while they moved, and a path that ended in such a cell."""

import numpy as np

from ..protocol import LawEvaluationError


class RelaxationError(LawEvaluationError):
    """The micro solver could not relax a point (no equilibrium reached, or its candidate
    contacts no longer cover the fluctuations)."""


class RigidityLostError(RelaxationError):
    """The relaxed cell has no rigid contact network left: no non-rattler disk, or a stiffness
    of the non-rattlers (one disk pinned) that is not positive definite (tension, a buckled
    network)."""


class CameApart(RigidityLostError):
    """No two disks touch any more where the solver's motion got to: ``w`` (N, 2) and ``th``
    (N,), the fluctuations and rotations there (None without rotations: the frictionless
    cell), a cell that collapsed."""

    def __init__(self, message: str, w, th) -> None:
        super().__init__(message)
        self.w, self.th = w, th


class CellFloats(RigidityLostError):
    """The quasi-static path ended in a cell that came apart: no disk keeps two contacts at the
    evaluated F (a loose frictional cell that collapsed). ``outputs`` is what ``evaluate``
    would have returned there, ``(W, P, A, trial_state)``: P of round-off, A zero, and the
    trial state with the disks where their motion left them. A stress-controlled driver may
    commit it, as a servo-controlled wall that retreats lets its cell collapse, to jam again
    further in (:func:`~dolfinx_granular.drivers.material_point.solve_point`'s ``collapse``);
    every other caller treats it as the :class:`RigidityLostError` it is."""

    def __init__(self, message: str, points=None, outputs=None) -> None:
        super().__init__(message, points)
        self.outputs = outputs


def evaluated(W, P, A, state, single: bool, floating: list) -> tuple:
    """A relaxed law's ``evaluate`` return, ``(W, P, A, trial_state)`` (one point's W, P and A
    where ``single``; A None where not computed), or :class:`CellFloats` with it where the
    points ``floating`` (their indices) ended in a cell come apart."""
    out = (W[0], P[0], (None if A is None else A[0]), state) if single else (W, P, A, state)
    if floating:
        raise CellFloats(
            f"point {floating[0]}: the cell has come apart (all its disks are rattlers)",
            np.array(floating), out,
        )  # fmt: skip
    return out
