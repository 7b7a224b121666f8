"""The 3-D scene's run: the weight in load steps, then the footing's; the files a run leaves.

Output folder (written on rank 0, atomically): a folder that holds a run's files (:data:`FILES`)
is refused unless ``force``, which removes those files, and only those, first
(:mod:`dolfinx_granular.io.outfolder`: the rule of every demo):

- ``summary.json``: ``status`` as the slope's (``running`` during the run, rewritten after every
  converged load step; ``converged``, ``failed`` where a load step gave up, ``interrupted`` by
  Ctrl-C), options, mesh and packing sizes, the settlement of the footing's loaded edge, Newton
  iterations, times (RVE, assembly, linear solve, rest; their shares of a Newton iteration) and
  the largest von Mises stress;
- ``convergence.csv``: one row per Newton step (phase, step, load parameter, iteration,
  residual norm, relative energy norm);
- ``footing3d.xdmf`` (+ ``.h5``): displacement and the Cauchy stress (cell means) at every
  converged load step, for ParaView;
- ``footing3d.png``: the pyvista figure (:mod:`~dolfinx_granular.footing3d.figure`).
"""

from __future__ import annotations

import os
import time
import warnings
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import dolfinx
from dolfinx import io

from ..drivers.loading import LoadStepper
from ..fem.fields import cauchy_output
from ..io.outfolder import claim_out
from ..io.runwriter import RunWriter
from ..laws.taylor import TaylorRVE
from ..packings.generation import generate_packing
from .geometry import FootingGeometry
from .model import FootingModel

if TYPE_CHECKING:
    from mpi4py.MPI import Comm

#: the files a run writes in its folder (``force`` removes these, and nothing else)
FILES = ("summary.json", "convergence.csv", "footing3d.xdmf", "footing3d.h5", "footing3d.png")


@dataclass
class FootingOptions:
    """What a run of the 3-D scene does.

    Attributes:
        particles: spheres per RVE (the packing is generated, seed ``seed``).
        seed: the packing's seed.
        normal_stiffness: k_n (N/m).
        refine: mesh refinement k (k³ x the 2280 hexahedra of the default scene).
        gravity_steps, footing_steps: nominal load steps of the two phases.
        footing_factor: the footing pressure reached, relative to the 2-D benchmark's.
        linear_solver: "direct" (MUMPS) or "iterative" (GMRES + GAMG with the rigid-body modes).
        figure: draw the pyvista PNG.
        geometry: the scene (None: :class:`FootingGeometry` refined ``refine`` times).
    """

    particles: int = 1000
    seed: int = 0
    normal_stiffness: float = 1e5
    refine: int = 1
    gravity_steps: int = 2
    footing_steps: int = 4
    footing_factor: float = 1.0
    linear_solver: str = "direct"
    figure: bool = True
    geometry: FootingGeometry | None = field(default=None, repr=False)

    def scene(self) -> FootingGeometry:
        g = self.geometry or FootingGeometry()
        return g.scaled(self.refine) if self.refine != 1 else g


def run_footing(
    comm: Comm,
    options: FootingOptions,
    out: str,
    force: bool = False,
    overwrite: bool | None = None,
) -> dict:
    """Run the scene with ``options`` and write its files to ``out``; the summary (a dict, the
    same on every rank). Collective.

    An ``out`` that holds a run's files raises
    :class:`~dolfinx_granular.io.outfolder.RunExistsError` before any work, unless ``force``
    (which removes those files, no others); ``overwrite`` is its old name (deprecated)."""
    _prepare(comm, out, _force(force, overwrite))
    t_start = time.perf_counter()
    packing = generate_packing(options.particles, seed=options.seed, dim=3)
    law = TaylorRVE(packing, options.normal_stiffness)
    model = FootingModel(comm, law, options.scene(), {"linear_solver": options.linear_solver})
    writer = RunWriter(out, comm)
    stepper, rows, steps, done = _load_path(model, options, writer)
    summary = _summary(model, options, stepper, steps, done, time.perf_counter() - t_start)
    writer.csv(
        "convergence.csv",
        ("phase", "step", "t", "iteration", "residual_norm", "energy_norm"),
        rows,
    )
    if options.figure:
        from .figure import plot_footing

        plot_footing(model, os.path.join(out, "footing3d.png"))
    writer.json("summary.json", summary)
    model.solver.destroy()
    return summary


def _force(force, overwrite):
    """``force``, or the deprecated ``overwrite`` where given (with a DeprecationWarning)."""
    if overwrite is None:
        return force
    warnings.warn(
        "run_footing(overwrite=...) is deprecated; use force=...", DeprecationWarning, stacklevel=3
    )
    return force or overwrite


def _load_path(model, options, writer):
    """Gravity, then the footing, in load steps: ``(stepper, convergence rows, step dicts,
    done)``. Every converged step goes to the XDMF file, and to ``summary.json`` as
    ``running``; Ctrl-C leaves it ``interrupted``."""
    comm = model.comm
    # (warn=False: a failure is reported in the run's log and summary.json)
    stepper = LoadStepper(model.solver, log=print if comm.rank == 0 else None, warn=False)
    rows, steps = [], []
    xdmf = io.XDMFFile(comm, writer.path("footing3d.xdmf"), "w")
    xdmf.write_mesh(model.mesh)

    def record(phase):
        def on_converged(inc):
            for it, rnorm, energy in inc.history:
                rows.append((phase, inc.step, inc.t, it, rnorm, energy))
            steps.append(
                {"phase": phase, "t": inc.t, "iterations": inc.iterations,
                 "settlement": model.settlement()}
            )  # fmt: skip
            time_value = float(len(steps))
            xdmf.write_function(model.u, time_value)
            xdmf.write_function(cauchy_output(model.material), time_value)
            writer.json("summary.json", _progress(options, steps, "running"))

        return on_converged

    phases = (
        ("gravity", model.set_gravity, options.gravity_steps),
        ("footing", lambda t: model.set_footing(options.footing_factor * t), options.footing_steps),
    )
    writer.json("summary.json", _progress(options, steps, "running"))
    done = True
    try:
        for name, set_load, n in phases:
            done = stepper.run_phase(name, set_load, 1.0 / n, on_converged=record(name)) and done
            if not done:
                break
    except KeyboardInterrupt:  # (no collective call here: the other ranks may be elsewhere)
        writer.json("summary.json", _progress(options, steps, "interrupted", "SIGINT"))
        raise
    xdmf.close()
    return stepper, rows, steps, done


def _progress(options, steps, status, interrupted_by=None):
    """The summary of a run in progress (or interrupted): its status, options and steps."""
    return {
        "status": status,
        "interrupted_by": interrupted_by,
        "options": _options(options),
        "completed_steps": len(steps),
        "steps": steps,
    }


def _options(options):
    return {k: v for k, v in asdict(options).items() if k != "geometry"}


def _prepare(comm, out, force):
    """Refuse different folders on different ranks (the collective writes would hang), then
    claim ``out``: refused if it holds a run's files unless ``force`` (nothing a user computed
    is lost). Collective."""
    if len(set(comm.allgather(os.path.abspath(out)))) > 1:
        raise ValueError(
            "run_footing was given different output folders on different ranks; pass every "
            "rank the same folder (e.g. broadcast rank 0's)"
        )
    claim_out(out, FILES, force, "footing3d", comm)


def _summary(model, options, stepper, steps, done, wall):
    """The summary dict (the same on every rank)."""
    comm = model.comm
    timings = model.solver.timings
    iterations = sum(s["iterations"] for s in steps)
    per_it = {k: v / max(iterations, 1) for k, v in timings.items()}
    total = sum(per_it.values())
    n_points = comm.allreduce(model.material.n_points)
    g = model.geometry
    return {
        "status": "converged" if done else "failed",  # (the slope's values)
        "converged": bool(done),
        "completed": bool(done),  # (the old name of converged, kept for old readers)
        "failed": stepper.failed,
        "interrupted_by": None,
        "options": _options(options),
        "cells": g.n_cells,
        "points": n_points,
        "dofs": model.V.dofmap.index_map.size_global * 3,
        "ranks": comm.size,
        "footing_area_m2": g.footing_area,
        "footing_load_N": model.footing_load(),
        "settlement_m": model.settlement(),
        "completed_steps": len(steps),
        "steps": steps,
        "newton_iterations": iterations,
        "cutbacks": len(stepper.cutbacks),
        "max_von_mises_Pa": model.max_von_mises(),
        "seconds": wall,
        "seconds_per_iteration": per_it,
        "share_per_iteration": {k: v / total for k, v in per_it.items()} if total else {},
        "rve_microseconds_per_point": 1e6 * per_it["rve"] / max(n_points, 1) * comm.size,
        "dolfinx": dolfinx.__version__,
    }
