# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # A footing near the crest of a 3-D slope
#
# The slope benchmark's cross-section, extruded in z into hexahedra with gmsh, carries a
# rectangular footing near its crest. At each of the 8 Gauss points of every hexahedron a
# periodic packing of spheres follows the macroscopic F (the Taylor RVE in 3-D); gravity comes
# first, then the footing's pressure, each in load steps. The planes z = 0 and z = depth roll
# (planes of symmetry), the base is fixed, the sides x = 0 and x = width roll.

# %%
"""A rectangular footing near the crest of a 3-D slope (hexahedra, sphere RVEs).

    mpirun -n 2 python demos/footing3d.py [--particles 1000] [--out results/footing3d] [--force]

``--small`` (or ``DEMO_SMALL=1``) is the reduced run of the tests: 100 spheres, a coarse
mesh of 120 hexahedra, written to ``results/footing3d-small`` by default. Writes
``summary.json`` (``status``: converged, failed, ...), ``convergence.csv``, ``footing3d.xdmf``
(ParaView) and ``footing3d.png`` to ``--out``. An ``--out`` that holds a run is refused (exit
status 2) unless ``--force``, which replaces those files and no others (``--overwrite``: its
old name, deprecated).
"""

from __future__ import annotations

import sys
import warnings

from dolfinx_granular.footing3d.geometry import FootingGeometry
from dolfinx_granular.footing3d.run import FILES as FILES  # (what --force replaces)
from dolfinx_granular.footing3d.run import FootingOptions, run_footing
from dolfinx_granular.io.commandline import Parser
from dolfinx_granular.io.outfolder import OutFolderError, refused
from dolfinx_granular.slope.geometry import SlopeGeometry

from mpi4py import MPI

# %% [markdown]
# ## Options
#
# The default scene has 2,280 hexahedra (20 columns x 19 rows x 6 layers): 18,240 RVEs. The
# linear solver defaults to GMRES with algebraic multigrid (GAMG, the rigid-body modes as its
# near-nullspace), which on this mesh is about 7x faster than the direct factorisation
# (docs/performance.md).

# %%
SMALL = FootingGeometry(SlopeGeometry(rows=3), depth=15.5, layers=2, footing_layers=(0, 1))


def parse_args(argv=None):
    """The options; ``out`` resolved (``results/footing3d[-small]``), ``small`` with
    ``DEMO_SMALL=1``, ``force`` with the deprecated ``--overwrite``."""
    ap = Parser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=1000, help="spheres per RVE")
    ap.add_argument("--seed", type=int, default=0, help="seed of the packing")
    ap.add_argument("--stiffness", type=float, default=1e5, help="k_n in N/m")
    ap.add_argument("--refine", type=int, default=1, help="mesh refinement k (k^3 x the cells)")
    ap.add_argument("--gravity-steps", type=int, default=2)
    ap.add_argument("--footing-steps", type=int, default=4)
    ap.add_argument("--footing-factor", type=float, default=1.0, help="of the 2-D pressure")
    ap.add_argument("--linear-solver", choices=("direct", "iterative"), default="iterative")
    ap.add_output("footing3d")
    ap.add_argument("--overwrite", action="store_true", help="deprecated: --force")
    ap.add_argument("--no-figure", action="store_true")
    a = ap.parse_args(argv)
    if a.overwrite:  # (old command lines keep working)
        warnings.warn("--overwrite is deprecated: use --force", FutureWarning, stacklevel=2)
        a.force = True
    return a


# %% [markdown]
# ## Run


# %%
def main(argv=None):
    comm = MPI.COMM_WORLD
    with warnings.catch_warnings():
        if comm.rank != 0:  # (one deprecation notice, not one per rank)
            warnings.simplefilter("ignore", FutureWarning)
        a = parse_args(argv)
    small = a.small
    options = FootingOptions(
        particles=100 if small else a.particles,
        seed=a.seed,
        normal_stiffness=a.stiffness,
        refine=a.refine,
        gravity_steps=a.gravity_steps,
        footing_steps=a.footing_steps,
        footing_factor=a.footing_factor,
        linear_solver=a.linear_solver,
        figure=not a.no_figure,
        geometry=SMALL if small else None,
    )
    try:  # (the folder is claimed first: a refusal costs no work)
        s = run_footing(comm, options, a.out, force=a.force)
    except OutFolderError as err:
        return refused(err, comm)
    if comm.rank == 0:
        share = ", ".join(f"{k} {100 * v:.0f} %" for k, v in s["share_per_iteration"].items())
        print(
            f"{s['cells']} hexahedra, {s['points']} RVEs of {options.particles} spheres on "
            f"{s['ranks']} rank(s): settlement {s['settlement_m']:.4f} m under "
            f"{-s['footing_load_N'] / 1e6:.1f} MN, {s['newton_iterations']} Newton iterations, "
            f"{s['seconds']:.0f} s; per iteration: {share}"
        )
        print(f"wrote {a.out} ({s['status']})")
    return 0 if s["status"] == "converged" else 1


if __name__ == "__main__":
    sys.exit(main())
