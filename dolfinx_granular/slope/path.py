"""A load phase by path following: past the slope's limit load and down its softening branch.

With ``SlopeOptions.path_following`` one phase's load is an unknown of arc-length continuation
(:class:`~dolfinx_granular.ArcLength`) instead of a prescribed sequence:

- ``"footing"``: the load parameter lam is the footing Constant (lam = ``load_factor`` is the
  nominal load times the load factor), the load pattern the footing pressure;
- ``"gravity"``: lam is the factor of the weight (1: the slope's own weight), the pattern the
  weight; the run ends with this phase (a slope that cannot stand gets no footing).

The path stops once the load has fallen to ``unload_fraction`` of its peak after a limit point,
or once the full load is carried without one, or after ``max_increments``. Every converged
increment is recorded and written like a load step; a restart continues the path (the last
increment Du is the difference of the last two stored displacement fields).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from dolfinx import fem

from ..drivers.arclength import ArcLength, load_reaches, unloaded_to
from ..fem import compat as dfx

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

    from petsc4py import PETSc

    from ..io.runwriter import NodeOrder
    from .model import SlopeModel


def _stop(load_factor, fraction):
    past_peak, carried = unloaded_to(fraction), load_reaches(load_factor)

    def stop(al):
        return past_peak(al) or carried(al)

    return stop


def load_path(
    model: SlopeModel,
    options: Any,
    say: Callable[[str], object],
    restart_state: dict | None = None,
    du_prev: PETSc.Vec | None = None,
) -> ArcLength:
    """The arc-length driver of the phase ``options.path_following`` of ``model`` from its
    converged state (that phase's load set), for ``options`` (a
    :class:`~dolfinx_granular.slope.run.SlopeOptions`); ``restart_state`` and ``du_prev``
    (:func:`last_increment`) continue a stored path."""
    o, full = options, options.path_full_load
    if o.path_following == "gravity":
        load, pattern, steps = model.gravity, model.gravity_pattern, o.gravity_steps
    else:
        load, pattern, steps = model.footing, model.footing_pattern, o.steps
    al = ArcLength(
        model.solver,
        load,
        pattern,
        dlam=full / steps,
        direction=np.sign(full) or 1.0,
        max_it=15,
        peak_refinement=16.0,
        log=lambda line: say("  " + line),
        stop=_stop(full, o.unload_fraction),
        warn=False,  # (the run reports a failed path in its log and summary.json)
    )
    al.ds_max = al.ds  # the arc of the first (nominal) step at most: the softening branch bends
    if restart_state is not None:
        al.resume(restart_state, du_prev)
    al.max_increments = o.max_increments - len(al.path)
    return al


def path_failure(model: SlopeModel, failed: dict) -> str:
    """The reason of the path's failure (an ArcLength ``failed`` dict), with what the RVEs
    under the footing have to say about it."""
    open_points = model.open_points()
    if open_points:
        return (
            f"{failed['reason']}; {open_points} RVEs have lost every contact (P = 0, a zero "
            "tangent): no equilibrium path continues from here"
        )
    return failed["reason"]


def last_increment(
    restart: Mapping[str, Any], nodes: NodeOrder, V: fem.FunctionSpace
) -> PETSc.Vec | None:
    """Du of the last stored increment of a restart (:func:`~dolfinx_granular.slope.run.
    load_restart`), as a vector of V; None before the second stored state."""
    u_history = restart["u_history"]
    if len(u_history) < 2:
        return None
    du = fem.Function(V)
    values = np.asarray(u_history[-1]) - np.asarray(u_history[-2])
    nodes.scatter_function(values, restart["nodes"], du)
    return dfx.petsc_vec(du).copy()


def path_summary(
    al: ArcLength | None,
    step_info: Sequence[Mapping[str, Any]],
    nominal_load: float,
    phase: str | None = "footing",
) -> dict | None:
    """The path's record for summary.json: its ``phase``, the peak (footing load in N/m or the
    weight's factor ``gravity``, settlement in m, step), the critical points crossed, how it
    stopped; None without a path (``al`` None). ``step_info``: the run's records of its steps;
    ``nominal_load``: the footing load (N/m)."""
    if al is None:
        return None
    load = "gravity" if phase == "gravity" else "footing_load"
    steps = [s for s in step_info if s["phase"] == phase]
    peak = max(steps, key=lambda s: abs(s[load]), default=None)
    if peak is not None:
        peak = {load: peak[load], "settlement": peak["settlement"], "step": peak["step"]}
        if phase == "footing":
            peak["load_factor"] = peak["footing_load"] / nominal_load
    return {
        "phase": phase,
        "increments": len(al.path),
        "stopped": al.stopped,
        "failed": al.failed["reason"] if al.failed else None,
        # the parabola through the sampled peak and its neighbours: the peak load between the
        # samples, in units of lam (the nominal footing load, or the weight)
        "peak_estimate": al.peak_estimate(),
        "peak": peak,
        "critical_points": [c.as_dict() for c in al.critical],
        "path": [
            {
                load: s[load],
                "settlement": s["settlement"],
                "non_elliptic_points": s["non_elliptic_points"],
                "open_points": s["open_points"],
            }
            for s in steps
        ],
    }
