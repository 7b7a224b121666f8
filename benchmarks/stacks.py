"""The DOLFINx stacks side by side: the same numbers and the speed of each.

Run: ``python benchmarks/stacks.py [--out docs] [--particles 700] [--steps 20]`` with any stack's
Python; it finds the installed stacks of this checkout (``.venv``: Debian's DOLFINx 0.5.2,
``.venv-current``: the 0.11 wheel) and runs each with its own Python and MPI launcher:

1. **Same numbers.** The slope with a 70-particle RVE from one packing file, 4 footing steps,
   serial and on 2 ranks: settlement and largest von Mises stress relative to the first stack's
   serial run (the solver stops at round-off, so the runs agree to ~1e-12).
2. **Speed.** Kernel µs per point (``TaylorRVE.evaluate``, P and A, 2000 points at ~2 %
   compression, best of 5) and the 700-particle slope on one rank: set-up with empty compiler
   caches (FFCx forms and Numba kernels compiled: ``XDG_CACHE_HOME`` and ``NUMBA_CACHE_DIR``
   point to empty folders) and with warm ones, their difference being the JIT time; material
   updates, assembly and the linear solves (SNES time outside the callbacks) from
   ``summary.json``.

Writes the section "DOLFINx releases" of ``OUT/performance.md`` (between the markers below, the
rest of the file untouched), ``OUT/perf_stacks.png`` and ``OUT/stacks.json``.
``--measure-kernel FILE`` is the per-stack worker: it times the kernel of this Python on the
packing FILE and prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass

from sections import command_line, markers, write_section

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SLOPE = os.path.join(ROOT, "demos", "slope.py")
BEGIN, END = markers("stacks.py")
#: the stacks of a checkout: (label, venv folder)
VENVS = (("Debian bookworm", ".venv"), ("PyPI wheel", ".venv-current"))


@dataclass(frozen=True)
class Stack:
    """One installed DOLFINx stack: its label, Python, versions and MPI command prefix."""

    label: str
    python: str
    versions: dict
    # mpi_command(2) of the stack's Python, e.g. ("mpirun", "-n", "2", "--oversubscribe",
    # "--allow-run-as-root"): 2 ranks with its own MPI (the flags let Open MPI start as root)
    mpi: tuple

    @property
    def name(self) -> str:
        return f"DOLFINx {self.versions['dolfinx']} ({self.label})"


_PROBE = """
import json, platform
import dolfinx_granular
import dolfinx, numba, numpy, mpi4py
from petsc4py import PETSc
from dolfinx_granular.fem.compat import mpi_command
print(json.dumps({"versions": {"dolfinx": dolfinx.__version__.split(".post")[0],
    "python": platform.python_version(), "petsc": ".".join(map(str, PETSc.Sys.getVersion())),
    "numba": numba.__version__, "numpy": numpy.__version__, "mpi4py": mpi4py.__version__},
    "mpi": mpi_command(2)}))
"""


def probe(python, label) -> Stack | None:
    """The stack of ``python`` if it imports dolfinx_granular and DOLFINx, else None."""
    if not os.access(python, os.X_OK):
        return None
    proc = subprocess.run([python, "-c", _PROBE], capture_output=True, text=True, cwd=ROOT)
    if proc.returncode != 0:
        return None
    info = json.loads(proc.stdout.strip().splitlines()[-1])
    return Stack(label, python, info["versions"], tuple(info["mpi"] or ()))


def installed_stacks(root=ROOT) -> list[Stack]:
    """The stacks of the checkout at ``root`` (``.venv``, ``.venv-current``) that work."""
    found = (probe(os.path.join(root, venv, "bin", "python"), label) for label, venv in VENVS)
    return [s for s in found if s is not None]


def is_running(stack) -> bool:
    """True if ``stack`` is the environment of the running Python."""
    venv = os.path.dirname(os.path.dirname(stack.python))
    return os.path.realpath(venv) == os.path.realpath(sys.prefix)


def run_slope(stack, out, *args, ranks=1, env=None, timeout=1800, accept=(0,)):
    """``demos/slope.py --no-figure --out OUT *args`` with the stack's Python (and MPI launcher
    for ranks > 1); returns its summary.json as a dict, or raises with the run's last lines if
    its exit status is not in ``accept`` (the slope exits with 1 where it stops before the full
    load, and still writes its summary)."""
    cmd = [stack.python, SLOPE, "--no-figure", "--out", str(out), *map(str, args)]
    if ranks > 1:
        if not stack.mpi:
            raise RuntimeError(f"{stack.name}: no MPI launcher")
        cmd = [stack.mpi[0], "-n", str(ranks), *stack.mpi[3:], *cmd]
    proc = subprocess.run(
        cmd,
        cwd=ROOT,
        env={**os.environ, **(env or {})},
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    if proc.returncode not in accept:
        tail = "\n".join((proc.stdout + proc.stderr).strip().splitlines()[-5:])
        raise RuntimeError(f"{stack.name}, {ranks} rank(s): slope failed:\n{tail}")
    with open(os.path.join(out, "summary.json")) as f:
        return json.load(f)


def same_numbers(stacks, packing_file, workdir, steps=4):
    """Settlement and largest von Mises stress of the slope on every stack, 1 and 2 ranks.

    Returns a list of dicts ``stack``, ``ranks``, ``settlement`` (m), ``max_von_mises`` (Pa),
    ``iterations`` and the relative differences ``d_settlement``, ``d_von_mises`` from the first
    run (the first stack, serial)."""
    rows = []
    for k, stack in enumerate(stacks):
        for ranks in (1, 2):
            out = os.path.join(workdir, f"same_{k}_{ranks}")
            s = run_slope(stack, out, "--packing", packing_file, "--steps", steps, ranks=ranks)
            rows.append(
                {
                    "stack": stack.name,
                    "ranks": ranks,
                    "iterations": s["iterations"],
                    "settlement": s["footing_settlement"],
                    "max_von_mises": s["max_von_mises"],
                }
            )
    ref = rows[0]
    for r in rows:
        r["d_settlement"] = abs(r["settlement"] - ref["settlement"]) / abs(ref["settlement"])
        r["d_von_mises"] = abs(r["max_von_mises"] - ref["max_von_mises"]) / abs(
            ref["max_von_mises"]
        )
    return rows


def measure_kernel(packing_file, points=2000, repeats=5) -> dict:
    """µs per point of ``TaylorRVE.evaluate`` (P and A) and ``stress`` (P) with this Python, and
    ``first_call_s``: the set-up and first evaluation, which compile the RVE's kernels (with the
    Numba cache the caller gives, empty in :func:`speed`)."""
    from dolfinx_granular import Packing, TaylorRVE
    from dolfinx_granular.timing import time_per_point

    from kernel import K_N, deformations  # benchmarks/kernel.py (imports dolfinx_granular)

    F = deformations(points)
    t0 = time.perf_counter()
    rve = TaylorRVE(Packing.load(packing_file), K_N)  # compiles (or loads) the pair search,
    rve.evaluate(F[:1])  # P(I) and the kernels
    first = time.perf_counter() - t0
    return {
        "us_PA": 1e6 * time_per_point(rve.evaluate, F, repeats),
        "us_P": 1e6 * time_per_point(rve.stress, F, repeats),
        "first_call_s": first,
    }


def speed(stack, packing_file, workdir, steps=20):
    """Kernel timing and the slope (one rank) with cold and warm compiler caches."""
    cold_cache = tempfile.mkdtemp(prefix="stacks_cache_", dir=workdir)
    proc = subprocess.run(
        [stack.python, __file__, "--measure-kernel", packing_file],
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=True,
        env=dict(os.environ, NUMBA_CACHE_DIR=os.path.join(cold_cache, "numba_kernel")),
    )
    kernel = json.loads(proc.stdout.strip().splitlines()[-1])
    cold_env = {"XDG_CACHE_HOME": cold_cache, "NUMBA_CACHE_DIR": os.path.join(cold_cache, "numba")}
    runs = {}
    for name, env in (("cold", cold_env), ("warm", cold_env)):  # the cold run fills the cache
        out = os.path.join(workdir, f"speed_{stack.label.replace(' ', '_')}_{name}")
        runs[name] = run_slope(stack, out, "--packing", packing_file, "--steps", steps, env=env)
    warm, cold = runs["warm"], runs["cold"]
    return {
        "stack": stack.name,
        "versions": stack.versions,
        "kernel": kernel,
        "setup_cold": cold["time_setup"],
        "setup_warm": warm["time_setup"],
        "jit": cold["time_setup"] - warm["time_setup"],
        "iterations": sum(warm["iterations"]),
        "rve": warm["time_rve"],
        "assembly": warm["time_assembly"],
        "solve": warm["time_solve"],
        "wall": warm["wall_time"],
        "settlement": warm["footing_settlement"],
    }


def markdown(same, speeds, particles, steps, command, minutes) -> str:
    """The performance.md section of both measurements."""
    worst = max(max(r["d_settlement"], r["d_von_mises"]) for r in same)
    lines = [
        BEGIN,
        "## 6. DOLFINx releases: the same numbers, and the speed of each",
        "",
        f"Generated by `{command}` on {time.strftime('%Y-%m-%d %H:%M')} in {minutes:.1f} min "
        "(this machine; each stack runs with its own Python and MPI).",
        "",
        "**Same numbers.** The slope with a 70-particle RVE from one packing file (seed 3), "
        "gravity and 4 footing steps, serial and on 2 ranks; differences relative to the "
        "first row. Largest difference: "
        f"{worst:.1e} (the target is 1e-9; Newton stops at round-off).",
        "",
        "| stack | ranks | Newton iterations per step | settlement (m) | rel. diff. | "
        "max von Mises (Pa) | rel. diff. |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in same:
        lines.append(
            f"| {r['stack']} | {r['ranks']} | {' '.join(map(str, r['iterations']))} | "
            f"{r['settlement']:.12f} | {r['d_settlement']:.1e} | "
            f"{r['max_von_mises']:.6e} | {r['d_von_mises']:.1e} |"
        )
    lines += [
        "",
        f"**Speed.** The {particles}-particle slope (seed 0, 380 cells, 1520 RVEs, "
        f"gravity and {steps} footing steps) on one rank, and the kernel on 2000 points. "
        "Seconds of wall time except the kernel (µs per point, best of 5).",
        "",
        "| | " + " | ".join(s["stack"] for s in speeds) + " |",
        "|---|" + "---|" * len(speeds),
    ]
    rows = [
        ("versions", lambda s: ", ".join(f"{k} {v}" for k, v in s["versions"].items())),
        ("kernel P+A (µs/point)", lambda s: f"{s['kernel']['us_PA']:.2f}"),
        ("kernel P only (µs/point)", lambda s: f"{s['kernel']['us_P']:.2f}"),
        ("set-up, empty caches (s)", lambda s: f"{s['setup_cold']:.1f}"),
        ("set-up, warm caches (s)", lambda s: f"{s['setup_warm']:.1f}"),
        ("JIT: FFCx forms + Numba kernels (s)", lambda s: f"{s['jit']:.1f}"),
        (
            "of which: compiling the RVE's Numba kernels (s)",
            lambda s: f"{s['kernel']['first_call_s']:.1f}",
        ),
        ("Newton iterations", lambda s: str(s["iterations"])),
        ("material updates: F + kernel (s)", lambda s: f"{s['rve']:.2f}"),
        ("assembly (s)", lambda s: f"{s['assembly']:.2f}"),
        ("linear solves, MUMPS (s)", lambda s: f"{s['solve']:.2f}"),
        ("wall time, warm (s)", lambda s: f"{s['wall']:.1f}"),
        ("settlement (m)", lambda s: f"{s['settlement']:.10f}"),
    ]
    for name, cell in rows:
        lines.append(f"| {name} | " + " | ".join(cell(s) for s in speeds) + " |")
    lines += ["", slower_sentence(speeds, rows), "", "![stacks](perf_stacks.png)", "", END]
    return "\n".join(lines) + "\n"


def slower_sentence(speeds, rows) -> str:
    """Where the last stack is more than 10 % slower than the first, and why (what each stack
    compiles, for the set-up with empty caches)."""
    first, last = speeds[0], speeds[-1]
    slower = []
    for name, cell in rows:
        if name in ("versions", "Newton iterations", "settlement (m)"):
            continue
        a, b = float(cell(first)), float(cell(last))
        if b > 1.1 * a and b - a >= 0.05:  # (differences below the table's last digit: noise)
            slower.append(f"{name} ({cell(last)} against {cell(first)})")
    if not slower:
        return f"**Where {last['stack']} is slower:** nowhere by more than 10 %."
    k0, k1 = first["kernel"]["first_call_s"], last["kernel"]["first_call_s"]
    return (
        f"**Where {last['stack']} is slower:** {'; '.join(slower)}. Only the first run with "
        "empty caches is: it compiles the Numba kernels (the RVE's: "
        f"{k1:.1f} s with Numba {last['versions'].get('numba', '?')} against {k0:.1f} s with "
        f"{first['versions'].get('numba', '?')}, measured alone) and the UFL forms (FFCx and "
        "a C compiler). Both caches persist, so every later run starts in the warm-cache time."
    )


def figure(path, same, speeds, particles, steps):
    """Left: relative differences of the same-number runs; right: time per part, per stack."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.2))
    labels = [
        f"{r['stack'].split(' (')[0]}\n{r['ranks']} rank{'s' if r['ranks'] > 1 else ''}"
        for r in same
    ]
    floor = 1e-17  # an exact match is drawn at this floor
    x = np.arange(len(same))
    for off, key, name in (
        (-0.2, "d_settlement", "settlement"),
        (0.2, "d_von_mises", "max von Mises"),
    ):
        ax1.bar(x + off, [max(r[key], floor) for r in same], width=0.4, label=name)
    ax1.axhline(1e-9, color="k", ls="--", lw=1, label="target 1e-9")
    ax1.set_yscale("log")
    ax1.set_ylim(floor / 3, 1e-7)
    ax1.set_xticks(x, labels, fontsize=8)
    ax1.set_ylabel("relative difference to the first run")
    ax1.set_title("70-particle slope: same numbers (bars at 1e-17: identical)", fontsize=10)
    ax1.legend(fontsize=8)
    parts = (
        ("setup_warm", "set-up (warm)"),
        ("jit", "JIT"),
        ("rve", "material"),
        ("assembly", "assembly"),
        ("solve", "linear solves"),
    )
    x2 = np.arange(len(parts))
    width = 0.8 / max(len(speeds), 1)
    for k, s in enumerate(speeds):
        ax2.bar(
            x2 + (k - (len(speeds) - 1) / 2) * width,
            [s[p] for p, _ in parts],
            width=width,
            label=f"{s['stack']}: kernel {s['kernel']['us_PA']:.2f} µs/pt",
        )
    ax2.set_xticks(x2, [name for _, name in parts], fontsize=9)
    ax2.set_ylabel("seconds (wall, one rank)")
    # load steps: gravity in one, then the footing in `steps`
    ax2.set_title(f"{particles}-particle slope, {steps + 1} load steps", fontsize=10)
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=os.path.join(ROOT, "docs"))
    p.add_argument("--particles", type=int, default=700)
    p.add_argument("--steps", type=int, default=20, help="footing steps of the speed runs")
    p.add_argument("--measure-kernel", metavar="FILE", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.measure_kernel:
        print(json.dumps(measure_kernel(a.measure_kernel)))
        return 0
    import dolfinx_granular

    started = time.perf_counter()
    stacks = installed_stacks()
    if not stacks:
        raise SystemExit("stacks: no stack installed (make setup / make setup-current)")
    print("stacks:", "; ".join(s.name for s in stacks), flush=True)
    with tempfile.TemporaryDirectory(prefix="stacks_") as work:
        small = os.path.join(work, "p70.npz")
        big = os.path.join(work, f"p{a.particles}.npz")
        dolfinx_granular.generate_packing(70, seed=3).save(small)
        dolfinx_granular.generate_packing(a.particles, seed=0).save(big)
        same = same_numbers(stacks, small, work)
        for r in same:
            print(
                f"  {r['stack']}, {r['ranks']} rank(s): settlement {r['settlement']!r} "
                f"({r['d_settlement']:.1e}), von Mises {r['max_von_mises']!r} "
                f"({r['d_von_mises']:.1e})",
                flush=True,
            )
        speeds = [speed(s, big, work, a.steps) for s in stacks]
    os.makedirs(a.out, exist_ok=True)
    with open(os.path.join(a.out, "stacks.json"), "w") as f:
        json.dump({"same_numbers": same, "speed": speeds}, f, indent=1)
    figure(os.path.join(a.out, "perf_stacks.png"), same, speeds, a.particles, a.steps)
    section = markdown(
        same,
        speeds,
        a.particles,
        a.steps,
        command_line("stacks.py", argv),
        (time.perf_counter() - started) / 60,
    )
    write_section(os.path.join(a.out, "performance.md"), section)
    print(section)
    return 0


if __name__ == "__main__":
    sys.exit(main())
