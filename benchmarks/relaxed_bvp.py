"""The relaxed RVE in boundary value problems: relaxed (frictionless and with friction mu =
``FRICTION``) against Taylor on a confined column and on the confined slope, Newton iterations per
step, time, and the speed-up on 2 ranks.

Run: ``.venv/bin/python benchmarks/relaxed_bvp.py`` (a few minutes on 2 cores; ``make bench``
does not run it).

Both problems start from a confined state: the packing (70 disks) is jammed at the confining
pressure, compressed to it and relaxed (``drivers.confinement.confined_packing``), and the
boundaries other than the supports carry the traction P(I) n that holds it. A stress-free
frictionless packing has no shear stiffness once relaxed: from it, the first Newton iterate of
either problem unjams RVEs.

- column: the README's 10 m x 10 m column (8 x 8 Q1 cells, rollers on the sides, fixed base),
  70 disks of seed 1, confined at ``COLUMN_CONFINEMENT``; a top load ``COLUMN_LOAD`` added in
  ``COLUMN_STEPS`` steps (load stepping, ``COLUMN_CUTBACKS`` cut-backs in a row at most);
- slope: the slope benchmark on its 2-row mesh (40 cells, 160 RVEs), 70 disks of seed 0,
  confined at ``SLOPE_CONFINEMENT``, the gravity phase in 20 steps, until it stops (the relaxed
  slope's limit) or carries the whole weight; the relaxed slopes' weight also by path following
  (``path_following="gravity"``, first increment 1/``SLOPE_PATH_STEPS`` of the weight); the first
  ``SPEEDUP_STEPS`` gravity steps serial and on 2 ranks.

Writes section 9 of ``OUT/performance.md`` (between its markers; ``report.py`` keeps it).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from sections import command_line, markers, write_section

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BEGIN, END = markers("relaxed_bvp.py")
K_N = 2.8e7
COLUMN_CONFINEMENT, COLUMN_LOAD, COLUMN_STEPS, COLUMN_CUTBACKS = 1e5, 1e5, 5, 6
SLOPE_CONFINEMENT, SLOPE_GRAVITY_STEPS, SPEEDUP_STEPS = 2.8e5, 20, 2
#: the path's first increment is 1/SLOPE_PATH_STEPS of the weight (with 1/20 its corrector
#: stagnates at 0.0976 x the weight, at a rearrangement, before the peak)
SLOPE_PATH_STEPS = 10
#: the Coulomb friction of the frictional relaxed RVE (k_t = k_n)
FRICTION = 0.5
LAWS = ("taylor", "relaxed", "relaxed_friction")
#: the laws whose slope is also followed by arc length
RELAXED = ("relaxed", "relaxed_friction")


# -- the cases, run in a process of their own (serial or under MPI) ----------------------------


def confined_law(name, seed, confinement):
    """The law of 70 disks of ``seed`` jammed at and confined to ``confinement`` (Pa)."""
    import warnings

    from dolfinx_granular import FrictionalRelaxedRVE, RelaxedRVE, TaylorRVE, generate_packing
    from dolfinx_granular.drivers.confinement import confined_packing

    p = confinement / K_N
    packing = confined_packing(generate_packing(70, seed=seed, pressure=p), K_N, p)
    if name == "relaxed":
        return RelaxedRVE(packing, K_N)
    if name == "relaxed_friction":
        return FrictionalRelaxedRVE(packing, K_N, K_N, FRICTION)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (the prestress is the confinement)
        return TaylorRVE(packing, K_N, allow_overlaps=True)


def column_case(law_name):
    """The confined README column under the added top load: one record per converged step."""
    from dolfinx_granular import GranularMaterial, LoadStepper, NewtonSolver, vector_space

    import ufl
    from dolfinx import fem, mesh
    from mpi4py import MPI

    comm, t0 = MPI.COMM_WORLD, time.perf_counter()
    msh = mesh.create_rectangle(comm, [[0, 0], [10, 10]], [8, 8], mesh.CellType.quadrilateral)
    V = vector_space(msh)
    u, v, du = fem.Function(V), ufl.TestFunction(V), ufl.TrialFunction(V)
    material = GranularMaterial(confined_law(law_name, 1, COLUMN_CONFINEMENT), u)
    top = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 10))
    bottom = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 0))
    walls = mesh.locate_entities_boundary(
        msh, 1, lambda x: np.isclose(x[0], 0) | np.isclose(x[0], 10)
    )
    facets = np.concatenate([top, walls])
    order = np.argsort(facets)
    tags = np.concatenate([np.full_like(top, 1), np.full_like(walls, 2)])[order]
    ds = ufl.Measure("ds", msh, subdomain_data=mesh.meshtags(msh, 1, facets[order], tags))
    load = fem.Constant(msh, 0.0)
    P0 = fem.Constant(msh, material.reference_stress())
    hold = ufl.dot(ufl.dot(P0, ufl.FacetNormal(msh)), v) * (ds(1) + ds(2))  # the confinement
    residual = material.residual_form(v) + load * v[1] * ds(1) - hold
    bcs = [
        fem.dirichletbc(np.zeros(2), fem.locate_dofs_topological(V, 1, bottom), V),
        fem.dirichletbc(0.0, fem.locate_dofs_topological(V.sub(0), 1, walls), V.sub(0)),
    ]
    solver = NewtonSolver(residual, material.jacobian_form(du, v), u, bcs, material)
    stepper = LoadStepper(solver, max_cutbacks=COLUMN_CUTBACKS, warn=False)  # (reported)
    steps = []

    def record(inc):
        uy = u.x.array.reshape(-1, 2)[:, 1]
        low = comm.allreduce(float(uy.min()) if uy.size else 0.0, op=MPI.MIN)
        its = inc.result.iterations
        steps.append(dict(load=inc.t * COLUMN_LOAD, settlement=low, iterations=its))

    def set_load(t):
        load.value = t * COLUMN_LOAD

    phase = stepper.phase("load", set_load, 1.0 / COLUMN_STEPS)
    phase.run(on_converged=record)
    solver.destroy()
    rve = comm.allreduce(material.timings["rve"], op=MPI.MAX)
    failed = phase.failed["reason"] if phase.failed else None
    return dict(steps=steps, failed=failed, rve=rve, wall=time.perf_counter() - t0)


def slope_case(law_name, stop_after, path=False):
    """The confined slope on the 2-row mesh: gravity in steps (by arc length with ``path``),
    until it stops or has the whole weight (``stop_after`` steps at most)."""
    from dolfinx_granular import generate_packing
    from dolfinx_granular.slope.geometry import SlopeGeometry
    from dolfinx_granular.slope.run import SlopeOptions, run_slope

    from mpi4py import MPI

    t0 = time.perf_counter()
    options = SlopeOptions(
        rve="taylor" if law_name == "taylor" else "relaxed",
        friction=FRICTION if law_name == "relaxed_friction" else 0.0,
        confinement=SLOPE_CONFINEMENT,
        gravity_steps=SLOPE_PATH_STEPS if path else SLOPE_GRAVITY_STEPS,
        geometry=SlopeGeometry(rows=2),
        path_following="gravity" if path else None,
    )
    packing = generate_packing(70, seed=0, pressure=SLOPE_CONFINEMENT / K_N)
    comm = MPI.COMM_WORLD
    with tempfile.TemporaryDirectory() as folder:
        out = comm.bcast(folder, root=0)  # (one folder for every rank: rank 0 writes there)
        s = run_slope(
            packing,
            options,
            out=out,
            figure=False,
            verbose=False,
            stop_after=stop_after or (None if path else SLOPE_GRAVITY_STEPS),
        )
    steps = [
        dict(gravity=i["gravity"], settlement=i["settlement"], iterations=n)
        for i, n in zip(s["step_info"], s["iterations"])
    ]
    failed = s["failed"]["reason"] if s["failed"] else None
    # the law's seconds on the slowest rank
    rve = s["time_rve_kernel"]
    path = s["path_following"] or {}
    return dict(
        steps=steps,
        failed=failed,
        rve=rve,
        wall=time.perf_counter() - t0,
        stopped=path.get("stopped"),
        critical=[c["kind"] for c in path.get("critical_points", [])],
    )


# -- the driver: every case in its own process -------------------------------------------------


def run_case(case, law_name, ranks, stop_after=None, path=False):
    """One case in a subprocess on ``ranks`` ranks; its record (rank 0's JSON line)."""
    from dolfinx_granular.fem.compat import mpi_command

    cmd = [sys.executable, os.path.abspath(__file__), "--case", case, "--law", law_name]
    if stop_after:
        cmd += ["--stop-after", str(stop_after)]
    if path:
        cmd += ["--path"]
    if ranks > 1:
        cmd = [*mpi_command(ranks), *cmd]
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def measure():
    res = {}
    for law_name in LAWS:
        res[("column", law_name, 1)] = run_case("column", law_name, 1)
        res[("slope", law_name, 2)] = run_case("slope", law_name, 2)
    for law_name in RELAXED:
        res[("slope path", law_name, 2)] = run_case("slope", law_name, 2, path=True)
    for ranks in (1, 2):
        res[("speedup", "relaxed", ranks)] = run_case("slope", "relaxed", ranks, SPEEDUP_STEPS)
    return res


# -- the section -------------------------------------------------------------------------------


def _row(name, r, x_key, x_unit):
    """One table row of a case's record."""
    steps = r["steps"]
    its = [s["iterations"] for s in steps]
    # the largest load (the last one under load control; a path may turn back after it)
    top = max(steps, key=lambda s: abs(s[x_key]), default=None)
    reached = f"{top[x_key]:.4g} {x_unit}" if top else "none"
    found = f"{top['settlement'] * 1e3:.2f} mm" if top else "-"
    # (the reason's kind only: its text holds |R|, which a table cell cannot)
    stop = "completed" if r["failed"] is None else f"stops: {r['failed'].split(':')[0]}"
    per_step = f"{np.mean(its):.1f} ({min(its)}-{max(its)})" if its else "-"
    return (
        f"| {name} | {len(steps)} | {reached} | {found} | {per_step} | {r['rve']:.1f} | "
        f"{r['wall']:.1f} | {stop} |"
    )


def _ending(r):
    """How a path's record ended, in words."""
    top = max(s["gravity"] for s in r["steps"]) if r["steps"] else 0.0
    crossed = ", ".join(r.get("critical") or []) or "none"
    if r["failed"] is not None:
        return f"at {top:.4g} x the weight: {r['failed']} (critical points crossed: {crossed})"
    if not r.get("critical"):
        return (
            f"after {len(r['steps'])} increments at {top:.4g} x the weight, without a critical "
            f"point (by the sign of det K); {r.get('stopped')}"
        )
    return (
        f"after {len(r['steps'])} increments with a peak of {top:.4g} x the weight (critical "
        f"points crossed, by the sign of det K: {crossed}); {r.get('stopped')}"
    )


def markdown(res, command, minutes):
    head = (
        "| run | converged steps | load reached | settlement there | Newton per step (range) "
        "| RVE updates (s) | wall (s) | end |\n|---|---|---|---|---|---|---|---|"
    )
    column = [_row(law, res[("column", law, 1)], "load", "Pa") for law in LAWS]
    slope = [_row(f"{law}, 2 ranks", res[("slope", law, 2)], "gravity", "x weight") for law in LAWS]
    slope += [
        _row(f"{law}, path following, 2 ranks", res[("slope path", law, 2)], "gravity",
             "x weight")
        for law in RELAXED
    ]  # fmt: skip
    s1, s2 = res[("speedup", "relaxed", 1)], res[("speedup", "relaxed", 2)]
    first = {law: res[("slope", law, 2)]["steps"][0] for law in LAWS}
    mm = {law: f"{first[law]['settlement'] * 1e3:.1f} mm" for law in LAWS}
    a, b = s1["steps"][-1]["settlement"], s2["steps"][-1]["settlement"]
    return f"""{BEGIN}
## 9. The relaxed RVE in boundary value problems

Generated by `{command}` on {time.strftime("%Y-%m-%d %H:%M")} in {minutes:.1f} min.

Relaxed against Taylor RVE (70 disks) on a confined column and on the confined slope: the packing
jammed at the confining pressure, compressed to it and relaxed, the boundaries holding that
stress (`--confinement`, [slope](slope.md#the-relaxed-rve-a-confined-slope)). `relaxed` is
frictionless, `relaxed_friction` the frictional relaxed RVE (mu = {FRICTION:g}, k_t = k_n, disks
that rotate; `--friction {FRICTION:g}`).

**Column** (the README's 8 x 8 mesh, seed 1, confined at {COLUMN_CONFINEMENT:.0e} Pa, a top
load of {COLUMN_LOAD:.0e} Pa added in {COLUMN_STEPS} steps, {COLUMN_CUTBACKS} cut-backs in a row at
most; serial):

{head}
{chr(10).join(column)}

**Slope** (2-row mesh: 40 cells, 160 RVEs; seed 0, confined at {SLOPE_CONFINEMENT:.1e} Pa;
gravity in {SLOPE_GRAVITY_STEPS} steps):

{head}
{chr(10).join(slope)}

At the first gravity step ({first["relaxed"]["gravity"]:g} x the weight) the relaxed slope
settles {mm["relaxed"]}, Taylor's {mm["taylor"]}. By path following (arc length on the weight's
factor, the first increment 1/{SLOPE_PATH_STEPS} of it, `--path-following gravity`) the
frictionless relaxed slope ends {_ending(res[("slope path", "relaxed", 2)])}; the frictional
one ends {_ending(res[("slope path", "relaxed_friction", 2)])}.

**2 ranks**: the first {SPEEDUP_STEPS} gravity steps of the relaxed slope take
{s1["rve"]:.1f} s of RVE updates serial and {s2["rve"]:.1f} s on 2 ranks (slowest rank):
{s1["rve"] / s2["rve"]:.2f}x. Their settlements: {a:.15g} m and {b:.15g} m (relative
difference {abs(a - b) / abs(a):.1e}).

{END}"""


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=os.path.join(ROOT, "docs"), help="folder of performance.md")
    p.add_argument("--case", choices=("column", "slope"), help=argparse.SUPPRESS)
    p.add_argument("--law", choices=LAWS, help=argparse.SUPPRESS)
    p.add_argument("--stop-after", type=int, help=argparse.SUPPRESS)
    p.add_argument("--path", action="store_true", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.case:
        from mpi4py import MPI

        if a.case == "column":
            r = column_case(a.law)
        else:
            r = slope_case(a.law, a.stop_after, a.path)
        if MPI.COMM_WORLD.rank == 0:
            print(json.dumps(r))
        return r
    t0 = time.perf_counter()
    res = measure()
    section = markdown(res, command_line("relaxed_bvp.py", argv), (time.perf_counter() - t0) / 60)
    os.makedirs(a.out, exist_ok=True)
    write_section(os.path.join(a.out, "performance.md"), section)
    print(section)
    return res


if __name__ == "__main__":
    main()
