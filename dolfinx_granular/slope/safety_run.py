"""A factor-of-safety run: the trials of the strength reduction (:mod:`.safety`) on the slope,
each in its own run folder, and what the run writes.

Into ``out``: ``safety.json`` (the answer, the strength, limit equilibrium beside it, the
geometry, every trial; rewritten after each trial with ``status`` ``running``),
``trials.csv`` (a row per trial, :data:`~.safety.TRIAL_COLUMNS`), ``strength.csv`` (the curve
used), ``packing.npz`` (the RVE's packing), ``mechanism.png`` (the displacement increment at the
limit of the failing end of the last bracket, Bishop's critical circles over it) and
``trials/mu_<mu_f>/`` (each trial's slope run: ``summary.json``, ``restart.npz``, ...). A run
started again on its folder (:func:`resume_state`) takes its finished trials from
``safety.json`` and runs the others.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from typing import TYPE_CHECKING, Any

from mpi4py import MPI

from ..io.runwriter import RunWriter
from ..io.strength_table import read_curve, write_curve
from ..packings.packing import Packing
from .limit_equilibrium import bishop_factor_of_safety, infinite_slope_factor_of_safety
from .options import SlopeOptions
from .run import RUN_FILES, clear_run, converged_steps, load_restart, run_slope
from .safety import (
    COLLAPSE_GROWTH,
    JUMP_GROWTH,
    TOLERANCE,
    TRIAL_COLUMNS,
    Trial,
    bracket,
    continuation_stop,
    continuation_trials,
    outcome,
    search,
    trial_line,
    trial_of,
)
from .safety_figure import draw_mechanism, limit_increment
from .safety_strength import Strength

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from .geometry import SlopeGeometry
    from .interrupt import StopRequest

#: the run folder of the strength reduction by continuation, relative to the safety run's
CONTINUATION = os.path.join("trials", "reduction")
#: the files of a factor-of-safety run in its folder (``--force`` removes these, no others)
SAFETY_FILES = (
    "safety.json",
    "trials.csv",
    "strength.csv",
    "packing.npz",
    "mechanism.png",
    *(f"trials/mu_*/{name}" for name in RUN_FILES),
    *(f"{CONTINUATION}/{name}" for name in RUN_FILES),
)


def trial_folder(mu_f: float) -> str:
    """The run folder of the trial at ``mu_f``, relative to the safety run's."""
    return os.path.join("trials", f"mu_{mu_f:.10g}")


def limit_equilibrium(
    geometry: SlopeGeometry,
    phi_cs: float,
    phi_peak: float,
    footing_scale: float,
    confinement: float = 0.0,
) -> dict:
    """Bishop's simplified method (critical circle) and the infinite slope with the
    critical-state and the peak friction angles (degrees), for safety.json; with a
    ``confinement`` p > 0 (Pa) also Bishop's with the cohesion p tan φ that the confining
    pressure on the slope's boundary amounts to (``bishop_cs_confined``, ``_peak_``)."""
    out = {}
    for which, phi in (("cs", phi_cs), ("peak", phi_peak)):
        circle = bishop_factor_of_safety(geometry, phi, footing_scale)
        out[f"bishop_{which}"] = circle.factor_of_safety
        out[f"bishop_circle_{which}"] = dataclasses.asdict(circle)
        out[f"infinite_slope_{which}"] = infinite_slope_factor_of_safety(geometry, phi)
        if confinement > 0.0:
            c = confinement * math.tan(math.radians(phi))
            confined = bishop_factor_of_safety(geometry, phi, footing_scale, cohesion=c)
            out[f"bishop_{which}_confined"] = confined.factor_of_safety
            out[f"bishop_circle_{which}_confined"] = dataclasses.asdict(confined)
    return out


class SafetyRun:
    """The strength reduction of one slope (the same on every rank of ``comm``).

    Args:
        packing: the RVE's packing (as for :func:`~.run.run_slope`).
        options: the slope's options at the user's friction mu (its load path: the weight by
            path following, or with a footing the weight in load steps and the footing by path
            following to ``load_factor`` = footing_scale). With a ``reduction`` the search is
            one run by continuation instead (:meth:`continuation`): the load under load
            control, then the friction lowered at the whole load.
        strength: phi(mu) of the slope's RVE (:class:`~.safety_strength.Strength`).
        out: the run's folder.
        tolerance: the last bracket's relative width in FS.
        footing_scale: the share of the footing load on the path (0: the weight alone).
        strength_source: how the curve was got (for safety.json).
        stop_request: signals stop the trial in progress after its load step, and the run.
        figure: draw mechanism.png at the end.
        say: rank 0's progress lines.
        started: ``time.perf_counter()`` when the command began (``wall_time``; default now).
    """

    def __init__(
        self,
        packing: Packing,
        options: SlopeOptions,
        strength: Strength,
        out: str | os.PathLike[str],
        comm: MPI.Comm = MPI.COMM_WORLD,
        tolerance: float = TOLERANCE,
        footing_scale: float = 0.0,
        strength_source: dict | None = None,
        stop_request: StopRequest | None = None,
        figure: bool = True,
        say: Callable[[str], Any] = lambda line: print(line, flush=True),
        started: float | None = None,
    ) -> None:
        self.packing, self.options, self.strength = packing, options, strength
        self.out, self.comm, self.tolerance = str(out), comm, float(tolerance)
        self.footing_scale, self.figure = float(footing_scale), figure
        self.stop_request = stop_request
        self.strength_source = strength_source or {}
        self.say = say if comm.rank == 0 else (lambda *a: None)
        self.writer = RunWriter(self.out, comm)
        self.started = time.perf_counter() if started is None else started
        self.interrupted_by = None  # (the signal's name that stopped a trial)
        self.stop = None  # (a continuation's: :func:`~.safety.continuation_stop`)
        g, mu = options.geometry, strength.mu
        self.phi = {w: strength.phi(mu, w) for w in ("cs", "peak")}
        limit = None  # (a grid search of a few seconds: once, on rank 0)
        if comm.rank == 0:
            limit = limit_equilibrium(
                g, self.phi["cs"], self.phi["peak"], footing_scale, options.confinement
            )
        self.limit = comm.bcast(limit, root=0)

    def fs(self, mu_f: float) -> float:
        """The critical-state factor of safety of ``mu_f``."""
        return self.strength.factor_of_safety(mu_f, "cs")

    def fs_peak(self, mu_f: float) -> float:
        return self.strength.factor_of_safety(mu_f, "peak")

    def run(self, trials: Sequence[Trial] = ()) -> dict:
        """Run the trials after the finished ``trials`` until the search ends (or a signal
        stops it); returns safety.json's dict."""
        if self.comm.rank == 0:
            self.packing.save(self.writer.path("packing.npz"))
        self.say(self._start_line())
        for n, t in enumerate(trials, 1):
            self.say(trial_line(t, self.fs, n) + " (finished before)")
        self._write(list(trials), "running")
        if self.options.reduction is not None:
            trials, done = self.continuation(trials)
        else:
            trials, done = search(
                self._trial,
                self.strength.mu,
                self.fs,
                self.tolerance,
                self.strength.mu_range,
                trials,
                self._after,
            )
        status = "done" if done else "interrupted"
        if done and self.figure:
            self._draw(trials)
        record = self._write(trials, status)
        self.say(self._end_line(record))
        return record

    def _start_line(self):
        o, mu = self.options, self.strength.mu
        load = (
            f"the weight and {self.footing_scale:g} x the footing"
            if self.footing_scale
            else "the weight"
        )
        what = f"{mu:g}"
        if o.rolling_friction:
            what += f" and the rolling friction mu_r = {o.rolling_friction:g} alike"
        how = (
            "by continuation at the whole load"
            if o.reduction is not None
            else f"FS to {100 * self.tolerance:g} %"
        )
        return (
            f"safety: strength reduction of the contact friction mu = {what} ({load}; {how}"
            f"): phi_cs {self.phi['cs']:.2f}°, phi_peak "
            f"{self.phi['peak']:.2f}° at p/k_n = {self.strength.p_over_kn:g}; Bishop "
            f"{self.limit['bishop_cs']:.4g} (cs), {self.limit['bishop_peak']:.4g} (peak)"
            f"{_confined(self.limit)}, infinite slope {self.limit['infinite_slope_cs']:.4g} (cs); "
            f"1:{o.geometry.slope_ratio:g} slope, {o.geometry.n_cells} cells{self._falls_note()}"
        )

    def _falls_note(self):
        """Where the strength curve falls as mu grows (phi is read on its non-decreasing fit)."""
        parts = [
            f"{w} from {a:.2f}° at mu = {m:g} to {b:.2f}° at {n:g}"
            for w in ("cs", "peak")
            for m, n, a, b in self.strength.falls(w)
        ]
        if not parts:
            return ""
        return (
            "; the curve falls (the seeds' scatter: measure more of them) where phi is read on "
            f"its non-decreasing fit: {', '.join(parts)}"
        )

    def continuation(self, finished: Sequence[Trial] = ()) -> tuple[list[Trial], bool]:
        """The strength reduction by continuation: one slope run (in :data:`CONTINUATION`)
        whose load phases carry the whole load at mu and whose reduction phase then lowers
        mu_f until no equilibrium is found after every cut-back. Returns the bracket's
        :class:`Trial` rows (:func:`~.safety.continuation_trials`) and whether the run
        finished (False: a signal stopped it; its restart file goes on)."""
        path = os.path.join(self.out, CONTINUATION)
        if finished:  # (safety.json holds them: the run was done; its folder is only read)
            summary = _finished_summary(path) if self.comm.rank == 0 else None
            self.stop = self.comm.bcast(summary and continuation_stop(summary), root=0)
            return list(finished), True
        summary, restart = self._stored(path)
        o = self.options
        if summary is None:
            more = " (continued from its restart file)" if restart else ""
            self.say(
                f"safety: continuation from mu = {o.friction:g} to {o.reduction:.4g} in "
                f"{o.reduction_steps} steps at the whole load, in {path}{more}"
            )
            summary = run_slope(
                self.packing, o, out=path, comm=self.comm, figure=False, restart=restart,
                stop_request=self.stop_request,
            )  # fmt: skip
        if summary["status"] == "interrupted":
            self.interrupted_by = summary["interrupted_by"]
            return [], False
        self.stop = continuation_stop(summary)
        trials = continuation_trials(
            summary,
            o.friction,
            lambda t: o.reduced_friction(t)[0],
            self.footing_scale,
            o.geometry.footing_load,
            CONTINUATION,
        )
        trials = self.comm.bcast(trials, root=0)
        self.strength.cover([t.mu_f for t in trials])
        for n in range(1, len(trials) + 1):
            self._after(trials[:n])
        return trials, True

    def _trial(self, mu_f: float) -> Trial | None:
        """The trial at ``mu_f``: run in its folder, or read from there where a run started
        again finds it finished (an unfinished one goes on from its restart file); None where
        a signal stopped it."""
        folder = trial_folder(mu_f)
        path = os.path.join(self.out, folder)
        summary, restart = self._stored(path)
        self.strength.cover([mu_f])  # (phi at mu_f, before the trial's lines say its FS)
        options = dataclasses.replace(
            self.options, friction=mu_f, rolling_friction=self.strength.rolling_ratio * mu_f
        )
        if summary is None:
            more = " (continued from its restart file)" if restart else ""
            self.say(f"safety: trial at mu_f = {mu_f:.6g} in {path}{more}")
            summary = run_slope(
                self.packing,
                options,
                out=path,
                comm=self.comm,
                figure=False,
                restart=restart,
                stop_request=self.stop_request,
            )
        else:
            self.say(f"safety: trial at mu_f = {mu_f:.6g}: finished before, in {path}")
        if summary["status"] == "interrupted":
            self.interrupted_by = summary["interrupted_by"]
            return None
        trial = trial_of(
            summary,
            mu_f,
            self.footing_scale,
            options.geometry.footing_load,
            folder,
            summary["wall_time"],
        )
        return self.comm.bcast(trial, root=0)  # (rank 0's verdict for every rank)

    def _stored(self, path):
        """(summary, restart) of what ``path`` holds: the summary dict of a finished run, or
        the restart dict of an unfinished one; (None, None) where it holds neither (its files
        cleared: the trial starts afresh)."""
        found = (None, None)
        if self.comm.rank == 0 and os.path.isdir(path):
            summary = _finished_summary(path)
            if summary is not None:
                found = (summary, None)
            elif converged_steps(path):
                found = (None, load_restart(path))
            else:
                clear_run(path)
        return self.comm.bcast(found, root=0)

    def _after(self, trials):
        self.say(trial_line(trials[-1], self.fs, len(trials)))
        self._write(trials, "running")

    def _write(self, trials, status):
        """safety.json and trials.csv of ``trials`` (rank 0 writes); the record."""
        record = self.record(trials, status)
        if self.comm.rank == 0:  # (the curve grows with the frictions measured)
            write_curve(self.writer.path("strength.csv"), self.strength.curve)
        self.writer.json("safety.json", record)
        self.writer.csv("trials.csv", TRIAL_COLUMNS, [list(t.as_dict().values()) for t in trials])
        return record

    def record(self, trials: Sequence[Trial], status: str) -> dict:
        """safety.json's dict."""
        o, g = self.options, self.options.geometry
        answer = outcome(trials, self.strength.mu, self.fs, self.fs_peak, self.tolerance)
        mu_f = answer["mu_f"]
        phi_f = {w: None if mu_f is None else self.strength.phi(mu_f, w) for w in ("cs", "peak")}
        return {
            "status": status,
            **answer,
            "tolerance": self.tolerance,
            "method": "bisection" if o.reduction is None else "continuation",
            **(self.stop or {"settlement_growth": None, "stopped_on": None}),
            "mu": self.strength.mu,
            "rolling_friction": self.options.rolling_friction,
            "phi_cs": self.phi["cs"],
            "phi_peak": self.phi["peak"],
            "phi_f_cs": phi_f["cs"],
            "phi_f_peak": phi_f["peak"],
            "curve_falls": {w: self.strength.falls(w) for w in ("cs", "peak")},
            "p_over_kn": self.strength.p_over_kn,
            **self.limit,
            "geometry": dataclasses.asdict(g),
            "slope_ratio": g.slope_ratio,
            "slope_angle": g.slope_angle,
            "footing_scale": self.footing_scale,
            "strength": {**self.strength_source, "file": "strength.csv"},
            "options": o.as_dict(),
            "particles": self.packing.n_particles,
            "ranks": self.comm.size,
            "wall_time": time.perf_counter() - self.started,
            "mechanism": self._mechanism(trials),
            "trials": [t.as_dict() for t in trials],
        }

    def _mechanism(self, trials):
        failing, _ = bracket(trials)
        if failing is None or not self.figure:
            return None
        return {"mu_f": failing.mu_f, "folder": failing.folder, "figure": "mechanism.png"}

    def _draw(self, trials):
        """mechanism.png of the failing end of the last bracket (rank 0)."""
        failing, _ = bracket(trials)
        if failing is None or self.comm.rank != 0:
            return
        field = limit_increment(os.path.join(self.out, failing.folder))
        if field is None:
            self.say(
                f"safety: no mechanism.png: the trial at mu_f = {failing.mu_f:g} converged no state"
            )
            return
        X, du, states = field
        circles = [
            ("Bishop, phi_cs", _circle(self.limit["bishop_circle_cs"]), "-"),
            ("Bishop, phi_peak", _circle(self.limit["bishop_circle_peak"]), "--"),
        ]
        title = (
            f"mu_f = {failing.mu_f:.4g}: {failing.phase} x{failing.carried:.3f} carried; "
            f"the increment to state {states}"
        )
        draw_mechanism(
            self.writer.path("mechanism.png"),
            self.options.geometry,
            X,
            du,
            circles,
            title,
            self.footing_scale,
        )

    def _end_line(self, record):
        if record["status"] == "interrupted":
            return (
                f"safety: interrupted after {len(record['trials'])} finished trials; "
                f"continue with --factor-of-safety --resume {self.out}"
            )
        fs = record["factor_of_safety"]
        bound = {"lower": "at least ", "upper": "below "}.get(record["bound"], "")
        spread = record["factor_of_safety_bracket"]
        within = f" (bracket {spread[0]:.4g} .. {spread[1]:.4g})" if spread else ""
        if record.get("curve_limited"):
            within += (
                " (the strength curve, not the search, sets how well FS is known: phi is flat "
                "or not monotone between the bracket's frictions)"
            )
        return (
            f"safety: factor of safety {bound}{fs:.4g}{within} from phi_cs, {bound}"
            f"{record['factor_of_safety_peak']:.4g} from phi_peak; mu / mu_f = "
            f"{record['mu_ratio']:.4g} (mu_f = {record['mu_f']:.5g}); Bishop "
            f"{record['bishop_cs']:.4g} (cs), {record['bishop_peak']:.4g} (peak)"
            f"{_confined(record)}, infinite slope {record['infinite_slope_cs']:.4g}; "
            f"{len(record['trials'])} trials, "
            f"{record['wall_time']:.1f} s; results in {self.out}{_stop_note(record)}"
        )


def _stop_note(record):
    """What a continuation's stop was, for its end line ("" for any other run)."""
    growth, stopped_on = record["settlement_growth"], record["stopped_on"]
    if stopped_on is None or growth is None:
        return ""
    said = f"the settlement's growth over the last steps {growth:.3g}"
    if stopped_on == "stress jump":
        return (
            f"; the reduction stopped on a stress jump of rearranging RVEs, not a collapse "
            f"({said}): the slope was settling at its steady rate, so its factor of safety is "
            "likely larger than this (--residual-tolerance passes such jumps)"
        )
    if stopped_on == "collapse":
        return f"; the reduction stopped where the slope collapsed ({said})"
    return (
        f"; {said} tells no stress jump (below {JUMP_GROWTH:g}) from a collapse "
        f"({COLLAPSE_GROWTH:g} and more)"
    )


def _confined(limit):
    """Bishop's FS with the confinement as cohesion, for a progress line ("" without one)."""
    if "bishop_cs_confined" not in limit:
        return ""
    return (f" (with the confinement as cohesion p tan phi: {limit['bishop_cs_confined']:.4g} "
            f"cs, {limit['bishop_peak_confined']:.4g} peak)")  # fmt: skip


def _finished_summary(path):
    """The summary dict of the finished (converged or failed) run in ``path``, else None."""
    try:
        with open(os.path.join(path, "summary.json")) as f:
            summary = json.load(f)
    except (OSError, ValueError):
        return None
    return summary if summary.get("status") in ("converged", "failed") else None


def _circle(d):
    from .limit_equilibrium import SlipCircle

    return SlipCircle(**d)


def resume_state(out: str | os.PathLike[str]) -> dict:
    """What a factor-of-safety run in ``out`` needs to go on: ``options`` (SlopeOptions),
    ``packing``, ``curve`` (strength.csv's rows), ``record`` (safety.json) and ``trials``;
    ValueError naming the problem where the folder holds none."""
    path = os.path.join(out, "safety.json")
    try:
        with open(path) as f:
            record = json.load(f)
        return {
            "record": record,
            "options": SlopeOptions.from_dict(record["options"]),
            "packing": Packing.load(os.path.join(out, "packing.npz")),
            "curve": read_curve(os.path.join(out, "strength.csv")),
            "trials": [Trial(**t) for t in record["trials"]],
        }
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ValueError(
            f"--resume {out}: no factor-of-safety run to continue there ({err}); start one "
            "with --factor-of-safety --out"
        ) from None
