"""One slope run of the performance report at a model level, timed by the library's own clocks.

The run is the library's slope benchmark, :class:`dolfinx_granular.slope.SlopeRun` (the mesh,
loads, load stepping and per-step output of ``demos/slope.py``); the report supplies only its
three factories: the law (the model level), the material (``GranularMaterial``, or the UFL linear
yardstick ``LinearElasticMaterial``) and the solver (the slope's Newton settings, plus
``skip_final_tangent`` for the ``taylor_skip`` level). Nothing is patched.

Timings come from the solver's and the material's :class:`~dolfinx_granular.timing.Stopwatch`,
read when the load path ends (before the summary's post-processing), and from PETSc's log events.

    python benchmarks/report_slope.py SPEC_JSON OUT_JSON

is the worker that :func:`mpi_slope_run` starts under MPI: one :func:`slope_run` from a JSON spec,
its result written by rank 0.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

import dolfinx_granular  # noqa: F401  (first: loads the MPI library of DOLFINx's PyPI wheel)
from dolfinx_granular import AdaptiveRVE, Packing, SmallStrainRVE, TaylorRVE
from dolfinx_granular.drivers.newton import NewtonSolver
from dolfinx_granular.fem.compat import mpi_command
from dolfinx_granular.fem.linear import LinearElasticMaterial
from dolfinx_granular.slope import (
    SlopeGeometry,
    SlopeOptions,
    SlopeRun,
    granular_material,
    newton_solver,
)
from dolfinx_granular.slope.summary import summarise

import numpy as np
from mpi4py import MPI

#: model levels: law and material of each
LEVELS = ("taylor", "taylor_skip", "small_strain", "adaptive", "adaptive_strain", "ufl_linear")
#: PETSc events read around the load path (LU factorisation and solves)
PETSC_EVENTS = ("PCSetUp", "KSPSolve")
#: categories of :func:`newton_split`, in seconds
CATEGORIES = (
    "newton",
    "F",
    "kernel",
    "residual_assembly",
    "jacobian_assembly",
    "scale_assembly",
    "assembly",
    "linear_solve",
    "rest",
)


def make_law(packing, normal_stiffness, level="taylor", tol=None):
    """The material-point law of a level: the Taylor RVE (``taylor``, ``taylor_skip``; also
    ``ufl_linear``, whose material takes only its eq. 15 modulus), ``SmallStrainRVE``
    (``small_strain``), ``AdaptiveRVE(tol)`` (``adaptive``; ``adaptive_strain``: strain
    criterion only)."""
    rve = TaylorRVE(packing, normal_stiffness)
    if level in ("taylor", "taylor_skip", "ufl_linear"):
        return rve
    if level == "small_strain":
        return SmallStrainRVE(rve)
    if level in ("adaptive", "adaptive_strain"):
        return AdaptiveRVE(rve, tol, contact_test=level == "adaptive")
    raise ValueError(f"unknown model level {level!r}; known: {', '.join(LEVELS)}")


def make_material(level):
    """The material factory of a level: the law on the 2x2 Gauss points, or for ``ufl_linear``
    the isotropic part of its eq. 15 modulus written in UFL (same quadrature)."""
    if level == "ufl_linear":
        return lambda law, u: LinearElasticMaterial.isotropic_part(law, u, quadrature_degree=2)
    return granular_material


def make_solver(level, petsc_options=None):
    """The solver factory of a level: the settings of the slope's default solver
    (:func:`dolfinx_granular.slope.model.newton_solver`), with ``skip_final_tangent`` for
    ``taylor_skip`` (stress only for a residual that ends the solve)."""

    def factory(*args):
        return newton_solver(
            *args,
            petsc_options=petsc_options,
            verbose=False,
            skip_final_tangent=level == "taylor_skip",
        )

    return factory


def petsc_events() -> dict:
    """``{event: {"time": s, "count": n}}`` of :data:`PETSC_EVENTS` so far (starts PETSc's log
    on the first call: events before it are not counted)."""
    from petsc4py import PETSc

    if not PETSc.Log.isActive():
        PETSc.Log.begin()
    info = {e: PETSc.Log.Event(e).getPerfInfo() for e in PETSC_EVENTS}
    return {e: {"time": float(i["time"]), "count": int(i["count"])} for e, i in info.items()}


def newton_split(solver, material) -> dict:
    """Seconds of the Newton solves per category, ``{"wall": {...}, "cpu": {...}}``, from the
    solver's and the material's Stopwatches (categories :data:`CATEGORIES`).

    ``newton``: SNES solves and the solver's work after them (final evaluation, commit or
    restore); ``F``: I + grad u at the points; ``kernel``: the law alone; the assemblies:
    residuals, Jacobians and the internal forces of the round-off test; ``linear_solve``: SNES
    time outside the solver's callbacks (LU factorisation and solve, SNES's vector work);
    ``rest``: the remainder (callbacks' own work, the material updates' bookkeeping)."""
    out = {}
    for clock in ("wall", "cpu"):
        s, m = getattr(solver.clock, clock), getattr(material.clock, clock)
        split = NewtonSolver.time_split(s)
        t = {
            "newton": s["snes"] + s["after"],
            "F": m["F"],
            "kernel": m["rve"],
            "residual_assembly": s["residual"],
            "jacobian_assembly": s["jacobian"],
            "scale_assembly": s["scale"],
            "assembly": split["assembly"],
            "linear_solve": split["solve"],
        }
        t["rest"] = t["newton"] - t["F"] - t["kernel"] - t["assembly"] - t["linear_solve"]
        out[clock] = {k: t[k] for k in CATEGORIES}  # (the tables' order)
    return out


def rve_alone(law, F, comm, repeats) -> float:
    """Best wall seconds over ``repeats`` of evaluating ``law`` at F (this rank's points), all
    ranks at once between barriers, max over ranks: the RVE work without the Newton loop."""
    best = np.inf
    for _ in range(repeats):
        comm.barrier()
        t0 = time.perf_counter()
        law.evaluate(F)
        comm.barrier()
        best = min(best, time.perf_counter() - t0)
    return comm.allreduce(best, op=MPI.MAX)


def _finish(run) -> dict:
    """The end of :func:`~dolfinx_granular.slope.run.run_slope` without figure and files: the
    stress extremes, the probes, the solver's PETSc objects freed, the summary dict."""
    m = run.model
    extremes = m.extremes()
    probes = m.probes(extremes[1][1])
    m.solver.destroy()  # collective, on every rank at the same point
    return summarise(run, extremes, probes)


def _scratch(comm):
    """A temporary folder for the run's files, the same on every rank."""
    return comm.bcast(tempfile.mkdtemp(prefix="slope_report_") if comm.rank == 0 else None)


def slope_run(
    packing, level="taylor", tol=None, steps=20, refine=1, comm=None, keep=False, rve_bench=0
) -> dict:
    """One slope run (gravity, then ``steps`` footing steps) at a model level.

    Args:
        packing: the RVE's packing. level, tol: see :func:`make_law`.
        refine: mesh refinement (:meth:`SlopeGeometry.refined`).
        keep: add the final F of this rank's points (``"_F"``) and the law (``"_rve"``).
        rve_bench: > 0: time the final state's RVE work alone that many times
            (:func:`rve_alone`, ``"rve_bench"``).

    Returns:
        a dict of plain data (JSON): the run's summary numbers, ``calls`` (residual and Jacobian
        assemblies, material updates, solves, KSP solves), ``times`` and ``cpu`` (seconds per
        category of :func:`newton_split`, max over ranks), ``petsc`` (events), per-rank kernel
        times and points.
    """
    comm = comm or MPI.COMM_WORLD
    options = SlopeOptions(steps=steps, geometry=SlopeGeometry().refined(refine))
    out = _scratch(comm)
    try:
        run = SlopeRun(
            packing,
            options,
            out,
            comm,
            verbose=False,
            law_factory=lambda p, k: make_law(p, k, level, tol),
            material_factory=make_material(level),
            solver_factory=make_solver(level, options.petsc_options),
        )
        before = petsc_events()
        run.run()
        after = petsc_events()
        res = _measured(run, comm)  # the clocks now hold the Newton solves only
        if rve_bench:
            res["rve_bench"] = rve_alone(run.law, np.array(run.model.material.F), comm, rve_bench)
        if keep:
            res["_F"], res["_rve"] = np.array(run.model.material.F), run.law
        summary = _finish(run)
    finally:
        comm.barrier()
        if comm.rank == 0:
            shutil.rmtree(out, ignore_errors=True)
    res["petsc"] = {
        e: {k: comm.allreduce(after[e][k] - before[e][k], op=MPI.MAX) for k in ("time", "count")}
        for e in PETSC_EVENTS
    }
    res["calls"]["ksp"] = res["petsc"]["KSPSolve"]["count"]
    res.update(
        level=level,
        tol=tol,
        particles=packing.n_particles,
        ranks=comm.size,
        steps=summary["steps"],
        refine=refine,
        cells=options.geometry.n_cells,
        points=summary["rves"],
        converged=summary["converged"],
        failed=summary["failed"],
        completed_steps=summary["completed_steps"],
        iterations=int(sum(summary["iterations"])),
        settlement=summary["footing_settlement"],
        max_von_mises=summary["max_von_mises"],
        wall_time=summary["wall_time"],
    )
    return res


def _measured(run, comm) -> dict:
    """Call counts, timings (max over ranks) and per-rank data of a run whose load path ended."""
    solver, material, law = run.model.solver, run.model.material, run.law
    split = newton_split(solver, material)
    calls = solver.clock.calls
    res = {
        "calls": {
            "residual": calls["residual"],
            "jacobian": calls["jacobian"],
            "updates": calls["rve"],
            "solves": calls["snes"],
        },
        "times": {k: comm.allreduce(v, op=MPI.MAX) for k, v in split["wall"].items()},
        "cpu": {k: comm.allreduce(v, op=MPI.MAX) for k, v in split["cpu"].items()},
        "kernel_per_rank": comm.allgather(split["wall"]["kernel"]),
        "kernel_cpu_per_rank": comm.allgather(split["cpu"]["kernel"]),
        "points_per_rank": comm.allgather(int(material.n_points)),
    }
    if hasattr(law, "totals"):  # AdaptiveRVE: points that took each branch
        res["level_counts"] = {k: comm.allreduce(v) for k, v in law.totals.items()}
    return res


def mpi_slope_run(packing_file, ranks, timeout=1200, **spec) -> dict:
    """:func:`slope_run` on ``ranks`` MPI processes (this Python's MPI launcher) in a
    subprocess; ``spec`` as its keyword arguments, the packing from ``packing_file``."""
    launcher = mpi_command(ranks)
    if launcher is None:
        raise RuntimeError("no MPI launcher (mpiexec/mpirun) found")
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "result.json")
        cmd = [
            *launcher,
            sys.executable,
            os.path.abspath(__file__),
            json.dumps({"packing": packing_file, **spec}),
            out,
        ]
        # env: Python's copy of the environment from start-up, without what MPI_Init (this
        # process has imported mpi4py) put into the C environment since: Open MPI's singleton
        # variables make the child launcher exit with 1 and no word
        proc = subprocess.run(
            cmd, env=dict(os.environ), capture_output=True, text=True, timeout=timeout
        )
        if proc.returncode != 0 or not os.path.isfile(out):
            raise RuntimeError(
                f"{' '.join(launcher)} ... failed ({proc.returncode}): "
                f"{(proc.stdout + proc.stderr)[-2000:]}"
            )
        with open(out) as f:
            return json.load(f)


def main(argv=None):
    """The MPI worker: ``SPEC_JSON OUT_JSON``."""
    spec_json, out_json = sys.argv[1:] if argv is None else argv
    spec = json.loads(spec_json)
    res = slope_run(Packing.load(spec.pop("packing")), **spec)
    if MPI.COMM_WORLD.rank == 0:
        with open(out_json, "w") as f:
            json.dump(res, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
