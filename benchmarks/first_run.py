"""The first run after set-up: how much of the slope demo's set-up is compiling, with and
without the set-up's warm-up (``python -m dolfinx_granular.warmup``).

Run: ``python benchmarks/first_run.py [--out docs] [--particles 700]`` with any stack's Python;
for every installed stack of this checkout (``.venv``, ``.venv-current``), from empty compiler
caches (``NUMBA_CACHE_DIR`` and ``XDG_CACHE_HOME`` point to empty folders, as after a fresh
clone):

1. **without the warm-up**: the demo (``demos/slope.py`` on 2 ranks, ``--no-figure``) twice: the
   first run compiles the Numba kernels and FFCx forms, the second finds them cached;
2. **with the warm-up**: ``python -m dolfinx_granular.warmup`` twice (the first fills the caches,
   the second finds them current and returns), then the demo twice;
3. **where the set-up goes**: the set-up's phases, serially, once from empty caches and once
   more with the caches that run filled.

Set-up is the demo's own ``time_setup`` (packing generation, meshing, forms, the RVE's first
evaluation), total its ``wall_time``; seconds of wall time. The machine's load average is stated,
since other processes share its cores. Writes the section "The first run after set-up" of
``OUT/performance.md`` (between the markers below, the rest of the file untouched) and
``OUT/first_run.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

from sections import command_line, markers, write_section
from stacks import ROOT, installed_stacks, run_slope

BEGIN, END = markers("first_run.py")

# the slope's set-up in phases (serial), timed: one JSON line of {phase: wall seconds}
_PHASES = """
import json, sys, time
import dolfinx_granular
from mpi4py import MPI
from dolfinx_granular.packings.generation import generate_packing
from dolfinx_granular.slope import SlopeOptions
from dolfinx_granular.slope.model import SlopeModel
t, out = [time.perf_counter()], {}
def lap(name):
    out[name] = time.perf_counter() - t[0]
    t[0] = time.perf_counter()
packing = generate_packing(int(sys.argv[1]), seed=0)
lap("packing generation")
options = SlopeOptions()
law = options.law(packing)
lap("RVE: candidate contacts, P(I)")
SlopeModel(MPI.COMM_SELF, law, options.geometry)
lap("mesh, material, forms")
print(json.dumps(out))
"""


def timed_warmup(stack, env) -> float:
    """Wall seconds of ``python -m dolfinx_granular.warmup`` with the stack's Python."""
    t0 = time.perf_counter()
    subprocess.run(
        [stack.python, "-m", "dolfinx_granular.warmup"],
        cwd=ROOT,
        env={**os.environ, **env},
        check=True,
        capture_output=True,
        timeout=3600,
    )
    return time.perf_counter() - t0


def phases(stack, workdir, particles) -> dict:
    """The set-up's phases (wall s) from empty caches, then again with the caches filled."""
    env = {
        **os.environ,
        "NUMBA_CACHE_DIR": os.path.join(workdir, "numba"),
        "XDG_CACHE_HOME": os.path.join(workdir, "xdg"),
    }
    found = {"stack": stack.name}
    for caches in ("empty", "filled"):
        proc = subprocess.run(
            [stack.python, "-c", _PHASES, str(particles)],
            cwd=ROOT,
            env=env,
            check=True,
            capture_output=True,
            text=True,
            timeout=3600,
        )
        found[caches] = json.loads(proc.stdout.strip().splitlines()[-1])
    return found


def measure(stack, workdir, warm, particles) -> dict:
    """From empty caches: the warm-up twice (if ``warm``), then the demo twice on 2 ranks."""
    env = {
        "NUMBA_CACHE_DIR": os.path.join(workdir, "numba"),
        "XDG_CACHE_HOME": os.path.join(workdir, "xdg"),
    }
    row = {"stack": stack.name, "warm_up": warm, "load_before": os.getloadavg()[0]}
    if warm:
        row["warmup_s"] = [timed_warmup(stack, env) for _ in range(2)]
    for run in ("first", "second"):
        s = run_slope(stack, os.path.join(workdir, run), "--particles", particles, ranks=2, env=env)
        row[run] = {"setup_s": s["time_setup"], "total_s": s["wall_time"]}
    row["load_after"] = os.getloadavg()[0]
    return row


def _runs_table(rows) -> list[str]:
    """One row per stack and variant: warm-up, first and second run."""
    lines = [
        "| stack | warm-up: first / again (s) | 1st run: set-up / total (s) | "
        "2nd run: set-up / total (s) | load average |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        warm = "/".join(f"{t:.1f}" for t in r["warmup_s"]) if r["warm_up"] else "none"
        runs = [f"{r[k]['setup_s']:.1f} / {r[k]['total_s']:.1f}" for k in ("first", "second")]
        load = f"{r['load_before']:.1f} .. {r['load_after']:.1f}"
        lines.append(f"| {r['stack']} | {warm} | {runs[0]} | {runs[1]} | {load} |")
    return lines


def _phases_table(found) -> list[str]:
    """One row per set-up phase, a column per stack and cache state."""
    names = list(found[0]["empty"]) if found else []
    head = "".join(f" {f['stack']}: empty / filled caches (s) |" for f in found)
    lines = ["| phase |" + head, "|---|" + "---|" * len(found)]
    for name in names + ["sum"]:
        cells = []
        for f in found:
            e, w = (
                (sum(f["empty"].values()), sum(f["filled"].values()))
                if name == "sum"
                else (f["empty"][name], f["filled"][name])
            )
            cells.append(f" {e:.1f} / {w:.1f} |")
        lines.append(f"| {name} |" + "".join(cells))
    return lines


def markdown(rows, found, particles, command, minutes) -> str:
    """The section: the runs' table, then where the set-up goes."""
    lines = [
        BEGIN,
        "## 8. The first run after set-up",
        "",
        f"Generated by `{command}` on {time.strftime('%Y-%m-%d %H:%M')} in {minutes:.1f} min.",
        "",
        f"The slope demo ({particles} particles, 2 ranks, `--no-figure`) from empty compiler "
        "caches, as after a fresh clone, without and with the set-up's warm-up "
        "(`python -m dolfinx_granular.warmup`, run by `scripts/setup.sh` and "
        "`scripts/setup-current.sh`). Seconds of wall time; set-up is the demo's own (packing, "
        "mesh, forms, the RVE's first evaluation), total its whole run without the figure.",
        "",
        *_runs_table(rows),
        "",
        "**Where the set-up goes** (serial, one rank): each phase from empty caches, then with "
        "the caches that run filled; the difference is compiling (the generator's and the "
        "RVE's Numba kernels, the slope's FFCx forms).",
        "",
        *_phases_table(found),
        "",
        "The warm-up runs the package's real code paths once on a 30-disk packing (the API's "
        "kernels, the slope's gravity step frictionless and with friction), so that Numba's "
        "cache (`cache=True`, keyed to each source file's modification time and the CPU) and "
        "FFCx's (`~/.cache/fenics`) hold everything the demo compiles. Repeated, it compares "
        "a record of the sources, interpreter and cache locations and returns; `make demo`, "
        "`make test` and `make bench` run it (`make warm`), so that an edited source is "
        "compiled before the run, not in it.",
        "",
        END,
    ]
    return "\n".join(lines) + "\n"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=os.path.join(ROOT, "docs"))
    p.add_argument("--particles", type=int, default=700)
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    rows, found = [], []
    for stack in installed_stacks():
        for warm in (False, True):
            with tempfile.TemporaryDirectory(prefix="first-run-") as workdir:
                rows.append(measure(stack, workdir, warm, a.particles))
                print(json.dumps(rows[-1]), flush=True)
        with tempfile.TemporaryDirectory(prefix="first-run-") as workdir:
            found.append(phases(stack, workdir, a.particles))
            print(json.dumps(found[-1]), flush=True)
    os.makedirs(a.out, exist_ok=True)
    with open(os.path.join(a.out, "first_run.json"), "w") as f:
        json.dump({"runs": rows, "phases": found}, f, indent=1)
    minutes = (time.perf_counter() - t0) / 60
    section = markdown(rows, found, a.particles, command_line("first_run.py", argv), minutes)
    write_section(os.path.join(a.out, "performance.md"), section)
    return 0


if __name__ == "__main__":
    sys.exit(main())
