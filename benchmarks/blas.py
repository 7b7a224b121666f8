"""The platform's BLAS: which one is loaded, and what it does to the project's timings and answers.

Run: ``.venv/bin/python benchmarks/blas.py [--parts matmul,slope,finest,footing,demo,relaxed]
[--repeats 5] [--runs 2] [--save results/blas/NAME]``, then compare two saved runs (another
BLAS between them) with ``.venv/bin/python benchmarks/blas.py --compare A B``; ``--doc
docs/performance.md`` with it (A the reference BLAS, B OpenBLAS) writes section 11 there.

Debian's numpy, SciPy, PETSc and MUMPS link ``libblas.so.3`` and ``liblapack.so.3``, which
Debian's alternatives point to the reference BLAS (``libblas3``, ``liblapack3``) or, once
installed, to OpenBLAS (``libopenblas0-serial``: one thread, so one per MPI rank). Switch them
(as root) with ``update-alternatives --set libblas.so.3-x86_64-linux-gnu PATH`` and
``update-alternatives --set liblapack.so.3-x86_64-linux-gnu PATH`` (``--display`` lists the
paths), or for one process by ``LD_LIBRARY_PATH=/usr/lib/x86_64-linux-gnu/blas:/usr/lib/x86_64-
linux-gnu/lapack`` (the reference BLAS ahead of the alternative). The script reports the library
it actually loaded (the BLAS and LAPACK files mapped into this process, ``/proc/self/maps``),
and times:

- ``matmul``: a float64 1000 x 1000 matrix product (numpy), GFLOP/s on one core, best of
  ``--repeats``;
- ``slope``: the MUMPS LU of the slope's Jacobian on its finest mesh (``--refine 4``: 6,080 Q1
  cells, 24,320 RVEs of the shipped 700-disk packing) at u = 0 under the whole weight, serial:
  the first factorisation (analysis and numeric), a refactorisation (numeric only, as in each
  later Newton iteration) and one solve, best of ``--repeats``; its answer is the Newton step;
- ``finest``: ``mpirun -n 2 demos/slope.py --refine 4`` (MUMPS), wall time and the linear
  solves' time from its ``summary.json``, best of ``--runs``; answer: its settlement;
- ``footing``: ``mpirun -n 2 demos/footing3d.py`` (the standard run: 1000 spheres, GMRES + GAMG)
  and the same with ``--linear-solver direct`` (MUMPS), wall time, best of ``--runs``; answer:
  the settlement in its ``summary.json``;
- ``demo``: ``mpirun -n 2 demos/slope.py`` (``make demo``'s run), wall time and settlement;
- ``relaxed``: ``benchmarks/relaxed.py --points 30``, its ``relaxed P+A`` line (ms per point),
  best of ``--runs``; answer: W, P and A of the relaxed RVE at that benchmark's 30 points.

``--save PREFIX`` writes the figures to ``PREFIX.json`` and the answers' arrays to
``PREFIX.npz``; ``--compare`` prints both runs' figures side by side and the largest relative
difference of every answer. Timings are wall clock on a shared machine: read the best of the
repeats, and the load average printed with them.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # one core (the serial OpenBLAS has one)

from dolfinx_granular.timing import best_time  # noqa: E402

import numpy as np  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PARTS = ("matmul", "slope", "finest", "footing", "demo", "relaxed")
K_N = 2.8e7  # the slope's and benchmarks/relaxed.py's k_n (N/m²)
#: what the finest slope's run keeps of its summary.json
FINEST_KEYS = ("iterations", "time_rve", "time_assembly", "time_solve", "completed_steps")


def loaded_libraries(pid: str = "self") -> list[str]:
    """The BLAS and LAPACK files mapped into process ``pid`` (real paths, as the loader
    resolved Debian's alternatives)."""
    found = set()
    with open(f"/proc/{pid}/maps") as f:
        for line in f:
            path = line.split()[-1] if len(line.split()) >= 6 else ""
            if re.search(r"(blas|lapack)[^/]*\.so", os.path.basename(path)):
                found.add(path)
    return sorted(found)


def blas_name(libraries: list[str]) -> str:
    """'OpenBLAS (serial)', 'OpenBLAS (pthread)', 'reference' ... from the mapped files."""
    text = " ".join(libraries)
    for key, name in (
        ("openblas-serial", "OpenBLAS (serial)"),
        ("openblas-pthread", "OpenBLAS (pthread)"),
        ("openblas-openmp", "OpenBLAS (OpenMP)"),
        ("openblas", "OpenBLAS"),
        ("atlas", "ATLAS"),
        ("blis", "BLIS"),
        ("mkl", "MKL"),
        ("/blas/libblas", "reference"),
    ):
        if key in text:
            return name
    return "unknown"


def matmul(repeats, n=1000):
    """GFLOP/s of a float64 n x n matrix product (2 n³ flops), best of ``repeats``."""
    rng = np.random.default_rng(0)
    a, b = rng.random((n, n)), rng.random((n, n))
    a @ b
    t, _ = best_time(lambda: a @ b, repeats)
    return {"n": n, "s": t, "gflops": 2.0 * n**3 / t / 1e9}


def slope_factorisation(repeats, refine=4):
    """MUMPS LU of the finest slope's Jacobian at u = 0 under the whole weight (serial): times
    of the first factorisation, a refactorisation and a solve (best of ``repeats``), and the
    Newton step (the answer)."""
    from dolfinx_granular import TaylorRVE, reference_packing
    from dolfinx_granular.slope.geometry import SlopeGeometry
    from dolfinx_granular.slope.model import SlopeModel

    from mpi4py import MPI
    from petsc4py import PETSc

    t0 = time.perf_counter()
    model = SlopeModel(
        MPI.COMM_WORLD, TaylorRVE(reference_packing(), K_N), SlopeGeometry().refined(refine)
    )
    model.set_gravity(1.0)
    solver = model.solver
    x, b = solver.x, solver.b
    x.set(0.0)
    solver.residual(x, b)
    A = solver.jacobian(x)
    t_setup = time.perf_counter() - t0

    def ksp():
        k = PETSc.KSP().create(model.comm)
        k.setOperators(A)
        k.setType("preonly")
        k.getPC().setType("lu")
        k.getPC().setFactorSolverType("mumps")
        return k

    first, refact, solve = np.inf, np.inf, np.inf
    du = A.createVecRight()
    for _ in range(repeats):
        k = ksp()
        t = time.perf_counter()
        k.setUp()  # analysis + numeric factorisation
        first = min(first, time.perf_counter() - t)
        solver.jacobian(x, A)  # the same values reassembled: a new matrix state
        k.setOperators(A)
        t = time.perf_counter()
        k.setUp()  # numeric factorisation only (the pattern is unchanged)
        refact = min(refact, time.perf_counter() - t)
        t = time.perf_counter()
        k.solve(b, du)
        solve = min(solve, time.perf_counter() - t)
        k.destroy()
    step = -du.getArray().copy()  # the Newton step from u = 0
    out = {
        "refine": refine,
        "cells": model.mesh.topology.index_map(2).size_global,
        "dofs": A.getSize()[0],
        "rves": model.material.n_points,
        "setup_s": t_setup,
        "factorisation_s": first,
        "refactorisation_s": refact,
        "solve_s": solve,
    }
    model.solver.destroy()
    return out, {"slope_newton_step": step}


def run_command(cmd, ranks, check=True):
    """Run ``cmd`` (a list: a script and its arguments) with this Python, under ``ranks`` MPI
    ranks; its wall time (s) and output. ``check``: fail unless it exits with 0 (the slope's
    finest mesh stops short of the full load: exit 1)."""
    from dolfinx_granular.fem.compat import mpi_command

    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    full = [*(mpi_command(ranks) if ranks > 1 else []), sys.executable, *cmd]
    t = time.perf_counter()
    res = subprocess.run(full, cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if check and res.returncode != 0:
        raise RuntimeError(f"{' '.join(full)} failed:\n{res.stdout}\n{res.stderr}")
    return wall, res.stdout


def demo_runs(script, args, runs, key, keep=(), check=True):
    """Best wall time of ``mpirun -n 2 python <script> args --out TMP --force --no-figure``
    over ``runs`` runs, ``summary.json[key]`` of each run (they must agree) and the summary's
    ``keep`` entries of the fastest run."""
    walls, answers, kept = [], [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(runs):
            out = os.path.join(tmp, "run")
            argv = [script, *args, "--out", out, "--force", "--no-figure"]
            wall, _ = run_command(argv, 2, check)
            with open(os.path.join(out, "summary.json")) as f:
                s = json.load(f)
            answers.append(s[key])
            if not walls or wall < min(walls):
                kept = {k: s[k] for k in keep}
            walls.append(wall)
    return {"wall_s": min(walls), "walls_s": walls, key: answers[0], **kept}, answers


def relaxed(runs, points=30, particles=700):
    """Best 'relaxed P+A' (ms per point) of ``benchmarks/relaxed.py --points 30`` over ``runs``
    runs, and W, P, A of the relaxed RVE at that benchmark's points (computed here as it does:
    seed 0, committed at 0.5 % isotropic compression, steps of 1e-4)."""
    lines, ms = [], []
    for _ in range(runs):
        _, out = run_command(["benchmarks/relaxed.py", "--points", str(points)], 1)
        line = next(s for s in out.splitlines() if s.startswith("relaxed P+A"))
        lines.append(line.strip())
        ms.append(float(line.split()[2]))
    from dolfinx_granular import generate_packing
    from dolfinx_granular.laws.relaxed import RelaxedRVE, RelaxedState

    rve = RelaxedRVE(generate_packing(particles, seed=0), K_N)
    F0 = np.eye(2) * (1.0 - 0.005)
    _, _, _, one = rve.evaluate(F0[None], rve.initial_state(1))
    state = RelaxedState.concatenate([one] * points)
    d = np.random.default_rng(0).normal(size=(points, 2, 2))
    d /= np.linalg.norm(d, axis=(1, 2))[:, None, None]
    W, P, A, _ = rve.evaluate(F0[None] + 1e-4 * d, state)
    figures = {"points": points, "relaxed_ms_per_point": min(ms), "lines": lines}
    return figures, {"relaxed_W": W, "relaxed_P": P, "relaxed_A": A}


def save(prefix, figures, answers):
    """``PREFIX.json`` (the figures) and ``PREFIX.npz`` (the answers' arrays)."""
    os.makedirs(os.path.dirname(os.path.abspath(prefix)), exist_ok=True)
    with open(prefix + ".json", "w") as f:
        json.dump(figures, f, indent=1)
    np.savez(prefix + ".npz", **answers)


def measure(parts, repeats, runs, prefix=None):
    """The figures (a dict) and the answers (arrays) of ``parts``, saved under ``prefix`` after
    each part where given."""
    figures = {"libraries": loaded_libraries(), "load_start": os.getloadavg()}
    figures["blas"] = blas_name(figures["libraries"])
    print(f"BLAS: {figures['blas']}: {', '.join(figures['libraries'])}", flush=True)
    answers = {}
    if "matmul" in parts:
        figures["matmul"] = r = matmul(repeats)
        print(f"matmul {r['n']}x{r['n']} float64, one core: {r['gflops']:.2f} GFLOP/s", flush=True)
    if prefix:
        save(prefix, figures, answers)
    if "slope" in parts:
        figures["slope"], a = slope_factorisation(repeats)
        answers.update(a)
        r = figures["slope"]
        figures["libraries_after_petsc"] = loaded_libraries()
        print(
            f"slope --refine {r['refine']} ({r['cells']} cells, {r['dofs']} dofs), MUMPS, serial: "
            f"factorisation {r['factorisation_s']:.3f} s, refactorisation "
            f"{r['refactorisation_s']:.3f} s, solve {r['solve_s']:.4f} s",
            flush=True,
        )
    if prefix:
        save(prefix, figures, answers)
    if "finest" in parts:
        figures["finest"], s = demo_runs(
            "demos/slope.py",
            ["--refine", "4"],
            runs,
            "footing_settlement",
            FINEST_KEYS,
            check=False,
        )
        answers["finest"] = np.array(s)
        r = figures["finest"]
        print(
            f"slope --refine 4, 2 ranks, MUMPS: {r['wall_s']:.1f} s "
            f"(runs {', '.join(f'{w:.1f}' for w in r['walls_s'])}), linear solves "
            f"{r['time_solve']:.1f} s, {sum(r['iterations'])} Newton iterations, "
            f"settlement {s[0]!r} m",
            flush=True,
        )
    if prefix:
        save(prefix, figures, answers)
    if "footing" in parts:
        for solver in ("iterative", "direct"):
            name = f"footing_{solver}"
            figures[name], s = demo_runs(
                "demos/footing3d.py", ["--linear-solver", solver], runs, "settlement_m"
            )
            answers[name] = np.array(s)
            print(
                f"footing3d, 2 ranks, {solver}: {figures[name]['wall_s']:.1f} s "
                f"(runs {', '.join(f'{w:.1f}' for w in figures[name]['walls_s'])}), "
                f"settlement {s[0]!r} m",
                flush=True,
            )
    if prefix:
        save(prefix, figures, answers)
    if "demo" in parts:
        figures["demo"], s = demo_runs("demos/slope.py", [], runs, "footing_settlement")
        answers["demo"] = np.array(s)
        print(
            f"slope demo, 2 ranks: {figures['demo']['wall_s']:.1f} s "
            f"(runs {', '.join(f'{w:.1f}' for w in figures['demo']['walls_s'])}), "
            f"settlement {s[0]!r} m",
            flush=True,
        )
    if prefix:
        save(prefix, figures, answers)
    if "relaxed" in parts:
        figures["relaxed"], a = relaxed(runs)
        answers.update(a)
        print(
            f"benchmarks/relaxed.py --points 30: relaxed P+A "
            f"{figures['relaxed']['relaxed_ms_per_point']:.2f} ms/point (best of {runs})",
            flush=True,
        )
    figures["load_end"] = os.getloadavg()
    if prefix:
        save(prefix, figures, answers)
    print(f"load average: start {figures['load_start'][0]:.2f}, end {figures['load_end'][0]:.2f}")
    return figures, answers


def relative_difference(a, b):
    """max |a - b| / max |b|."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    scale = np.abs(b).max()
    return float(np.abs(a - b).max() / scale) if scale > 0 else float(np.abs(a - b).max())


#: (label, command, part, key, "faster when higher") of the compared figures
ROWS = [
    ("matmul 1000 x 1000, GFLOP/s", "numpy `a @ b`, float64, one core", "matmul", "gflops", True),
    ("slope `--refine 4`: MUMPS LU, analysis + numeric (s)", "in process, serial", "slope",
     "factorisation_s", False),
    ("slope `--refine 4`: MUMPS refactorisation (s)", "in process, serial", "slope",
     "refactorisation_s", False),
    ("slope `--refine 4`: one solve (s)", "in process, serial", "slope", "solve_s", False),
    ("slope `--refine 4`: the run, wall (s)", "`mpirun -n 2 python demos/slope.py --refine 4`",
     "finest", "wall_s", False),
    ("slope `--refine 4`: its linear solves (s)", "the same run's `summary.json` `time_solve`",
     "finest", "time_solve", False),
    ("3-D footing, GMRES + GAMG, wall (s)", "`mpirun -n 2 python demos/footing3d.py`",
     "footing_iterative", "wall_s", False),
    ("3-D footing, MUMPS, wall (s)", "the same with `--linear-solver direct`", "footing_direct",
     "wall_s", False),
    ("slope demo, wall (s)", "`mpirun -n 2 python demos/slope.py` (`make demo`)", "demo",
     "wall_s", False),
    ("relaxed P+A (ms per point)", "`python benchmarks/relaxed.py --points 30`", "relaxed",
     "relaxed_ms_per_point", False),
]  # fmt: skip
#: the answers, by their key in the saved arrays
ANSWERS = {
    "slope_newton_step": "slope `--refine 4`: the Newton step from u = 0 (every dof)",
    "finest": "slope `--refine 4`: settlement (m)",
    "footing_iterative": "3-D footing, GMRES + GAMG: settlement (m)",
    "footing_direct": "3-D footing, MUMPS: settlement (m)",
    "demo": "slope demo: settlement (m)",
    "relaxed_W": "relaxed RVE, 30 points: W",
    "relaxed_P": "relaxed RVE, 30 points: P",
    "relaxed_A": "relaxed RVE, 30 points: A",
}


def load(prefix):
    """The figures and the answers saved under ``prefix``."""
    with open(prefix + ".json") as f:
        return json.load(f), dict(np.load(prefix + ".npz"))


def compared(fa, fb):
    """(label, command, a, b, speed-up of b over a) of every figure both runs hold."""
    out = []
    for label, command, part, key, higher in ROWS:
        if part in fa and part in fb:
            va, vb = fa[part][key], fb[part][key]
            out.append((label, command, va, vb, vb / va if higher else va / vb))
    return out


def differences(aa, ab):
    """(label, a, b, relative difference, spread) of every answer both runs hold (over all
    runs of a command); a and b are the values of the first runs where an answer is one number
    per run, else None; spread: the largest relative difference between the runs of a command
    with the same BLAS (None for one run or an array)."""
    out = []
    for key, label in ANSWERS.items():
        if key in aa and key in ab:
            one = aa[key].ndim == 1 and aa[key].size <= 4  # a command's runs: the first one's
            va, vb = (float(aa[key][0]), float(ab[key][0])) if one else (None, None)
            spread = [relative_difference(x, x[0]) for x in (aa[key], ab[key]) if one]
            spread = max(spread) if spread and min(len(aa[key]), len(ab[key])) > 1 else None
            out.append((label, va, vb, relative_difference(aa[key], ab[key]), spread))
    return out


def compare(prefix_a, prefix_b):
    """Print two saved runs' figures side by side and their answers' differences."""
    (fa, aa), (fb, ab) = load(prefix_a), load(prefix_b)
    print(f"{'':52s} {fa['blas']:>18s} {fb['blas']:>18s}")
    for label, _, va, vb, speedup in compared(fa, fb):
        print(f"{label:52s} {va:18.4g} {vb:18.4g}   speed-up {speedup:.2f}")
    print("answers (largest difference relative to the largest entry):")
    for label, va, vb, d, spread in differences(aa, ab):
        values = f"   ({va!r} and {vb!r})" if va is not None else ""
        same = f", runs with the same BLAS {spread:.1e}" if spread is not None else ""
        print(f"  {label:60s} {d:.1e}{values}{same}")


def section(prefix_a, prefix_b, argv):
    """The markdown of section 11 from two saved runs (a: the reference BLAS, b: OpenBLAS)."""
    from sections import command_line, markers

    (fa, aa), (fb, ab) = load(prefix_a), load(prefix_b)
    begin, end = markers("blas.py")
    lines = [begin, "## 11. The platform's BLAS", ""]
    lines += [
        f"Generated by `{command_line('blas.py', argv)}` on {time.strftime('%Y-%m-%d %H:%M')} "
        f"from two runs of `python benchmarks/blas.py --save PREFIX` on this machine (2 cores), "
        "one with each BLAS, switched between them by `update-alternatives --set` (libblas.so.3 "
        "and liblapack.so.3); each run names the library it loaded, read from its own "
        "`/proc/self/maps`.",
        "",
        "Debian's numpy, SciPy, PETSc and MUMPS call the BLAS and LAPACK of Debian's "
        "alternatives: the reference implementation unless another is installed. "
        "`scripts/setup.sh` installs the serial OpenBLAS (`libopenblas0-serial`) and selects it: "
        "one thread, so one per MPI rank, whatever the environment says. Best of the repeats "
        "(in process) or runs (commands); the speed-up is reference time over OpenBLAS time.",
        "",
        f"| | command | {fa['blas']} | {fb['blas']} | speed-up |",
        "|---|---|---|---|---|",
    ]
    for label, command, va, vb, speedup in compared(fa, fb):
        lines.append(f"| {label} | {command} | {va:.4g} | {vb:.4g} | {speedup:.2f}x |")
    lines += ["", "The answers with each BLAS (largest difference relative to the largest entry, "
              "over all runs of a command; a value: the first run's; 2-rank runs differ between "
              "themselves in the last digits with either BLAS):",
              "", f"| answer | {fa['blas']} | {fb['blas']} | relative difference | between "
              "runs with the same BLAS |", "|---|---|---|---|---|"]  # fmt: skip
    for label, va, vb, d, spread in differences(aa, ab):
        cells = (f"{va!r} | {vb!r}") if va is not None else "(array) | (array)"
        same = f"{spread:.1e}" if spread is not None else "-"
        lines.append(f"| {label} | {cells} | {d:.1e} | {same} |")
    loads = ", ".join(
        f"{f['blas']} {f['load_start'][0]:.2f} .. {f['load_end'][0]:.2f}" for f in (fa, fb)
    )
    lines += ["", f"Load average (1 min) at the start and end of each run: {loads}.", "", end]
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", default=",".join(PARTS), help=f"of {','.join(PARTS)}")
    ap.add_argument("--repeats", type=int, default=5, help="in-process repeats (best of)")
    ap.add_argument("--runs", type=int, default=2, help="runs of each command (best of)")
    ap.add_argument("--save", help="write PREFIX.json (figures) and PREFIX.npz (answers)")
    ap.add_argument("--compare", nargs=2, metavar=("A", "B"), help="two --save prefixes")
    ap.add_argument("--doc", help="with --compare (A: reference, B: OpenBLAS): write section 11")
    a = ap.parse_args(argv)
    if a.compare:
        compare(*a.compare)
        if a.doc:
            from sections import write_section

            write_section(a.doc, section(*a.compare, sys.argv[1:] if argv is None else argv))
        return None
    parts = [p for p in a.parts.split(",") if p]
    unknown = set(parts) - set(PARTS)
    if unknown:
        ap.error(f"unknown parts {sorted(unknown)}: choose of {PARTS}")
    figures, _ = measure(parts, a.repeats, a.runs, a.save)
    return figures


if __name__ == "__main__":
    main()
