"""The footing phase by path following: past the slope's limit load and down its softening branch.

With ``SlopeOptions.path_following`` the footing load is an unknown of arc-length continuation
(:class:`~dolfinx_granular.arclength.ArcLength`) instead of a prescribed sequence: the load
parameter lam is the footing Constant (lam = ``load_factor`` is the nominal load times the load
factor), the load pattern the footing pressure. The path stops once the load has fallen to
``unload_fraction`` of its peak after a limit point, or once the full load (lam = load_factor) is
carried without one, or after ``max_increments``. Every converged increment is recorded and
written like a load step; a restart continues the path (the last increment Du is the difference
of the last two stored displacement fields).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from dolfinx import fem

from .. import _dolfinx as dfx
from ..arclength import ASKED_TO_STOP, ArcLength, load_reaches, unloaded_to
from ..solver import SolveResult

if TYPE_CHECKING:
    from collections.abc import Callable

    from .run import SlopeRun


def _stop(load_factor, fraction):
    past_peak, carried = unloaded_to(fraction), load_reaches(load_factor)

    def stop(al):
        return past_peak(al) or carried(al)

    return stop


def follow_footing_path(
    run: SlopeRun,
    phase_index: int,
    converged: Callable[[int, int, float, SolveResult], bool],
    t0: float = 0.0,
    restart_state: dict | None = None,
) -> bool:
    """Drive the footing phase of ``run`` (a SlopeRun) by arc length from t0 (a converged state);
    True unless the path failed (a stop that ``converged`` asked for sets ``run.stepper.stopped``).
    ``converged(phase_index, step, t, result)`` records and writes an increment."""
    m, o = run.model, run.options
    m.set_footing(t0)  # the loads of the converged state: the weight and the footing at t0
    al = ArcLength(
        m.solver,
        m.footing,
        m.footing_pattern,
        dlam=o.load_factor / o.steps,
        direction=np.sign(o.load_factor) or 1.0,
        max_it=15,
        peak_refinement=16.0,
        log=lambda line: run.say("  " + line),
    )
    al.ds_max = al.ds  # the arc of the first (nominal) step at most: the softening branch bends
    if restart_state is not None:
        al.resume(restart_state, _last_increment(run))
    run.arclength = al

    def on_increment(inc):
        result = SolveResult(
            converged=True,
            reason=2,
            reason_name="ARC_LENGTH",
            iterations=inc.iterations,
            history=list(inc.history),
            residual_norm=inc.residual_norm,
            stopped_by=inc.converged_by,
        )
        run.stepper.step += 1
        return converged(phase_index, run.stepper.step, inc.lam / o.load_factor, result)

    ok = al.run(
        o.max_increments - len(al.path),
        stop=_stop(o.load_factor, o.unload_fraction),
        on_converged=on_increment,
    )
    if ok and al.stopped == ASKED_TO_STOP:
        # stopped where asked, not at an end of the path: a stopped run, as the LoadStepper
        # marks one under load control (status "stopped", the hint to continue with --resume)
        run.stepper.stopped = True
    if not ok:
        run.stepper.failed = {
            "phase": "footing",
            "step": run.stepper.step + 1,
            "t": al.lam / o.load_factor,
            "reason": _why(run, al.failed),
            "limit_load": None,
        }
    return ok


def _why(run, failed):
    """The path's failure, with what the RVEs under the footing have to say about it."""
    open_points = run.model.open_points()
    if open_points:
        return (
            f"{failed}; {open_points} RVEs have lost every contact (P = 0, a zero tangent): "
            "no equilibrium path continues from here"
        )
    return failed


def _last_increment(run):
    """Du of the last stored increment of the run's restart (None before the second stored
    state), as a vector."""
    u_history = run.restart["u_history"]
    if len(u_history) < 2:
        return None
    du = fem.Function(run.model.V)
    values = np.asarray(u_history[-1]) - np.asarray(u_history[-2])
    run.nodes.scatter_function(values, run.restart["nodes"], du)
    return dfx.petsc_vec(du).copy()


def path_summary(run: SlopeRun) -> dict | None:
    """The path's record for summary.json: the peak (footing load in N/m, settlement in m,
    step), the critical points crossed, how it stopped; None without path following."""
    al = getattr(run, "arclength", None)
    if al is None:
        return None
    footing = [s for s in run.step_info if s["phase"] == "footing"]
    peak = max(footing, key=lambda s: abs(s["footing_load"]), default=None)
    estimate = al.peak_estimate()
    return {
        "increments": len(al.path),
        "stopped": al.stopped,
        "failed": al.failed,
        # the parabola through the sampled peak and its neighbours: the peak footing load
        # between the samples, in units of the nominal load (lam is the footing Constant)
        "peak_estimate": estimate,
        "peak": None
        if peak is None
        else {
            "footing_load": peak["footing_load"],
            "settlement": peak["settlement"],
            "step": peak["step"],
            "load_factor": peak["footing_load"] / run.options.geometry.footing_load,
        },
        "critical_points": [c.as_dict() for c in al.critical],
        "path": [
            {
                "footing_load": s["footing_load"],
                "settlement": s["settlement"],
                "non_elliptic_points": s["non_elliptic_points"],
                "open_points": s["open_points"],
            }
            for s in footing
        ],
    }
