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
others; the packings cached in ``OUT/packings`` stay and are reused.

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
from dataclasses import dataclass

from dolfinx_granular import (
    ControlError,
    FrictionalRelaxedRVE,
    FrictionalRVE,
    LawEvaluationError,
    MaterialPoint,
)
from dolfinx_granular.drivers.confinement import compress
from dolfinx_granular.io.commandline import Parser, world_comm
from dolfinx_granular.io.outfolder import claim_or_refuse, claim_out
from dolfinx_granular.io.shear_figures import save_figure
from dolfinx_granular.laws.relaxed.path import stretch, stretches_between
from dolfinx_granular.packings.cache import PackingCache
from dolfinx_granular.packings.generation import MAX_PRESSURE

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

K_N = 2.8e7  # normal contact stiffness, N/m² (table 1 of the paper)
K_T = K_N  # tangential stiffness, N/m² (a common DEM choice, as the friction study)
SUBSTEPS = (1e-3, 5e-4, 2.5e-4, 1.25e-4)  # the substeps of the convergence study
CONVERGENCE = dict(pressure=1e-2, mu=0.5)  # p / k_n and mu of the convergence study
MAX_CUTS = 3  # halvings of a failed step before its test stops
CRITICAL = 0.75  # the "critical state": the steps past this fraction of the strain reached
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
#: the stop reasons a test can have (a law or driver error's message follows "stopped: ")
BUDGET_STOP = "time budget"

# %% [markdown]
# ## Packings, laws and measures
#
# The packings are jammed at the confining pressure and cached (the relaxed study's files); the
# confinement compresses them along F = lam I to it.


# %%


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
# ## 2. Confined simple shear and the biaxial test
#
# Both start from the confined state F_c = lam I and prescribe one strain x in steps while the
# material-point driver solves one more, y, so that a normal stress stays -p. A step that fails
# is halved; a step that fails after :data:`MAX_CUTS` halvings ends the test, which keeps the
# steps it reached and the error (the known limit of the micro solver at large strain, where
# the cell rearranges).


# %%
@dataclass(frozen=True)
class Loading:
    """A test's path from F_c = lam I: F[drive_ij] = lam (base + sign x), x (column ``drive``)
    prescribed; F[held_ij] = lam (1 + y), y (column ``free``) solved so that sigma[held_ij] =
    -p; F's other components stay F_c's. ``limits``: the configuration's keys of the largest x
    and of the number of steps to it."""

    test: str
    drive: str
    free: str
    drive_ij: tuple
    held_ij: tuple
    base: float
    sign: float
    limits: tuple
    label: str  # the axis label of x
    title: str

    def strains(self, F, lam):
        """(x, y) of F (+ 0.0: no -0.0 at x = 0)."""
        x = (F[self.drive_ij] / lam - self.base) / self.sign + 0.0
        return float(x), float(F[self.held_ij] / lam - 1.0)


SHEAR = Loading("shear", "gamma", "e22", (0, 1), (1, 1), 0.0, 1.0, ("max_shear", "shear_steps"),
                "shear strain γ [%]", "Confined simple shear (σ22 = −p, F11 held)")  # fmt: skip
BIAXIAL = Loading("biaxial", "eps1", "e11", (1, 1), (0, 0), 1.0, -1.0,
                  ("max_strain", "biaxial_steps"), "axial strain ε1 [%]",
                  "Biaxial compression (σ11 = −p, F12 = F21 = 0)")  # fmt: skip
LOADINGS = {loading.test: loading for loading in (SHEAR, BIAXIAL)}


def step_row(loading, law, mu, Fc, Dc, r, before, seconds):
    """A step's row (the result ``r``); ``Dc``: the confined state's dissipation; ``before``: the
    committed state before the step (None: the confined state, no step: no sliding share)."""
    lam = Fc[0, 0]
    x, y = loading.strains(r.F, lam)
    p, qp, taup = ratios(r.sigma)
    relaxed = isinstance(law, FrictionalRelaxedRVE)
    state = r.state if relaxed or before is None else before
    contacts, z, share = network(law, r.F, state, mu)
    return {
        loading.drive: x,
        loading.free: y,
        **{f"F{i + 1}{j + 1}": float(r.F[i, j]) for i in range(2) for j in range(2)},
        "sigma11_Pa": r.sigma[0, 0],
        "sigma12_Pa": r.sigma[0, 1],
        "sigma22_Pa": r.sigma[1, 1],
        "p_Pa": p,
        "q_over_p": qp,
        "tau_over_p": taup,
        "volumetric_strain": float(np.log(np.linalg.det(r.F) / np.linalg.det(Fc))),
        "contacts": contacts,
        "z": z,
        "sliding_share": share if before is not None else float("nan"),
        "dissipation_Pa": float(r.state.dissipation[0]) - Dc,
        "newton_iterations": r.iterations,
        "wall_s": seconds,
    }


def load_test(loading, law_name, packing, mu, pressure, targets, budget=None):
    """One test (``loading``) of one packing to the strains ``targets``: ``(step rows, stop
    message or "")``. Row 0 is the confined state (x = 0); a test whose confinement failed has
    no rows."""
    law = make_law(law_name, packing, mu)
    P, t0 = pressure * K_N, time.perf_counter()
    try:
        point = confine(law, pressure)
    except (ControlError, LawEvaluationError) as err:
        return [], f"stopped: confinement failed: {err}"[:300]
    Fc, (x, y) = point.F.copy(), (loading.drive, loading.free)
    lam, Dc = Fc[0, 0], float(point.state.dissipation[0])
    rows = [step_row(loading, law, mu, Fc, Dc, point.last, None, time.perf_counter() - t0)]
    # each target gets MAX_CUTS halvings in all (those whose midpoints were reached included),
    # as the driver's ramp
    targets, done, cuts, stop = list(targets), 0.0, 0, ""
    left, t_step = len(targets), time.perf_counter()
    while targets:
        if budget is not None and time.perf_counter() - t0 > budget:
            stop = f"stopped: {BUDGET_STOP} of {budget:g} s reached"
            break
        F = point.F.copy()
        F[loading.drive_ij] = lam * (loading.base + loading.sign * targets[0])
        if len(rows) > 1:  # y's guess: extrapolated along the last step
            a, b = rows[-2], rows[-1]
            rate = (b[y] - a[y]) / (b[x] - a[x])
            F[loading.held_ij] = lam * (1.0 + b[y] + rate * (targets[0] - b[x]))
        before = point.state
        try:
            # (Newton's steps on y capped at p / k_n: a trial F far off the path takes the
            # path-dependent micro solver there, and it fails more often; with 10 p / k_n,
            # 200 disks at p / k_n = 1e-2, mu = 0.5 stopped at gamma = 0.8 %, not 6.8 %)
            r = point.step(F, {loading.held_ij: -P}, max_increment=pressure)
        except (ControlError, LawEvaluationError) as err:
            if cuts == MAX_CUTS:
                stop = f"stopped: {err}"[:300]
                break
            targets.insert(0, 0.5 * (done + targets[0]))
            cuts += 1
            continue
        done = targets.pop(0)
        if len(targets) < left:  # one of the targets reached: the next gets its halvings
            left, cuts = len(targets), 0
        rows.append(step_row(loading, law, mu, Fc, Dc, r, before, time.perf_counter() - t_step))
        t_step = time.perf_counter()
    return rows, stop


def test_measures(rows, stop, target, loading):
    """Scalars of one test: how far it got (x), peak, critical and final q/p (and final tau/p),
    peak and final dilatancy d e_v / d x, final e_v, critical and final z and sliding share,
    final dissipation. Critical: the mean over the steps with x >= CRITICAL x_reached."""
    x_name = loading.drive
    out = {f"{x_name}_reached": rows[-1][x_name] if rows else 0.0, "target": target,
           "stopped": bool(stop), "message": stop}  # fmt: skip
    if len(rows) < 2:
        return out
    g = np.array([r[x_name] for r in rows])
    qp = np.array([r["q_over_p"] for r in rows])
    ev = np.array([r["volumetric_strain"] for r in rows])
    k = int(np.argmax(qp))
    window = max(1, (len(rows) - 1) // 10)
    dil = (ev[window:] - ev[:-window]) / (g[window:] - g[:-window])
    tail = int(np.searchsorted(g, 0.8 * g[-1]))
    tail = min(tail, len(rows) - 2)
    critical = g >= (CRITICAL - 1e-9) * g[-1]  # (a step at 3/4 of x_reached, round-off aside)

    def mean(key):  # over the critical steps (NaN where none has a value)
        v = np.array([r[key] for r in rows], dtype=float)[critical]
        return float(v[np.isfinite(v)].mean()) if np.isfinite(v).any() else float("nan")

    last = rows[-1]
    out.update({
        "qp_start": qp[0],
        "qp_peak": qp[k],
        f"{x_name}_peak": g[k],
        "critical_from": CRITICAL * g[-1],
        "qp_critical_last_quarter": mean("q_over_p"),
        "qp_final": qp[-1],
        "taup_final": last["tau_over_p"],
        "dilatancy_peak": float(dil.max()),
        "dilatancy_final": float((ev[-1] - ev[tail]) / (g[-1] - g[tail])),
        "ev_final": ev[-1],
        "z_critical_last_quarter": mean("z"),
        "z_final": last["z"],
        "sliding_critical_last_quarter": mean("sliding_share"),
        "sliding_final": last["sliding_share"],
        "dissipation_final_Pa": last["dissipation_Pa"],
    })  # fmt: skip
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
def run_tests(loading, cfg, cache, say, t0):
    """Every test of ``loading`` (both laws, each mu, p and seed): ``(steps, tests, summary,
    paths)``; writes nothing."""
    top, count = (cfg[key] for key in loading.limits)
    targets = np.linspace(0.0, top, count + 1)[1:]
    steps, tests, paths = [], [], {}
    total = len(cfg["pressures"]) * len(cfg["mus"]) * len(cfg["seeds"])
    x = loading.drive
    for p in cfg["pressures"]:
        for mu in cfg["mus"]:
            for s in cfg["seeds"]:
                packing = cache.get(cfg["particles"], s, p)
                for law in ("relaxed", "taylor"):
                    t = time.perf_counter()
                    rows, stop = load_test(loading, law, packing, mu, p, targets, cfg["budget"])
                    seconds = time.perf_counter() - t
                    paths[(law, mu, p, s)] = (rows, stop)
                    key = dict(law=law, mu=mu, p_over_kn=p, seed=s)
                    steps += [dict(key, step=k, **r) for k, r in enumerate(rows)]
                    m = test_measures(rows, stop, top, loading)
                    tests.append(dict(key, **m, seconds=seconds))
                    if law == "relaxed":
                        say(f"{loading.test} relaxed mu {mu:g} p/kn {p:g} seed {s}: {x} "
                            f"{100 * m[f'{x}_reached']:.2f} % in {seconds:.1f} s"
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
    cache = PackingCache(os.path.join(out, "packings"))  # (kept by force, reused)
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
        steps, tests, summary, paths = run_tests(loading, cfg, cache, say, t0)
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
def _values(kind, ok, what, example, many=False):
    """An argparse type: a ``kind`` (a comma-separated tuple of distinct ones with ``many``),
    each passing ``ok``; otherwise an error that says ``what`` to give, e.g. ``example``."""

    def convert(text):
        fix = f"give {what}, e.g. {example}"
        values = []
        for v in text.split(",") if many else (text,):
            try:
                values.append(kind(v))
            except ValueError:
                number = "whole number" if kind is int else "number"
                raise argparse.ArgumentTypeError(f"{v!r} is not a {number}: {fix}") from None
        for v in values:
            if not (np.isfinite(v) and ok(v)):
                raise argparse.ArgumentTypeError(f"{v!r} is out of range: {fix}")
        if len(set(values)) < len(values):
            raise argparse.ArgumentTypeError(f"{text!r} repeats a value: {fix}")
        return tuple(values) if many else values[0]

    return convert


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
    budget = _values(float, lambda v: v >= 0.0, "seconds >= 0 (0: none)", "90")
    particles = _values(int, lambda v: v >= 10, "a whole number >= 10", "700")
    seeds = _values(int, lambda v: v >= 0, "comma-separated whole numbers >= 0", "0,1,2", True)
    mus = _values(float, lambda v: v >= 0.0, "comma-separated mu >= 0", "0,0.1,0.3,0.5,1", True)
    range_p = f"comma-separated p / k_n in (0, {MAX_PRESSURE:g}]"
    pressures = _values(float, lambda v: 0.0 < v <= MAX_PRESSURE, range_p, "1e-2,1e-3", True)
    shear = _values(float, lambda v: 0.0 < v <= 2.0, "a shear strain in (0, 2]", "0.5")
    strain = _values(float, lambda v: 0.0 < v < 0.9, "an axial strain in (0, 0.9)", "0.3")
    shear_steps = _values(int, lambda v: v >= 1, whole, "250")
    biaxial_steps = _values(int, lambda v: v >= 1, whole, "60")
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
