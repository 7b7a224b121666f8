# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Contact fabric of a sphere packing, drawn on the sphere
#
# A jammed, stress-free periodic packing of spheres from the sieve curve is deformed affinely
# (every sphere follows F, the Taylor assumption) in three ways: not at all, by a uniaxial
# compression along z and by a simple shear in the x-z plane. For each, the active contacts'
# normals give the fabric tensor A = mean n ⊗ n, its anisotropy a and major axis, and the
# density of the normals on the unit sphere, drawn as a map.

# %%
"""Contact-normal fabric of a 3-D packing under affine deformations, as maps on the sphere.

    python demos/fabric3d.py [--particles 1000] [--strain 0.02] [--out results/fabric3d] [--force]

``--small`` (or ``DEMO_SMALL=1``) is the reduced run of the tests: 100 spheres, written to
``results/fabric3d-small`` by default. Writes ``fabric3d.csv`` (one row per deformation:
contacts, fabric tensor, anisotropy, major axis) and ``fabric3d.png`` to ``--out``. An ``--out``
that holds them is refused (exit status 2) unless ``--force``, which replaces those files and no
others (``--overwrite``: its old name, deprecated). Under MPI, rank 0 does the work (one packing
is a serial job).
"""

from __future__ import annotations

import csv
import os
import sys
import warnings

from dolfinx_granular import (
    anisotropy_3d,
    contact_normals,
    fabric_tensor,
    generate_packing,
)
from dolfinx_granular.io.commandline import Parser
from dolfinx_granular.io.outfolder import claim_or_refuse
from dolfinx_granular.io.plotting import plot_sphere_densities

import numpy as np
from mpi4py import MPI

#: the files it writes in --out (what --force replaces)
FILES = ("fabric3d.csv", "fabric3d.png")
#: the fabric tensor's components in the CSV
FABRIC = ("xx", "yy", "zz", "xy", "xz", "yz")


def parse_args(argv=None):
    """The options; ``out`` resolved (``results/fabric3d[-small]``), ``small`` with
    ``DEMO_SMALL=1``, ``force`` with the deprecated ``--overwrite``."""
    ap = Parser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=1000, help="spheres in the packing")
    ap.add_argument("--seed", type=int, default=0, help="seed of the packing")
    ap.add_argument(
        "--strain", type=float, default=0.02, help="compressive strain and shear (0 < strain < 0.2)"
    )
    ap.add_argument("--delta", type=float, default=15.0, help="cone of influence in degrees")
    ap.add_output("fabric3d")
    ap.add_argument("--overwrite", action="store_true", help="deprecated: --force")
    a = ap.parse_args(argv)
    if not 0.0 < a.strain < 0.2:
        ap.error(f"--strain must lie in (0, 0.2), got {a.strain}")
    if a.overwrite:  # (old command lines keep working)
        warnings.warn("--overwrite is deprecated: use --force", FutureWarning, stacklevel=2)
        a.force = True
    return a


# %% [markdown]
# ## Deformations
#
# Compression shortens the z axis: gaps between spheres stacked along z close first, so the
# new contacts' normals point near ±z. Shear F = I + gamma e_x ⊗ e_z compresses along
# (1, 0, -1) / sqrt(2) and stretches along (1, 0, 1) / sqrt(2).


# %%
def deformations(strain):
    """``(name, F (3, 3))`` of the three cases."""
    compression = np.diag([1.0, 1.0, 1.0 - strain])
    shear = np.eye(3)
    shear[0, 2] = strain
    return [
        ("F = I", np.eye(3)),
        (f"compression ε_zz = -{100 * strain:g} %", compression),
        (f"shear γ_xz = {100 * strain:g} %", shear),
    ]


def fabric_rows(packing, cases):
    """One row per case: name, normals (N_c, 3), contacts, fabric A (3, 3), anisotropy a and
    major axis (3,)."""
    rows = []
    for name, F in cases:
        normals = contact_normals(packing, F)
        A = fabric_tensor(normals)
        a, axis = anisotropy_3d(A)
        rows.append({"case": name, "normals": normals, "contacts": len(normals), "A": A,
                     "a": a, "axis": axis})  # fmt: skip
    return rows


# %% [markdown]
# ## Run


# %%
def write(out, rows, delta):
    with open(os.path.join(out, "fabric3d.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["case", "contacts", *(f"A_{k}" for k in FABRIC), "anisotropy", "axis_x",
                    "axis_y", "axis_z"])  # fmt: skip
        for r in rows:
            A = [r["A"]["xyz".index(k[0]), "xyz".index(k[1])] for k in FABRIC]
            w.writerow([r["case"], r["contacts"], *(f"{v:.6f}" for v in A), f"{r['a']:.6f}",
                        *(f"{c:.6f}" for c in r["axis"])])  # fmt: skip
    panels = [(f"{r['case']}: a = {r['a']:.3f}", r["normals"]) for r in rows]
    fig = plot_sphere_densities(panels, delta_deg=delta)
    fig.savefig(os.path.join(out, "fabric3d.png"), dpi=110)


def main(argv=None):
    comm = MPI.COMM_WORLD
    with warnings.catch_warnings():
        if comm.rank != 0:  # (one deprecation notice, not one per rank)
            warnings.simplefilter("ignore", FutureWarning)
        a = parse_args(argv)
    # every rank takes rank 0's answer (exit status 2 alike), then rank 0 works alone
    if claim_or_refuse(a.out, FILES, a.force, "fabric3d", comm):
        return 2
    if comm.rank != 0:
        return 0
    particles = 100 if a.small else a.particles
    packing = generate_packing(particles, dim=3, seed=a.seed)
    rows = fabric_rows(packing, deformations(a.strain))
    for r in rows:
        axis = ", ".join(f"{c:+.3f}" for c in r["axis"])
        print(f"{r['case']:28s} {r['contacts']:6d} contacts, anisotropy a = {r['a']:.3f}, "
              f"major axis ({axis})")  # fmt: skip
    write(a.out, rows, a.delta)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
