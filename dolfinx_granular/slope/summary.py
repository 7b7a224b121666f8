"""What a slope run reports at its end: ``summary.json`` and the figure-7 view.

The summary holds the load path (iterations, cut-backs, per step the settlement, the RVEs
without a loaded contact and those that lost strong ellipticity), the stop (converged, stopped,
failed at a limit load), the stress extremes at the last converged state and the timings.

``run`` is a :class:`~dolfinx_granular.slope.run.SlopeRun` throughout (not imported here: that
module imports this one, and the slope's modules form no circle).
"""

from __future__ import annotations

import signal
import time
from typing import TYPE_CHECKING, Any

import numpy as np
from mpi4py import MPI

from ..io.postprocess import plot_load_settlement, plot_slope
from ..laws.validity import OVERLAP_THRESHOLD
from .path import path_summary

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping, Sequence
    from os import PathLike


def limit_footing_load(failed: dict | None, run: Any) -> float | None:
    """The footing load (N/m) that a footing phase which failed at a limit load carried at its
    last converged state, or None (no failure, no limit load, another phase)."""
    if failed is None or failed["limit_load"] is None or failed["phase"] != "footing":
        return None
    o = run.options
    return o.load_factor * failed["limit_load"]["t_converged"] * o.geometry.footing_load


def limit_message(failed: dict, run: Any) -> str | None:
    """The log line of a failed footing phase that stopped at a limit load, or None."""
    footing_load = limit_footing_load(failed, run)
    if footing_load is None:
        return None
    limit, lf = failed["limit_load"], run.options.load_factor
    return (
        f"slope: limit load: the slope carries at most {abs(footing_load):.4g} N/m "
        f"of footing {'uplift' if lf < 0 else 'load'} ({abs(lf) * limit['t_converged']:.4g} x "
        f"the nominal footing load); the displacement per load increment has grown "
        f"{1 / limit['stiffness_ratio']:.3g}-fold. Past a limit point load control finds no "
        "equilibrium."
    )


def report_stop(run: Any, path: dict | None) -> None:
    """Log how the run ended (failure, limit load, the end of a path, a requested stop);
    ``path``: :func:`~dolfinx_granular.slope.path.path_summary` of the run."""
    failed = run.failed
    if path is not None and path["peak"] is not None:
        peak = path["peak"]
        load = (
            f"peak gravity factor {peak['gravity']:.4g} (x the weight)"
            if path["phase"] == "gravity"
            else f"peak footing load {abs(peak['footing_load']):.4g} N/m "
            f"({abs(peak['load_factor']):.4g} x the nominal load)"
        )
        run.say(
            f"slope: path: {len(run.arclength.path)} increments, {load} at a settlement of "
            f"{peak['settlement']:.4f} m"
            + (f"; stopped: {path['stopped']}" if path["stopped"] else "")
        )
    if failed is not None:
        run.say(
            f"slope: load step {failed['step']} ({failed['phase']}, t = {failed['t']:.6g} "
            f"reached) did not converge: {failed['reason']}; stopping."
        )
        line = limit_message(failed, run)
        if line:
            run.say(line)
    elif run.interrupted:
        name = signal.Signals(run.interrupted).name
        run.say(
            f"slope: interrupted ({name}) after step {run.step}; continue with --resume "
            f"{run.writer.out}"
            if run.step
            else f"slope: interrupted ({name}) before the first load step; nothing to resume"
        )
    elif run.stopped:
        run.say(
            f"slope: stopped after step {run.step} as asked (--stop-after); continue "
            f"with --resume {run.writer.out}"
        )


def summarise(
    run: Any,
    extremes: tuple[np.ndarray, tuple[float, list[float]], tuple[float, list[float]]],
    probes: Sequence[tuple[str, np.ndarray | None, np.ndarray, str, Any]],
    figure_time: float = 0.0,
    colour_range: tuple[float, float] | None = None,
    path: dict | None = None,
) -> dict:
    """The summary dict of a run at its last converged state (collective); ``extremes`` and
    ``probes`` from :class:`~dolfinx_granular.slope.model.SlopeModel`, the figure's time and
    colour range from :func:`draw_figure`, ``path`` from
    :func:`~dolfinx_granular.slope.path.path_summary` (computed here if not given)."""
    o = run.options
    return {
        **_how_it_ran(run),
        **_final_state(run, extremes),
        **_timings(run, figure_time),
        "step_info": run.step_info,
        # the figure's colour bar (MPa), which spans the Gauss-point extremes its markers name
        "figure_colour_range": colour_range,
        "probes": {label: {"point": xp.tolist(), "F": Fp.tolist()} for label, xp, Fp, *_ in probes},
        # path following (SlopeOptions.path_following): the peak, the critical points, the path
        "path_following": path_summary(
            run.arclength, run.step_info, o.geometry.footing_load, o.path_following
        )
        if path is None
        else path,
    }


def _how_it_ran(run: Any) -> dict:
    """The summary's record of the load path: steps, status, failure, cut-backs, options."""
    failed = run.failed
    footing_load = limit_footing_load(failed, run)
    if footing_load is not None:  # the limit load's record with the load carried, in N/m
        failed = {**failed, "limit_load": {**failed["limit_load"], "footing_load": footing_load}}
    status = run_status(run)
    o = run.options
    return {
        "ranks": run.comm.size,
        "steps": run.n_nominal,
        "completed_steps": run.step,
        "status": status,
        "converged": status == "converged",
        "failed": failed,
        # the signal that stopped an interrupted run (SIGINT, SIGTERM)
        "interrupted_by": signal.Signals(run.interrupted).name if run.interrupted else None,
        "resumed_from": run.resumed_from,
        "cutbacks": [c.as_dict() for c in run.stepper.cutbacks],
        "load_factor": o.load_factor,
        # the slope's run over its rise and its angle (degrees); restart.npz holds the geometry
        "slope_ratio": o.geometry.slope_ratio,
        "slope_angle": o.geometry.slope_angle,
        "stabilise": o.stabilise,
        "allow_overlaps": o.allow_overlaps,
    }


def _final_state(run: Any, extremes: tuple) -> dict:
    """The summary's record of the last converged state (collective) and the material's
    options."""
    m, comm, o, info = run.model, run.comm, run.options, run.step_info
    _, (vmax, xmax), (vmin, xmin) = extremes
    prestress = getattr(run.law, "prestress", None)
    return {
        "open_points": m.open_points(),
        # at the last converged step: points whose tangent lost strong ellipticity
        "non_elliptic_points": info[-1].get("non_elliptic_points", 0) if info else 0,
        # largest |nodal force of the stabilising stress| / |external load| over the steps
        "stabiliser_force_max": max([s.get("stabiliser_force", 0.0) for s in info] or [0.0]),
        "iterations": run.iterations,
        "footing_settlement": m.settlement(),
        "footing_settlement_point": m.edge.tolist(),
        "friction": o.friction,
        "rolling_friction": o.rolling_friction,
        "rve": o.rve,
        # Pa: the packing compressed and relaxed to it, held by the boundaries (0: none)
        "confinement": o.confinement,
        "gravity_steps": o.gravity_steps,
        "unload": o.unload,
        # J per metre of slope: the energy the contacts' sliding dissipated (0 without friction)
        "dissipated_energy": m.material.dissipated_energy(),
        # after the footing load came off again (``--unload``): the settlement it left behind,
        # beyond that of the soil's own weight (m, negative = down)
        "permanent_settlement": _permanent_settlement(run),
        "max_von_mises": vmax,
        "max_von_mises_location": xmax,
        "min_von_mises": vmin,
        "min_von_mises_location": xmin,
        "min_singular_value_F": m.min_singular_value(),
        "particles": run.packing.n_particles,
        "rves": comm.allreduce(m.material.n_points),
        # the reference state of the RVE: P(I) in Pa, and |P(I)| / |C|
        "prestress": None if prestress is None else prestress.tolist(),
        "prestress_ratio": getattr(run.law, "prestress_ratio", None),
        # where the contact law leaves its range: overlap / smaller radius (validity.py)
        "overlap_validity": _overlap_validity(run),
    }


def _timings(run: Any, figure_time: float) -> dict:
    """The summary's wall and CPU seconds (collective): the run, the RVEs per rank and their
    balance, assembly, solve and output."""
    m, comm = run.model, run.comm
    t = {k: comm.allreduce(v, op=MPI.MAX) for k, v in m.solver.timings.items()}
    rve_ranks = comm.allgather(float(m.material.timings["rve"]))
    rve_cpu = comm.allgather(float(m.material.clock.cpu["rve"]))
    updates = comm.allgather(m.material.update_seconds)
    return {
        "wall_time": time.perf_counter() - run.t_start,
        "time_setup": run.setup_time,
        "time_rve": t["rve"],
        "time_rve_kernel": max(rve_ranks),
        # each rank's RVE seconds (wall, its own points' law evaluations) and max / mean: how
        # evenly the points' work divides (1: evenly)
        "time_rve_ranks": rve_ranks,
        "rve_imbalance": rve_imbalance(rve_ranks),
        # CPU seconds alike (what a shared machine's load does not inflate)
        "time_rve_ranks_cpu": rve_cpu,
        "rve_imbalance_cpu": rve_imbalance(rve_cpu),
        # the same per evaluation (every rank waits for the slowest at each one): the sum over
        # the evaluations of the slowest rank's seconds over that of the ranks' mean
        "rve_imbalance_per_update": rve_imbalance_per_update(updates),
        "time_assembly": t["assembly"],
        "time_solve": t["solve"],
        "time_output": run.time_output + figure_time,
    }


def rve_imbalance(seconds: Sequence[float]) -> float:
    """max / mean of the ranks' RVE seconds (1.0: evenly divided, or no time at all)."""
    mean = float(np.mean(seconds))
    return float(np.max(seconds)) / mean if mean > 0.0 else 1.0


def rve_imbalance_per_update(per_rank: Sequence[Sequence[float]]) -> float | None:
    """sum over the updates of the slowest rank's RVE seconds / sum of the ranks' mean: at every
    update the ranks wait for the slowest (1.0: evenly divided); None if the ranks counted
    different numbers of updates."""
    if len({len(u) for u in per_rank}) != 1:
        return None
    t = np.array(per_rank, dtype=float).reshape(len(per_rank), -1)
    mean = t.mean(axis=0).sum()
    return float(t.max(axis=0).sum() / mean) if mean > 0.0 else 1.0


def run_status(run: Any) -> str:
    """``failed`` (a phase gave up), ``interrupted`` (SIGINT/SIGTERM), ``stopped``
    (``--stop-after``) or ``converged``."""
    if run.failed:
        return "failed"
    if run.interrupted:
        return "interrupted"
    return "stopped" if run.stopped else "converged"


def _overlap_validity(run):
    """The last state's validity measure and the first step whose overlaps passed the
    threshold (None: none did); None for a law without disks (collective)."""
    entry = run.model.overlap_validity()
    if entry is None:
        return None
    beyond = [s["step"] for s in run.step_info if s.get("overlap_points_above")]
    return {**entry, "first_step_beyond": beyond[0] if beyond else None}


def _permanent_settlement(run):
    info = run.step_info
    if not (info and info[-1]["phase"] == "unloading" and info[-1]["t"] >= 1.0):
        return None
    gravity = next(s for s in info if s["phase"] == "gravity" and s["t"] >= 1.0)
    return info[-1]["settlement"] - gravity["settlement"]


def draw_figure(
    run: Any,
    path: str | PathLike[str],
    data: tuple[np.ndarray, ...],
    extremes: tuple[np.ndarray, tuple[float, list[float]], tuple[float, list[float]]],
    probes: Sequence[tuple[str, np.ndarray | None, np.ndarray, str, Any]],
) -> tuple[float, tuple[float, float]]:
    """Figure 7 on rank 0: von Mises on the deformed slope, the extremes and four probe RVEs'
    force networks. Returns the seconds it took and the colour bar's range (MPa)."""
    t0 = time.perf_counter()
    _, (vmax, xmax), (vmin, xmin) = extremes
    markers = [(label, xp, text) for label, xp, _, text, _ in probes]
    markers[0] = ("A", xmax, f"max {vmax / 1e6:.3f} MPa")
    markers.append(("min", xmin, f"{vmin / 1e6:.3f} MPa"))
    insets = [
        (label, run.law, Fp, f"{text}, x = ({xp[0]:.1f}, {xp[1]:.1f}) m", state)
        for label, xp, Fp, text, state in probes
    ]
    settlement = run.step_info[-1]["settlement"] if run.step_info else 0.0
    colour_range = plot_slope(
        path,
        data,
        markers,
        insets,
        value_range=(vmin, vmax),
        title=f"step {run.step}: settlement {settlement:.3f} m, "
        f"{run.packing.n_particles} particles, deformation x1{_overlap_title(run)}",
    )
    return time.perf_counter() - t0, colour_range


def _overlap_title(run):
    """``; overlaps > 10 % of r at 89 % of the points`` for the figure's title ('' without)."""
    info = run.step_info[-1] if run.step_info else {}
    if "overlap_fraction_above" not in info:
        return ""
    return (
        f"; overlaps > {100 * OVERLAP_THRESHOLD:g} % of r at "
        f"{100 * info['overlap_fraction_above']:.3g} % of the points"
    )


def load_settlement_curve(
    step_info: Iterable[Mapping[str, Any]],
) -> tuple[np.ndarray, np.ndarray]:
    """(settlement (m), footing load (N/m)) of the converged steps from the gravity state on
    (loading, and unloading where there is one), signed as in the log and ``summary.json``:
    negative = downward."""
    steps = [s for s in step_info if s["phase"] != "gravity" or s["t"] >= 1.0]
    return (
        np.array([s["settlement"] for s in steps]),
        np.array([s["footing_load"] for s in steps]),
    )


def draw_load_settlement(run: Any, path: str | PathLike[str]) -> None:
    """``load_settlement.png``: the footing's load-settlement path (with its hysteresis when the
    load came off again), or the gravity factor against the settlement when the weight was
    taken by path following; rank 0."""
    o = run.options
    law = f"Coulomb friction mu = {o.friction:g}" if o.friction > 0 else "frictionless contacts"
    if o.rolling_friction > 0:
        law += f", rolling friction mu_r = {o.rolling_friction:g}"
    axis = {}
    if o.path_following == "gravity":
        settlement = [s["settlement"] for s in run.step_info]
        load = [s["gravity"] for s in run.step_info]
        axis = {"load_label": "gravity factor (x the weight)", "load_unit": 1.0}
    else:
        settlement, load = load_settlement_curve(run.step_info)
    plot_load_settlement(
        path,
        [(law, settlement, load, {"marker": "o", "ms": 3})],
        title=f"slope, {run.packing.n_particles}-particle RVE, {law} (negative = downward, "
        "as in summary.json)",
        **axis,
    )
