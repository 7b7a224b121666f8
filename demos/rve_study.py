# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # How large must the RVE be? Section 4 of Meier, Steinmann & Kuhl
#
# Packings of 70 ... 2800 disks from the CEN standard sand, each a Taylor RVE: their grains and
# fabric (figures 2 and 3), the stress along four strain-controlled paths at one material point
# (figures 4 and 5, `MaterialPoint.path`), and the scatter over seeds against the cost of a point.

# %%
"""RVE-size study (section 4 of Meier, Steinmann & Kuhl): figures 2-5 and speed against error.

    python demos/rve_study.py [--out results/rve_study] [--small] [--no-cache] [--force]

``--small`` (or ``DEMO_SMALL=1``) is the reduced run of the tests, written to
``results/rve_study-small`` by default; under ``mpirun`` rank 0 runs the (serial) study and the
other ranks exit. An ``--out`` that holds the study's tables or figures is refused (exit status
2) unless ``--force``, which replaces those files and no others (the packing cache stays).

* 5 packings each of 70, 350 and 700 particles (seeds 0-4) from the CEN standard sand;
* figure 2 (sieve curve with a packing's grains), figure 3 (packings and contact-normal densities
  for angles of influence 10, 20, 30 degrees);
* uniaxial compression in 11 and 22 and simple shear in 12 and 21 to 10 % (Taylor RVE, paper's
  k_n = 2.8e7 N/m²): figures 4 and 5, mean ± standard deviation (ddof = 1) over the seeds;
* speed against error: coefficient of variation (ddof = 1) over 10 seeds (0-9) of sigma_11 at
  5 % compression and sigma_12 at 5 % shear, and the evaluation time of stress and tangent per
  quadrature point, for 70 ... 2800 particles.

Writes PNGs and CSVs to ``--out``; packings are cached in ``OUT/packings`` (``--no-cache``
regenerates them). ``--small`` is a reduced run for the tests (2-3 seeds, 70 and 140 particles).
"""

from __future__ import annotations

import csv
import json
import os
import sys
import time

from dolfinx_granular import TaylorRVE, cen_standard_sand
from dolfinx_granular.drivers.material_point import MaterialPoint
from dolfinx_granular.io import plotting
from dolfinx_granular.io.commandline import Parser, world_comm
from dolfinx_granular.io.outfolder import claim_or_refuse, claim_out
from dolfinx_granular.packings.cache import PackingCache
from dolfinx_granular.packings.fabric import (
    anisotropy,
    contact_angles,
    density_deviation,
    fabric_tensor,
)
from dolfinx_granular.packings.generation import network_stats
from dolfinx_granular.packings.gsd import DEFAULT_D_MIN
from dolfinx_granular.timing import time_per_point

import numpy as np

K_N = 2.8e7  # normal contact stiffness, N/m² (table 1 of the paper)
MAX_STRAIN = 0.10
DPI = 110

FULL = dict(
    fig_sizes=(70, 350, 700),
    speed_sizes=(70, 350, 700, 1400, 2800),
    seeds=5,
    speed_seeds=10,
    steps=20,
)
SMALL = dict(fig_sizes=(70,), speed_sizes=(70, 140), seeds=2, speed_seeds=3, steps=4)
#: the files it writes in --out (what --force replaces; the packing cache is kept)
FILES = ("summary.json", "packings.csv", "stress_curves.csv", "speed_error.csv",
         "speed_error.png", "fig2_sieve_curve.png", "fig3_packings_densities.png",
         "fig4_compression.png", "fig5_shear.png")  # fmt: skip

# name -> (F as a function of the parameter s, axis label); s runs from 0 to MAX_STRAIN
PATHS = {
    "compression_11": (lambda s: np.array([[1.0 - s, 0.0], [0.0, 1.0]]), "1 − F11"),
    "compression_22": (lambda s: np.array([[1.0, 0.0], [0.0, 1.0 - s]]), "1 − F22"),
    "shear_12": (lambda s: np.array([[1.0, s], [0.0, 1.0]]), "F12"),
    "shear_21": (lambda s: np.array([[1.0, 0.0], [s, 1.0]]), "F21"),
}


# %% [markdown]
# ## Stress along strain paths, at one material point


# %%
def stress_paths(rves, steps):
    """``{path: (s (steps+1,), mean (steps+1, 2, 2), std (steps+1, 2, 2))}`` over the RVEs,
    each path strain-controlled at one material point (:class:`MaterialPoint`)."""
    s = np.linspace(0.0, MAX_STRAIN, steps + 1)
    out = {}
    for name, (F_of, _) in PATHS.items():
        F = np.array([F_of(si) for si in s])
        # (seeds, steps+1, 2, 2)
        sig = np.array([[r.sigma for r in MaterialPoint(rve).path(F)] for rve in rves])
        out[name] = (s, sig.mean(axis=0), sig.std(axis=0, ddof=1 if len(rves) > 1 else 0))
    return out


def evaluation_time(rve, n_points=2000, repeats=3):
    """Best wall time (s) per quadrature point of stress + tangent (``rve.evaluate``) for F near I
    (every entry of F - I uniform in [-0.05, 0.05])."""
    rng = np.random.default_rng(0)
    F = np.eye(2) + rng.uniform(-0.05, 0.05, (n_points, 2, 2))
    return time_per_point(rve.evaluate, F, repeats)


def write_csv(path, header, rows):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)


# %% [markdown]
# ## Tables and figures


# %%
def packing_table(cache, rves, out):
    """``OUT/packings.csv``: per packing its generation time, volume fraction, coordination,
    rattlers, the residual prestress, fabric anisotropy and the deviation of the contact-normal
    density from uniform (``rves``: ``{n: [TaylorRVE per seed]}``)."""
    rows = []
    for n, group in rves.items():
        for s, rve in enumerate(group):
            p = rve.packing
            st = network_stats(p)
            ratio = np.abs(rve.cauchy(np.eye(2))).max() / np.abs(rve.cauchy(0.99 * np.eye(2))).max()
            ang = contact_angles(p)
            a, _ = anisotropy(fabric_tensor(ang))
            rows.append(
                [
                    n,
                    s,
                    f"{cache.generation_time(n, s):.3f}",
                    f"{st.volume_fraction:.4f}",
                    f"{st.coordination:.3f}",
                    st.min_coordination,
                    f"{st.rattler_fraction:.3f}",
                    f"{ratio:.2e}",
                    f"{a:.4f}",
                    f"{density_deviation(ang, np.radians(20.0)):.4f}",
                ]
            )
    write_csv(
        os.path.join(out, "packings.csv"),
        [
            "n",
            "seed",
            "generation_time_s",
            "volume_fraction",
            "coordination_nonrattlers",
            "min_coordination",
            "rattler_fraction",
            "prestress_ratio",
            "fabric_anisotropy",
            "density_deviation_20deg",
        ],
        rows,
    )


def packing_figures(figure_sets, out):
    """Figure 2 (the sieve curve with the grains of the largest size's first packing) and figure 3
    (packings and contact-normal densities); ``figure_sets``: ``{n: [Packing per seed]}``."""
    n_show = max(figure_sets)
    fig = plotting.plot_sieve_curve(
        cen_standard_sand(), figure_sets[n_show][0], d_min=DEFAULT_D_MIN
    )
    fig.savefig(os.path.join(out, "fig2_sieve_curve.png"), dpi=DPI)
    rattlers = {n: [network_stats(p).rattlers for p in group] for n, group in figure_sets.items()}
    fig = plotting.plot_packings_and_densities(figure_sets, rattlers=rattlers)
    fig.savefig(os.path.join(out, "fig3_packings_densities.png"), dpi=80)


def stress_figures(figure_sets, steps, out):
    """Figures 4 and 5 and ``OUT/stress_curves.csv``: Cauchy stress along the four paths, mean
    and standard deviation over the packings of each size (``figure_sets``: ``{n: [TaylorRVE
    per seed]}``)."""
    curves = {n: stress_paths(group, steps) for n, group in figure_sets.items()}
    rows = []
    for name in PATHS:
        for n in figure_sets:
            s, mean, std = curves[n][name]
            for k in range(s.size):
                rows.append(
                    [name, n, f"{s[k]:.4f}"]
                    + [
                        f"{v:.6e}"
                        for a, b in ((0, 0), (1, 1), (0, 1))
                        for v in (mean[k, a, b], std[k, a, b])
                    ]
                )
    write_csv(
        os.path.join(out, "stress_curves.csv"),
        [
            "path",
            "n",
            "strain",
            "sigma11_mean_Pa",
            "sigma11_std_Pa",
            "sigma22_mean_Pa",
            "sigma22_std_Pa",
            "sigma12_mean_Pa",
            "sigma12_std_Pa",
        ],
        rows,
    )

    def panels(names, titles):
        return [
            (t, PATHS[k][1], {n: curves[n][k] for n in figure_sets}) for k, t in zip(names, titles)
        ]

    seeds = max(len(group) for group in figure_sets.values())
    fig = plotting.plot_stress_curves(
        panels(
            ["compression_11", "compression_22"],
            ["uniaxial compression in 11", "uniaxial compression in 22"],
        ),
        f"Fig. 4: compression, mean ± std over {seeds} RVEs (solid σ11, dashed σ22)",
    )
    fig.savefig(os.path.join(out, "fig4_compression.png"), dpi=DPI)
    fig = plotting.plot_stress_curves(
        panels(["shear_12", "shear_21"], ["simple shear in 12", "simple shear in 21"]),
        f"Fig. 5: simple shear, mean ± std over {seeds} RVEs (solid σ11, dashed σ22)",
    )
    fig.savefig(os.path.join(out, "fig5_shear.png"), dpi=DPI)


def speed_error(cache, rve_sets, out):
    """Scatter of the stress over the seeds against the cost of a point, per particle count
    (``rve_sets``: ``{n: [TaylorRVE per seed]}``): ``OUT/speed_error.csv`` and ``.png``; returns
    the rows (dicts)."""
    F_c = np.array([[0.95, 0.0], [0.0, 1.0]])
    F_s = np.array([[1.0, 0.05], [0.0, 1.0]])
    table = []
    for n, rves in rve_sets.items():
        sc = np.array([r.cauchy(F_c)[0, 0] for r in rves])
        ss = np.array([r.cauchy(F_s)[0, 1] for r in rves])
        ddof = 1 if len(rves) > 1 else 0
        table.append(
            {
                "n": n,
                "sigma11_compression_mean_Pa": float(sc.mean()),
                "cv_compression": float(sc.std(ddof=ddof) / abs(sc.mean())),
                "sigma12_shear_mean_Pa": float(ss.mean()),
                "cv_shear": float(ss.std(ddof=ddof) / abs(ss.mean())),
                "time_per_point": float(np.median([evaluation_time(r) for r in rves[:2]])),
                "generation_time_s": float(
                    np.mean([cache.generation_time(n, s) for s in range(len(rves))])
                ),
                "seeds": len(rves),
            }
        )
    keys = list(table[0])
    write_csv(
        os.path.join(out, "speed_error.csv"),
        keys,
        [[f"{row[k]:.6g}" if isinstance(row[k], float) else row[k] for k in keys] for row in table],
    )
    plotting.plot_speed_error(table).savefig(os.path.join(out, "speed_error.png"), dpi=DPI)
    return table


# %% [markdown]
# ## The study


# %%
def run(out="results/rve_study", small=False, use_cache=True, verbose=True, force=False):
    """Run the study, write figures and tables to ``out``; returns a summary dict. An ``out``
    that holds a study raises ``RunExistsError`` first, unless ``force`` (which removes its
    files, no others; the packing cache stays)."""
    claim_out(out, FILES, force, "rve_study")
    t_start = time.perf_counter()
    cfg = SMALL if small else FULL
    say = print if verbose else (lambda *a, **k: None)
    cache = PackingCache(os.path.join(out, "packings"), use_cache)
    sizes = sorted(set(cfg["fig_sizes"]) | set(cfg["speed_sizes"]))
    packings = {}
    for n in sizes:
        seeds = max(
            cfg["seeds"] if n in cfg["fig_sizes"] else 0,
            cfg["speed_seeds"] if n in cfg["speed_sizes"] else 0,
        )
        packings[n] = [cache.get(n, s) for s in range(seeds)]
        say(
            f"{n:5d} particles: generated / loaded {seeds} packings "
            f"({time.perf_counter() - t_start:.1f} s)"
        )
    # one RVE per packing, shared by the table, the stress curves and the speed measurement
    rves = {
        n: [TaylorRVE(p, K_N, min_stretch=0.85) for p in group] for n, group in packings.items()
    }
    packing_table(cache, rves, out)
    packing_figures({n: packings[n][: cfg["seeds"]] for n in cfg["fig_sizes"]}, out)
    say(f"figures 2 and 3 ({time.perf_counter() - t_start:.1f} s)")
    stress_figures({n: rves[n][: cfg["seeds"]] for n in cfg["fig_sizes"]}, cfg["steps"], out)
    say(f"figures 4 and 5 ({time.perf_counter() - t_start:.1f} s)")
    table = speed_error(cache, {n: rves[n] for n in cfg["speed_sizes"]}, out)

    say("\n    n   CV(σ11, 5 % compr.)  CV(σ12, 5 % shear)  time/point [µs]  generation [s]")
    for row in table:
        say(
            f"{row['n']:5d}  {100 * row['cv_compression']:17.2f} %  {100 * row['cv_shear']:16.2f} %"
            f"  {1e6 * row['time_per_point']:15.2f}  {row['generation_time_s']:14.2f}"
        )
    runtime = time.perf_counter() - t_start
    say(f"\nwrote {out}/ in {runtime:.1f} s")
    summary = {
        "runtime_s": runtime,
        "speed_error": table,
        "seeds": list(range(cfg["seeds"])),
        "speed_seeds": cfg["speed_seeds"],
        "fig_sizes": list(cfg["fig_sizes"]),
    }
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    return summary


def parse_args(argv=None):
    """The options; ``out`` resolved (``results/rve_study[-small]``)."""
    parser = Parser(description=__doc__.split("\n")[0])
    parser.add_output("rve_study")
    parser.add_argument("--no-cache", action="store_true", help="regenerate the packings")
    return parser.parse_args(argv)


def main(argv=None):
    args = parse_args(argv)
    comm = world_comm()
    # every rank takes rank 0's answer (exit status 2 alike) before any work
    if claim_or_refuse(args.out, FILES, args.force, "rve_study", comm):
        return 2
    if comm is None or comm.rank == 0:  # a serial study: rank 0 runs it, the others rest
        run(args.out, small=args.small, use_cache=not args.no_cache, force=args.force)
    return 0


# %% [markdown]
# Run as a script; in a notebook call `run("results/rve_study-small", small=True)` instead of
# this cell (`force=True` replaces an earlier study there).

# %%
if __name__ == "__main__":
    sys.exit(main())
