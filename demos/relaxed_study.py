# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Relaxed against Taylor: moduli over pressure, and shear under confinement
#
# Under the Taylor assumption every disk follows F; in a `RelaxedRVE` the disks find their
# static equilibrium. For frictionless harmonic disks the jamming literature (O'Hern, Silbert,
# Liu & Nagel, PRE 68, 011306, 2003) finds that near jamming the bulk modulus B stays finite,
# the shear modulus falls as G ~ p^(1/2) and the excess coordination as z - z_iso ~ p^(1/2)
# (z_iso = 4 in 2-D). The Taylor bound keeps G of the order of B at every pressure.

# %%
"""Relaxed against Taylor RVE: bulk and shear moduli over pressure, coordination, confined shear.

    python demos/relaxed_study.py [--out results/relaxed_study] [--small] [--force]

``--small`` (or ``DEMO_SMALL=1``) is the reduced run of the tests, written to
``results/relaxed_study-small`` by default; under ``mpirun`` rank 0 runs the (serial) study and
the other ranks exit. An ``--out`` that holds the study's tables or figures is refused (exit
status 2) unless ``--force``, which replaces those files and no others; the packings cached in
``OUT/packings`` stay and are reused.

* packings: ``generate_packing(n, seed, pressure=p)`` for each target pressure p / k_n: the
  contact network jammed at that pressure, so that compressing it to p keeps its network
  (``--small``: 70 disks, one seed, two pressures);
* each packing is compressed along F = lam I to the mean pressure -tr(sigma) / 2 = p, in
  pressure steps (the material-point driver, warm-started from step to step; near jamming
  controlling sigma_11 = sigma_22 instead takes nearly free deviatoric steps, and the
  relaxations fail); there the relaxed and the Taylor tangents are taken at the same F;
* moduli from the spatial tangent a_abcd = F_bB F_dD A_aBcD / J (what the tangent of Cauchy's
  stress gives, its stress terms included): B = (a_1111 + a_2222 + a_1122 + a_2211) / 4, and G
  the average over the plane's orientations of the shear modulus,
  G = (a_1111 + a_2222 - a_1122 - a_2211) / 8 + (a_1212 + a_2121 + a_1221 + a_2112) / 8;
* coordination: z = 2 contacts / disks over the non-rattlers of the relaxed state;
* confined simple shear, F = [[1, gamma], [0, F22]] with sigma_22 = -p (p / k_n = 1e-3), for
  both laws; steps where the relaxed contact network changed are marked.

Writes to ``--out``: ``moduli.csv`` (one row per packing and pressure), ``shear.csv`` (every
shear step), ``relaxed_moduli.png``, ``relaxed_coordination.png``, ``relaxed_shear.png``.
"""

from __future__ import annotations

import csv
import os
import sys
import time

from dolfinx_granular import (
    ControlError,
    LawEvaluationError,
    MaterialPoint,
    RelaxedRVE,
    TaylorRVE,
)
from dolfinx_granular.drivers.confinement import compress, ramp
from dolfinx_granular.io.commandline import Parser, world_comm
from dolfinx_granular.io.outfolder import claim_or_refuse, claim_out
from dolfinx_granular.io.shear_figures import save_figure
from dolfinx_granular.laws.relaxed import at_rest
from dolfinx_granular.packings.cache import PackingCache

import numpy as np
from matplotlib.figure import Figure

K_N = 2.8e7  # N/m², table 1 of the paper
FULL = dict(particles=700, seeds=(0, 1, 2), pressures=(1e-5, 1e-4, 1e-3, 1e-2), shear_steps=40)
SMALL = dict(particles=70, seeds=(0,), pressures=(1e-3, 3e-3), shear_steps=4)
SHEAR_PRESSURE, MAX_SHEAR = 1e-3, 0.02
#: the files it writes in --out (what --force replaces; the packing cache is kept)
FILES = ("moduli.csv", "shear.csv", "relaxed_moduli.png", "relaxed_coordination.png",
         "relaxed_shear.png")  # fmt: skip


# %% [markdown]
# ## Packings jammed at each pressure, compressed to it
#
# ``compress`` and ``ramp`` (:mod:`dolfinx_granular.drivers.confinement`) step the material
# point in geometric pressure steps, halving a step where the network rearranges; the moduli
# rows compress along F = lam I (``isotropic=True``), the shear keeps sigma_22 = -p.


# %%


def moduli(F, P, A):
    """(B, G) in Pa of the spatial tangent of (F, P, A) (2, 2, 2, 2) (see the module doc)."""
    J = np.linalg.det(F)
    a = np.einsum("bB,dD,aBcD->abcd", F, F, A) / J
    B = (a[0, 0, 0, 0] + a[1, 1, 1, 1] + a[0, 0, 1, 1] + a[1, 1, 0, 0]) / 4
    G = (a[0, 0, 0, 0] + a[1, 1, 1, 1] - a[0, 0, 1, 1] - a[1, 1, 0, 0]) / 8
    G += (a[0, 1, 0, 1] + a[1, 0, 1, 0] + a[0, 1, 1, 0] + a[1, 0, 0, 1]) / 8
    return B, G


def coordination(rve, F, state):
    """z over the non-rattlers of the relaxed state at F, and the rattler fraction."""
    eq = at_rest(rve.cell, F, state.w[0], False)
    n = rve.packing.radii.shape[0]
    return 2.0 * eq.network.size / (n - eq.rattlers), eq.rattlers / n


def moduli_row(packing, seed, pressure):
    """One row of moduli.csv: the packing compressed to ``pressure``, both laws at its F."""
    relaxed = RelaxedRVE(packing, K_N)
    point = MaterialPoint(relaxed)
    t = time.perf_counter()
    try:
        # (the driver's strain steps capped at ten times the strain the pressure asks for)
        r = compress(point, pressure * K_N, max_increment=10 * pressure, isotropic=True)
    except (ControlError, LawEvaluationError) as err:  # e.g. a cell that unjams: report it
        keys = ("p_over_kn", "B_relaxed", "G_relaxed", "B_taylor", "G_taylor", "G_ratio", "z",
                "rattlers", "fluctuation")  # fmt: skip
        return dict(seed=seed, target=pressure, **dict.fromkeys(keys, np.nan),
                    seconds=time.perf_counter() - t, status=f"failed: {err}"[:200])  # fmt: skip
    seconds = time.perf_counter() - t
    _, Pr, Ar, _ = relaxed.evaluate(r.F, point.state)
    _, Pt, At = TaylorRVE(packing, K_N).evaluate(r.F)
    (Br, Gr), (Bt, Gt) = moduli(r.F, Pr, Ar), moduli(r.F, Pt, At)
    z, rattlers = coordination(relaxed, r.F, point.state)
    p = -np.trace(r.sigma) / 2
    return dict(
        seed=seed,
        target=pressure,
        p_over_kn=p / K_N,
        B_relaxed=Br,
        G_relaxed=Gr,
        B_taylor=Bt,
        G_taylor=Gt,
        G_ratio=Gt / Gr,
        z=z,
        rattlers=rattlers,
        fluctuation=float(point.state.fluctuation[0]),
        seconds=seconds,
        status="ok",
    )


# %% [markdown]
# ## Confined simple shear


# %%
def shear_rows(packing, steps):
    """Confined simple shear to MAX_SHEAR in ``steps`` for both laws: one dict per step (a path
    ends where its law failed, which is printed)."""
    rows, p = [], SHEAR_PRESSURE * K_N

    def load(gamma, F):
        F[0, 1] = gamma
        return F, {(0, 0): -p, (1, 1): -p}

    for name, law in (("relaxed", RelaxedRVE(packing, K_N)), ("taylor", TaylorRVE(packing, K_N))):
        point, cap = MaterialPoint(law), 10 * SHEAR_PRESSURE
        try:  # along F = lam I, as the moduli rows (mixed control fails near jamming)
            compress(point, p, max_increment=cap, isotropic=True)
            error = None
        except (ControlError, LawEvaluationError) as err:
            error = err
        gammas = np.linspace(0.0, MAX_SHEAR, steps + 1)[1:]
        path, error = ([], error) if error else ramp(point, gammas, load, cap, partial=True)
        if error is not None:
            print(f"confined shear, {name}: stopped: {error}"[:240])
        for r in path:
            s = r.sigma
            pm, q = -(s[0, 0] + s[1, 1]) / 2, np.hypot((s[0, 0] - s[1, 1]) / 2, s[0, 1])
            moved = bool(r.state.rearranged[0]) if name == "relaxed" else False
            rows.append(dict(law=name, gamma=r.F[0, 1], q_over_p=q / pm, p=pm, rearranged=moved))
    return rows


# %% [markdown]
# ## Figures and tables


# %%
def sqrt_line(ax, p, y, label):
    """A dashed c p^(1/2) over the range of p, c fitted (log mean) to the points with y > 0."""
    if np.any(y > 0):
        c = np.exp(np.mean(np.log(y[y > 0]) - 0.5 * np.log(p[y > 0])))
        ref = np.geomspace(p.min(), p.max(), 10)
        ax.loglog(ref, c * np.sqrt(ref), "k--", lw=0.8, label=label)


def moduli_figure(rows):
    fig = Figure(figsize=(6.4, 4.4))
    ax = fig.subplots()
    rows = [r for r in rows if r["status"] == "ok"]
    p = np.array([r["p_over_kn"] for r in rows])
    for key, style, label in (
        ("B_taylor", "s", "B Taylor"),
        ("G_taylor", "^", "G Taylor"),
        ("B_relaxed", "o", "B relaxed"),
        ("G_relaxed", "v", "G relaxed"),
    ):
        v = np.array([r[key] for r in rows]) / K_N
        ax.loglog(p[v > 0], v[v > 0], style, label=label, alpha=0.8)
    G = np.array([r["G_relaxed"] for r in rows]) / K_N
    sqrt_line(ax, p, G, "p^(1/2) (O'Hern et al. 2003)")
    ax.set_xlabel("p / k_n")
    ax.set_ylabel("modulus / k_n")
    ax.legend(fontsize=8)
    return fig


def coordination_figure(rows):
    fig = Figure(figsize=(5.6, 4.0))
    ax = fig.subplots()
    rows = [r for r in rows if r["status"] == "ok"]
    p = np.array([r["p_over_kn"] for r in rows])
    dz = np.array([r["z"] for r in rows]) - 4.0
    ax.loglog(p[dz > 0], dz[dz > 0], "o", label="relaxed, non-rattlers")
    sqrt_line(ax, p, dz, "p^(1/2)")
    ax.set_xlabel("p / k_n")
    ax.set_ylabel("z - 4")
    ax.legend(fontsize=8)
    return fig


def shear_figure(rows):
    fig = Figure(figsize=(6.0, 4.0))
    ax = fig.subplots()
    for law, style in (("taylor", "-"), ("relaxed", "-o")):
        r = [x for x in rows if x["law"] == law]
        g = 100 * np.array([x["gamma"] for x in r])
        qp = np.array([x["q_over_p"] for x in r])
        ax.plot(g, qp, style, ms=3, label=law)
        moved = np.array([x["rearranged"] for x in r])
        if moved.any():
            ax.plot(g[moved], qp[moved], "rx", label="relaxed: network changed")
    ax.set_xlabel("shear gamma (%)")
    ax.set_ylabel("q / p")
    ax.legend(fontsize=8)
    return fig


def write_csv(path, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def run(out="results/relaxed_study", small=False, verbose=True, force=False):
    """Run the study, write the CSVs and figures to ``out``; returns the two tables. An ``out``
    that holds a study raises ``RunExistsError`` first, unless ``force`` (which removes its
    files, no others)."""
    claim_out(out, FILES, force, "relaxed_study")
    cfg = SMALL if small else FULL
    say = print if verbose else (lambda *a, **k: None)
    cache = PackingCache(os.path.join(out, "packings"))  # (kept by force, reused)
    t0, rows = time.perf_counter(), []
    total = len(cfg["pressures"]) * len(cfg["seeds"])
    for pressure in cfg["pressures"]:
        for seed in cfg["seeds"]:
            rows.append(moduli_row(cache.get(cfg["particles"], seed, pressure), seed, pressure))
            r, done = rows[-1], f"packing {len(rows)} of {total}, {time.perf_counter() - t0:.0f} s"
            if r["status"] != "ok":
                say(f"p/kn {pressure:.0e} seed {seed}: {r['status']} ({done})")
                continue
            say(
                f"p/kn {r['p_over_kn']:.2e} seed {seed}: B {r['B_relaxed']:.3e} / "
                f"{r['B_taylor']:.3e} Pa, G {r['G_relaxed']:.3e} / {r['G_taylor']:.3e} Pa "
                f"(relaxed / Taylor), z {r['z']:.3f} ({done})"
            )
    say(f"confined shear in {cfg['shear_steps']} steps (the full study's longest part)")
    shear = shear_rows(
        cache.get(cfg["particles"], cfg["seeds"][0], SHEAR_PRESSURE), cfg["shear_steps"]
    )
    write_csv(os.path.join(out, "moduli.csv"), rows)
    write_csv(os.path.join(out, "shear.csv"), shear)
    for name, fig in (
        ("moduli", moduli_figure(rows)),
        ("coordination", coordination_figure(rows)),
        ("shear", shear_figure(shear)),
    ):
        save_figure(fig, os.path.join(out, f"relaxed_{name}.png"))
    negative = sum(r["G_relaxed"] < 0 for r in rows)
    failed = sum(r["status"] != "ok" for r in rows)
    ratio = np.array([r["G_ratio"] for r in rows if r["G_relaxed"] > 0])
    spread = (f"{ratio.min():.3g} to {ratio.max():.3g} (median {np.median(ratio):.3g})"
              if ratio.size else "none with G > 0")  # fmt: skip
    say(f"Taylor over relaxed G: {spread}; {negative} of {len(rows)} packings with G < 0, "
        f"{failed} failed")  # fmt: skip
    say(f"wrote {out}/ in {time.perf_counter() - t0:.1f} s")
    return rows, shear


def parse_args(argv=None):
    """The options; ``out`` resolved (``results/relaxed_study[-small]``)."""
    parser = Parser(description=__doc__.split("\n")[0])
    parser.add_output("relaxed_study")
    return parser.parse_args(argv)


def main(argv=None):
    args = parse_args(argv)
    comm = world_comm()
    # every rank takes rank 0's answer (exit status 2 alike) before any work
    if claim_or_refuse(args.out, FILES, args.force, "relaxed_study", comm):
        return 2
    if comm is None or comm.rank == 0:  # a serial study: rank 0 runs it, the others rest
        run(args.out, small=args.small, force=args.force)
    return 0


# %% [markdown]
# Run as a script; in a notebook call `run("results/relaxed_study")` instead of this cell
# (`force=True` replaces an earlier study there).

# %%
if __name__ == "__main__":
    sys.exit(main())
