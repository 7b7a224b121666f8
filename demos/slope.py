# ---
# jupyter:
#   jupytext:
#     text_representation:
#       format_name: percent
# ---

# %% [markdown]
# # Slope stability under a strip footing, with a granular RVE at every Gauss point
#
# Section 5 of Meier, Steinmann & Kuhl: a slope of quartz sand, plane strain, first under its
# own weight, then under an eccentric flexible strip footing applied in load steps. Every Gauss
# point carries a periodic packing of disks (the RVE) that follows the macroscopic deformation
# gradient F (Taylor assumption) and interacts through linear normal contact springs.
#
#     mpirun -n 2 python demos/slope.py [--particles 700] [--steps 20] [--out results/slope] ...
#     python demos/slope.py --help
#
# `--small` (or `DEMO_SMALL=1`) is a reduced run for the tests: `--particles 70 --steps 4`, into
# `results/slope-small` unless `--out` is given.
#
# `--factor-of-safety` finds the slope's factor of safety by strength reduction of the contact
# friction (the frictional relaxed RVE; see docs/slope.md); with `--small` on a 2-row mesh with
# a coarse strength curve and bracket, into `results/slope-safety-small` (with `--continuation`,
# one run that lowers the friction at the whole weight, on the same mesh).
# An `--out` that holds a run is refused unless `--force` (replace it) or `--resume DIR`
# (continue it); Ctrl-C stops after the load step in progress, and `--resume DIR` goes on.
#
# All the work is library code (`dolfinx_granular.slope`); this script is its command line.

# %%
import os
import sys

from dolfinx_granular.slope import SlopeOptions, cli, run_slope  # noqa: F401 (walkthrough)

#: what ``--small`` (or ``DEMO_SMALL=1``) puts before the other arguments (they override it)
SMALL = ["--particles", "70", "--steps", "4", "--out", "results/slope-small"]
#: the same with ``--factor-of-safety``: 40 cells, half the footing after the weight (on so
#: coarse a mesh the weight alone fails only below mu = 0.125, where trials are slow), one
#: packing per friction in the strength curve, its tests to 2 %, the bracket to 5 % in FS
SMALL_SAFETY = ["--particles", "70", "--rows", "2", "--gravity-steps", "4", "--steps", "4",
                "--footing-scale", "0.5", "--strength-seeds", "1", "--strength-strain", "0.02",
                "--fs-tolerance", "0.05", "--out", "results/slope-safety-small"]  # fmt: skip
#: the same with ``--continuation``: the weight alone (one run lowers mu at the whole weight)
SMALL_CONTINUATION = ["--particles", "70", "--rows", "2", "--gravity-steps", "4",
                      "--strength-seeds", "1", "--strength-strain", "0.02",
                      "--out", "results/slope-safety-small"]  # fmt: skip

# %% [markdown]
# ## The pieces
#
# 1. **The RVE.** `generate_packing(700, seed=0)` jams 700 disks from the CEN standard sand in a
#    periodic cell and removes the jamming overlaps, so that the reference state is stress-free.
#    `TaylorRVE(packing, 2.8e7)` evaluates the stress (eq. 10) and the consistent tangent
#    (eqs. 12-13) of that packing under any F.
# 2. **The model.** `SlopeModel` meshes the reconstructed slope with gmsh (`SlopeGeometry`: every
#    dimension in one place; `--slope-ratio N` for a slope of run over rise N, `with_slope_ratio`),
#    puts the RVE (`GranularMaterial`) on the 2x2 Gauss points of its 380 Q1 cells (at the
#    paper's 45°), fixes the base, holds the sides on rollers and applies gravity and the footing
#    as dead loads.
# 3. **The load path.** `SlopeRun` applies gravity in one step, then the footing in `--steps`
#    equal steps, each solved by Newton's method with the consistent tangent (quadratic
#    convergence, table 2 of the paper). A step that fails is cut back and retried; a load the
#    slope cannot carry ends at its limit load, with every converged step on disk.
# 4. **The results.** `slope.xdmf` (displacement and von Mises per step), `convergence.csv`
#    (every Newton iterate), `summary.json` and `slope.png` (figure 7: von Mises on the deformed
#    slope and four RVEs' contact force networks); `restart.npz` continues the run
#    (`--resume DIR`, on any number of ranks).
#
# In your own code the same run is `run_slope(packing, SlopeOptions(steps=20), out="results")`.
#
# 5. **The factor of safety** (`--factor-of-safety`): trials from the start of the load path at
#    reduced contact friction mu_f, bisected between one that fails and one that carries the
#    whole load; FS = tan phi(mu) / tan phi(mu_f) from the RVE's strength curve
#    (`dolfinx_granular.slope.safety_run.SafetyRun`). It writes `safety.json`, `trials.csv`,
#    `mechanism.png` and each trial's run folder.


# %%
def main(argv=None):
    """The slope's command line; ``--small`` (or ``DEMO_SMALL=1``): a reduced run for tests."""
    argv = list(sys.argv[1:] if argv is None else argv)
    small = "--small" in argv or os.environ.get("DEMO_SMALL") == "1"
    prefix = SMALL
    if "--factor-of-safety" in argv:
        prefix = SMALL_CONTINUATION if "--continuation" in argv else SMALL_SAFETY
    if "--strength" in argv:  # (a given curve: nothing to measure)
        prefix = without(prefix, MEASURED_CURVE)
    return cli.main((prefix if small else []) + [a for a in argv if a != "--small"])


#: the options of a strength curve that the run measures itself (with their values)
MEASURED_CURVE = ("--strength-seeds", "--strength-strain")


def without(args, options):
    """``args`` (option, value, ...) without ``options`` and their values."""
    out, skip = [], False
    for a in args:
        if skip or a in options:
            skip = not skip
            continue
        out.append(a)
    return out


if __name__ == "__main__":
    sys.exit(main())
