"""The report's slope studies: which runs, how many repeats, which run is kept.

Every function returns plain data (the dicts of :func:`report_slope.slope_run`, keys starting
with ``_`` removed unless said otherwise); ``log`` prints progress lines.
"""

from __future__ import annotations

import subprocess

from dolfinx_granular import AdaptiveRVE, TaylorRVE
from dolfinx_granular.slope.run import K_N

from report_slope import mpi_slope_run, slope_run
from report_tables import public

#: the levels of the Newton-iteration breakdown, in table order
ITERATION_LEVELS = ("taylor", "taylor_skip", "small_strain", "ufl_linear")


def iteration_runs(cfg, packing, log) -> dict:
    """``{level: [runs]}`` of :data:`ITERATION_LEVELS`, ``cfg["repeats"]`` interleaved repeats
    each (so that every level sees the same machine load) after a one-step warm-up of each (JIT
    compilation). The first Taylor run keeps its final F and law (``_F``, ``_rve``)."""
    log("slope warm-up (JIT) ...")
    for level in ITERATION_LEVELS:
        slope_run(packing, level, steps=1)
    runs = {level: [] for level in ITERATION_LEVELS}
    for rep in range(cfg["repeats"]):
        for level in ITERATION_LEVELS:
            log(f"slope {level} repeat {rep + 1} ...")
            keep = level == "taylor" and rep == 0
            runs[level].append(slope_run(packing, level, steps=cfg["steps"], keep=keep))
    return runs


def rank_runs(cfg, packing_file, log, bench_repeats=10) -> dict:
    """Taylor on 1 and 2 MPI ranks, up to 3 interleaved repeats each: ``{ranks: run}`` with the
    run of the fastest RVE kernel (wall), its ``rve_bench`` the best over the repeats and
    ``repeats`` their number, or ``{"error": message}`` if every attempt failed."""
    tries, errors = {1: [], 2: []}, {}
    for rep in range(max(1, min(cfg["repeats"], 3))):
        for ranks in (1, 2):  # interleaved, so that both see the same load
            log(f"slope on {ranks} rank(s) (MPI), repeat {rep + 1} ...")
            try:
                tries[ranks].append(
                    mpi_slope_run(
                        packing_file,
                        ranks,
                        level="taylor",
                        steps=cfg["steps"],
                        rve_bench=bench_repeats,
                    )
                )
            except (RuntimeError, subprocess.TimeoutExpired) as err:
                errors[ranks] = str(err)[-500:]
    out = {}
    for ranks, runs in tries.items():
        if not runs:
            out[ranks] = {"error": errors.get(ranks, "no run")}
            continue
        best = dict(min(runs, key=lambda r: r["times"]["kernel"]))
        best["rve_bench"] = min(r["rve_bench"] for r in runs)
        best["repeats"] = len(runs)
        out[ranks] = best
    return out


def refinement_runs(cfg, packing, log) -> list[dict]:
    """Taylor on the meshes refined by each factor of ``cfg["refinements"]``."""
    runs = []
    for refine in cfg["refinements"]:
        log(f"slope refined x{refine} ...")
        runs.append(public(slope_run(packing, "taylor", steps=cfg["steps"], refine=refine)))
    return runs


def size_runs(cfg, packings, log) -> list[dict]:
    """Taylor for every particle count of ``cfg["error_sizes"]`` and seed, each with the
    generation time of its packing (``generation_time``, s)."""
    runs = []
    for n in cfg["error_sizes"]:
        for seed in range(cfg["seeds"]):
            log(f"slope {n} particles seed {seed} ...")
            r = public(slope_run(packings.get(n, seed), "taylor", steps=cfg["steps"]))
            r["generation_time"] = packings.generation_time(n, seed)
            runs.append(r)
    return runs


def level_runs(cfg, packings, log) -> list[dict]:
    """Every model level (adaptive ones for each tolerance of ``cfg["level_tols"]``) on the
    ``cfg["particles"]`` packings of every seed."""
    specs = [("small_strain", None), ("ufl_linear", None), ("taylor_skip", None)]
    for tol in cfg["level_tols"]:
        specs += [("adaptive", tol), ("adaptive_strain", tol)]
    runs = []
    for level, tol in specs:
        for seed in range(cfg["seeds"]):
            log(f"slope level {level} tol {tol} seed {seed} ...")
            packing = packings.get(cfg["particles"], seed)
            runs.append(public(slope_run(packing, level, tol, steps=cfg["steps"])))
    return runs


def adaptive_bounds(packing, tol=0.01) -> dict:
    """The stretch bounds of AdaptiveRVE's contact test for ``packing``: the largest singular
    value of F it admits and the smallest one it requires."""
    bounds = AdaptiveRVE(TaylorRVE(packing, K_N), tol).stretch_bounds
    return {"smax_allowed": float(bounds[0]), "smin_required": float(bounds[1])}
