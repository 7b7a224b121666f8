"""Slope stability benchmark (section 5 of Meier, Steinmann & Kuhl): dead load, then an eccentric
flexible strip footing in load steps, with a Taylor RVE of a disk packing at every Gauss point.

    python demos/slope.py [--particles 700] [--seed 0] [--packing FILE] [--steps 20] [--out DIR]
                          [--load-factor 1] [--stabilise 0] [--line-search basic]
    mpirun -n 2 python demos/slope.py

Load steps are adaptive (:class:`dolfinx_granular.loading.LoadStepper`): a step that fails (Newton
divergence, a singular matrix where contacts have opened, an RVE outside its range, stagnation) is
cut back and retried from the last converged state; every cut-back is logged and listed in
summary.json (``cutbacks``). ``--load-factor`` scales the footing load (2: doubled, -0.25: uplift);
``--stabilise`` adds a small stiffness where an RVE has no loaded contact (see
:class:`~dolfinx_granular.material.GranularMaterial`).

Writes to DIR: convergence.csv (one row per Newton step: step, iteration, residual norm at the
iterate the step started from, relative energy norm |R_k . du_k| / |R_0 . du_0|), summary.json
(iterations per step, footing settlement, von Mises extremes, timings; wall_time counts from the
start of main, packing generation and JIT compilation included), slope.xdmf (+ .h5: displacement
and cell-mean von Mises per step) and slope.png (figure 7).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)  # for meshes/ when run from a checkout

import numpy as np  # noqa: E402
from mpi4py import MPI  # noqa: E402

K_N = 2.8e7  # normal contact stiffness, N/m² (table 1)
# A residual this small relative to the full external load vector is round-off.
RESIDUAL_RTOL = 1e-14


def make_packing(particles, seed, packing_file=None):
    """The RVE's packing: from ``packing_file`` if given, else ``generate_packing(particles, seed)``."""
    from dolfinx_granular import Packing

    if packing_file:
        return Packing.load(packing_file)
    from dolfinx_granular.generation import generate_packing  # lazy: a separate, optional module

    return generate_packing(particles, seed=seed)


def run(packing, steps=20, out="results/slope", comm=MPI.COMM_WORLD, geometry=None,
        normal_stiffness=K_N, figure=True, verbose=True, petsc_options=None, started=None,
        load_factor=1.0, stabilise=0.0, max_cutbacks=6):
    """Run the benchmark and write the results to ``out``; returns the summary dict.

    Args:
        packing: the RVE microstructure (a Packing; same on every rank).
        steps: number of equal (nominal) footing load steps after the gravity step; a step that
            fails is cut back (at most ``max_cutbacks`` halvings in a row).
        load_factor: multiplies the footing load of the geometry (negative: uplift).
        stabilise: stiffness at points without loaded contacts, relative to the eq. 15 modulus.
        geometry: a :class:`meshes.slope.SlopeGeometry` (default: the reconstruction).
        started: ``time.perf_counter()`` at which the run began (for ``wall_time``), default now.
    """
    t_start = time.perf_counter() if started is None else started
    import ufl
    from dolfinx import fem, io
    from petsc4py import PETSc

    from dolfinx_granular import TaylorRVE
    from dolfinx_granular.material import GranularMaterial
    from dolfinx_granular.postprocess import (cell_function, gather_mesh, global_extremum,
                                              nearest_point_value, plot_slope, von_mises)
    from dolfinx_granular.loading import LoadStepper
    from dolfinx_granular.solver import NewtonSolver
    from meshes.slope import BOTTOM, FOOTING, LEFT, RIGHT, SlopeGeometry, create_mesh

    g = geometry or SlopeGeometry()
    say = (lambda *a: print(*a, flush=True)) if (verbose and comm.rank == 0) else (lambda *a: None)
    if comm.rank == 0:
        os.makedirs(out, exist_ok=True)
    msh, _, facets = create_mesh(comm, g)
    V = fem.VectorFunctionSpace(msh, ("Lagrange", 1))
    u = fem.Function(V, name="displacement")
    v, du = ufl.TestFunction(V), ufl.TrialFunction(V)
    rve = TaylorRVE(packing, normal_stiffness)
    # (stabilise only when asked: callers may substitute a material class without it)
    material = GranularMaterial(rve, u, quadrature_degree=2,
                                **({"stabilise": stabilise} if stabilise else {}))

    # Dead loads on the reference configuration: gravity and the footing pressure (no follower).
    gravity = fem.Constant(msh, PETSc.ScalarType(0.0))
    footing = fem.Constant(msh, PETSc.ScalarType(0.0))
    q = g.footing_pressure_on_strip(ufl.SpatialCoordinate(msh)[0])
    ds = ufl.Measure("ds", domain=msh, subdomain_data=facets)
    f_ext = (gravity * (-g.density * g.gravity) * v[1] * ufl.dx
             + footing * q * v[1] * ds(FOOTING))
    residual = material.residual_form(v) - f_ext
    jacobian = material.jacobian_form(du, v)

    fdim = msh.topology.dim - 1
    zero = np.zeros(2, dtype=PETSc.ScalarType)
    bcs = [fem.dirichletbc(zero, fem.locate_dofs_topological(V, fdim, facets.find(BOTTOM)), V)]
    for tag in (LEFT, RIGHT):
        dofs = fem.locate_dofs_topological(V.sub(0), fdim, facets.find(tag))
        bcs.append(fem.dirichletbc(PETSc.ScalarType(0.0), dofs, V.sub(0)))

    # Round-off level of the residual: a small fraction of the full external load.
    gravity.value, footing.value = 1.0, load_factor
    f_full = fem.petsc.assemble_vector(fem.form(f_ext))
    f_full.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    residual_atol = RESIDUAL_RTOL * f_full.norm()
    f_full.destroy()
    solver = NewtonSolver(residual, jacobian, u, bcs, material, residual_atol=residual_atol,
                          max_it=15, prefix="slope_", petsc_options=petsc_options,
                          verbose=verbose)

    V0 = fem.FunctionSpace(msh, ("DG", 0))
    xdmf = io.XDMFFile(comm, os.path.join(out, "slope.xdmf"), "w")
    xdmf.write_mesh(msh)
    # Settlement under the loaded footing edge: the mesh node there (columns end on it).
    edge = np.array([g.loaded_edge, float(g.surface_height(g.loaded_edge))])
    dof_x = V.tabulate_dof_coordinates()[:, :2]
    n_owned_dofs = V.dofmap.index_map.size_local
    edge_dofs = np.flatnonzero(np.linalg.norm(dof_x[:n_owned_dofs] - edge, axis=1) < 1e-6 * g.width)

    n_nominal = 1 + steps
    rows, iterations, step_info = [], [], []
    say(f"slope: {msh.topology.index_map(2).size_global} cells, "
        f"{comm.allreduce(material.n_points)} RVEs of {packing.n_particles} particles, "
        f"{comm.size} rank(s), {n_nominal} load steps, footing load x{load_factor:g}"
        + (f", stabiliser {stabilise:g}" if stabilise else ""))
    setup_time = time.perf_counter() - t_start
    time_output = 0.0
    clock = [time.perf_counter()]

    def converged_step(phase, step, t, result):
        nonlocal time_output
        lam_g, lam_f = (t, 0.0) if phase == "gravity" else (1.0, load_factor * t)
        elapsed = time.perf_counter() - clock[0]
        iterations.append(result.iterations)
        rows.extend((step, it, rn, en) for it, rn, en in result.history)
        step_info.append({"step": step, "phase": phase, "t": t, "gravity": lam_g,
                          "footing_load": lam_f * g.footing_load,
                          "iterations": result.iterations, "converged": True,
                          "residual_norm": result.residual_norm, "reason": result.reason_name,
                          "open_points": comm.allreduce(getattr(material, "n_open", 0)), "time": elapsed})
        say(f"step {step:2d}/{n_nominal}: gravity x{lam_g:.2f}, footing {lam_f * g.footing_load:.3e} N/m, "
            f"{result.iterations} iterations, {elapsed:.2f} s")
        t_out = time.perf_counter()
        vm_cells = cell_function(V0, material.cell_average(von_mises(material.cauchy())))
        vm_cells.name = "von_mises"
        xdmf.write_function(u, float(step))
        xdmf.write_function(vm_cells, float(step))
        time_output += time.perf_counter() - t_out
        clock[0] = time.perf_counter()

    def set_gravity(t):
        gravity.value, footing.value = t, 0.0

    def set_footing(t):
        gravity.value, footing.value = 1.0, load_factor * t

    stepper = LoadStepper(solver, max_cutbacks=max_cutbacks, log=lambda line: say("  " + line))
    ok = stepper.run("gravity", set_gravity, 1.0,
                     on_converged=lambda *a: converged_step("gravity", *a))
    if ok:
        ok = stepper.run("footing", set_footing, 1.0 / steps,
                         on_converged=lambda *a: converged_step("footing", *a))
    failed = stepper.failed
    if failed is not None:
        say(f"slope: load step {failed['step']} ({failed['phase']}, t = {failed['t']:.6g} reached) "
            f"did not converge: {failed['reason']}; stopping.")
    xdmf.close()
    done = stepper.step  # converged load steps

    # Extremes at the Gauss points of the last converged state (reference coordinates).
    vm = von_mises(material.cauchy())
    X = material.points
    vmax, xmax = global_extremum(comm, vm, X, "max")
    vmin, xmin = global_extremum(comm, vm, X, "min")
    settle_local = [float(u.x.array[2 * d + 1]) for d in edge_dofs]
    settlement = [s for part in comm.allgather(settle_local) for s in part][0]
    smin = comm.allreduce(
        float(np.linalg.svd(material.F, compute_uv=False).min()) if material.n_points else np.inf,
        op=MPI.MIN)
    t = {k: comm.allreduce(v, op=MPI.MAX) for k, v in solver.timings.items()}
    t_kernel = comm.allreduce(material.timings["rve"], op=MPI.MAX)

    probes = [("A", xmax, "max von Mises"),
              ("B", [g.loaded_edge - 0.5 * g.column_width, 0.75 * g.crest_height], "under the footing"),
              ("C", [g.slope_end + 0.5 * g.column_width, 0.9 * g.toe_height], "at the toe"),
              ("D", [0.5 * g.footing_start + 0.5 * g.column_width, 0.1 * g.crest_height], "deep")]
    probe_F = [nearest_point_value(comm, X, material.F, p) for _, p, _ in probes]
    data = gather_mesh(V, u, material.cell_average(vm)) if figure else None
    # Collective PETSc clean-up while all ranks are at the same point (rank 0 renders after this).
    solver.destroy()
    if figure and comm.rank == 0:
        t_out = time.perf_counter()
        markers = [(lab, xp, txt) for (lab, _, txt), (xp, _) in zip(probes, probe_F)]
        markers.append(("min", xmin, f"{vmin / 1e6:.3f} MPa"))
        markers[0] = ("A", xmax, f"max {vmax / 1e6:.3f} MPa")
        insets = [(lab, rve, Fp, f"{txt}, x = ({xp[0]:.1f}, {xp[1]:.1f}) m")
                  for (lab, _, txt), (xp, Fp) in zip(probes, probe_F)]
        plot_slope(os.path.join(out, "slope.png"), data, markers, insets,
                   title=f"step {done}/{n_nominal}: settlement {settlement:.3f} m, "
                         f"{packing.n_particles} particles, deformation x1")
        time_output += time.perf_counter() - t_out

    wall = time.perf_counter() - t_start
    summary = {
        "ranks": comm.size,
        "steps": n_nominal,
        "completed_steps": done,
        "converged": failed is None,
        "failed": failed,
        "cutbacks": [c.as_dict() for c in stepper.cutbacks],
        "load_factor": load_factor,
        "stabilise": stabilise,
        "open_points": comm.allreduce(getattr(material, "n_open", 0)),
        "iterations": iterations,
        "footing_settlement": settlement,
        "footing_settlement_point": edge.tolist(),
        "max_von_mises": vmax, "max_von_mises_location": xmax,
        "min_von_mises": vmin, "min_von_mises_location": xmin,
        "min_singular_value_F": smin,
        "particles": packing.n_particles,
        "rves": comm.allreduce(material.n_points),
        "wall_time": wall,
        "time_setup": setup_time,
        "time_rve": t["rve"],
        "time_rve_kernel": t_kernel,
        "time_assembly": t["assembly"],
        "time_solve": t["solve"],
        "time_output": time_output,
        "step_info": step_info,
        "probes": {lab: {"point": xp.tolist(), "F": Fp.tolist()}
                   for (lab, _, _), (xp, Fp) in zip(probes, probe_F)},
    }
    if comm.rank == 0:
        with open(os.path.join(out, "convergence.csv"), "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["step", "iteration", "residual_norm", "energy_norm_rel"])
            w.writerows((s, i, f"{r:.16e}", f"{e:.16e}") for s, i, r, e in rows)
        with open(os.path.join(out, "summary.json"), "w") as f:
            json.dump(summary, f, indent=1)
        say(f"slope: done in {wall:.1f} s (set-up {setup_time:.1f} s, RVE {t['rve']:.1f} s, "
            f"assembly {t['assembly']:.1f} s, solve {t['solve']:.1f} s, output {time_output:.1f} s); "
            f"settlement "
            f"{settlement:.4f} m; von Mises {vmin:.4g} .. {vmax:.4g} Pa; results in {out}")
    return summary


class UserError(ValueError):
    """Bad input (options, files): reported as one line ``error: ...`` with exit status 2."""


class _Parser(argparse.ArgumentParser):
    """argparse that raises :class:`UserError` (one line) instead of printing the usage block."""

    def error(self, message):
        raise UserError(f"{message} (see '{self.prog} --help')")


def _int_at_least(low):
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {value}")
        return value
    return parse


def _finite(low=None):
    def parse(text):
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not np.isfinite(value) or (low is not None and value < low):
            raise argparse.ArgumentTypeError(
                f"must be a finite number{f' >= {low}' if low is not None else ''}, got {text!r}")
        return value
    return parse


def build_parser():
    p = _Parser(prog="demos/slope.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--particles", type=_int_at_least(2), default=700,
                   help="particles per RVE, >= 2 (default 700)")
    p.add_argument("--seed", type=_int_at_least(0), default=0, help="packing generator seed (default 0)")
    p.add_argument("--packing", help="load the packing from this .npz file instead of generating")
    p.add_argument("--steps", type=_int_at_least(1), default=20, help="footing load steps (default 20)")
    p.add_argument("--out", default="results/slope", help="output folder (default results/slope)")
    p.add_argument("--no-figure", action="store_true", help="skip slope.png")
    p.add_argument("--load-factor", type=_finite(), default=1.0,
                   help="multiplies the footing load (2: doubled, -0.25: uplift; default 1)")
    p.add_argument("--stabilise", type=_finite(0.0), default=0.0,
                   help="stiffness where an RVE has no loaded contact, relative to the eq. 15 "
                        "modulus (default 0: off)")
    p.add_argument("--line-search", choices=["basic", "bt", "l2", "cp"], default="basic",
                   help="SNES line search (default basic: full Newton steps)")
    p.add_argument("--debug", action="store_true", help="show the traceback of an error")
    return p


def _check_out(out):
    """Create ``out`` and prove that a file can be written there (before any work is done)."""
    try:
        os.makedirs(out, exist_ok=True)
        probe = os.path.join(out, f".write-test-{os.getpid()}")
        with open(probe, "w"):
            pass
        os.remove(probe)
    except OSError as err:
        raise UserError(f"--out {out!r} cannot be written ({err.strerror or err}); choose a "
                        "writable folder") from None


def _prepare(a):
    """Rank 0's part of the set-up: output folder and packing (generated or loaded)."""
    from dolfinx_granular.packing import PackingFileError

    _check_out(a.out)
    try:
        return make_packing(a.particles, a.seed, a.packing)
    except PackingFileError as err:
        raise UserError(f"--packing: {err}; give a .npz written by 'python -m dolfinx_granular "
                        "generate' or Packing.save") from err


def main(argv=None):
    """Command line entry; returns 0 (all steps converged), 1 (stopped at a failed step) or 2
    (bad input: one line ``error: ...`` on stderr, the traceback only with ``--debug``)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    comm = MPI.COMM_WORLD
    debug = "--debug" in argv
    started = time.perf_counter()
    try:
        a = build_parser().parse_args(argv)
        packing = failure = None
        if comm.rank == 0:
            try:
                packing = _prepare(a)
            except Exception as err:  # let the other ranks stop too instead of waiting in bcast
                packing = failure = err
        packing = comm.bcast(packing, root=0)  # every rank must use the identical RVE
        if isinstance(packing, Exception):
            raise failure or UserError(str(packing))  # rank 0: the original, with its cause
        summary = run(packing, steps=a.steps, out=a.out, comm=comm, figure=not a.no_figure,
                      started=started, load_factor=a.load_factor, stabilise=a.stabilise,
                      petsc_options={"snes_linesearch_type": a.line_search})
    except (ValueError, OSError) as err:  # user errors: bad options, files, meshes
        if debug:
            raise
        if comm.rank == 0:
            print(f"error: {err}", file=sys.stderr, flush=True)
        return 2
    return 0 if summary["converged"] else 1


if __name__ == "__main__":
    sys.exit(main())
