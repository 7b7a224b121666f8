"""Performance report: speed against error, measured on the machine at hand.

    python benchmarks/report.py [--out docs] [--seeds 5] [--steps 20] [--repeats 3] [--tiny]
    make bench            (make bench-current: the same on the DOLFINx 0.11 stack)

Writes ``OUT/performance.md`` and its figures ``OUT/perf_*.png`` (and the raw numbers to
``results/performance.json``, or ``OUT/performance.json`` for another ``--out``); every number in
them is measured in that run. The sections that other scripts keep in ``performance.md``
(between their markers: ``benchmarks/stacks.py``'s, ``benchmarks/friction_path.py``'s) are carried
over. Sections:

1. kernel: µs per quadrature point (P only, P and tangent) for 70 ... 2800 particles beside plain
   NumPy and a straightforward Numba loop (``benchmarks/kernel.py``), contacts per second, and the
   fraction of the measured floating-point peak (``benchmarks/flops.py``);
2. one Newton iteration on the slope: F evaluation, RVE kernel, assembly, linear solve, the rest;
   beside the same slope with a UFL small-strain linear material (the isotropic projection of
   the eq. 15 modulus), same mesh and solver;
3. scaling: 1 vs 2 MPI ranks, and mesh refinement 380 -> 1520 -> 6080 cells;
4. speed against error: settlement and max von Mises against particle count (several seeds) and
   against model level (``dolfinx_granular.laws.levels``), error relative to the largest RVE;
5. paying only for what is used: stress-only residuals and post-processing, force networks only
   where a figure shows them.

This file is the command line and the order of the work; the pieces, one job each:
``report_slope`` (one slope run through the library's ``SlopeRun`` and its factories, timed by
the solver's and the material's own clocks; the MPI worker), ``flops`` (the machine's FMA
peak), ``report_measure`` (kernel, post-processing, machine), ``report_studies`` (which slope
runs, repeats), ``report_tables`` (derived numbers), ``report_figures``, ``report_markdown``.
``--tiny`` is a reduced run for the tests.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import tempfile
import time

import dolfinx_granular  # noqa: F401  (first: loads the MPI library of DOLFINx's PyPI wheel)
from dolfinx_granular.fem.compat import mpi_command
from dolfinx_granular.laws.levels import isotropic_lame
from dolfinx_granular.packings.cache import PackingCache

import flops  # benchmarks/flops.py: the machine's FMA peak
import report_figures
import report_markdown
import report_measure
import report_studies
import report_tables
from sections import command_line

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

FULL = dict(
    kernel_sizes=(70, 350, 700, 1400, 2800),
    kernel_points=2000,
    kernel_repeats=5,
    error_sizes=(70, 350, 700, 1400, 2800),
    seeds=5,
    steps=20,
    particles=700,
    refinements=(1, 2, 4),
    repeats=3,
    level_tols=(1e-3, 1e-2),
)
TINY = dict(
    kernel_sizes=(70, 140),
    kernel_points=20,
    kernel_repeats=1,
    error_sizes=(70, 140),
    seeds=1,
    steps=2,
    particles=70,
    refinements=(1, 2),
    repeats=1,
    level_tols=(1e-2,),
)


def run_all(cfg, log=print) -> dict:
    """Every measurement of the report; returns a dict of results (plain data)."""
    res = {
        "config": {k: list(v) if isinstance(v, tuple) else v for k, v in cfg.items()},
        "load_start": os.getloadavg(),
    }
    with tempfile.TemporaryDirectory(prefix="perf_report_") as tmp:
        packings = PackingCache(tmp)  # fresh: generation times are this machine's
        log("peak ...")
        res["peak"] = flops.measure()
        log(f"  {res['peak']['gflops_per_core']:.1f} GFLOP/s per core")
        log("kernel ...")
        res["kernel"] = report_measure.kernel_rows(
            cfg["kernel_sizes"], cfg["kernel_points"], cfg["kernel_repeats"], packings, res["peak"]
        )
        n0 = cfg["particles"]
        pk0 = packings.get(n0, 0)
        runs = report_studies.iteration_runs(cfg, pk0, log)
        res["iteration"] = report_tables.iteration_summary(runs)
        res["matched_linear"] = report_tables.matched_linear(
            res["iteration"]["taylor"], res["iteration"]["ufl_linear"]
        )
        lame = isotropic_lame(runs["taylor"][0]["_rve"].small_strain_modulus())
        res["ufl_lame"] = [float(x) for x in lame]  # (lam, mu) in Pa of the UFL yardstick
        final = runs["taylor"][0]  # its final state: F at every point and the law
        res.update(
            report_measure.final_state_costs(final["_rve"], final["_F"], cfg["kernel_repeats"])
        )
        res["ranks"] = report_studies.rank_runs(cfg, packings.path(n0, 0), log)
        res["refinement"] = report_studies.refinement_runs(cfg, pk0, log)
        res["sizes"] = report_studies.size_runs(cfg, packings, log)
        res["adaptive_bounds"] = report_studies.adaptive_bounds(pk0)
        res["levels"] = report_studies.level_runs(cfg, packings, log)
    res["load_end"] = os.getloadavg()
    return res


def describe(res, command, elapsed):
    """Add the machine, the versions, the date and the command line to the results."""
    launcher = mpi_command(2)
    res.update(
        versions=report_measure.versions(),
        cpu=report_measure.cpu_model(),
        lu=report_measure.lu_solver(),
        mpi_launcher=os.path.basename(launcher[0]) if launcher else "mpirun",
        date=datetime.datetime.now().strftime("%Y-%m-%d %H:%M"),
        command=command,
        elapsed=elapsed,
    )


def render(res, out) -> str:
    """Figures and ``performance.md`` of the results ``res`` in ``out``; returns the path."""
    os.makedirs(out, exist_ok=True)
    paths = report_figures.make_figures(res, out)
    res["targets"] = report_tables.targets(res)
    path = os.path.join(out, "performance.md")
    report_markdown.write(
        path, report_markdown.markdown(res, paths, res["command"], res["elapsed"])
    )
    return path


def parse(argv):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=os.path.join(ROOT, "docs"), help="output folder (docs/)")
    p.add_argument("--seeds", type=int, help="packings per particle count (default 5)")
    p.add_argument("--steps", type=int, help="footing load steps of each slope run (default 20)")
    p.add_argument("--repeats", type=int, help="repeats of the timed slope runs (default 3)")
    p.add_argument("--tiny", action="store_true", help="reduced sizes for the tests")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument(
        "--json",
        help="raw results of the run (default: results/performance.json "
        "for the report in docs/, else OUT/performance.json, so that `make "
        "bench-current` keeps `make bench`'s)",
    )
    p.add_argument(
        "--render",
        metavar="JSON",
        help="only redraw figures and markdown from the "
        "performance.json of an earlier run (no measurement)",
    )
    a = p.parse_args(argv)
    if a.json is None:
        docs = os.path.realpath(a.out) == os.path.realpath(os.path.join(ROOT, "docs"))
        a.json = os.path.join(ROOT, "results") if docs else a.out
        a.json = os.path.join(a.json, "performance.json")
    return a


def main(argv=None) -> int:
    a = parse(argv)
    if a.render:
        with open(a.render) as f:
            res = json.load(f)
        res["ranks"] = {int(k): v for k, v in res["ranks"].items()}
        render(res, a.out)
        return 0
    cfg = dict(TINY if a.tiny else FULL, tiny=a.tiny)
    cfg.update(
        {k: getattr(a, k) for k in ("seeds", "steps", "repeats") if getattr(a, k) is not None}
    )
    log = (lambda *x: None) if a.quiet else (lambda *x: print(*x, flush=True))
    t0 = time.perf_counter()
    res = run_all(cfg, log)
    describe(res, command_line("report.py", argv), time.perf_counter() - t0)
    path = render(res, a.out)
    os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
    with open(a.json, "w") as f:
        json.dump(res, f, indent=1, default=float)
    log(f"wrote {path} in {(time.perf_counter() - t0) / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
