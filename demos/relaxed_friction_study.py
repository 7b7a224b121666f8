# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Frictional relaxed RVE: the substep, and confined simple shear against contact friction
#
# A `FrictionalRelaxedRVE` relaxes frictional disks (Coulomb's law, rotations free) to static
# equilibrium at every F, along the quasi-static path from its committed state in substeps;
# each substep is one backward-Euler increment of the contact law, so the substep is part of
# the model. This study states the substep and shows how the answer converges as it shrinks,
# then shears one material point under a constant confining pressure for several contact
# friction coefficients mu, beside the frictional Taylor RVE (`FrictionalRVE`) on the same
# packings and load path. For 2-D disks the literature finds a macroscopic friction
# q/p of about 0.1 without contact friction and 0.25-0.30 at the critical state for
# mu = 0.4-0.5 (the values the figure shows as a reference).

# %%
"""Frictional relaxed RVE: substep convergence, confined simple shear for several mu, Taylor beside.

    python demos/relaxed_friction_study.py [--out results/relaxed_friction_study] [--small]
        [--budget SECONDS] [--force]

``--small`` (or ``DEMO_SMALL=1``) is the reduced run of the tests, written to
``results/relaxed_friction_study-small`` by default; under ``mpirun`` rank 0 runs the (serial)
study and the other ranks exit. An ``--out`` that holds the study's tables or figures is refused
(exit status 2) unless ``--force``, which replaces those files and no others; the packings
cached in ``OUT/packings`` stay and are reused.

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
  so that sigma_22 = -p (Newton from e22 extrapolated along the last step); mu = 0, 0.1, 0.3,
  0.5, 1 at p / k_n = 1e-2, 1e-3 to gamma = 10 % in 50 steps (``--small``: mu = 0, 0.5 at
  1e-2, to 1 % in 5 steps). A step that fails (the micro solver's ``RelaxationError`` where the
  cell rearranges, or the driver) is halved, 3 times at most; then the test stops there and
  records how far it got and why, and the study goes on. ``--budget`` caps each test's wall
  time, checked before every step, so a slow step can overrun it (default: none with
  ``--small``, 90 s otherwise: the full study then took 46 min on 2 busy cores); a test stopped
  by it says so. How far such a test gets depends on the machine; the path up to there does not.

Measures (2-D, compression positive): p = -(sigma_11 + sigma_22) / 2,
q = sqrt(((sigma_11 - sigma_22) / 2)^2 + sigma_12^2), q / p = sin(phi mobilised), tau / p =
sigma_12 / p; the volumetric strain e_v = ln(det F / det F_c) from the confined state, and the
dilatancy d e_v / d gamma (secants over a tenth of the path reached: peak the largest, final the
secant over its last fifth); the coordination z = 2 C / N over the N disks with at least 2
contacts (overlap > 0) and the C contacts between them; the share of the contacts that slid in
the step (empty at mu = 0, where no contact carries a tangential force: the Taylor law calls
all of them sliding, the relaxed one none); the dissipation since the confined state.

Writes to ``--out``: ``convergence.csv`` (one row per substep), ``shear_steps.csv`` (every
step of every confined shear test, both laws), ``shear_tests.csv`` (one row per test: how far
it got, its stop message, peak and final q / p and dilatancy), ``shear_summary.csv`` (one row
per law, mu and p: mean and standard deviation over the seeds) and the figures
``relaxed_friction_convergence.png``, ``relaxed_friction_qp_gamma.png``,
``relaxed_friction_qp_mu.png``.
"""

from __future__ import annotations

import csv
import os
import sys
import time

from dolfinx_granular import (
    ControlError,
    FrictionalRelaxedRVE,
    FrictionalRVE,
    LawEvaluationError,
    MaterialPoint,
    Packing,
    generate_packing,
)
from dolfinx_granular.drivers.confinement import compress
from dolfinx_granular.io.commandline import Parser, world_comm
from dolfinx_granular.io.outfolder import claim_or_refuse, claim_out
from dolfinx_granular.io.shear_figures import save_figure
from dolfinx_granular.laws.relaxed.path import stretch, stretches_between

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

K_N = 2.8e7  # normal contact stiffness, N/m² (table 1 of the paper)
K_T = K_N  # tangential stiffness, N/m² (a common DEM choice, as the friction study)
SUBSTEPS = (1e-3, 5e-4, 2.5e-4, 1.25e-4)  # the substeps of the convergence study
CONVERGENCE = dict(pressure=1e-2, mu=0.5)  # p / k_n and mu of the convergence study
MAX_CUTS = 3  # halvings of a failed confined-shear step before its test stops
# the literature's macroscopic friction of 2-D disks (the reference of the q/p-mu figure):
# about 0.1 without contact friction, 0.25-0.30 at the critical state for mu = 0.4-0.5
LITERATURE_MU0 = 0.1
LITERATURE_CRITICAL = ((0.4, 0.5), (0.25, 0.30))
DPI = 110

FULL = dict(particles=200, seeds=(0, 1, 2), mus=(0.0, 0.1, 0.3, 0.5, 1.0),
            pressures=(1e-2, 1e-3), max_shear=0.10, steps=50, convergence_shear=0.02,
            budget=90.0)  # fmt: skip
SMALL = dict(particles=70, seeds=(0,), mus=(0.0, 0.5), pressures=(1e-2,), max_shear=0.01,
             steps=5, convergence_shear=0.01, budget=None)  # fmt: skip
#: the files it writes in --out (what --force replaces; the packing cache is kept)
FILES = ("convergence.csv", "shear_steps.csv", "shear_tests.csv", "shear_summary.csv",
         "relaxed_friction_convergence.png", "relaxed_friction_qp_gamma.png",
         "relaxed_friction_qp_mu.png")  # fmt: skip
#: the stop reasons a test can have (a law or driver error's message follows "stopped: ")
BUDGET_STOP = "time budget"


# %% [markdown]
# ## Packings, laws and measures
#
# The packings are jammed at the confining pressure and cached (the relaxed study's files); the
# confinement compresses them along F = lam I to it.


# %%
def packing_at(n, seed, pressure, folder):
    """The packing of n disks jammed at ``pressure`` (p / k_n), cached in ``folder``."""
    path = os.path.join(folder, f"relaxed_{n}_{seed}_{pressure:g}.npz")
    if os.path.exists(path):
        return Packing.load(path)
    packing = generate_packing(n, seed=seed, pressure=pressure)
    packing.save(path)
    return packing


def make_law(name, packing, mu):
    """The frictional relaxed (``"relaxed"``) or Taylor (``"taylor"``) RVE with friction mu."""
    cls = FrictionalRelaxedRVE if name == "relaxed" else FrictionalRVE
    return cls(packing, K_N, K_T, mu)


def ratios(sigma):
    """(p in Pa, q / p, tau / p) of a Cauchy stress (2, 2)."""
    s11, s22, s12 = sigma[0, 0], sigma[1, 1], sigma[0, 1]
    p = -0.5 * (s11 + s22)
    return p, np.hypot(0.5 * (s11 - s22), s12) / p, s12 / p


def network(law, F, state, mu):
    """(contacts with overlap > 0, z over the disks with >= 2 of them, sliding share or NaN at
    mu = 0) of the 1-point ``state`` at F. The relaxed RVE's state is the one at F (its contacts
    are read, not solved again; sliding: slid in the increment to it); the Taylor RVE's is the
    committed state before the step to F (its ``contacts`` takes the step)."""
    c = law.contacts(F, state)
    on = c.overlap > 0.0
    pairs = c.pairs[on]
    n = law.packing.radii.shape[0]
    degree = np.bincount(pairs.ravel(), minlength=n)
    carried = degree >= 2
    between = carried[pairs[:, 0]] & carried[pairs[:, 1]]
    z = 2.0 * between.sum() / carried.sum() if carried.any() else 0.0
    sliding = np.asarray(c.sliding)[on]
    share = float(sliding.mean()) if mu > 0.0 and on.any() else float("nan")
    return int(on.sum()), float(z), share


def confine(law, pressure):
    """A :class:`MaterialPoint` of ``law`` compressed along F = lam I to the mean pressure
    ``pressure`` (p / k_n); its last result is the confined state. Raises what ``compress``
    raises."""
    point = MaterialPoint(law)
    # (the driver's strain steps capped at ten times the strain the pressure asks for)
    compress(point, pressure * K_N, max_increment=10 * pressure, isotropic=True)
    return point


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
# ## 2. Confined simple shear
#
# Each test: confine, then shear with sigma_22 = -p held and F11 fixed. A step that fails is
# halved; a step that fails after :data:`MAX_CUTS` halvings ends the test, which keeps the steps
# it reached and the error (the known limit of the micro solver at large strain, where the cell
# rearranges).


# %%
def shear_test(law_name, packing, mu, pressure, gammas, budget=None):
    """Confined simple shear of one packing: ``(step rows, stop message or "")``. Row 0 is the
    confined state (gamma = 0); a test whose confinement failed has no rows."""
    law = make_law(law_name, packing, mu)
    P, t0 = pressure * K_N, time.perf_counter()
    try:
        point = confine(law, pressure)
    except (ControlError, LawEvaluationError) as err:
        return [], f"stopped: confinement failed: {err}"[:300]
    Fc, relaxed = point.F.copy(), law_name == "relaxed"
    lam, Dc = Fc[0, 0], float(point.state.dissipation[0])

    def record(r, before, seconds):
        """A step's row; ``before``: the committed state before it (None: the confined
        state, no shear step: no sliding share)."""
        p, qp, taup = ratios(r.sigma)
        state = r.state if relaxed or before is None else before
        contacts, z, share = network(law, r.F, state, mu)
        return dict(
            gamma=float(r.F[0, 1] / lam),
            e22=float(r.F[1, 1] / lam - 1.0),
            sigma11_Pa=r.sigma[0, 0],
            sigma12_Pa=r.sigma[0, 1],
            sigma22_Pa=r.sigma[1, 1],
            q_over_p=qp,
            tau_over_p=taup,
            volumetric_strain=float(np.log(np.linalg.det(r.F) / np.linalg.det(Fc))),
            contacts=contacts,
            z=z,
            sliding_share=share if before is not None else float("nan"),
            dissipation_Pa=float(r.state.dissipation[0]) - Dc,
            newton_iterations=r.iterations,
            wall_s=seconds,
        )

    rows = [record(point.last, None, time.perf_counter() - t0)]
    # each target gamma gets MAX_CUTS halvings in all (those whose midpoints were reached
    # included), as the driver's ramp
    targets, done, cuts, stop = list(gammas), 0.0, 0, ""
    left, t_step = len(targets), time.perf_counter()
    while targets:
        if budget is not None and time.perf_counter() - t0 > budget:
            stop = f"stopped: {BUDGET_STOP} of {budget:g} s reached"
            break
        F = point.F.copy()
        F[0, 1] = lam * targets[0]
        if len(rows) > 1:  # e22's guess: extrapolated along the last step's dilatancy
            a, b = rows[-2], rows[-1]
            rate = (b["e22"] - a["e22"]) / (b["gamma"] - a["gamma"])
            F[1, 1] = lam * (1.0 + b["e22"] + rate * (targets[0] - b["gamma"]))
        before = point.state
        try:
            # (Newton's steps on e22 capped at p / k_n: a trial F22 far off the path takes the
            # path-dependent micro solver there, and it fails more often; with 10 p / k_n,
            # 200 disks at p / k_n = 1e-2, mu = 0.5 stopped at gamma = 0.8 %, not 6.8 %)
            r = point.step(F, {(1, 1): -P}, max_increment=pressure)
        except (ControlError, LawEvaluationError) as err:
            if cuts == MAX_CUTS:
                stop = f"stopped: {err}"[:300]
                break
            targets.insert(0, 0.5 * (done + targets[0]))
            cuts += 1
            continue
        done = targets.pop(0)
        if len(targets) < left:  # one of ``gammas`` reached: the next gets its halvings
            left, cuts = len(targets), 0
        rows.append(record(r, before, time.perf_counter() - t_step))
        t_step = time.perf_counter()
    return rows, stop


def test_measures(rows, stop, target):
    """Scalars of one test: how far it got, peak and final q/p (and tau/p), peak and final
    dilatancy, final e_v, z, sliding share and dissipation."""
    out = dict(gamma_reached=rows[-1]["gamma"] if rows else 0.0, target=target,
               stopped=bool(stop), message=stop)  # fmt: skip
    if len(rows) < 2:
        return out
    g = np.array([r["gamma"] for r in rows])
    qp = np.array([r["q_over_p"] for r in rows])
    ev = np.array([r["volumetric_strain"] for r in rows])
    k = int(np.argmax(qp))
    window = max(1, (len(rows) - 1) // 10)
    dil = (ev[window:] - ev[:-window]) / (g[window:] - g[:-window])
    tail = int(np.searchsorted(g, 0.8 * g[-1]))
    tail = min(tail, len(rows) - 2)
    last = rows[-1]
    out.update(
        qp_start=qp[0],
        qp_peak=qp[k],
        gamma_peak=g[k],
        qp_final=qp[-1],
        taup_final=last["tau_over_p"],
        dilatancy_peak=float(dil.max()),
        dilatancy_final=float((ev[-1] - ev[tail]) / (g[-1] - g[tail])),
        ev_final=ev[-1],
        z_final=last["z"],
        sliding_final=last["sliding_share"],
        dissipation_final_Pa=last["dissipation_Pa"],
    )
    return out


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


SUMMARY_KEYS = ("qp_peak", "qp_final", "taup_final", "dilatancy_peak", "dilatancy_final",
                "ev_final", "z_final", "sliding_final", "gamma_reached")  # fmt: skip


def summary_rows(tests):
    """One row per (law, mu, p): mean and std over the seeds, the smallest gamma reached and
    the number of tests stopped early."""
    groups = {}
    for t in tests:
        groups.setdefault((t["law"], t["mu"], t["p_over_kn"]), []).append(t)
    rows = []
    for (law, mu, p), ts in groups.items():
        row = dict(law=law, mu=mu, p_over_kn=p, seeds=len(ts))
        for key in SUMMARY_KEYS:
            v = np.array([t.get(key, np.nan) for t in ts], dtype=float)
            ok = v[np.isfinite(v)]
            row[f"{key}_mean"] = ok.mean() if ok.size else np.nan
            row[f"{key}_std"] = ok.std(ddof=1) if ok.size > 1 else (0.0 if ok.size else np.nan)
        row["gamma_reached_min"] = min(t["gamma_reached"] for t in ts)
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


def qp_gamma_figure(paths, cfg):
    """q / p (top) and e_v (bottom) over gamma, one column per p, one colour per mu; relaxed
    solid (thick: the first seed), Taylor dashed; a cross where a relaxed test stopped."""
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
                    g = 100 * np.array([r["gamma"] for r in rows])
                    first = s == seeds[0]
                    kw = dict(color=color, lw=1.5 if first else 0.6, alpha=1.0 if first else 0.6)
                    label = f"μ = {mu:g} ({law})" if first else None
                    top.plot(g, [r["q_over_p"] for r in rows], style, label=label, **kw)
                    bot.plot(g, [100 * r["volumetric_strain"] for r in rows], style, **kw)
                    if stop and law == "relaxed":
                        top.plot(g[-1], rows[-1]["q_over_p"], "x", color="red", ms=6)
        top.set_title(f"p / k_n = {p:g} (x: relaxed test stopped)", fontsize=9)
        top.set_ylabel("q / p")
        bot.set_ylabel("volumetric strain e_v = ln(J / J_c) [%]")
        bot.set_xlabel("shear strain γ [%]")
        for ax in (top, bot):
            ax.grid(True, alpha=0.3)
        top.legend(fontsize=6, ncol=2)
    title = (f"Confined simple shear (σ22 = −p, F11 held), {cfg['particles']} disks, "
             f"{len(seeds)} seed(s)\nrelaxed (solid) and Taylor (dashed)")  # fmt: skip
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def qp_mu_figure(summary, cfg):
    """Peak and final q / p over mu (mean ± std over the seeds) for each law and p, beside the
    literature's values for 2-D disks."""
    fig = Figure(figsize=(9.6, 4.6))
    ax = fig.add_subplot()
    styles = {"relaxed": ("o", 1.0), "taylor": ("s", 0.45)}
    for law in ("relaxed", "taylor"):
        marker, alpha = styles[law]
        for color, p in zip(("C0", "C1", "C2"), cfg["pressures"]):
            rows = [r for r in summary if r["law"] == law and r["p_over_kn"] == p]
            mu = np.array([r["mu"] for r in rows])
            for what, ls, fill in (("peak", "-", "none"), ("final", ":", None)):
                ax.errorbar(
                    mu, [r[f"qp_{what}_mean"] for r in rows],
                    yerr=[r[f"qp_{what}_std"] for r in rows], fmt=marker + ls, color=color,
                    alpha=alpha, mfc=fill, ms=6, capsize=3, label=f"{law}, p/kn = {p:g}, {what}",
                )  # fmt: skip
    (m0, m1), (q0, q1) = LITERATURE_CRITICAL
    ax.fill_between([m0, m1], q0, q1, color="C3", alpha=0.25,
                    label="2-D disks, literature:\ncritical state, μ = 0.4-0.5")  # fmt: skip
    ax.plot([0.0], [LITERATURE_MU0], "*", color="C3", ms=12, label="2-D disks, literature: μ = 0")
    ax.set_xlabel("contact friction coefficient μ")
    ax.set_ylabel("q / p (peak: open, final: filled)")
    ax.set_title("Macroscopic against contact friction (mean ± std over the seeds; final: where "
                 "each test got to, shear_tests.csv)", fontsize=8)  # fmt: skip
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))
    fig.tight_layout()
    return fig


def print_tables(say, conv, tests, summary):
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
    say("\nconfined shear: mean ± std over the seeds (final: where each test got to)")
    say("  law      mu    p/kn   q/p peak       q/p final      dil peak  dil final  "
        "gamma reached (min)  stopped")  # fmt: skip
    for r in summary:
        say(f"  {r['law']:7s}  {r['mu']:3g}  {r['p_over_kn']:6.0e}  "
            f"{r['qp_peak_mean']:.3f}±{r['qp_peak_std']:.3f}  "
            f"{r['qp_final_mean']:.3f}±{r['qp_final_std']:.3f}  "
            f"{r['dilatancy_peak_mean']:8.3f}  {r['dilatancy_final_mean']:9.3f}  "
            f"{100 * r['gamma_reached_mean']:5.2f} % ({100 * r['gamma_reached_min']:5.2f} %)"
            f"  {r['stopped']} of {r['seeds']}")  # fmt: skip
    stops = [t for t in tests if t["stopped"]]
    if stops:
        say("\nstopped early:")
        for t in stops:
            say(f"  {t['law']} mu {t['mu']:g} p/kn {t['p_over_kn']:g} seed {t['seed']} at "
                f"gamma {100 * t['gamma_reached']:.3f} %: {t['message'][:160]}")  # fmt: skip


# %% [markdown]
# ## The study


# %%
def run(out="results/relaxed_friction_study", small=False, verbose=True, force=False,
        budget="default"):  # fmt: skip
    """Run the study, write the CSVs and figures to ``out``; returns ``(convergence rows, test
    rows, summary rows)``. ``budget``: seconds per confined shear test (None: no limit;
    "default": the configuration's). An ``out`` that holds a study raises ``RunExistsError``
    first, unless ``force`` (which removes its files, no others)."""
    claim_out(out, FILES, force, "relaxed_friction_study")
    cfg = dict(SMALL if small else FULL)
    if budget != "default":
        cfg["budget"] = budget
    say = print if verbose else (lambda *a, **k: None)
    folder = os.path.join(out, "packings")  # (a cache: kept by force, reused)
    os.makedirs(folder, exist_ok=True)
    t0 = time.perf_counter()
    n, seeds = cfg["particles"], cfg["seeds"]

    # 1. the substep
    packing = packing_at(n, seeds[0], CONVERGENCE["pressure"], folder)
    conv, curves = convergence_rows(packing, cfg["convergence_shear"], say)
    write_csv(os.path.join(out, "convergence.csv"), conv)

    # 2. confined simple shear
    gammas = np.linspace(0.0, cfg["max_shear"], cfg["steps"] + 1)[1:]
    steps, tests, paths = [], [], {}
    total = len(cfg["pressures"]) * len(cfg["mus"]) * len(seeds)
    for p in cfg["pressures"]:
        for mu in cfg["mus"]:
            for s in seeds:
                packing = packing_at(n, s, p, folder)
                for law in ("relaxed", "taylor"):
                    t = time.perf_counter()
                    rows, stop = shear_test(law, packing, mu, p, gammas, cfg["budget"])
                    seconds = time.perf_counter() - t
                    paths[(law, mu, p, s)] = (rows, stop)
                    key = dict(law=law, mu=mu, p_over_kn=p, seed=s)
                    steps += [dict(key, step=k, **r) for k, r in enumerate(rows)]
                    m = test_measures(rows, stop, cfg["max_shear"])
                    tests.append(dict(key, **m, seconds=seconds))
                    if law == "relaxed":
                        say(f"relaxed mu {mu:g} p/kn {p:g} seed {s}: gamma "
                            f"{100 * m['gamma_reached']:.2f} % in {seconds:.1f} s"
                            f"{' (' + stop[:100] + ')' if stop else ''} "
                            f"[test {len(tests) // 2 + 1} of {total}, "
                            f"{time.perf_counter() - t0:.0f} s]")  # fmt: skip
    summary = summary_rows(tests)
    write_csv(os.path.join(out, "shear_steps.csv"), steps)
    write_csv(os.path.join(out, "shear_tests.csv"), tests)
    write_csv(os.path.join(out, "shear_summary.csv"), summary)
    figures = {
        "convergence": convergence_figure(conv, curves),
        "qp_gamma": qp_gamma_figure(paths, cfg),
        "qp_mu": qp_mu_figure(summary, cfg),
    }
    for name, fig in figures.items():
        save_figure(fig, os.path.join(out, f"relaxed_friction_{name}.png"), DPI)
    print_tables(say, conv, tests, summary)
    say(f"\nwrote {out}/ in {time.perf_counter() - t0:.1f} s")
    return conv, tests, summary


def parse_args(argv=None):
    """The options; ``out`` resolved (``results/relaxed_friction_study[-small]``)."""
    parser = Parser(description=__doc__.split("\n")[0])
    parser.add_output("relaxed_friction_study")
    parser.add_argument(
        "--budget",
        type=float,
        help="wall seconds per confined shear test (default: 90, none with --small; 0: none)",
    )
    return parser.parse_args(argv)


def main(argv=None):
    args = parse_args(argv)
    comm = world_comm()
    # every rank takes rank 0's answer (exit status 2 alike) before any work
    if claim_or_refuse(args.out, FILES, args.force, "relaxed_friction_study", comm):
        return 2
    if comm is None or comm.rank == 0:  # a serial study: rank 0 runs it, the others rest
        budget = "default" if args.budget is None else (args.budget or None)
        run(args.out, small=args.small, force=args.force, budget=budget)
    return 0


# %% [markdown]
# Run as a script; in a notebook call `run("results/relaxed_friction_study")` instead of this
# cell (`force=True` replaces an earlier study there).

# %%
if __name__ == "__main__":
    sys.exit(main())
