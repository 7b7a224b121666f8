"""The driver protocol: load control and path following seen alike by the code that runs them.

A driver (:class:`~dolfinx_granular.LoadPhase`,
:class:`~dolfinx_granular.ArcLength`,
:class:`~dolfinx_granular.SNESArcLength`) acts on a
:class:`~dolfinx_granular.GranularProblem` and takes converged increments until it reaches
its end, fails, or is asked to stop:

* ``run(on_converged=None) -> bool``: ``on_converged(increment)`` after each converged increment,
  with u and the materials at the converged state; returning False stops the run there
  (``stopped`` is then :data:`ASKED_TO_STOP`). True unless the driver failed.
* one record per converged increment, an :class:`IncrementRecord`;
* ``failed``: None, or a :func:`failure` dict;
* ``stopped``: None, or why the driver stopped before its natural end or failure (a str).

A failure is also said once as a warning naming the reason and a remedy: a
:class:`SolveFailedWarning` from a solve the user called, a :class:`LoadPathWarning` from a driver
that has given up (the failed solves it recovered from by cutting back stay silent). Every rank
warns alike (the failure is collective), so that a filter turning them into errors
(``warnings.simplefilter("error", LoadPathWarning)``) acts on all ranks.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from ..laws.relaxed import RelaxedRVE
from ..laws.relaxed_friction import FrictionalRelaxedRVE
from ..laws.taylor import PRESTRESS_WARNING, _user_stacklevel

if TYPE_CHECKING:
    from collections.abc import Callable

#: ``stopped`` of a driver whose ``on_converged`` returned False (a stop the caller asked for)
ASKED_TO_STOP = "asked to stop"


class SolveFailedWarning(UserWarning):
    """A :meth:`~dolfinx_granular.NewtonSolver.solve` failed (u and the materials are back where
    it started); the message names the reason and a remedy."""


class LoadPathWarning(UserWarning):
    """A load path (:class:`~dolfinx_granular.LoadStepper`, :class:`~dolfinx_granular.ArcLength`,
    :class:`~dolfinx_granular.SNESArcLength`) gave up; the message names the reason and a
    remedy."""


#: the remedy of a relaxed RVE on a stress-free packing: it has no shear stiffness once relaxed
UNCONFINED_RELAXED = (
    "a RelaxedRVE on a stress-free packing has no shear stiffness once relaxed (the first "
    "iterate unjams it; a FrictionalRelaxedRVE's too: friction holds no more than mu times "
    "its vanishing normal forces): build it on confined_packing(packing, k_n, p / k_n) and "
    "hold its reference stress with holding_traction(material) on the free faces"
)

#: the laws whose disks relax to equilibrium, so that a stress-free packing unjams
RELAXED_LAWS = (RelaxedRVE, FrictionalRelaxedRVE)


def unconfined_relaxed(materials: Any) -> bool:
    """True if a material of ``materials`` carries a relaxed RVE (frictionless or frictional,
    :data:`RELAXED_LAWS`) whose reference stress P(I) is at most the prestress tolerance of a
    stress-free packing (1e-6 of its modulus)."""
    for material in materials or ():
        law = getattr(material, "rve", None)
        if isinstance(law, RELAXED_LAWS):
            P0 = law.stress(np.eye(2)[None], law.initial_state(1))[1][0]
            if np.linalg.norm(P0) <= PRESTRESS_WARNING * np.linalg.norm(law.small_strain_modulus()):
                return True
    return False


def warn_failure(message: str, category: type[Warning], remedy: str) -> None:
    """One warning of ``category``: ``message``, then the remedy, attributed to the first line
    outside the package (the user's call of the solver or driver)."""
    warnings.warn(f"{message}. Remedy: {remedy}", category, stacklevel=_user_stacklevel())


@runtime_checkable
class IncrementRecord(Protocol):
    """What every driver records of a converged increment.

    Attributes:
        step: 1-based number of the increment in the driver's run (all its phases).
        t: the load parameter at its end.
        iterations: Newton (corrector) steps it took.
        history: ``(iteration, |R| at its start (N), relative energy norm)`` per step.
        residual_norm: |R| at its end (N).
        converged_by: the test that ended it (``energy norm``, ``round-off``, ...).
        reason_name: how it converged: the SNES reason name, or the driver's name.
    """

    step: int
    t: float
    iterations: int
    history: list
    residual_norm: float
    converged_by: str
    reason_name: str


@runtime_checkable
class Driver(Protocol):
    """Load control or path following: see the module doc."""

    failed: dict | None
    stopped: str | None

    def run(self, on_converged: Callable[[Any], bool | None] | None = None) -> bool: ...


def failure(
    phase: str, step: int, t: float, reason: str, limit_load: dict | None = None
) -> dict[str, Any]:
    """The ``failed`` record of a driver: the phase, the increment that failed (1-based), the
    load parameter of the last converged state, why, and the limit load recognised there (a
    :func:`~dolfinx_granular.drivers.loading.limit_point` dict) or None."""
    return {
        "phase": phase,
        "step": int(step),
        "t": float(t),
        "reason": reason,
        "limit_load": limit_load,
    }
