"""Adaptive load stepping: cut a failed load increment back and retry, grow it after easy steps.

A phase drives a load parameter t from its start to 1 (the caller maps t to the loads, e.g. gravity
or the footing pressure). Each increment is one :meth:`~dolfinx_granular.NewtonSolver.solve`.
When it fails for any reason (SNES divergence, a singular Jacobian where contacts have opened, an
RVE outside its range, stagnation), the solver restores the last converged state and the increment
is halved,
at most ``max_cutbacks`` times in a row; after a step converging in at most ``easy_iterations``
Newton steps the increment grows by ``grow`` up to the nominal one; an increment below
``min_fraction`` of the nominal one ends the phase as failed. Contact opening and closing
makes the global problem non-smooth (section 6 of Meier, Steinmann & Kuhl): smaller increments keep
Newton's start inside the basin of the new contact state, they do not change the equilibrium found.

No increment, however small, passes a limit point of the load-displacement path (the structure
collapses, or a cohesionless soil lets go of a pulled footing): past it no equilibrium exists at a
higher load. A failed phase is therefore checked for one (:func:`limit_point`) and, if the path
stiffness has collapsed, reported as a limit load rather than a solver failure. A failed phase
warns once (:class:`~dolfinx_granular.LoadPathWarning`: the reason and a remedy); the failed solves
the stepper recovers from by cutting back are part of its work and stay silent.

:meth:`LoadStepper.phase` gives one phase as a driver of the
:class:`~dolfinx_granular.drivers.protocol.Driver` protocol (``run(on_converged)`` with one
:class:`LoadIncrement` per converged increment), as path following is driven.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .protocol import (
    ASKED_TO_STOP,
    UNCONFINED_RELAXED,
    LoadPathWarning,
    failure,
    unconfined_relaxed,
    warn_failure,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

    from .newton import NewtonSolver, SolveResult


@dataclass
class Cutback:
    """One failed increment that was cut back (or, if it was the last allowed, ended the phase).

    Attributes:
        phase: name of the load phase.
        step: number of the converged increment that was being attempted (1-based, whole run).
        t_from: load parameter of the last converged state.
        t_to: load parameter that was attempted.
        reason: why the solve failed (:attr:`~dolfinx_granular.SolveResult.why`).
        iterations: Newton steps spent on the failed attempt.
    """

    phase: str
    step: int
    t_from: float
    t_to: float
    reason: str
    iterations: int

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class LoadIncrement:
    """One converged increment of load control (an
    :class:`~dolfinx_granular.drivers.protocol.IncrementRecord`).

    Attributes:
        step: number of the converged increment (1-based, all phases of the stepper).
        phase: name of the load phase.
        t, dt: the load parameter at its end and the increment that led there.
        increment_norm: |du| over all dofs and ranks (m).
        result: the :class:`~dolfinx_granular.SolveResult` of its solve.
    """

    step: int
    phase: str
    t: float
    dt: float
    increment_norm: float
    result: SolveResult

    @property
    def iterations(self) -> int:
        return self.result.iterations

    @property
    def history(self) -> list:
        return self.result.history

    @property
    def residual_norm(self) -> float:
        return self.result.residual_norm

    @property
    def converged_by(self) -> str:
        return self.result.stopped_by

    @property
    def reason_name(self) -> str:
        return self.result.reason_name


def limit_point(
    path: Sequence[Mapping[str, Any]], t_failed: float, stiffness_drop: float = 0.2
) -> dict[str, float] | None:
    """Recognise a limit point (maximum load) of load control from the converged increments.

    The path stiffness of increment k is ``S_k = dt_k / |du_k|`` (load parameter per Euclidean
    norm of the displacement increment over all dofs). Near a smooth limit point t*, u - u* ~
    sqrt(t* - t), so S² falls linearly to zero; extrapolating S² through the last two increments
    (at their midpoints) estimates t*. The path counts as collapsed when S has fallen to
    ``stiffness_drop`` of its first value and t* lies within two failed increments, or (weaker
    drop, sharper location) when S has at least halved and t* lies inside the failed increment.

    Args:
        path: the phase's converged increments, dicts with ``t`` (at the end), ``dt`` and
            ``increment_norm`` (|du|, m), in order.
        t_failed: smallest load parameter that was attempted and failed.
        stiffness_drop: S_last / S_first at or below which the path counts as collapsed.

    Returns:
        None if the path does not point to a limit before ``t_failed``; else a dict with
        ``t_converged`` (last carried), ``t_failed``, ``t_estimate`` (extrapolated t*) and
        ``stiffness_ratio`` (S_last / S_first).
    """
    S = [p["dt"] / p["increment_norm"] for p in path if p["increment_norm"] > 0.0]
    if len(S) < 3 or len(S) != len(path):
        return None
    ratio = S[-1] / S[0]
    if not (ratio <= 0.5 and S[-1] < S[-2]):
        return None
    m1, m2 = (p["t"] - 0.5 * p["dt"] for p in path[-2:])
    t_star = m2 + S[-1] ** 2 * (m2 - m1) / (S[-2] ** 2 - S[-1] ** 2)
    t_last = path[-1]["t"]
    if not np.isfinite(t_star):
        return None
    # the extrapolated maximum lies inside (or just beyond) the increment that could not be carried
    collapsed = ratio <= stiffness_drop and t_star <= t_last + 2.0 * (t_failed - t_last)
    if not (collapsed or t_star <= t_failed):
        return None
    return {
        "t_converged": float(t_last),
        "t_failed": float(t_failed),
        "t_estimate": float(t_star),
        "stiffness_ratio": float(ratio),
    }


class LoadStepper:
    """Drive a :class:`~dolfinx_granular.NewtonSolver` through load phases adaptively.

    Args:
        solver: the Newton solver (a :class:`~dolfinx_granular.NewtonSolver`: a failed
            solve restores u and the material data, a converged one commits the history).
        max_cutbacks: most consecutive halvings of one increment before the phase fails.
        min_fraction: smallest increment, relative to the nominal one, before the phase fails.
        grow: factor applied to the increment after an easy step (capped at the nominal one).
        easy_iterations: a converged step with at most this many Newton steps is easy (Newton
            to the energy norm 1e-20 of the paper takes 4-8 steps from a good start).
        log: callable taking one progress line (e.g. ``print`` on rank 0), or None.
        warn: a phase that gives up issues one :class:`~dolfinx_granular.LoadPathWarning` naming
            the reason and a remedy (False: the caller reports :attr:`failed` itself).

    Attributes:
        cutbacks: every :class:`Cutback` so far, in order.
        step: number of converged increments so far (all phases).
        dt: the increment the next attempt will use (None before the first phase).
        failed: None, or a :func:`~dolfinx_granular.drivers.protocol.failure` dict
            ``{"phase", "step", "t", "reason", "limit_load"}`` once a phase has given up;
            ``limit_load`` is the :func:`limit_point` dict when the path stiffness shows a limit
            point there, else None.
        stopped: None, or :data:`~dolfinx_granular.drivers.protocol.ASKED_TO_STOP` once
            ``on_converged`` asked to stop.
        path: one dict per converged increment: ``phase``, ``t``, ``dt`` and ``increment_norm``
            (Euclidean norm of the displacement increment over all dofs and ranks, m).

    A run resumed from a restart sets :attr:`step`, :attr:`cutbacks` and :attr:`path` and passes
    ``t`` and ``dt`` to :meth:`run`; it then takes the same increments as the uninterrupted run.
    """

    def __init__(
        self,
        solver: NewtonSolver,
        *,
        max_cutbacks: int = 6,
        min_fraction: float = 1e-3,
        grow: float = 1.5,
        easy_iterations: int = 8,
        log: Callable[[str], object] | None = None,
        warn: bool = True,
    ) -> None:
        if max_cutbacks < 0 or grow < 1.0 or easy_iterations < 0 or not 0 < min_fraction <= 1:
            raise ValueError(
                "need max_cutbacks >= 0, 0 < min_fraction <= 1, grow >= 1 and easy_iterations >= 0"
            )
        self.min_fraction = float(min_fraction)
        self.solver = solver
        self.max_cutbacks = int(max_cutbacks)
        self.grow = float(grow)
        self.easy_iterations = int(easy_iterations)
        self.log = log or (lambda line: None)
        self.warn = bool(warn)
        self.cutbacks: list[Cutback] = []
        self.step = 0
        self.dt = None
        self.failed = None
        self.stopped = None
        self.path: list[dict] = []

    def phase(
        self,
        name: str,
        set_load: Callable[[float], object],
        increment: float,
        t: float = 0.0,
        dt: float | None = None,
    ) -> LoadPhase:
        """One load phase as a :class:`~dolfinx_granular.drivers.protocol.Driver` (arguments as
        :meth:`run`)."""
        return LoadPhase(self, name, set_load, increment, t, dt)

    def run(
        self,
        phase: str,
        set_load: Callable[[float], object],
        increment: float,
        t: float = 0.0,
        dt: float | None = None,
        on_converged: Callable[[int, float, SolveResult], bool | None] | None = None,
    ) -> bool:
        """Take t from ``t`` to 1 in increments of at most ``increment``; True if t reached 1.

        Args:
            phase: name used in the log and in :attr:`cutbacks`.
            set_load: ``set_load(t)`` sets the loads (constants, boundary values) for parameter t.
            increment: nominal increment of t, in (0, 1].
            t: start of the phase (a converged state at this t is in ``solver.u``).
            dt: first increment to try (default ``increment``), e.g. from a restart.
            on_converged: ``on_converged(step, t, result)`` after each converged increment, with
                u and the material data at the converged state; returning False stops the run
                there (:attr:`stopped`, not :attr:`failed`).
        """
        record = None
        if on_converged is not None:
            record = lambda inc: on_converged(inc.step, inc.t, inc.result)  # noqa: E731
        return self.run_phase(phase, set_load, increment, t, dt, record)

    def run_phase(
        self,
        phase: str,
        set_load: Callable[[float], object],
        increment: float,
        t: float = 0.0,
        dt: float | None = None,
        on_converged: Callable[[LoadIncrement], bool | None] | None = None,
    ) -> bool:
        """:meth:`run`, with ``on_converged(increment)`` given a :class:`LoadIncrement`."""
        if not 0.0 < increment <= 1.0:
            raise ValueError(f"increment must lie in (0, 1], got {increment!r}")
        n_grid = 1.0 / increment
        dt = increment if dt is None else min(float(dt), increment)
        cuts = 0
        while t < 1.0:
            target = min(t + dt, 1.0)
            # back on the nominal grid k * increment after growing: no round-off drift in t
            k = round(target * n_grid)
            if abs(target * n_grid - k) < 1e-9:
                target = min(k / n_grid, 1.0)
            set_load(target)
            result, increment_norm = self._solve()
            if result.converged:
                inc = self._converged(phase, t, target, increment_norm, result)
                t, cuts = target, 0
                if result.iterations <= self.easy_iterations:
                    dt = min(dt * self.grow, increment)
                self.dt = dt
                if on_converged is not None and on_converged(inc) is False:
                    self.stopped = ASKED_TO_STOP  # the caller asked to stop here (--stop-after)
                    return False
                continue
            # (the solver has restored u and the material data of the converged state at t)
            cut = Cutback(
                phase, self.step + 1, float(t), float(target), result.why, result.iterations
            )
            self.cutbacks.append(cut)
            smallest = (target - t) / 2.0 < self.min_fraction * increment
            if cuts >= self.max_cutbacks or smallest:
                self._give_up(phase, t, target, cut, smallest)
                set_load(t)
                return False
            cuts += 1
            dt = self.dt = (target - t) / 2.0
            self.log(
                f"{phase}: cut-back {cuts}/{self.max_cutbacks}: t = {t:.6g} -> {target:.6g} "
                f"failed after {result.iterations} Newton steps ({cut.reason}); "
                f"retrying with increment {dt:.4g}"
            )
        return True

    def _converged(self, phase, t, target, increment_norm, result):
        """Record a converged increment from t to target; its :class:`LoadIncrement`."""
        record = {
            "phase": phase,
            "t": float(target),
            "dt": float(target - t),
            "increment_norm": increment_norm,
        }
        self.path.append(record)
        self.step += 1
        return LoadIncrement(self.step, result=result, **record)

    def _solve(self):
        """One solve; its result and the norm of the displacement increment (m, all ranks)."""
        u = self.solver.u
        V = u.function_space
        n_owned = V.dofmap.index_map.size_local * V.dofmap.index_map_bs
        saved = u.x.array[:n_owned].copy()
        # (a failed solve is cut back: the phase warns once if it gives up, not every solve)
        result = self.solver.solve(warn=False)
        du = u.x.array[:n_owned] - saved
        return result, float(np.sqrt(V.mesh.comm.allreduce(du @ du)))

    def _give_up(self, phase, t, target, cut, smallest):
        """Record that the phase failed, checking the path for a limit point."""
        self.log(
            f"{phase}: t = {t:.6g} -> {target:.6g} failed ({cut.reason}); "
            + (
                f"increment {target - t:.3g} cannot be halved further"
                if smallest
                else f"{self.max_cutbacks} cut-backs in a row"
            )
            + ", giving up"
        )
        # (the last attempt is the smallest: each cut-back halves the increment)
        limit = limit_point([p for p in self.path if p["phase"] == phase], target)
        self.failed = failure(phase, self.step + 1, t, cut.reason, limit)
        if limit is not None:
            self.log(
                f"{phase}: limit load: the path stiffness fell to "
                f"{100 * limit['stiffness_ratio']:.1f} % of its initial value and "
                f"extrapolates to zero at t = {limit['t_estimate']:.6g}; no larger load has "
                "an equilibrium nearby (load control cannot pass a limit point)"
            )
        if self.warn:
            how = f"after {self.max_cutbacks} cut-backs in a row"
            how = "at the smallest increment" if smallest else how
            reason = cut.reason.rstrip(".")
            warn_failure(
                f"load phase {phase!r} failed {how}: t = {t:.6g} -> {target:.6g} ({reason}); "
                f"u and the materials are at the last converged state, t = {t:.6g}",
                LoadPathWarning,
                self._remedy(limit, cut.reason),
            )

    def _remedy(self, limit, reason):
        """What to do about a phase that gave up (limit: the :func:`limit_point` dict or None)."""
        if limit is not None:
            return (
                f"the path stiffness fell to {100 * limit['stiffness_ratio']:.1f} % of its "
                f"initial value, extrapolating to zero at t = {limit['t_estimate']:.6g}: a limit "
                "load, which load control cannot pass; follow the path past it with ArcLength"
            )
        if unconfined_relaxed(getattr(self.solver, "materials", ())):
            return UNCONFINED_RELAXED
        if "lost every contact" in reason:
            return (
                "the granular material carries no tension: confine it (a confining load, or "
                "a confined packing held by holding_traction) or stabilise the open points "
                "(GranularMaterial(..., stabilise=1e-3))"
            )
        return (
            f"smaller load increments, more cut-backs in a row (LoadStepper(max_cutbacks=...), "
            f"now {self.max_cutbacks}) or a smaller smallest increment (min_fraction, now "
            f"{self.min_fraction:g})"
        )


class LoadPhase:
    """One phase of a :class:`LoadStepper` as a :class:`~dolfinx_granular.drivers.protocol.Driver`:
    :meth:`run` takes t to 1 (arguments of :meth:`LoadStepper.run`, bound here)."""

    def __init__(self, stepper, name, set_load, increment, t=0.0, dt=None):
        self.stepper, self.name, self.set_load = stepper, name, set_load
        self.increment, self.t, self.dt = increment, t, dt

    @property
    def failed(self) -> dict | None:
        return self.stepper.failed

    @property
    def stopped(self) -> str | None:
        return self.stepper.stopped

    def run(self, on_converged: Callable[[LoadIncrement], bool | None] | None = None) -> bool:
        """Take the phase's t to 1; True unless it failed (the protocol's rule: a stop asked
        for by ``on_converged`` shows in :attr:`stopped`)."""
        self.stepper.stopped = None
        ok = self.stepper.run_phase(
            self.name, self.set_load, self.increment, self.t, self.dt, on_converged
        )
        return ok or self.stopped is not None
