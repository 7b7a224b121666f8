"""The strength of an RVE, measured: peak and critical-state friction angles from biaxial tests.

:func:`strength_tests` runs the biaxial test (:data:`~.element_tests.BIAXIAL`: sigma_11 = -p
held, the axial strain eps1 prescribed) of the frictional relaxed RVE (or the frictional Taylor
RVE) for every contact friction mu, rolling friction mu_r (the relaxed RVE's), confining
pressure p / k_n and packing seed, each once (:class:`~.element_cache.ElementTestCache`);
:func:`strength_curve` tabulates them per (mu, mu_r, p / k_n): sin phi = q / p at the peak (the
largest over the test) and at the critical state (the mean over the last quarter of the strain
reached), phi in degrees and tan phi, as the mean and standard deviation over the seeds, with
how far the tests got and why any stopped. :func:`friction_angle` reads phi off the curve,
linear in mu (the factor of safety's tan phi(mu)), or off its non-decreasing fit
(:func:`nondecreasing`).
"""

from __future__ import annotations

import itertools
import math
import os
from typing import TYPE_CHECKING

import numpy as np

from ..packings.cache import PackingCache
from ..packings.generation import MAX_PRESSURE
from .element_cache import ElementTestCache
from .element_tests import BIAXIAL, K_N, K_T, LAWS, make_law, measures

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from os import PathLike

#: the strength of one test (one packing): its columns besides law, mu, mu_r, p_over_kn and seed
MEASURES = ("sin_phi_peak", "sin_phi_cs", "phi_peak_deg", "phi_cs_deg", "tan_phi_peak",
            "tan_phi_cs")  # fmt: skip
#: the columns of the curve (one row per law, mu and p / k_n), in order
COLUMNS = ("law", "mu", "mu_r", "p_over_kn", "kappa", "particles", "seeds", "k_n", "k_t",
           *(f"{m}_{s}" for m in MEASURES for s in ("mean", "std")), "eps1_target",
           "eps1_reached_mean", "eps1_reached_min", "stopped", "stop_reasons")  # fmt: skip
#: which angle :func:`friction_angle` reads: peak or critical state
WHICH = {"peak": "phi_peak_deg_mean", "cs": "phi_cs_deg_mean"}


def check_parameters(mus, pressures, particles, seeds, max_strain, steps, k_n, k_t, law,
                     rolling=(0.0,)):  # fmt: skip
    """Raise ValueError naming the first bad value of :func:`strength_tests` and its fix."""
    if law not in LAWS:
        raise ValueError(f"unknown law {law!r}: give one of {', '.join(LAWS)}")
    if law != "relaxed" and any(rolling):
        raise ValueError("rolling friction is a setting of the relaxed RVE: give mu_r = 0 alone "
                         f"with law {law!r}")  # fmt: skip
    checks = (
        ("mu", mus, lambda v: v >= 0.0, "contact friction mu >= 0"),
        ("mu_r", rolling, lambda v: v >= 0.0, "rolling friction mu_r >= 0"),
        ("p_over_kn", pressures, lambda v: 0.0 < v <= MAX_PRESSURE,
         f"p / k_n in (0, {MAX_PRESSURE:g}]"),
        ("seed", seeds, lambda v: v >= 0 and v == int(v), "whole numbers >= 0"),
        ("particles", (particles,), lambda v: v >= 10 and v == int(v), "a whole number >= 10"),
        ("max_strain", (max_strain,), lambda v: 0.0 < v < 0.9, "an axial strain in (0, 0.9)"),
        ("steps", (steps,), lambda v: v >= 1 and v == int(v), "a whole number >= 1"),
        ("k_n", (k_n,), lambda v: v > 0.0, "a stiffness > 0 in N/m²"),
        ("k_t", (k_t,), lambda v: v > 0.0, "a stiffness > 0 in N/m²"),
    )  # fmt: skip
    for name, values, ok, what in checks:
        if len(values) == 0:
            raise ValueError(f"{name}: give at least one value ({what})")
        if len(set(values)) < len(values):
            raise ValueError(f"{name} repeats a value in {tuple(values)}: give each once")
        for v in values:
            if not (math.isfinite(v) and ok(v)):
                raise ValueError(f"{name} = {v!r} is out of range: give {what}")


def strength_tests(
    particles: int = 200,
    seeds: Sequence[int] = (0, 1, 2),
    mus: Sequence[float] = (0.0, 0.1, 0.3, 0.5, 1.0),
    pressures: Sequence[float] = (1e-2, 1e-3),
    max_strain: float = 0.3,
    steps: int = 60,
    k_n: float = K_N,
    k_t: float = K_T,
    law: str = "relaxed",
    substep: float | None = None,
    budget: float | None = None,
    cache: str | PathLike[str] = "strength_cache",
    say: Callable[[str], None] | None = None,
    rolling: Sequence[float] = (0.0,),
    each_step: bool = False,
) -> list[dict]:
    """One row per biaxial test (law, mu, mu_r, p_over_kn, seed, particles, k_n, k_t):
    :data:`MEASURES`, ``eps1_target``, ``eps1_reached``, ``stopped``, ``message``, ``seconds``
    (of the runs that computed it), ``cached`` and ``went_on_from`` (the strain eps1 this run
    went on from, where a time budget had stopped the test before; None: none).

    Args:
        particles, seeds: the packings, ``generate_packing(particles, seed, pressure=p)``.
        mus, pressures: contact friction mu and p / k_n, in (0, 1e-2].
        max_strain, steps: the axial strain eps1 reached in ``steps`` equal steps.
        k_n, k_t: contact stiffnesses (N/m²); default table 1 of the paper, 2.8e7.
        law: ``"relaxed"`` (:class:`~dolfinx_granular.FrictionalRelaxedRVE`) or ``"taylor"``
            (:class:`~dolfinx_granular.FrictionalRVE`).
        substep: the relaxed RVE's substep (None: its default; part of the model).
        budget: wall seconds per test (None: no limit); a test stopped by it says so, and goes
            on from its last step under a larger budget (or none).
        cache: folder of the packings (``packings/``) and the tests (``tests/``), reused.
        say: called with a line per test (None: silent).
        rolling: rolling friction mu_r of the relaxed RVE (its cap mu_r r_eff f_n), each with
            every mu.
        each_step: ``say`` a line per step of the tests that run, too (:func:`step_line`).
    """
    check_parameters(mus, pressures, particles, seeds, max_strain, steps, k_n, k_t, law, rolling)
    if substep is not None and law != "relaxed":
        raise ValueError("substep is a setting of the relaxed RVE: leave it out with law='taylor'")
    packings = PackingCache(os.path.join(cache, "packings"))
    stored = ElementTestCache(os.path.join(cache, "tests"))
    targets = np.linspace(0.0, max_strain, steps + 1)[1:]
    rows = []
    for p, mu, mu_r, seed in itertools.product(pressures, mus, rolling, seeds):
        rve = make_law(law, packings.get(particles, seed, p), mu, k_n, k_t, mu_r)
        if substep is not None:
            rve.settings.substep = float(substep)
        row = dict(law=law, mu=float(mu), mu_r=float(mu_r), p_over_kn=float(p), seed=int(seed),
                   particles=int(particles), k_n=float(k_n), k_t=float(k_t))  # fmt: skip
        on_step = (lambda r, t=dict(row): say(step_line(t, r))) if say and each_step else None
        run = stored.run(BIAXIAL, rve, rve.packing, seed, p, targets, budget, on_step)
        row.update(strength_of(run.rows, run.stop, max_strain))
        went_on = run.rows[run.resumed_rows - 1]["eps1"] if run.resumed_rows else None
        rows.append(dict(row, seconds=run.seconds, cached=run.cached, went_on_from=went_on))
        if say is not None:
            say(progress_line(rows[-1]))
    return rows


def strength_of(rows, stop, max_strain):
    """:data:`MEASURES` of one biaxial test (its step rows and stop message, as
    :func:`~.element_tests.load_test` returns them), with eps1_reached, stopped, message."""
    m = measures(rows, stop, max_strain, BIAXIAL)
    out = dict(eps1_target=float(max_strain), eps1_reached=m["eps1_reached"],
               stopped=m["stopped"], message=m["message"])  # fmt: skip
    for which, key in (("peak", "qp_peak"), ("cs", "qp_critical_last_quarter")):
        s = float(m.get(key, math.nan))
        # (q / p <= 1 while both principal stresses are compressive; NaN otherwise)
        phi = math.degrees(math.asin(s)) if abs(s) <= 1.0 else math.nan
        out[f"sin_phi_{which}"], out[f"phi_{which}_deg"] = s, phi
        out[f"tan_phi_{which}"] = math.tan(math.radians(phi))
    return out


def _label(t):
    """The test ``t`` (law, mu, mu_r, p_over_kn, seed) as its lines name it."""
    rolling = f" mu_r {t['mu_r']:g}" if t["mu_r"] else ""
    return f"{t['law']} mu {t['mu']:g}{rolling} p/kn {t['p_over_kn']:g} seed {t['seed']}"


def step_line(t, r):
    """One step's line: the test ``t`` (law, mu, mu_r, p_over_kn, seed) and its step row r."""
    miss = abs(r["control_error_Pa"]) / r["p_Pa"] if r["p_Pa"] else math.nan
    return (f"  {_label(t)}: "
            f"eps1 {100 * r['eps1']:.2f} %, q/p {r['q_over_p']:.3f}, sigma_11 off -p by "
            f"{100 * miss:.2f} %, {r['wall_s']:.1f} s")  # fmt: skip


def progress_line(t):
    """One test's progress line."""
    where = f"eps1 {100 * t['eps1_reached']:.2f} %"
    why = f" ({t['message'][:100]})" if t["stopped"] else ""
    if t.get("went_on_from") is not None:
        where += f" (went on from {100 * t['went_on_from']:.2f} %)"
    return (f"{_label(t)}: {where}, "
            f"sin phi peak {t['sin_phi_peak']:.3f}, cs {t['sin_phi_cs']:.3f} in "
            f"{t['seconds']:.1f} s{' (cached)' if t['cached'] else ''}{why}")  # fmt: skip


def curve_rows(tests):
    """The strength curve of ``tests`` (rows of :func:`strength_tests`): one row per (law, mu,
    mu_r, p / k_n) with :data:`COLUMNS`; the std over the seeds with ddof = 1 (0 for one
    seed)."""
    groups = {}
    for t in tests:
        groups.setdefault((t["law"], t["mu"], t.get("mu_r", 0.0), t["p_over_kn"]), []).append(t)
    curve = []
    for (law, mu, mu_r, p), ts in groups.items():
        first = ts[0]
        row = dict(law=law, mu=mu, mu_r=mu_r, p_over_kn=p, kappa=1.0 / p,
                   particles=first["particles"], seeds=len(ts), k_n=first["k_n"],
                   k_t=first["k_t"])  # fmt: skip
        for key in MEASURES:
            v = np.array([t[key] for t in ts], dtype=float)
            ok = v[np.isfinite(v)]
            row[f"{key}_mean"] = float(ok.mean()) if ok.size else math.nan
            spread = float(ok.std(ddof=1)) if ok.size > 1 else 0.0
            row[f"{key}_std"] = spread if ok.size else math.nan
        reached = [t["eps1_reached"] for t in ts]
        stops = [f"seed {t['seed']} at {100 * t['eps1_reached']:.2f} %: {t['message']}"
                 for t in ts if t["stopped"]]  # fmt: skip
        row.update(eps1_target=first["eps1_target"], eps1_reached_mean=float(np.mean(reached)),
                   eps1_reached_min=float(min(reached)), stopped=len(stops),
                   stop_reasons="; ".join(stops))  # fmt: skip
        curve.append(row)
    return curve


def strength_curve(**options) -> list[dict]:
    """The strength curve, one row per (law, mu, mu_r, p / k_n) with :data:`COLUMNS`:
    :func:`curve_rows` of :func:`strength_tests` (``options``: its keyword arguments)."""
    return curve_rows(strength_tests(**options))


def on_line(row, rolling_ratio: float) -> bool:
    """The curve's ``row`` has mu_r = ``rolling_ratio`` mu (a row without mu_r: 0)."""
    mu_r = float(row.get("mu_r", 0.0))
    return math.isclose(mu_r, rolling_ratio * float(row["mu"]), rel_tol=1e-9, abs_tol=1e-12)


def nondecreasing(values, weights) -> np.ndarray:
    """The weighted least-squares non-decreasing fit of ``values`` (n,) with ``weights`` (n,)
    > 0, by pooling adjacent violators: where a value falls below the one before, both become
    their weighted mean, until none falls. Non-finite values are left out and stay as they are;
    a non-decreasing input comes back unchanged."""
    values = np.asarray(values, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    fitted = values.copy()
    finite = np.flatnonzero(np.isfinite(values))
    blocks = []  # [sum of w v, sum of w, members] per pooled run
    for k in finite:
        blocks.append([weights[k] * values[k], weights[k], [k]])
        while len(blocks) > 1 and blocks[-2][0] * blocks[-1][1] > blocks[-1][0] * blocks[-2][1]:
            total, weight, members = blocks.pop()
            blocks[-1][0] += total
            blocks[-1][1] += weight
            blocks[-1][2] += members
    for total, weight, members in blocks:
        if len(members) > 1:  # (a single value is kept bit for bit)
            fitted[members] = total / weight
    return fitted


def falls(rows, which: str = "cs") -> list[tuple[float, float, float, float]]:
    """Where phi (``which``: ``"cs"`` or ``"peak"``, degrees) falls as mu grows along ``rows``
    (one line of a curve: one law, mu_r / mu and p / k_n): (mu, the next mu, phi at each) per
    such pair of neighbours in mu; the pairs that :func:`nondecreasing` pools."""
    rows = sorted(rows, key=lambda r: float(r["mu"]))
    pairs = [(float(a["mu"]), float(b["mu"]), float(a[WHICH[which]]), float(b[WHICH[which]]))
             for a, b in itertools.pairwise(rows)]  # fmt: skip
    return [p for p in pairs if p[3] < p[2]]


def friction_angle(curve, mu: float, p_over_kn: float, which: str = "cs", law=None,
                   rolling_ratio: float = 0.0, monotone: bool = False) -> float:  # fmt: skip
    """The friction angle phi (degrees) of ``curve`` (rows of :func:`strength_curve`, or of
    its CSV) at contact friction ``mu``, linear in mu between the tabulated values, at the
    tabulated confining pressure ``p_over_kn``; ``which``: ``"cs"`` (critical state, mean over
    the seeds) or ``"peak"``; ``law``: the curve's law where it holds several;
    ``rolling_ratio``: the rows with mu_r = rolling_ratio mu (the line the strength reduction
    follows, both frictions reduced alike; 0: without rolling resistance); ``monotone``: read
    on the curve's :func:`nondecreasing` fit over mu (each row weighted by its seeds), where
    the seeds' scatter makes the means fall somewhere though more friction cannot weaken the
    material.

    Raises:
        ValueError: ``which`` unknown, ``p_over_kn`` not tabulated, ``mu`` outside the
            tabulated range, or no angle measured at the mu values around it.
    """
    if which not in WHICH:
        raise ValueError(f"which = {which!r}: give one of {', '.join(WHICH)}")
    laws = sorted({r["law"] for r in curve})
    if law is None and len(laws) > 1:
        raise ValueError(f"the curve holds the laws {', '.join(laws)}: pass law= one of them")
    rows = [r for r in curve if law is None or r["law"] == law]
    rows = [r for r in rows if on_line(r, rolling_ratio)]
    here = [r for r in rows if math.isclose(float(r["p_over_kn"]), p_over_kn, rel_tol=1e-9)]
    if not here:
        tabulated = ", ".join(f"{p:g}" for p in sorted({float(r["p_over_kn"]) for r in rows}))
        raise ValueError(f"p_over_kn = {p_over_kn:g} is not in the curve: give one of "
                         f"{tabulated or 'none (an empty curve)'}, or measure it")  # fmt: skip
    here.sort(key=lambda r: float(r["mu"]))
    mu_tab = np.array([float(r["mu"]) for r in here])
    phi = np.array([float(r[WHICH[which]]) for r in here])
    if monotone:
        phi = nondecreasing(phi, [float(r.get("seeds", 1)) for r in here])
    if not (mu_tab[0] <= mu <= mu_tab[-1]):
        raise ValueError(f"mu = {mu:g} lies outside the curve's mu = {mu_tab[0]:g} to "
                         f"{mu_tab[-1]:g} at p/k_n = {p_over_kn:g}: measure the strength there "
                         "(no extrapolation)")  # fmt: skip
    if np.unique(mu_tab).size < mu_tab.size:
        raise ValueError(f"the curve holds a mu twice at p/k_n = {p_over_kn:g}: pass one law's "
                         "rows of one measurement")  # fmt: skip
    k = int(np.searchsorted(mu_tab, mu))
    around = phi[k : k + 1] if mu_tab[k] == mu else phi[k - 1 : k + 1]
    if not np.isfinite(around).all():
        raise ValueError(f"no {which} friction angle was measured next to mu = {mu:g} at "
                         f"p/k_n = {p_over_kn:g} (its tests stopped before a step): see the "
                         "curve's stop_reasons")  # fmt: skip
    return float(np.interp(mu, mu_tab, phi))
