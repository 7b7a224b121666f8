# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # The slope's collapse: load control against path following, on two meshes
#
# Under load control the doubled footing load stops at the slope's limit load: past it no
# equilibrium carries a larger load. Path following (arc length) goes through the peak and down
# the softening branch. This study runs both, on the 380-cell mesh and on the 1520-cell one (the
# softening branch depends on the mesh: deformation localises in a band one element wide where
# the RVEs have lost strong ellipticity), and the uplift case by path following.
#
#     mpirun -n 2 python demos/slope_collapse.py [--particles 700] [--meshes 1 2] [--out DIR]
#         [--force]
#
# ``--small`` (or ``DEMO_SMALL=1``): 70 particles (seed 1), 4 footing steps, the 380-cell mesh
# only, written to ``results/slope_collapse-small`` by default (else ``results/slope_collapse``).
#
# Writes ``collapse.png`` (load-settlement curves, and how the RVEs that lost ellipticity spread
# along the path), ``collapse.csv`` (every converged state of every run) and ``collapse.json``
# (peak loads, critical points, increments, wall times), and each run's own output folder
# (``load_control_380/``, ``path_380/``, ...). An ``--out`` that holds a study is refused (exit
# status 2) unless ``--force``, which replaces those files and no others.

# %%
from __future__ import annotations

import os
import sys
import time

from dolfinx_granular import generate_packing
from dolfinx_granular.io.commandline import Parser
from dolfinx_granular.io.outfolder import claim_or_refuse
from dolfinx_granular.io.runwriter import RunWriter
from dolfinx_granular.slope import SlopeGeometry, SlopeOptions, run_slope
from dolfinx_granular.slope.run import RUN_FILES

from mpi4py import MPI

# %% [markdown]
# ## The runs
#
# One packing for all runs; the mesh refinement K multiplies the columns and rows (K² x 380
# cells); the first footing increment is the nominal step of ``steps``.

#: the files it writes in --out (what --force replaces): its own, and every slope run's in the
#: runs' folders (whatever meshes an earlier study took)
FILES = ("collapse.csv", "collapse.json", "collapse.png") + tuple(
    f"{run}_[0-9]*/{name}" for run in ("load_control", "path", "uplift_path") for name in RUN_FILES
)


def runs(meshes, steps):
    """(name, options) of every run of the study."""
    out = []
    for k in meshes:
        g = SlopeGeometry().refined(k)
        out.append(
            (f"load_control_{g.n_cells}", SlopeOptions(steps=steps, load_factor=2.0, geometry=g))
        )
        out.append(
            (
                f"path_{g.n_cells}",
                SlopeOptions(steps=steps, load_factor=2.0, path_following=True, geometry=g),
            )
        )
    # the uplift's load levels off over a long way before its peak: more increments
    g = SlopeGeometry().refined(meshes[0])
    out.append(
        (
            f"uplift_path_{g.n_cells}",
            SlopeOptions(
                steps=steps, load_factor=-0.25, path_following=True, max_increments=300, geometry=g
            ),
        )
    )
    return out


def run_all(packing, meshes, steps, out, comm, say):
    results = {}
    for name, options in runs(meshes, steps):  # (the folder claimed: no earlier run's files)
        t0 = time.perf_counter()
        s = run_slope(
            packing, options, out=os.path.join(out, name), comm=comm, figure=False, verbose=False
        )
        wall = time.perf_counter() - t0
        results[name] = {"summary": s, "wall": wall, "cells": options.geometry.n_cells}
        say(f"{name}: {s['status']}, {s['completed_steps']} steps, {wall:.1f} s")
    return results


# %% [markdown]
# ## What to look at
#
# The load-settlement curves of the loaded footing edge (load control and path following on the
# same axes), the peak of each path, and the RVEs whose tangent has lost strong ellipticity
# along each path.


# %%
def curve(summary):
    """Settlement (m), footing load (MN/m) and non-elliptic RVEs of the footing steps, signed
    as in summary.json and the log (negative = downward)."""
    steps = [s for s in summary["step_info"] if s["phase"] == "footing"]
    return (
        [s["settlement"] for s in steps],
        [s["footing_load"] / 1e6 for s in steps],
        [s["non_elliptic_points"] for s in steps],
    )


def figure(results, path):
    # a Figure of its own, no pyplot: savefig renders the PNG with Agg whatever the backend
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 4.6))
    ax1, ax2 = fig.subplots(1, 2)
    for name, r in results.items():
        if name.startswith("uplift"):
            continue
        settle, load, non_elliptic = curve(r["summary"])
        style = "--o" if name.startswith("load") else "-"
        label = (
            f"{'load control' if name.startswith('load') else 'path following'}, {r['cells']} cells"
        )
        ax1.plot(settle, load, style, ms=3, label=label)
        if not name.startswith("load"):
            ax2.plot(range(1, len(load) + 1), non_elliptic, label=label)
    ax1.set_xlabel("settlement of the loaded footing edge (m, negative = down)")
    ax1.set_ylabel("footing load (MN/m, negative = down)")
    ax1.set_title("doubled footing load: the limit load and past it", fontsize=10)
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3)
    ax2.set_xlabel("path increment")
    ax2.set_ylabel("RVEs that lost strong ellipticity")
    ax2.set_title("loss of ellipticity along the path", fontsize=10)
    ax2.legend(fontsize=8)
    ax2.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def records(results):
    """Rows for collapse.csv and the study's summary dict."""
    rows, summary = [], {}
    for name, r in results.items():
        s = r["summary"]
        for k, (settle, load, ne) in enumerate(zip(*curve(s)), start=1):
            rows.append((name, r["cells"], k, settle, load, ne))
        path = s.get("path_following") or {}
        summary[name] = {
            "cells": r["cells"],
            "status": s["status"],
            "wall_time": r["wall"],
            "ranks": s["ranks"],
            "completed_steps": s["completed_steps"],
            "iterations": sum(s["iterations"]),
            "peak": path.get("peak"),
            "critical_points": path.get("critical_points"),
            "stopped": path.get("stopped") or s.get("failed"),
            "limit_load": (s["failed"] or {}).get("limit_load"),
        }
    return rows, summary


# %%
#: the reduced run of ``--small``: one 380-cell mesh, a 70-particle packing, 4 footing steps
SMALL = dict(particles=70, seed=1, steps=4, meshes=[1])


def parse_args(argv=None):
    """The options, ``--small``'s where not given; ``out`` resolved
    (``results/slope_collapse[-small]``)."""
    p = Parser(
        description="The slope's collapse: load control and path "
        "following on two meshes, and the uplift."
    )
    p.add_argument("--particles", type=int, default=700)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--steps", type=int, default=20, help="nominal footing steps")
    p.add_argument("--meshes", type=int, nargs="+", default=[1, 2], help="refinements K")
    p.add_output("slope_collapse", f"reduced run (tests; also DEMO_SMALL=1): {SMALL}, unless given")
    if p.parse_args(argv).small:
        p.set_defaults(**SMALL)
    return p.parse_args(argv)


def main(argv=None):
    a = parse_args(argv)
    comm = MPI.COMM_WORLD
    if claim_or_refuse(a.out, FILES, a.force, "slope_collapse", comm):  # (before any work)
        return 2
    say = (lambda *x: print(*x, flush=True)) if comm.rank == 0 else (lambda *x: None)
    packing = comm.bcast(generate_packing(a.particles, seed=a.seed) if comm.rank == 0 else None)
    results = run_all(packing, a.meshes, a.steps, a.out, comm, say)
    if comm.rank == 0:
        write_study(a.out, results, say)
    return 0


def write_study(out, results, say):
    """collapse.csv, collapse.json and collapse.png (rank 0), and a line per run."""
    rows, summary = records(results)
    writer = RunWriter(out, MPI.COMM_SELF)  # (atomic files, floats to 17 digits)
    writer.csv(
        "collapse.csv",
        ["run", "cells", "step", "settlement_m", "footing_load_MN_per_m", "non_elliptic_points"],
        rows,
    )
    writer.json("collapse.json", summary)
    figure(results, os.path.join(out, "collapse.png"))
    for name, s in summary.items():
        peak = s["peak"] or {}
        say(
            f"{name}: {s['completed_steps']} steps, peak x{abs(peak.get('load_factor', 0)):.4g}"
            f", {s['wall_time']:.0f} s on {s['ranks']} rank(s); {s['stopped']}"
        )


if __name__ == "__main__":
    sys.exit(main())
