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
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:
    from collections.abc import Callable

#: ``stopped`` of a driver whose ``on_converged`` returned False (a stop the caller asked for)
ASKED_TO_STOP = "asked to stop"


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
