"""The factor of safety by strength reduction on the contact friction: the search and its answer.

Each trial runs the slope from the start of its load path with the contacts' friction reduced
to mu_f: the weight by path following (and, with a ``footing_scale`` S > 0, the weight in load
steps and then S x the footing by path following). A trial *passes* where the whole load is
carried and *fails* where path following finds a limit point before it, or where no equilibrium
is found along it (the run stops early).

The search (:func:`next_friction`) starts at the user's mu; while every trial passes it halves
mu_f (at most :data:`HALVINGS` times), while every trial fails it doubles it (at most
:data:`DOUBLINGS` times); once a failing mu_f lies below a passing one it bisects that bracket
until the factors of safety of its ends differ by at most ``tolerance`` (relative), or until its
ends' frictions do (:func:`settled`): where phi is flat in mu, as below mu of about 0.1, the
scatter of the measured curve between packings can make phi at the two ends of a narrow bracket
differ more than its width, and no bisection would narrow FS. The factor of
safety is FS = tan phi(mu) / tan phi(mu_f) with phi from the strength curve
(:func:`~dolfinx_granular.drivers.strength.friction_angle`, linear in mu) and mu_f the middle of
the last bracket; mu / mu_f is reported beside it, never alone (phi saturates in mu).

Pure Python: nothing here needs DOLFINx (:mod:`.safety_run` runs the trials).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

#: the most halvings of mu_f below the user's mu while every trial passes (mu / 64)
HALVINGS = 6
#: the most doublings of mu_f above the user's mu while every trial fails (4 mu)
DOUBLINGS = 2
#: the default relative width of the last bracket in FS (1 %)
TOLERANCE = 0.01
#: a load parameter this close below its full value counts as the whole load (round-off)
WHOLE = 1e-9


@dataclass(frozen=True)
class Trial:
    """One run of the slope at the reduced friction ``mu_f``.

    ``passed``: the whole load was carried; ``phase``: the load phase where the run stopped
    (``gravity`` or ``footing``); ``carried``: that phase's load reached, as a share of its
    whole (the weight's factor, or the footing's share of S x the footing load; > 1 where the
    last increment overshot); ``gravity``: the weight's factor reached; ``footing``: the share
    of S x the footing reached (0 without a footing); ``seconds``: the run's wall time;
    ``why``: how it ended; ``status``: the run's ``summary.json`` status; ``folder``: its run
    folder, relative to the safety run's.
    """

    mu_f: float
    passed: bool
    phase: str
    carried: float
    gravity: float
    footing: float
    seconds: float
    why: str
    status: str
    folder: str

    def as_dict(self) -> dict:
        return asdict(self)


#: the columns of trials.csv, in order
TRIAL_COLUMNS = tuple(Trial.__dataclass_fields__)


def trial_of(
    summary: Mapping[str, Any],
    mu_f: float,
    footing_scale: float,
    footing_load: float,
    folder: str,
    seconds: float,
) -> Trial:
    """The :class:`Trial` of a finished slope run (its ``summary.json`` dict) at ``mu_f`` with
    ``footing_scale`` x the footing load ``footing_load`` (N/m, the geometry's) after the
    weight."""
    info = summary.get("step_info") or []
    gravity = max([float(s["gravity"]) for s in info] or [0.0])
    footing = 0.0
    if footing_scale > 0.0:
        whole = footing_scale * footing_load
        footing = max([s["footing_load"] / whole for s in info if s["phase"] == "footing"] or [0.0])
    carried_all = gravity >= 1.0 - WHOLE and (footing_scale == 0.0 or footing >= 1.0 - WHOLE)
    phase = "footing" if footing_scale > 0.0 and gravity >= 1.0 - WHOLE else "gravity"
    carried = footing if phase == "footing" else gravity
    passed = carried_all and summary["status"] == "converged"
    return Trial(
        float(mu_f),
        passed,
        phase,
        carried,
        gravity,
        footing,
        float(seconds),
        _why(summary, passed),
        summary["status"],
        folder,
    )


def _why(summary, passed):
    """How a trial's run ended, in words."""
    if passed:
        return "carried the whole load"
    failed = summary.get("failed")
    if failed:
        return f"no equilibrium in the {failed['phase']}: {failed['reason']}"
    if summary["status"] == "interrupted":
        return f"interrupted by {summary.get('interrupted_by')}"
    stopped = (summary.get("path_following") or {}).get("stopped") or summary["status"]
    # (past the peak: the path turned at a limit point; else it ran out of increments)
    what = "limit point" if "past the peak" in stopped else "stopped"
    return f"{what} before the whole load: {stopped}"


def continuation_trials(
    summary: Mapping[str, Any],
    mu: float,
    reduced: Callable[[float], float],
    footing_scale: float,
    footing_load: float,
    folder: str,
) -> list[Trial]:
    """The answer of a strength reduction by continuation (one slope run whose last phase,
    ``reduction``, lowers mu at the whole load; its finished ``summary.json`` dict) as the
    :class:`Trial` rows of a bracket: the least friction that carried the load (passed) and
    the one at which its reduction step found no equilibrium after every cut-back (failed;
    ``reduced(t)``: mu_f at t of the phase; ``footing_scale`` x ``footing_load`` (N/m) the
    footing on the path). One row where the reduction reached its end (passed: FS at least
    that) or where the load phases failed before it (failed at mu)."""
    info = summary.get("step_info") or []
    steps = [s for s in info if s["phase"] == "reduction"]
    load = 1.0 if footing_scale > 0.0 else 0.0
    seconds, status = float(summary["wall_time"]), summary["status"]
    failed = summary.get("failed")
    if failed is not None and failed["phase"] != "reduction":  # (the load before it)
        return [trial_of(summary, mu, footing_scale, footing_load, folder, seconds)]
    last = steps[-1]["friction"] if steps else mu
    rows = [
        Trial(last, True, "reduction", 1.0, 1.0, load, seconds,
              f"carried the whole load at mu_f = {last:.6g}", status, folder)
    ]  # fmt: skip
    if failed is not None:
        cut = [c for c in summary.get("cutbacks") or [] if c["phase"] == "reduction"][-1]
        mu_fail = reduced(cut["t_to"])
        why = f"no equilibrium at mu_f = {mu_fail:.6g} after every cut-back: {failed['reason']}"
        stop = continuation_stop(summary)
        if stop["settlement_growth"] is not None:
            why += (
                f"; the settlement per unit ln(mu) over the last {GROWTH_STEPS} steps: "
                f"{stop['settlement_growth']:.3g} x its median step's ({stop['stopped_on']})"
            )
        rows.append(
            Trial(mu_fail, False, "reduction", 1.0, 1.0, load, seconds, why, status, folder)
        )
    return rows


#: the steps at the end of a reduction whose settlement rate :func:`settlement_growth` compares
GROWTH_STEPS = 3


def settlement_growth(steps: Sequence[Mapping[str, Any]]) -> float | None:
    """How fast a reduction's last steps settled the slope beside its steps before: the
    settlement (m) per unit ln(mu) over the last :data:`GROWTH_STEPS` steps, divided by the
    median of every step's own rate. Near a collapse it grows without bound; where Newton
    stopped on the stress jumps of rearranging RVEs with the slope far from collapse it stays
    near 1 (:func:`continuation_stop` reads it). None with fewer than ``GROWTH_STEPS + 2``
    steps or no settlement.

    ``steps``: the reduction's converged steps (``summary.json`` ``step_info`` rows, with
    ``friction`` and ``settlement``), in order.
    """
    if len(steps) < GROWTH_STEPS + 2 or any("settlement" not in s for s in steps):
        return None
    mu = np.log([s["friction"] for s in steps])
    u = np.array([s["settlement"] for s in steps], dtype=float)
    rates = np.abs(np.diff(u) / np.diff(mu))
    typical = float(np.median(rates[np.isfinite(rates)]))
    k = GROWTH_STEPS
    last = abs((u[-1] - u[-1 - k]) / (mu[-1] - mu[-1 - k]))
    return last / typical if typical > 0.0 and np.isfinite(last) else None


#: a continuation's stop whose :func:`settlement_growth` lies below this was a stress jump
JUMP_GROWTH = 2.0
#: ... and at this or above, a collapse (between the two it is left unread: ``unclear``)
COLLAPSE_GROWTH = 5.0


def continuation_stop(summary: Mapping[str, Any]) -> dict | None:
    """What ended a continuation whose reduction found no equilibrium (its ``summary.json``
    dict; None for any other run): ``settlement_growth`` (:func:`settlement_growth`, None
    with too few steps) and ``stopped_on``: ``"collapse"`` (at least
    :data:`COLLAPSE_GROWTH`: the slope's settlement ran away), ``"stress jump"`` (below
    :data:`JUMP_GROWTH`: it settled at its steady rate, and Newton stopped on the stress
    jump of a rearranging RVE; as far as that tells, mu_f is an upper bound of the
    collapse's and FS a lower bound) or ``"unclear"`` (between, or no growth)."""
    failed = summary.get("failed")
    if failed is None or failed["phase"] != "reduction":
        return None
    growth = settlement_growth(
        [s for s in summary.get("step_info") or [] if s["phase"] == "reduction"]
    )
    stopped_on = "unclear"
    if growth is not None and growth >= COLLAPSE_GROWTH:
        stopped_on = "collapse"
    elif growth is not None and growth < JUMP_GROWTH:
        stopped_on = "stress jump"
    return {"settlement_growth": growth, "stopped_on": stopped_on}


def bracket(trials: Sequence[Trial]) -> tuple[Trial | None, Trial | None]:
    """(failing, passing): the passing trial of least mu_f and the failing trial of largest
    mu_f below it (None where there is none)."""
    passes = sorted((t for t in trials if t.passed), key=lambda t: t.mu_f)
    low = passes[0] if passes else None
    fails = [t for t in trials if not t.passed and (low is None or t.mu_f < low.mu_f)]
    return max(fails, key=lambda t: t.mu_f, default=None), low


def next_friction(
    trials: Sequence[Trial],
    mu: float,
    fs: Callable[[float], float],
    tolerance: float = TOLERANCE,
    mu_range: tuple[float, float] = (0.0, math.inf),
) -> float | None:
    """The next trial's mu_f, or None once the search is done (module docstring).

    ``fs(mu_f)``: the factor of safety of mu_f; ``mu_range``: the frictions the strength curve
    covers (a halving or doubling outside it ends the search with a bound)."""
    if not trials:
        return float(mu)
    failing, passing = bracket(trials)
    if failing is None:  # every trial passed: weaker
        below = passing.mu_f / 2.0
        ok = below >= mu / 2.0**HALVINGS * (1 - 1e-12) and below >= mu_range[0]
        return below if ok else None
    if passing is None:  # every trial failed: stronger
        above = failing.mu_f * 2.0
        ok = above <= mu * 2.0**DOUBLINGS * (1 + 1e-12) and above <= mu_range[1]
        return above if ok else None
    if settled(fs, failing, passing, tolerance):
        return None
    return 0.5 * (failing.mu_f + passing.mu_f)


def settled(fs: Callable[[float], float], failing: Trial, passing: Trial, tolerance: float) -> bool:
    """Whether the bracket (failing, passing) is narrow enough: its ends' FS, or their frictions,
    differ by at most ``tolerance`` (relative)."""
    narrow_mu = passing.mu_f / failing.mu_f - 1.0 <= tolerance
    return width(fs, failing, passing) <= tolerance or narrow_mu


def width(fs: Callable[[float], float], failing: Trial, passing: Trial) -> float:
    """The bracket's relative width in FS: FS(failing) / FS(passing) - 1 (< 0 where phi falls
    with mu on the curve between them)."""
    return fs(failing.mu_f) / fs(passing.mu_f) - 1.0


def outcome(
    trials: Sequence[Trial],
    mu: float,
    fs: Callable[[float], float],
    fs_peak: Callable[[float], float],
    tolerance: float = TOLERANCE,
) -> dict:
    """The answer of the trials so far: ``factor_of_safety`` (critical state) and
    ``factor_of_safety_peak`` at ``mu_f``, ``mu_ratio`` = mu / mu_f, the ``mu_f_bracket``
    (failing, passing) and its ``factor_of_safety_bracket`` (low, high), ``bound``: None where
    a bracket exists, ``"lower"`` where every trial passed (FS >= the value: even the least
    mu_f carried the load), ``"upper"`` where every trial failed (FS < the value),
    ``converged`` (the bracket within ``tolerance``, :func:`settled`) and ``curve_limited``
    (converged, but the bracket's FS differ by more than ``tolerance``, or fall as mu_f rises:
    phi is not monotone between its ends, and FS is as uncertain as the strength curve, not as
    the search). Empty values without trials."""
    failing, passing = bracket(trials)
    out = dict(
        factor_of_safety=None,
        factor_of_safety_peak=None,
        mu_f=None,
        mu_ratio=None,
        mu_f_bracket=None,
        factor_of_safety_bracket=None,
        bound=None,
        converged=False,
        curve_limited=False,
    )
    if failing is None and passing is None:
        return out
    if failing is not None and passing is not None:
        mu_f = 0.5 * (failing.mu_f + passing.mu_f)
        ends = sorted((fs(passing.mu_f), fs(failing.mu_f)))
        done = settled(fs, failing, passing, tolerance)
        out.update(
            mu_f_bracket=[failing.mu_f, passing.mu_f],
            factor_of_safety_bracket=ends,
            converged=done,
            curve_limited=done and not 0.0 <= width(fs, failing, passing) <= tolerance,
        )
    else:
        mu_f = (passing or failing).mu_f
        out["bound"] = "lower" if failing is None else "upper"
    out.update(
        mu_f=mu_f,
        mu_ratio=mu / mu_f,
        factor_of_safety=fs(mu_f),
        factor_of_safety_peak=fs_peak(mu_f),
    )
    return out


def search(
    run_trial: Callable[[float], Trial | None],
    mu: float,
    fs: Callable[[float], float],
    tolerance: float = TOLERANCE,
    mu_range: tuple[float, float] = (0.0, math.inf),
    trials: Sequence[Trial] = (),
    on_trial: Callable[[list[Trial]], None] | None = None,
) -> tuple[list[Trial], bool]:
    """Run trials (``run_trial(mu_f)``: the :class:`Trial`, or None where the run was
    interrupted) from the finished ``trials`` on until :func:`next_friction` is done;
    ``on_trial(trials)`` after each. Returns the trials and whether the search finished."""
    trials = list(trials)
    while (mu_f := next_friction(trials, mu, fs, tolerance, mu_range)) is not None:
        trial = run_trial(mu_f)
        if trial is None:
            return trials, False
        trials.append(trial)
        if on_trial is not None:
            on_trial(trials)
    return trials, True


def trial_line(trial: Trial, fs: Callable[[float], float], n: int) -> str:
    """The console line of the n-th trial."""
    verdict = "passed" if trial.passed else "FAILED"
    return (
        f"safety: trial {n}: mu_f = {trial.mu_f:.6g} (FS {fs(trial.mu_f):.4g}) {verdict}: "
        f"{trial.phase} x{trial.carried:.4g} carried, {trial.seconds:.1f} s; {trial.why[:160]}"
    )
