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

Every converged load step is on disk at once (so a failed or killed run loses nothing): slope.xdmf
gets the step appended, convergence.csv, summary.json (``status`` "running") and restart.npz are
replaced atomically. ``--resume DIR`` continues a run from DIR/restart.npz with the options stored
there and gives the same answer as an uninterrupted run; ``--stop-after K`` stops after K
converged steps (to split a run on purpose).

Writes to DIR: convergence.csv (one row per Newton step: step, iteration, residual norm at the
iterate the step started from, relative energy norm |R_k . du_k| / |R_0 . du_0|), summary.json
(iterations per step, footing settlement, von Mises extremes, timings; per step the RVEs without
a loaded contact, ``open_points``, and those whose tangent has lost strong ellipticity,
``non_elliptic_points``; a stop at a limit load in ``failed.limit_load``; wall_time counts from the
start of main, packing generation and JIT compilation included), slope.xdmf (+ .h5: displacement
and cell-mean von Mises per step) and slope.png (figure 7).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io as io_module
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
        load_factor=1.0, stabilise=0.0, max_cutbacks=6, restart=None, stop_after=None):
    """Run the benchmark and write the results to ``out``; returns the summary dict.

    Args:
        packing: the RVE microstructure (a Packing; same on every rank).
        steps: number of equal (nominal) footing load steps after the gravity step; a step that
            fails is cut back (at most ``max_cutbacks`` halvings in a row).
        load_factor: multiplies the footing load of the geometry (negative: uplift).
        stabilise: stiffness at points without loaded contacts, relative to the eq. 15 modulus.
        geometry: a :class:`meshes.slope.SlopeGeometry` (default: the reconstruction).
        started: ``time.perf_counter()`` at which the run began (for ``wall_time``), default now.
        restart: the dict of :func:`load_restart` to continue from (same options as that run).
        stop_after: stop after this many converged load steps (all phases, counted from 1).
    """
    t_start = time.perf_counter() if started is None else started
    from dolfinx_granular import TaylorRVE  # first: it loads the MPI of DOLFINx's PyPI wheel
    from dolfinx_granular._dolfinx import function_space, vector_space
    from dolfinx_granular.material import GranularMaterial
    from dolfinx_granular.postprocess import (cell_function, gather_mesh, global_extremum,
                                              min_acoustic_eigenvalue, nearest_point_value,
                                              plot_slope, von_mises)
    from dolfinx_granular.loading import Cutback, LoadStepper
    from dolfinx_granular.solver import NewtonSolver
    from meshes.slope import BOTTOM, FOOTING, LEFT, RIGHT, SlopeGeometry, create_mesh

    import dolfinx.fem.petsc  # noqa: F401  (fem.petsc below)
    import ufl
    from dolfinx import fem, io
    from petsc4py import PETSc

    g = geometry or SlopeGeometry()
    say = (lambda *a: print(*a, flush=True)) if (verbose and comm.rank == 0) else (lambda *a: None)
    if comm.rank == 0:
        os.makedirs(out, exist_ok=True)
    msh, _, facets = create_mesh(comm, g)
    V = vector_space(msh)
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

    # The stabiliser's share of the internal forces: |f_stab| / |f_ext| on the free dofs.
    stab_form = (fem.form(ufl.inner(material.P_stab, ufl.grad(v)) * material.dx)
                 if getattr(material, "P_stab", None) is not None else None)
    f_ext_form = fem.form(f_ext)

    def stabiliser_share():
        if stab_form is None:
            return 0.0
        norms = []
        for form in (stab_form, f_ext_form):
            b = fem.petsc.assemble_vector(form)
            b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
            fem.petsc.set_bc(b, bcs, None, 0.0)  # reactions are not forces on the soil
            norms.append(b.norm())
            b.destroy()
        return norms[0] / norms[1] if norms[1] > 0 else 0.0

    V0 = function_space(msh, "DG", 0)
    xdmf_path = os.path.join(out, "slope.xdmf")
    with io.XDMFFile(comm, xdmf_path, "w") as xdmf:
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
    nodes = _NodeOrder(comm, dof_x[:n_owned_dofs], tolerance=1e-9 * g.width)
    options = {"steps": steps, "load_factor": load_factor, "stabilise": stabilise,
               "max_cutbacks": max_cutbacks, "petsc_options": petsc_options or {},
               "normal_stiffness": normal_stiffness, "geometry": dataclasses.asdict(g)}
    u_history = []  # rank 0: u of every converged step, in node order (restart and XDMF rewrite)

    def write_output(step):
        """Append u and the cell-mean von Mises stress of the current state to the XDMF file
        (open and closed per step: the HDF5 file is complete on disk after every step)."""
        vm_cells = cell_function(V0, material.cell_average(von_mises(material.cauchy())))
        vm_cells.name = "von_mises"
        with io.XDMFFile(comm, xdmf_path, "a") as xdmf:
            xdmf.write_function(u, float(step))
            xdmf.write_function(vm_cells, float(step))

    stepper = LoadStepper(solver, max_cutbacks=max_cutbacks, log=lambda line: say("  " + line))
    phases = [("gravity", 1.0), ("footing", 1.0 / steps)]
    start_phase, start_t, start_dt = 0, 0.0, None
    resumed_from = None
    if restart is not None:
        state = restart["state"]
        resumed_from = state["step"]
        rows = [tuple(r) for r in state["rows"]]
        iterations, step_info = list(state["iterations"]), list(state["step_info"])
        stepper.step = state["step"]
        stepper.cutbacks = [Cutback(**c) for c in state["cutbacks"]]
        stepper.path = list(state.get("path", []))
        # Rewrite the XDMF file from the stored states (valid whatever the partition was).
        for k, values in enumerate(restart["u_history"], start=1):
            nodes.scatter(values, u, restart["nodes"])
            material.update(tangent=False)
            write_output(k)
        u_history = list(restart["u_history"]) if comm.rank == 0 else []
        start_phase, start_t, start_dt = state["phase"], state["t"], state["dt"]
        if start_t >= 1.0:  # the stored step ended a phase: go on with the next one
            start_phase, start_t, start_dt = start_phase + 1, 0.0, None
        say(f"slope: resumed from {restart['path']} after step {resumed_from} "
            f"({phases[min(start_phase, 1)][0]}, t = {start_t:.6g})")
    setup_time = time.perf_counter() - t_start
    time_output = 0.0
    clock = [time.perf_counter()]

    def non_elliptic_points():
        """Points whose tangent has lost strong ellipticity (localisation possible)."""
        A = getattr(material, "tangent", None)
        if A is None:
            return 0
        lowest = min_acoustic_eigenvalue(A)
        scale = comm.allreduce(float(np.abs(A).max()) if len(A) else 0.0, op=MPI.MAX)
        return comm.allreduce(int(np.count_nonzero(lowest < -1e-12 * scale)))

    def settlement_now():
        local = [float(u.x.array[2 * d + 1]) for d in edge_dofs]
        return [s for part in comm.allgather(local) for s in part][0]

    def converged_step(phase_index, step, t, result):
        nonlocal time_output
        phase = phases[phase_index][0]
        lam_g, lam_f = (t, 0.0) if phase == "gravity" else (1.0, load_factor * t)
        elapsed = time.perf_counter() - clock[0]
        iterations.append(result.iterations)
        rows.extend((step, it, rn, en) for it, rn, en in result.history)
        step_info.append({"step": step, "phase": phase, "t": t, "gravity": lam_g,
                          "footing_load": lam_f * g.footing_load,
                          "iterations": result.iterations, "converged": True,
                          "residual_norm": result.residual_norm, "reason": result.reason_name,
                          "open_points": comm.allreduce(getattr(material, "n_open", 0)),
                          "non_elliptic_points": non_elliptic_points(),
                          "settlement": settlement_now(), "stabiliser_force": stabiliser_share(),
                          "time": elapsed})
        say(f"step {step:2d}/{n_nominal}: gravity x{lam_g:.2f}, footing {lam_f * g.footing_load:.3e} N/m, "
            f"{result.iterations} iterations, {elapsed:.2f} s")
        t_out = time.perf_counter()
        write_output(step)
        values = nodes.gather(u)
        if comm.rank == 0:
            u_history.append(values)
            state = {"step": step, "phase": phase_index, "t": t, "dt": stepper.dt,
                     "iterations": iterations, "step_info": step_info, "rows": rows,
                     "cutbacks": [c.as_dict() for c in stepper.cutbacks], "path": stepper.path}
            _write_convergence(out, rows)
            _write_restart(out, packing, options, state, nodes.X, u_history)
            _write_json(out, {"status": "running", "ranks": comm.size, "steps": n_nominal,
                              "completed_steps": step, "resumed_from": resumed_from,
                              "cutbacks": state["cutbacks"], "iterations": iterations,
                              "footing_settlement": step_info[-1]["settlement"],
                              "load_factor": load_factor, "stabilise": stabilise,
                              "step_info": step_info})
        time_output += time.perf_counter() - t_out
        clock[0] = time.perf_counter()
        return not (stop_after is not None and step >= stop_after)

    def set_gravity(t):
        gravity.value, footing.value = t, 0.0

    def set_footing(t):
        gravity.value, footing.value = 1.0, load_factor * t

    setters = [set_gravity, set_footing]
    for i in range(start_phase, len(phases)):
        name, increment = phases[i]
        t0 = start_t if i == start_phase else 0.0
        setters[i](t0)  # the loads of the converged state the phase starts from
        if not stepper.run(name, setters[i], increment, t=t0,
                           dt=start_dt if i == start_phase else None,
                           on_converged=lambda *a, i=i: converged_step(i, *a)):
            break
    failed = stepper.failed
    if failed is not None:
        say(f"slope: load step {failed['step']} ({failed['phase']}, t = {failed['t']:.6g} reached) "
            f"did not converge: {failed['reason']}; stopping.")
        limit = failed["limit_load"]
        if limit is not None and failed["phase"] == "footing":
            limit["footing_load"] = load_factor * limit["t_converged"] * g.footing_load  # N/m
            say(f"slope: limit load: the slope carries at most "
                f"{abs(limit['footing_load']):.4g} N/m of footing "
                f"{'uplift' if load_factor < 0 else 'load'} "
                f"({abs(load_factor) * limit['t_converged']:.4g} x the nominal footing load); "
                f"the displacement per load increment has grown "
                f"{1 / limit['stiffness_ratio']:.3g}-fold. Past a limit point load control finds "
                "no equilibrium.")
    elif stepper.stopped:
        say(f"slope: stopped after step {stepper.step} as asked (--stop-after); continue with "
            f"--resume {out}")
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
        "status": "failed" if failed else ("stopped" if stepper.stopped else "converged"),
        "converged": failed is None and not stepper.stopped,
        "failed": failed,
        "resumed_from": resumed_from,
        "cutbacks": [c.as_dict() for c in stepper.cutbacks],
        "load_factor": load_factor,
        "stabilise": stabilise,
        "open_points": comm.allreduce(getattr(material, "n_open", 0)),
        # at the last converged step: points whose tangent lost strong ellipticity
        "non_elliptic_points": step_info[-1].get("non_elliptic_points", 0) if step_info else 0,
        # largest |nodal force of the stabilising stress| / |external load| over the steps
        "stabiliser_force_max": max([s.get("stabiliser_force", 0.0) for s in step_info] or [0.0]),
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
        _write_convergence(out, rows)
        _write_json(out, summary)
        say(f"slope: done in {wall:.1f} s (set-up {setup_time:.1f} s, RVE {t['rve']:.1f} s, "
            f"assembly {t['assembly']:.1f} s, solve {t['solve']:.1f} s, output {time_output:.1f} s); "
            f"settlement "
            f"{settlement:.4f} m; von Mises {vmin:.4g} .. {vmax:.4g} Pa; results in {out}")
    return summary


def _atomic_write(path, data):
    """Replace ``path`` by ``data`` (bytes or str) atomically: a reader or a killed run sees the
    old file or the new one, never a partial one."""
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "wb") as f:
        f.write(data.encode() if isinstance(data, str) else data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _write_convergence(out, rows):
    buf = io_module.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["step", "iteration", "residual_norm", "energy_norm_rel"])
    w.writerows((s, i, f"{r:.16e}", f"{e:.16e}") for s, i, r, e in rows)
    _atomic_write(os.path.join(out, "convergence.csv"), buf.getvalue())


def _write_json(out, summary):
    _atomic_write(os.path.join(out, "summary.json"), json.dumps(summary, indent=1))


RESTART_FORMAT = "dolfinx_granular.slope_restart"


def _write_restart(out, packing, options, state, X, u_history):
    buf = io_module.BytesIO()
    np.savez(buf, format=np.array(RESTART_FORMAT), version=np.array(1),
             options=np.array(json.dumps(options)), state=np.array(json.dumps(state)),
             centers=packing.centers, radii=packing.radii, box=packing.box, nodes=X,
             u_history=np.asarray(u_history))
    _atomic_write(os.path.join(out, "restart.npz"), buf.getvalue())


def load_restart(folder):
    """Read ``folder/restart.npz``: a dict with ``options`` and ``state`` (dicts), ``packing``,
    ``nodes`` (n, 2) and ``u_history`` (steps, n, 2); raises :class:`UserError` if unusable."""
    from dolfinx_granular import Packing

    path = os.path.join(folder, "restart.npz")
    if not os.path.isfile(path):
        raise UserError(f"--resume: {path!r} does not exist; give the --out folder of a run that "
                        "completed at least one load step")
    try:
        with np.load(path, allow_pickle=False) as f:
            if str(f["format"]) != RESTART_FORMAT:
                raise ValueError("not a slope restart file")
            restart = {"options": json.loads(str(f["options"])), "state": json.loads(str(f["state"])),
                       "packing": Packing(f["centers"], f["radii"], f["box"]),
                       "nodes": np.array(f["nodes"]), "u_history": np.array(f["u_history"]),
                       "path": path}
    except Exception as err:  # zip, key, JSON or packing errors: all mean an unusable file
        raise UserError(f"--resume: {path!r} is not a usable restart file ({err}); start the "
                        "run again without --resume") from err
    return restart


class _NodeOrder:
    """u's owned values gathered on rank 0 in a partition-independent order (nodes sorted by x,
    then y), and scattered back to any partition by matching node coordinates."""

    def __init__(self, comm, x_owned, tolerance):
        self.comm, self.tolerance = comm, tolerance
        self.n_owned = x_owned.shape[0]
        parts = comm.gather(np.asarray(x_owned), root=0)
        self.X = self.order = None
        if comm.rank == 0:
            X = np.concatenate(parts)
            self.order = np.lexsort((X[:, 1], X[:, 0]))
            self.X = X[self.order]

    def gather(self, u):
        parts = self.comm.gather(u.x.array[: 2 * self.n_owned].reshape(-1, 2).copy(), root=0)
        return np.concatenate(parts)[self.order] if self.comm.rank == 0 else None

    def scatter(self, values, u, X):
        """Set u (owned and ghost dofs) from ``values`` (n, 2) at the nodes ``X`` (n, 2)."""
        from scipy.spatial import cKDTree

        x = u.function_space.tabulate_dof_coordinates()[:, :2]
        dist, idx = cKDTree(X).query(x)
        worst = self.comm.allreduce(float(dist.max()) if dist.size else 0.0, op=MPI.MAX)
        if worst > self.tolerance:  # decided on every rank alike: no rank is left waiting
            raise UserError("--resume: the restart file belongs to another mesh; start the run "
                            "again without --resume")
        u.x.array[:] = values[idx].ravel()


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
    p.add_argument("--stop-after", type=_int_at_least(1), metavar="K",
                   help="stop after K converged load steps (resume later with --resume)")
    p.add_argument("--resume", metavar="DIR",
                   help="continue the run in DIR from its restart.npz (its options and packing; "
                        "the options above are ignored except --no-figure and --stop-after)")
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
    """Rank 0's part of the set-up: output folder and packing (generated or loaded), or the
    restart dict for ``--resume``."""
    from dolfinx_granular.packing import PackingFileError

    if a.resume:
        restart = load_restart(a.resume)
        _check_out(a.resume)
        return restart
    _check_out(a.out)
    try:
        return make_packing(a.particles, a.seed, a.packing)
    except PackingFileError as err:
        raise UserError(f"--packing: {err}; give a .npz written by 'python -m dolfinx_granular "
                        "generate' or Packing.save") from err


def main(argv=None):
    """Command line entry; returns 0 (all steps converged, or stopped by ``--stop-after``), 1
    (stopped at a failed step) or 2 (bad input: one line ``error: ...`` on stderr, the traceback
    only with ``--debug``)."""
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
        if a.resume:
            restart = packing
            o = restart["options"]
            from meshes.slope import SlopeGeometry

            summary = run(restart["packing"], steps=o["steps"], out=a.resume, comm=comm,
                          geometry=SlopeGeometry(**o["geometry"]),
                          normal_stiffness=o["normal_stiffness"], figure=not a.no_figure,
                          petsc_options=o["petsc_options"], started=started,
                          load_factor=o["load_factor"], stabilise=o["stabilise"],
                          max_cutbacks=o["max_cutbacks"], restart=restart,
                          stop_after=a.stop_after)
        else:
            summary = run(packing, steps=a.steps, out=a.out, comm=comm, figure=not a.no_figure,
                          started=started, load_factor=a.load_factor, stabilise=a.stabilise,
                          petsc_options={"snes_linesearch_type": a.line_search},
                          stop_after=a.stop_after)
    except (ValueError, OSError) as err:  # user errors: bad options, files, meshes
        if debug:
            raise
        if comm.rank == 0:
            print(f"error: {err}", file=sys.stderr, flush=True)
        return 2
    return 0 if summary["status"] in ("converged", "stopped") else 1


if __name__ == "__main__":
    sys.exit(main())
