# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # A granular column under a surface load: the API, step by step
#
# The pieces a user puts together to solve a boundary value problem with a granular RVE at every
# Gauss point: a **mesh**, a **law** (a packing of disks and its contact springs, checked first
# at one material point), a **material** (the law on the Gauss points), the **problem** (forms
# and boundary conditions), a **driver** (Newton's method inside adaptive load stepping) and the
# **output** (displacement and Cauchy stress in XDMF, a stress probe per load step as CSV).
#
#     python demos/granular_column.py [--out results/granular_column] [--small] [--force]
#     mpirun -n 2 python demos/granular_column.py --small
#
# ``--small`` (or ``DEMO_SMALL=1`` in the environment, e.g. for a notebook) takes a 70-particle
# packing, a 4 x 4 mesh and 3 load steps, written to ``results/granular_column-small`` by
# default; the full run 350 particles, 8 x 8 cells and 6 steps. An ``--out`` that holds a run is
# refused (exit status 2) unless ``--force``, which replaces its files and no others.
# Serial or under MPI: every line below runs on every rank.

# %%
from __future__ import annotations

import csv
import json
import os
import sys

from dolfinx_granular import (
    GranularMaterial,
    LoadStepper,
    NewtonSolver,
    TaylorRVE,
    generate_packing,
    probe,
    vector_space,
)
from dolfinx_granular.drivers.material_point import MaterialPoint
from dolfinx_granular.fem.compat import repair_xdmf
from dolfinx_granular.fem.fields import cauchy_output
from dolfinx_granular.io.commandline import Parser
from dolfinx_granular.io.outfolder import OutFolderError, claim_out, refused

import numpy as np
import ufl
from dolfinx import fem, io, mesh
from mpi4py import MPI

SIZES = dict(full=dict(particles=350, cells=8, steps=6), small=dict(particles=70, cells=4, steps=3))
HEIGHT = 10.0  # side of the column, m
PRESSURE = 3e5  # final surface pressure on top, Pa
K_N = 2.8e7  # normal contact stiffness, N/m² (table 1 of Meier, Steinmann & Kuhl)
PROBE = (5.0, 2.0)  # where the stress is recorded, m
#: the files it writes in its folder (what --force replaces)
FILES = ("column.xdmf", "column.h5", "probe.csv", "summary.json")


# %% [markdown]
# ## 1. The mesh
#
# A square of quadrilaterals, distributed over the ranks of the communicator.


# %%
def make_mesh(comm, cells):
    """The column [0, HEIGHT]² as cells x cells Q1 quadrilaterals."""
    return mesh.create_rectangle(
        comm, [[0.0, 0.0], [HEIGHT, HEIGHT]], [cells, cells], mesh.CellType.quadrilateral
    )


# %% [markdown]
# ## 2. The law, checked at one material point
#
# `generate_packing` jams disks from the CEN standard sand in a periodic cell (deterministic per
# seed); `TaylorRVE` gives stress and consistent tangent under any F. Before any finite element,
# the material-point driver answers a calibration question: under a vertical pressure p with
# rigid side walls (F11 = 1, F12 = F21 = 0, F22 solved so that σ22 = −p), how much does the
# column settle and what lateral stress (K0 = σ11/σ22) does it carry?


# %%
def make_law(comm, particles):
    """A TaylorRVE of a packing generated on rank 0 and shared (the same law on every rank)."""
    packing = comm.bcast(generate_packing(particles, seed=1) if comm.rank == 0 else None)
    return TaylorRVE(packing, normal_stiffness=K_N)


def oedometer(law, pressure):
    """One material point under sigma_22 = -pressure with F11 = 1: (F22 - 1, K0)."""
    step = MaterialPoint(law).step(np.eye(2), stress={(1, 1): -pressure})
    return step.F[1, 1] - 1.0, step.sigma[0, 0] / step.sigma[1, 1]


# %% [markdown]
# ## 3. The material and 4. the problem
#
# `GranularMaterial(law, u)` holds the law's first Piola stress P and tangent dP/dF at the Gauss
# points of this rank's cells, with the forms that use them: the residual ∫ P : ∇v dx and its
# consistent Jacobian. The column has a fixed base, rollers on its sides and a surface pressure
# p(t) = t · PRESSURE (a `Constant`, changed by the driver).


# %%
def make_problem(msh, law):
    """(u, material, residual, jacobian, bcs, p) of the column."""
    V = vector_space(msh)
    u, v, du = fem.Function(V, name="displacement"), ufl.TestFunction(V), ufl.TrialFunction(V)
    material = GranularMaterial(law, u, quadrature_degree=2)
    fdim = msh.topology.dim - 1
    top = mesh.locate_entities_boundary(msh, fdim, lambda x: np.isclose(x[1], HEIGHT))
    base = mesh.locate_entities_boundary(msh, fdim, lambda x: np.isclose(x[1], 0.0))
    sides = mesh.locate_entities_boundary(
        msh, fdim, lambda x: np.isclose(x[0], 0.0) | np.isclose(x[0], HEIGHT)
    )
    tags = mesh.meshtags(msh, fdim, top, np.full_like(top, 1))
    ds = ufl.Measure("ds", msh, subdomain_data=tags)
    p = fem.Constant(msh, 0.0)  # Pa, positive downwards
    residual = material.residual_form(v) + p * v[1] * ds(1)
    jacobian = material.jacobian_form(du, v)
    bcs = [
        fem.dirichletbc(np.zeros(2), fem.locate_dofs_topological(V, fdim, base), V),
        fem.dirichletbc(0.0, fem.locate_dofs_topological(V.sub(0), fdim, sides), V.sub(0)),
    ]
    return u, material, residual, jacobian, bcs, p


# %% [markdown]
# ## 5. The driver and 6. the output
#
# `NewtonSolver` runs PETSc SNES with the consistent tangent; a failed solve restores the last
# converged state, so `LoadStepper` can cut the load increment back and retry. After every
# converged increment `on_converged` appends u and the cell-mean Cauchy stress to the XDMF file
# (time = load factor) and probes the stress at the Gauss point nearest to PROBE (gathered over
# the ranks: every rank gets the same answer).


# %%
def solve(msh, law, steps, out, say):
    """Load the column in ``steps`` nominal increments; returns (stepper, probe rows)."""
    u, material, residual, jacobian, bcs, p = make_problem(msh, law)
    solver = NewtonSolver(residual, jacobian, u, bcs, material, prefix="column_")
    stepper = LoadStepper(solver, log=say)
    xdmf_path = os.path.join(out, "column.xdmf")
    with io.XDMFFile(msh.comm, xdmf_path, "w") as xdmf:
        xdmf.write_mesh(msh)
    rows = []

    def on_converged(step, t, result):
        with io.XDMFFile(msh.comm, xdmf_path, "a") as xdmf:
            xdmf.write_function(u, t)
            xdmf.write_function(cauchy_output(material), t)
        s = probe(material, [PROBE])
        rows.append([step, t, t * PRESSURE, result.iterations, *s.cauchy[0].ravel()])

    stepper.run("pressure", lambda t: setattr(p, "value", t * PRESSURE), 1.0 / steps,
                on_converged=on_converged)  # fmt: skip
    if msh.comm.rank == 0:
        repair_xdmf(xdmf_path)  # (pyvista and ParaView read DOLFINx 0.9+'s XDMF then)
    return stepper, rows, top_settlement(u)


def top_settlement(u):
    """The largest downward displacement of the top surface over all ranks (m, negative)."""
    msh = u.function_space.mesh
    x = u.function_space.tabulate_dof_coordinates()
    n_owned = u.function_space.dofmap.index_map.size_local
    on_top = np.flatnonzero(np.isclose(x[:n_owned, 1], HEIGHT))
    uy = u.x.array.reshape(-1, 2)[on_top, 1]
    return msh.comm.allreduce(float(uy.min()) if uy.size else np.inf, op=MPI.MIN)


def write_results(out, rows, stepper, settlement, calibration):
    """probe.csv (one row per converged increment) and summary.json (rank 0 only)."""
    with open(os.path.join(out, "probe.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "t", "pressure_Pa", "newton_iterations"]
                   + [f"sigma{a}{b}_Pa" for a in (1, 2) for b in (1, 2)])  # fmt: skip
        w.writerows(rows)
    summary = dict(
        converged=stepper.failed is None and not stepper.stopped,
        steps=stepper.step,
        newton_iterations=int(sum(r[3] for r in rows)),
        top_settlement_m=settlement,
        oedometer=dict(zip(("e22", "K0"), calibration)),
    )
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    return summary


# %% [markdown]
# ## The whole run


# %%
def run(out="results/granular_column", small=False, comm=MPI.COMM_WORLD, force=False):
    """Solve the column and write column.xdmf, probe.csv and summary.json to ``out``; returns
    the summary dict (on every rank). An ``out`` that holds a run raises ``RunExistsError``
    first, unless ``force`` (which removes its files, no others)."""
    claim_out(out, FILES, force, "granular_column", comm)
    cfg = SIZES["small" if small else "full"]
    say = print if comm.rank == 0 else None
    law = make_law(comm, cfg["particles"])
    calibration = oedometer(law, PRESSURE)
    if say:
        say(f"one material point at p = {PRESSURE:.0e} Pa: e22 = {calibration[0]:.3e}, "
            f"K0 = {calibration[1]:.3f}")  # fmt: skip
    msh = make_mesh(comm, cfg["cells"])
    stepper, rows, settlement = solve(msh, law, cfg["steps"], out, say)
    summary = None
    if comm.rank == 0:
        summary = write_results(out, rows, stepper, settlement, calibration)
        say(f"top settlement {settlement:.6e} m in {stepper.step} increments; wrote {out}/")
    return comm.bcast(summary)


def parse_args(argv=None):
    """The options; ``out`` resolved (``results/granular_column[-small]``)."""
    parser = Parser(description="A granular column under a surface load.")
    parser.add_output("granular_column")
    return parser.parse_args(argv)


def main(argv=None):
    args = parse_args(argv)
    try:  # (run claims the folder first: a refusal costs no work)
        summary = run(args.out, args.small, force=args.force)
    except OutFolderError as err:
        return refused(err, MPI.COMM_WORLD)
    return 0 if summary["converged"] else 1


# %% [markdown]
# Run as a script; in a notebook call `run("results/granular_column-small", small=True)` instead
# (`force=True` replaces an earlier run there).

# %%
if __name__ == "__main__":
    sys.exit(main())
