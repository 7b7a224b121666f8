# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Frictional relaxed RVE: the substep, confined simple shear and biaxial tests against friction
#
# A `FrictionalRelaxedRVE` relaxes frictional disks (Coulomb's law, rotations free) to static
# equilibrium at every F, along the quasi-static path from its committed state in substeps;
# each substep is one backward-Euler increment of the contact law, so the substep is part of
# the model. This study states the substep and shows how the answer converges as it shrinks,
# then shears one material point under a constant confining pressure, and compresses it in a
# biaxial test under a constant lateral stress, for several contact friction coefficients mu,
# beside the frictional Taylor RVE (`FrictionalRVE`) on the same packings and load paths. For
# 2-D disks the literature finds a macroscopic friction q/p of about 0.1 without contact
# friction and 0.25-0.30 at the critical state for mu = 0.4-0.5 (da Cruz et al. 2005),
# saturating above mu ~ 0.5, and a peak of about 0.38-0.45 for dense packings at mu = 0.5 (the
# values the figure shows as a reference).

# %%
"""Frictional relaxed RVE: substep convergence, confined shear and biaxial tests; Taylor beside.

    python demos/relaxed_friction_study.py [--out results/relaxed_friction_study] [--small]
        [--budget SECONDS] [--force] [--tests convergence,shear,biaxial] [--particles N]
        [--seeds 0,1,2] [--mus 0,0.1,0.3,0.5,1] [--pressures 1e-2,1e-3] [--max-shear G]
        [--shear-steps K] [--max-strain E] [--biaxial-steps K]

``--small`` (or ``DEMO_SMALL=1``) is the reduced run of the tests, written to
``results/relaxed_friction_study-small`` by default; the other options replace that run's (or
the full run's) values, so the issue's study is e.g. ``--particles 700 --max-shear 0.5
--shear-steps 250 --max-strain 0.3 --biaxial-steps 60 --budget 0``. Under ``mpirun`` rank 0
runs the (serial) study and the other ranks exit. An ``--out`` that holds the study's tables or
figures is refused (exit status 2) unless ``--force``, which replaces those files and no
others; the packings cached in ``OUT/packings`` and the tests in ``OUT/tests`` (each shear and
biaxial test's rows, :class:`~dolfinx_granular.drivers.element_cache.ElementTestCache`) stay and
are reused, so that a study stopped and started again with ``--force`` goes on where it stopped.

* packings: ``generate_packing(n, seed, pressure=p)`` for each confining pressure p / k_n (the
  network jammed at that pressure), cached; 200 disks, seeds 0-2 (``--small``: 70 disks, seed 0);
* contacts: k_n = k_t = 2.8e7 N/m² (table 1 of the paper; k_t = k_n as the friction study);
* confinement: F = lam I compressed to the mean pressure -tr(sigma) / 2 = p
  (:func:`~dolfinx_granular.drivers.confinement.compress` with ``isotropic=True``, as the
  relaxed study: near jamming, mixed control of the confinement takes the nearly free
  deviatoric steps), for the relaxed and the Taylor RVE alike; the law's default path settings
  (substep 1e-3, ``substep_overlap`` 0.25);
* substep convergence: the packing confined at p / k_n = 1e-2, mu = 0.5, then strain-controlled
  simple shear F = F_c [[1, gamma], [0, 1]] to gamma = 2 % (``--small``: 1 %) in load steps of
  |dU| just under 0.9e-3, with ``rve.settings.substep`` = 1e-3, 5e-4, 2.5e-4, 1.25e-4
  (``substep_overlap`` = 1e9, so that ``substep`` alone sets the substep): each load step is
  then 1, 2, 4, 8 substeps, every substep half the last; the confined state is the same for all
  four (only the shear path's substep changes);
* confined simple shear: F = [[1, gamma], [0, 1 + e22]] F_c (F_c = lam I the confined state,
  gamma the shear of the confined cell), F11 = lam held (rigid side walls, the friction study's
  box) and e22 solved by the material-point driver (:class:`~dolfinx_granular.MaterialPoint`)
  so that sigma_22 = -p (Newton from e22 extrapolated along the last step); to gamma = 10 % in
  50 steps (``--small``: 1 % in 5);
* biaxial test: F = [[1 + e11, 0], [0, 1 - eps1]] F_c, the axial compression eps1 prescribed,
  F12 = F21 = 0, and e11 solved so that the lateral stress sigma_11 = -p (as e22 in the shear);
  to eps1 = 30 % in 60 steps of 0.5 % (``--small``: 1 % in 4);
* both tests for mu = 0, 0.1, 0.3, 0.5, 1 at p / k_n = 1e-2, 1e-3 (``--small``: mu = 0, 0.5 at
  1e-2). A step that fails (the micro solver's ``RelaxationError`` where the cell rearranges,
  or the driver) is halved, 3 times at most; then the test stops there and records how far it
  got and why, and the study goes on. ``--budget`` caps each test's wall time, checked before
  every step, so a slow step can overrun it (default: none with ``--small``, 90 s otherwise:
  the full shear study then took 46 min on 2 busy cores); a test stopped by it says so. How far
  such a test gets depends on the machine; the path up to there does not.

Measures (2-D, compression positive): p = -(sigma_11 + sigma_22) / 2,
q = sqrt(((sigma_11 - sigma_22) / 2)^2 + sigma_12^2) = (sigma_1 - sigma_3) / 2 from the
principal stresses, q / p = sin(phi mobilised), tau / p = sigma_12 / p; the volumetric strain
e_v = ln(det F / det F_c) from the confined state (dilation positive), and the dilatancy
d e_v / d x along the test's strain x = gamma or eps1 (secants over a tenth of the path reached:
peak the largest, final the secant over its last fifth); the coordination z = 2 C / N over the
N disks with at least 2 contacts (overlap > 0) and the C contacts between them; the share of
the contacts that slid in the step (empty at mu = 0, where no contact carries a tangential
force: the Taylor law calls all of them sliding, the relaxed one none); the dissipation since
the confined state. The "critical state" of a test (columns ``*_critical_last_quarter``) is
the mean over the steps in the last quarter of the strain it reached (x >= 0.75 x_reached): of
a test stopped early (``stopped``) it is only where that test got to.

Writes to ``--out``: ``convergence.csv`` (one row per substep); per test (``shear``,
``biaxial``) ``<test>_steps.csv`` (every step of every test, both laws), ``<test>_tests.csv``
(one row per test: how far it got, its stop message, peak, critical and final q / p,
dilatancy, z and sliding share) and ``<test>_summary.csv`` (one row per law, mu and p: mean and
standard deviation over the seeds); the figures ``relaxed_friction_convergence.png``,
``relaxed_friction_qp_gamma.png`` (shear), ``relaxed_friction_biaxial.png`` and
``relaxed_friction_qp_mu.png`` (both tests). ``--tests`` leaves out the files of those it skips.
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
import time

from dolfinx_granular import ControlError, LawEvaluationError, MaterialPoint
from dolfinx_granular.drivers.element_cache import ElementTestCache
from dolfinx_granular.drivers.element_tests import (
    BIAXIAL,
    LOADINGS,
    SHEAR,
    confine,
    make_law,
    measures,
    ratios,
)
from dolfinx_granular.io.commandline import Parser, checked_values, world_comm
from dolfinx_granular.io.outfolder import claim_or_refuse, claim_out
from dolfinx_granular.io.shear_figures import save_figure
from dolfinx_granular.laws.relaxed.path import stretch, stretches_between
from dolfinx_granular.packings.cache import PackingCache
from dolfinx_granular.packings.generation import MAX_PRESSURE

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

SUBSTEPS = (1e-3, 5e-4, 2.5e-4, 1.25e-4)  # the substeps of the convergence study
CONVERGENCE = dict(pressure=1e-2, mu=0.5)  # p / k_n and mu of the convergence study
# the literature's macroscopic friction q/p of 2-D disks (the reference of the q/p-mu figure):
# about 0.1 without contact friction, 0.25-0.30 at the critical state for mu = 0.4-0.5
# (da Cruz et al. 2005), saturating above mu ~ 0.5; a peak of 0.38-0.45 (dense, mu = 0.5)
LITERATURE_MU0 = 0.1
LITERATURE_CRITICAL = ((0.4, 0.5), (0.25, 0.30))
LITERATURE_PEAK = (0.5, (0.38, 0.45))
DPI = 110

TESTS = ("convergence", "shear", "biaxial")
FULL = dict(tests=TESTS, particles=200, seeds=(0, 1, 2), mus=(0.0, 0.1, 0.3, 0.5, 1.0),
            pressures=(1e-2, 1e-3), max_shear=0.10, shear_steps=50, max_strain=0.30,
            biaxial_steps=60, convergence_shear=0.02, budget=90.0)  # fmt: skip
SMALL = dict(tests=TESTS, particles=70, seeds=(0,), mus=(0.0, 0.5), pressures=(1e-2,),
             max_shear=0.01, shear_steps=5, max_strain=0.01, biaxial_steps=4,
             convergence_shear=0.01, budget=None)  # fmt: skip
#: the files it writes in --out (what --force replaces; the packing cache is kept)
FILES = ("convergence.csv", "shear_steps.csv", "shear_tests.csv", "shear_summary.csv",
         "biaxial_steps.csv", "biaxial_tests.csv", "biaxial_summary.csv",
         "relaxed_friction_convergence.png", "relaxed_friction_qp_gamma.png",
         "relaxed_friction_biaxial.png", "relaxed_friction_qp_mu.png")  # fmt: skip

# %% [markdown]
# ## Packings, laws and measures
#
# The packings are jammed at the confining pressure and cached (the relaxed study's files); the
# confinement compresses them along F = lam I to it. The laws (`make_law`), the confinement
# (`confine`) and the measures (`ratios`, `network`) are the package's element tests,
# `dolfinx_granular.drivers.element_tests`, as the `strength` command uses them.


# %% [markdown]
# ## 1. The substep
#
# Strain-controlled simple shear of the confined cell, F = F_c [[1, gamma], [0, 1]], from the
# same confined state with each substep. The load steps are just under the coarsest substep in
# |dU| (U the right stretch), so that a load step is 1, 2, 4 or 8 substeps: the substep halves
# exactly from one row to the next.


# %%
def shear_gammas(lam, max_shear, longest):
    """gamma (k,) of simple shear F = lam [[1, gamma], [0, 1]] to ``max_shear`` in equal steps
    with |dU| just under 0.9 ``longest`` (|dU| = lam dgamma / sqrt(2) to first order)."""
    dgamma = 0.9 * longest * np.sqrt(2.0) / lam
    steps = int(np.ceil(max_shear / dgamma))
    return np.linspace(0.0, max_shear, steps + 1)[1:]


def simple_shear(Fc, gamma):
    return Fc @ np.array([[1.0, gamma], [0.0, 1.0]])


def substep_run(rve, confined, gammas, substep):
    """Strain-controlled shear along ``gammas`` from the ``confined`` point's state with
    ``rve.settings.substep = substep``: ``(row, curve)``, the row a dict of the end (sigma_12 /
    p, q / p, dissipation in the shear) with the substeps per load step (min-max) and the
    effective substep (the largest |dU| of a substep), or the error where it stopped; the curve
    (gamma (k,), tau / p (k,)) from the confined state on."""
    rve.settings.substep, rve.settings.substep_overlap = substep, 1e9
    point = MaterialPoint(rve, state=confined.state)
    Fc = point.F = confined.F.copy()
    counts, longest, t0 = [], 0.0, time.perf_counter()
    row, curve = dict(substep=substep), [(0.0, ratios(confined.last.sigma)[2])]
    try:
        for g in gammas:
            F = simple_shear(Fc, g)
            m = stretches_between(point.F, F, substep).shape[0] + 1
            counts.append(m)
            longest = max(longest, np.linalg.norm(stretch(F) - stretch(point.F)) / m)
            r = point.step(F)
            curve.append((g, ratios(r.sigma)[2]))
    except (ControlError, LawEvaluationError) as err:
        row.update(gamma=float(point.F[0, 1] / Fc[0, 0]), status=f"stopped: {err}"[:200])
        row.update(sigma12_over_p=np.nan, q_over_p=np.nan, dissipation_Pa=np.nan)
    else:
        p, qp, taup = ratios(r.sigma)
        D = float(r.state.dissipation[0] - confined.state.dissipation[0])
        row.update(gamma=float(gammas[-1]), status="ok", sigma12_over_p=taup, q_over_p=qp,
                   dissipation_Pa=D)  # fmt: skip
    row.update(substeps_per_step=f"{min(counts)}-{max(counts)}" if counts else "",
               effective_substep=longest, seconds=time.perf_counter() - t0)  # fmt: skip
    return row, tuple(np.array(c) for c in zip(*curve))


def convergence_rows(packing, max_shear, say):
    """``(rows, curves)``: one row per substep of :data:`SUBSTEPS` with the differences to the
    finest's, and ``{substep: (gamma, tau / p)}``."""
    rve = make_law("relaxed", packing, CONVERGENCE["mu"])
    confined = confine(rve, CONVERGENCE["pressure"])
    gammas = shear_gammas(confined.F[0, 0], max_shear, max(SUBSTEPS))
    say(f"substep convergence: mu = {CONVERGENCE['mu']:g}, p/kn = {CONVERGENCE['pressure']:g}, "
        f"gamma to {100 * max_shear:g} % in {gammas.size} load steps")  # fmt: skip
    rows, curves = [], {}
    for h in SUBSTEPS:
        row, curves[h] = substep_run(rve, confined, gammas, h)
        rows.append(row)
        say(f"  substep {h:g}: {row['status'][:120]} ({row['seconds']:.1f} s)")
    finest = rows[-1]
    for r in rows:
        for key in ("sigma12_over_p", "q_over_p"):
            r[f"diff_{key}"] = r[key] - finest[key]
        r["rel_diff_dissipation"] = r["dissipation_Pa"] / finest["dissipation_Pa"] - 1.0
    return rows, curves


# %% [markdown]
# ## 2. Confined simple shear and the biaxial test
#
# Both start from the confined state F_c = lam I and prescribe one strain x in steps while the
# material-point driver solves one more, y, so that a normal stress stays -p
# (`dolfinx_granular.drivers.element_tests`: `Loading`, `SHEAR`, `BIAXIAL`, `load_test`). A
# step that fails is halved; a step that fails after `MAX_CUTS` halvings ends the test, which
# keeps the steps it reached and the error (the known limit of the micro solver at large
# strain, where the cell rearranges). `measures` gives a test's scalars (how far it got, peak
# and critical q/p, dilatancy, z, sliding share). Each test is run once: `ElementTestCache`
# keeps its rows in `OUT/tests` (kept by `--force`, as the packings), so that a study stopped
# and started again goes on where it stopped.


# %% [markdown]
# ## Tables and figures


# %%
def fmt(v):
    """A CSV cell: floats as their shortest round-trip repr (NaN as empty)."""
    if isinstance(v, (float, np.floating)):
        return "" if np.isnan(v) else repr(float(v))
    return v


def write_csv(path, rows, header=None):
    header = header or list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=header)
        w.writeheader()
        w.writerows({k: fmt(v) for k, v in r.items()} for r in rows)


SUMMARY_KEYS = ("qp_peak", "qp_critical_last_quarter", "qp_final", "taup_final",
                "dilatancy_peak", "dilatancy_final", "ev_final", "z_critical_last_quarter",
                "z_final", "sliding_critical_last_quarter", "sliding_final")  # fmt: skip


def summary_rows(tests, loading):
    """One row per (law, mu, p): mean and std over the seeds, the smallest strain reached and
    the number of tests stopped early (their critical and final values: where they got to)."""
    reached = f"{loading.drive}_reached"
    groups = {}
    for t in tests:
        groups.setdefault((t["law"], t["mu"], t["p_over_kn"]), []).append(t)
    rows = []
    for (law, mu, p), ts in groups.items():
        row = dict(law=law, mu=mu, p_over_kn=p, seeds=len(ts))
        for key in (*SUMMARY_KEYS, reached):
            v = np.array([t.get(key, np.nan) for t in ts], dtype=float)
            ok = v[np.isfinite(v)]
            row[f"{key}_mean"] = ok.mean() if ok.size else np.nan
            row[f"{key}_std"] = ok.std(ddof=1) if ok.size > 1 else (0.0 if ok.size else np.nan)
        row[f"{reached}_min"] = min(t[reached] for t in ts)
        row["stopped"] = sum(t["stopped"] for t in ts)
        rows.append(row)
    return rows


def _colors(n):
    return colormaps["viridis"](np.linspace(0.0, 0.9, n))


def convergence_figure(conv, paths):
    """Left: tau / p over gamma for each substep; right: the end's difference to the finest
    substep against the substep (log-log), with a first-order line."""
    fig = Figure(figsize=(10.4, 4.2))
    left, right = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    for color, (h, path) in zip(_colors(len(paths)), paths.items()):
        left.plot(100 * path[0], path[1], "-o", ms=2.5, color=color, label=f"substep {h:g}")
    left.set_xlabel("shear strain γ [%]")
    left.set_ylabel("τ / p = σ12 / p")
    left.legend(fontsize=8)
    rows = [r for r in conv[:-1] if r["status"] == "ok"]
    h = np.array([r["substep"] for r in rows])
    for key, label in (("diff_sigma12_over_p", "|Δ τ/p|"), ("diff_q_over_p", "|Δ q/p|"),
                       ("rel_diff_dissipation", "|Δ D| / D")):  # fmt: skip
        d = np.abs([r[key] for r in rows])
        if np.any(d > 0):
            right.loglog(h[d > 0], d[d > 0], "o-", label=label)
            right.loglog(h, d[0] * h / h[0], "k:", lw=0.8)
    right.set_xlabel("substep (|ΔU| of the right stretch)")
    right.set_ylabel(f"difference to substep {conv[-1]['substep']:g}")
    right.legend(fontsize=8, title="dotted: first order", title_fontsize=7)
    for ax in (left, right):
        ax.grid(True, alpha=0.3)
    fig.suptitle("Frictional relaxed RVE: simple shear against the substep", fontsize=10)
    fig.tight_layout()
    return fig


def curves_figure(paths, cfg, loading):
    """q / p (top) and e_v (bottom) over the test's strain, one column per p, one colour per
    mu; relaxed solid (thick: the first seed), Taylor dashed; a cross where a relaxed test
    stopped."""
    pressures, mus, seeds = cfg["pressures"], cfg["mus"], cfg["seeds"]
    fig = Figure(figsize=(max(6.4, 5.2 * len(pressures)), 7.0))
    for j, p in enumerate(pressures):
        top = fig.add_subplot(2, len(pressures), j + 1)
        bot = fig.add_subplot(2, len(pressures), len(pressures) + j + 1, sharex=top)
        for color, mu in zip(_colors(len(mus)), mus):
            for law, style in (("relaxed", "-"), ("taylor", "--")):
                for s in seeds:
                    rows, stop = paths.get((law, mu, p, s), ([], ""))
                    if not rows:
                        continue
                    g = 100 * np.array([r[loading.drive] for r in rows])
                    first = s == seeds[0]
                    kw = dict(color=color, lw=1.5 if first else 0.6, alpha=1.0 if first else 0.6)
                    label = f"μ = {mu:g} ({law})" if first else None
                    top.plot(g, [r["q_over_p"] for r in rows], style, label=label, **kw)
                    bot.plot(g, [100 * r["volumetric_strain"] for r in rows], style, **kw)
                    if stop and law == "relaxed":
                        top.plot(g[-1], rows[-1]["q_over_p"], "x", color="red", ms=6)
        top.set_title(f"p / k_n = {p:g} (x: relaxed test stopped)", fontsize=9)
        top.set_ylabel("q / p = sin φ")
        bot.set_ylabel("volumetric strain e_v = ln(J / J_c) [%]")
        bot.set_xlabel(loading.label)
        for ax in (top, bot):
            ax.grid(True, alpha=0.3)
        top.legend(fontsize=6, ncol=2)
    title = (f"{loading.title}, {cfg['particles']} disks, {len(seeds)} seed(s)\n"
             "relaxed (solid) and Taylor (dashed)")  # fmt: skip
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


#: the q/p-mu figure's markers per (test, law), lines per test and colours per pressure (C3:
#: the literature)
MARKERS = {("shear", "relaxed"): "o", ("shear", "taylor"): "s", ("biaxial", "relaxed"): "^",
           ("biaxial", "taylor"): "D"}  # fmt: skip
LINES = {"shear": ("-", ":"), "biaxial": ("--", "-.")}  # (peak, critical)
PRESSURE_COLORS = ("C0", "C1", "C2", "C4", "C5", "C6", "C8", "C9")


def literature_bands(ax, top):
    """The literature's q/p of 2-D disks on ``ax`` (mu up to ``top``)."""
    (m0, m1), (q0, q1) = LITERATURE_CRITICAL
    ax.fill_between([m0, m1], q0, q1, color="C3", alpha=0.25,
                    label="2-D disks, literature:\ncritical state, μ = 0.4-0.5")  # fmt: skip
    if top > m1:
        ax.fill_between([m1, top], q0, q1, color="C3", alpha=0.08,
                        label="literature: saturating\nabove μ ≈ 0.5")  # fmt: skip
    mp, (p0, p1) = LITERATURE_PEAK
    ax.plot([mp, mp], [p0, p1], color="C3", lw=7, alpha=0.45, solid_capstyle="butt",
            label=f"literature: peak, dense, μ = {mp:g}")  # fmt: skip
    ax.plot([0.0], [LITERATURE_MU0], "*", color="C3", ms=12, label="literature: μ = 0")


def qp_mu_figure(summaries, cfg):
    """Peak and critical q / p over mu (mean ± std over the seeds) for each test, law and p,
    beside the literature's values for 2-D disks. ``summaries``: {test: summary rows}."""
    fig = Figure(figsize=(10.4, 5.2))
    ax = fig.add_subplot()
    for test, summary in summaries.items():
        for law in ("relaxed", "taylor"):
            marker, alpha = MARKERS[test, law], 1.0 if law == "relaxed" else 0.45
            for k, p in enumerate(cfg["pressures"]):
                rows = [r for r in summary if r["law"] == law and r["p_over_kn"] == p]
                mu = np.array([r["mu"] for r in rows])
                for what, ls, fill in zip(("peak", "critical_last_quarter"), LINES[test],
                                          ("none", None)):  # fmt: skip
                    ax.errorbar(
                        mu, [r[f"qp_{what}_mean"] for r in rows],
                        yerr=[r[f"qp_{what}_std"] for r in rows], fmt=marker + ls,
                        color=PRESSURE_COLORS[k % len(PRESSURE_COLORS)], alpha=alpha, mfc=fill,
                        ms=6, capsize=3, label=f"{test}, {law}, p/kn = {p:g}, {what[:8]}",
                    )  # fmt: skip
    literature_bands(ax, max(cfg["mus"]))
    ax.set_xlabel("contact friction coefficient μ")
    ax.set_ylabel("q / p = sin φ (peak: open, critical: filled)")
    ax.set_title("Macroscopic against contact friction (mean ± std over the seeds; critical: the "
                 "mean over the last quarter\nof the strain each test reached, where it got to "
                 "if stopped early: *_tests.csv)", fontsize=8)  # fmt: skip
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=6, loc="center left", bbox_to_anchor=(1.02, 0.5))
    fig.tight_layout()
    return fig


def print_convergence(say, conv):
    say("\nsubstep convergence (end of the shear; differences to the finest substep)")
    say("  substep  substeps/step  tau/p      q/p        D [Pa]       Δ tau/p     Δ q/p      "
        "ΔD/D       time [s]")  # fmt: skip
    for r in conv:
        if r["status"] != "ok":
            say(f"  {r['substep']:7.3g}  {r['status']}")
            continue
        say(f"  {r['substep']:7.3g}  {r['substeps_per_step']:>13}  {r['sigma12_over_p']:.6f}  "
            f"{r['q_over_p']:.6f}  {r['dissipation_Pa']:11.4f}  {r['diff_sigma12_over_p']:+.3e}  "
            f"{r['diff_q_over_p']:+.3e}  {r['rel_diff_dissipation']:+.3e}  "
            f"{r['seconds']:7.1f}")  # fmt: skip


def print_summary(say, loading, tests, summary):
    """The table of one test: mean ± std over the seeds; its tests stopped early."""
    x = loading.drive
    say(
        f"\n{loading.test}: mean ± std over the seeds of q/p = sin phi (crit: the mean over the "
        "last quarter of the strain reached;\n  final: the last step; of a test stopped early "
        "both are where it got to), e_v, dilatancy d e_v / d " + x + ", z, sliding share"
    )
    say("  law      mu    p/kn   q/p peak     q/p crit     q/p final  e_v fin %  dil peak  "
        f"dil fin  z crit  slid crit  {x} reached (min)   stopped")  # fmt: skip
    for r in summary:
        say(f"  {r['law']:7s}  {r['mu']:3g}  {r['p_over_kn']:6.0e}  "
            f"{r['qp_peak_mean']:.3f}±{r['qp_peak_std']:.3f}  "
            f"{r['qp_critical_last_quarter_mean']:.3f}±{r['qp_critical_last_quarter_std']:.3f}  "
            f"{r['qp_final_mean']:9.3f}  {100 * r['ev_final_mean']:9.3f}  "
            f"{r['dilatancy_peak_mean']:8.3f}  {r['dilatancy_final_mean']:7.3f}  "
            f"{r['z_critical_last_quarter_mean']:6.3f}  "
            f"{r['sliding_critical_last_quarter_mean']:9.3f}  "
            f"{100 * r[f'{x}_reached_mean']:6.2f} % ({100 * r[f'{x}_reached_min']:6.2f} %)"
            f"  {r['stopped']} of {r['seeds']}")  # fmt: skip
    for t in (t for t in tests if t["stopped"]):
        say(
            f"  stopped early: {t['law']} mu {t['mu']:g} p/kn {t['p_over_kn']:g} seed "
            f"{t['seed']} at {x} {100 * t[f'{x}_reached']:.3f} %: {t['message'][:160]}"
        )


# %% [markdown]
# ## The study


# %%
def run_tests(loading, cfg, packings, stored, say, t0):
    """Every test of ``loading`` (both laws, each mu, p and seed): ``(steps, tests, summary,
    paths)``; writes nothing but the tests' cache: ``packings`` (:class:`PackingCache`) gives the
    packings, ``stored`` (:class:`ElementTestCache`) runs each test once."""
    top, count = (cfg[key] for key in loading.limits)
    targets = np.linspace(0.0, top, count + 1)[1:]
    steps, tests, paths = [], [], {}
    total = len(cfg["pressures"]) * len(cfg["mus"]) * len(cfg["seeds"])
    x = loading.drive
    for p in cfg["pressures"]:
        for mu in cfg["mus"]:
            for s in cfg["seeds"]:
                packing = packings.get(cfg["particles"], s, p)
                for law in ("relaxed", "taylor"):
                    rve = make_law(law, packing, mu)
                    run = stored.run(loading, rve, packing, s, p, targets, cfg["budget"])
                    rows, stop = run.rows, run.stop
                    paths[(law, mu, p, s)] = (rows, stop)
                    key = dict(law=law, mu=mu, p_over_kn=p, seed=s)
                    steps += [dict(key, step=k, **r) for k, r in enumerate(rows)]
                    m = measures(rows, stop, top, loading)
                    tests.append(dict(key, **m, seconds=run.seconds))
                    if law == "relaxed":
                        say(f"{loading.test} relaxed mu {mu:g} p/kn {p:g} seed {s}: {x} "
                            f"{100 * m[f'{x}_reached']:.2f} % in {run.seconds:.1f} s"
                            f"{' (cached)' if run.cached else ''}"
                            f"{' (' + stop[:100] + ')' if stop else ''} "
                            f"[test {len(tests) // 2 + 1} of {total}, "
                            f"{time.perf_counter() - t0:.0f} s]")  # fmt: skip
    return steps, tests, summary_rows(tests, loading), paths


def configuration(small, budget, options):
    """The run's configuration: :data:`SMALL` or :data:`FULL` with ``options`` (its keys; None:
    the default) and ``budget`` ("default": the configuration's) in place."""
    cfg = dict(SMALL if small else FULL)
    unknown = sorted(set(options) - set(cfg))
    if unknown:
        raise TypeError(f"unknown option(s) {unknown}: the configuration's are {sorted(cfg)}")
    cfg.update({k: v for k, v in options.items() if v is not None})
    if budget != "default":
        cfg["budget"] = budget
    return cfg


def run(out="results/relaxed_friction_study", small=False, verbose=True, force=False,
        budget="default", **options):  # fmt: skip
    """Run the study, write the CSVs and figures to ``out``; returns ``(convergence rows or
    None, {test: (test rows, summary rows)})``. ``budget``: seconds per test (None: no limit;
    "default": the configuration's); ``options``: the configuration's other values (tests,
    particles, seeds, mus, pressures, max_shear, shear_steps, max_strain, biaxial_steps). An
    ``out`` that holds a study raises ``RunExistsError`` first, unless ``force`` (which removes
    its files, no others)."""
    claim_out(out, FILES, force, "relaxed_friction_study")
    cfg = configuration(small, budget, options)
    say = print if verbose else (lambda *a, **k: None)
    # (both kept by force, and reused: a study started again goes on where it stopped)
    cache = PackingCache(os.path.join(out, "packings"))
    stored = ElementTestCache(os.path.join(out, "tests"))
    t0 = time.perf_counter()
    figures, conv, results = {}, None, {}

    if "convergence" in cfg["tests"]:  # 1. the substep
        packing = cache.get(cfg["particles"], cfg["seeds"][0], CONVERGENCE["pressure"])
        conv, curves = convergence_rows(packing, cfg["convergence_shear"], say)
        write_csv(os.path.join(out, "convergence.csv"), conv)
        figures["convergence"] = convergence_figure(conv, curves)

    for loading in (SHEAR, BIAXIAL):  # 2. confined shear, the biaxial test
        if loading.test not in cfg["tests"]:
            continue
        steps, tests, summary, paths = run_tests(loading, cfg, cache, stored, say, t0)
        for name, rows in (("steps", steps), ("tests", tests), ("summary", summary)):
            write_csv(os.path.join(out, f"{loading.test}_{name}.csv"), rows)
        name = "qp_gamma" if loading is SHEAR else "biaxial"
        figures[name] = curves_figure(paths, cfg, loading)
        results[loading.test] = (tests, summary)
    if results:
        figures["qp_mu"] = qp_mu_figure({k: v[1] for k, v in results.items()}, cfg)

    for name, fig in figures.items():
        save_figure(fig, os.path.join(out, f"relaxed_friction_{name}.png"), DPI)
    if conv is not None:
        print_convergence(say, conv)
    for test, (tests, summary) in results.items():
        print_summary(say, LOADINGS[test], tests, summary)
    say(f"\nwrote {out}/ in {time.perf_counter() - t0:.1f} s")
    return conv, results


# %% [markdown]
# ## The command line
#
# Every option of the configuration; a bad value is an argparse error (exit status 2) that
# names the option and what to give instead.


# %%
def _tests(text):
    """The tests of ``--tests`` in :data:`TESTS`'s order."""
    names = [t.strip() for t in text.split(",") if t.strip()]
    bad = [t for t in names if t not in TESTS]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"unknown test(s) {', '.join(bad) or repr(text)}: give a comma-separated list of "
            f"{', '.join(TESTS)}, e.g. shear,biaxial"
        )
    return tuple(t for t in TESTS if t in names)


def parse_args(argv=None):
    """The options; ``out`` resolved (``results/relaxed_friction_study[-small]``)."""
    whole = "a whole number >= 1"
    budget = checked_values(float, lambda v: v >= 0.0, "seconds >= 0 (0: none)", "90")
    particles = checked_values(int, lambda v: v >= 10, "a whole number >= 10", "700")
    seeds = checked_values(
        int, lambda v: v >= 0, "comma-separated whole numbers >= 0", "0,1,2", True
    )
    mus = checked_values(
        float, lambda v: v >= 0.0, "comma-separated mu >= 0", "0,0.1,0.3,0.5,1", True
    )
    range_p = f"comma-separated p / k_n in (0, {MAX_PRESSURE:g}]"
    pressures = checked_values(float, lambda v: 0.0 < v <= MAX_PRESSURE, range_p, "1e-2,1e-3", True)
    shear = checked_values(float, lambda v: 0.0 < v <= 2.0, "a shear strain in (0, 2]", "0.5")
    strain = checked_values(float, lambda v: 0.0 < v < 0.9, "an axial strain in (0, 0.9)", "0.3")
    shear_steps = checked_values(int, lambda v: v >= 1, whole, "250")
    biaxial_steps = checked_values(int, lambda v: v >= 1, whole, "60")
    parser = Parser(description=__doc__.split("\n")[0])
    parser.add_output("relaxed_friction_study")
    add = parser.add_argument
    add("--budget", type=budget, help="wall seconds per test (default: 90, --small: none; 0: none)")
    add("--tests", type=_tests, help=f"comma-separated, of {', '.join(TESTS)} (default: all)")
    add("--particles", type=particles, help="disks per packing (default: 200, --small: 70)")
    add("--seeds", type=seeds, help="packing seeds (default: 0,1,2, --small: 0)")
    add("--mus", type=mus, help="contact friction (default: 0,0.1,0.3,0.5,1, --small: 0,0.5)")
    add("--pressures", type=pressures, help="p / k_n (default: 1e-2,1e-3, --small: 1e-2)")
    add("--max-shear", type=shear, help="the shear's last gamma (default: 0.1, --small: 0.01)")
    add("--shear-steps", type=shear_steps, help="steps to --max-shear (default: 50, --small: 5)")
    add("--max-strain", type=strain, help="the biaxial's last eps1 (default: 0.3, --small: 0.01)")
    add(
        "--biaxial-steps",
        type=biaxial_steps,
        help="steps to --max-strain (default: 60, --small: 4)",
    )
    return parser.parse_args(argv)


#: the options that go to :func:`run` as configuration values
OPTIONS = ("tests", "particles", "seeds", "mus", "pressures", "max_shear", "shear_steps",
           "max_strain", "biaxial_steps")  # fmt: skip


def main(argv=None):
    args = parse_args(argv)
    comm = world_comm()
    # every rank takes rank 0's answer (exit status 2 alike) before any work
    if claim_or_refuse(args.out, FILES, args.force, "relaxed_friction_study", comm):
        return 2
    if comm is None or comm.rank == 0:  # a serial study: rank 0 runs it, the others rest
        budget = "default" if args.budget is None else (args.budget or None)
        options = {name: getattr(args, name) for name in OPTIONS}
        run(args.out, small=args.small, force=args.force, budget=budget, **options)
    return 0


# %% [markdown]
# Run as a script; in a notebook call `run("results/relaxed_friction_study")` instead of this
# cell (`force=True` replaces an earlier study there; the configuration's values as keywords,
# e.g. `run(out, tests=("biaxial",), particles=700, max_strain=0.3, biaxial_steps=60)`).

# %%
if __name__ == "__main__":
    sys.exit(main())
