"""``demos/slope.py --factor-of-safety``: the strength reduction's command line (:mod:`.cli`
parses, this checks the combination and runs :class:`~.safety_run.SafetyRun`).

Unless given, the options of :data:`DEFAULTS` apply (the frictional relaxed RVE, which the
strength reduction needs). The load path is the weight by path following, or with
``--footing-scale S`` > 0 the weight in ``--gravity-steps`` load steps and S x the footing by
path following (its first increment 1/``--steps`` of it). Options that the strength reduction
sets itself are refused, as are those that would be ignored. The strength curve is measured on
the slope's packings (:mod:`.safety_strength`; tests cached in ``OUT/strength_cache``, which
``--force`` keeps) unless ``--strength CSV`` gives one. An ``--out`` that holds a
factor-of-safety run is refused unless ``--force`` (which removes its files, no others) or
``--resume`` (which takes the finished trials and runs the rest).
"""

from __future__ import annotations

import dataclasses
import os
from typing import TYPE_CHECKING

from ..io.outfolder import OutFolderError, claim_out
from ..io.strength_table import merge_curves, read_curve
from ..packings.packing import PackingFileError
from .arguments import UserError, make_packing, options_of
from .interrupt import RunInterrupted
from .options import K_N
from .safety import HALVINGS
from .safety_run import SAFETY_FILES, SafetyRun, resume_state
from .safety_strength import Strength, measured_rows

if TYPE_CHECKING:
    import argparse

    from mpi4py import MPI

    from .interrupt import StopRequest

#: the options a factor-of-safety run takes unless they are given
DEFAULTS = {
    "rve": "relaxed",
    "friction": 0.5,
    "confinement": 2.8e5,
    "particles": 70,
    "gravity_steps": 10,  # (the first arc: a tenth of the weight, not all of it at once)
    "out": "results/slope-safety",
}
#: options that the strength reduction sets itself
SET_HERE = ("path_following", "unload", "stop_after", "load_factor", "linear_solver")
#: what ``--factor-of-safety --resume DIR`` takes from the command line
RESUME = {"factor_of_safety", "resume", "no_figure", "debug"}


def check(a: argparse.Namespace, given: set[str]) -> None:
    """Refuse what the strength reduction cannot take (UserError naming the fix)."""
    if a.resume:
        ignored = sorted(given - RESUME)
        if ignored:
            raise UserError(
                f"--factor-of-safety --resume {a.resume} goes on with the run's own "
                f"options: drop {_names(ignored)}"
            )
        return
    refused = sorted(given & set(SET_HERE))
    if refused:
        raise UserError(
            f"--factor-of-safety sets the load path itself (the weight by path "
            f"following, then --footing-scale x the footing): drop {_names(refused)}"
        )
    if a.friction <= 0.0:
        raise UserError(
            "--factor-of-safety reduces the contacts' friction: give --friction MU > 0 "
            f"(default {DEFAULTS['friction']})"
        )
    if a.rve != "relaxed":
        raise UserError(
            "--factor-of-safety takes its strength from the frictional relaxed RVE: "
            "drop --rve taylor (or give --rve relaxed)"
        )
    if "steps" in given and a.footing_scale == 0.0:
        raise UserError(
            "--steps sets the footing's first increment: give --footing-scale S > 0, "
            "or drop --steps"
        )
    if "reduction_steps" in given and not a.continuation:
        raise UserError("--reduction-steps applies to --continuation: add it, or drop it")
    if a.strength and given & {"strength_seeds", "strength_strain"}:
        names = _names(sorted(given & {"strength_seeds", "strength_strain"}))
        raise UserError(f"{names} apply to a measured strength curve: drop them, or --strength")
    if a.packing and not a.strength:
        raise UserError(
            "the strength curve is measured on generated packings, not on --packing: "
            "give --strength CSV measured for it, or drop --packing"
        )


def _names(dests):
    return ", ".join("--" + d.replace("_", "-") for d in dests)


def run_safety(
    a: argparse.Namespace,
    given: set[str],
    comm: MPI.Comm,
    stop: StopRequest,
    started: float | None = None,
) -> dict:
    """Run (or continue) the factor-of-safety run that ``a`` asks for (``given``: the options
    the command line named; ``started``: its ``time.perf_counter()``); its status dict for the
    command line (``converged``, or ``interrupted`` with ``interrupted_by``)."""
    for name, value in DEFAULTS.items():
        if name not in given:
            setattr(a, name, value)
    check(a, given)
    say = (lambda line: print(line, flush=True)) if comm.rank == 0 else (lambda line: None)
    prepare = _resumed if a.resume else _new
    prepared = prepare(a, comm, stop, say, started)
    if prepared is None:
        return {"status": "converged"}
    run, finished = prepared
    record = run.run(finished)
    if record["status"] == "interrupted":
        return {"status": "interrupted", "interrupted_by": run.interrupted_by}
    return {"status": "converged"}


def _new(a, comm, stop, say, started):
    """(run, []) of a new run: its options, a user's curve (checked before the folder is
    claimed), the folder, the packing, a measured curve."""
    if a.continuation:  # (the load under load control, then the reduction phase)
        a.path_following, a.load_factor = None, a.footing_scale
    else:
        a.path_following = "footing" if a.footing_scale > 0.0 else "gravity"
        a.load_factor = a.footing_scale if a.footing_scale > 0.0 else 1.0
    options = options_of(a)
    if a.continuation:
        options = dataclasses.replace(
            options, reduction=a.friction / 2.0**HALVINGS, reduction_steps=a.reduction_steps
        )
    p_over_kn = options.confinement / options.normal_stiffness
    ratio = options.rolling_friction / options.friction  # (mu_r / mu: divided alike)
    curve = _read(a.strength, p_over_kn, a.friction, ratio) if a.strength else None
    try:
        claim_out(a.out, SAFETY_FILES, a.force, "factor-of-safety", comm)
    except OutFolderError as err:
        raise UserError(f"{err} (or continue it: --factor-of-safety --resume {a.out})") from None
    packing = _on_rank0(comm, stop, lambda: _packing(a, options))
    # safety.json's source: the user's file, or their list where several were merged
    files = a.strength or []
    source, measure = {"source": files[0] if len(files) == 1 else files}, None
    if curve is None:
        seeds = list(range(a.seed, a.seed + a.strength_seeds))
        source = {
            "source": "measured",
            "particles": a.particles,
            "seeds": seeds,
            "max_strain": a.strength_strain,
            "cache": os.path.join(a.out, "strength_cache"),
        }
        measure = _measurer(source, options, comm, stop, say)
    strength = Strength(curve or [], p_over_kn, a.friction, measure, ratio)
    run = SafetyRun(
        packing,
        options,
        strength,
        a.out,
        comm,
        a.fs_tolerance,
        a.footing_scale,
        source,
        stop,
        figure=not a.no_figure,
        say=say,
        started=started,
    )
    return run, []


def _measurer(source, options, comm, stop, say):
    """``measure(mus)``: the strength curve's rows at ``mus`` measured on rank 0 with the
    slope's RVE as ``source`` (safety.json's ``strength``) says, on every rank."""
    k_n = options.normal_stiffness
    k_t = options.tangential_stiffness or k_n
    p_over_kn = options.confinement / k_n
    ratio = options.rolling_friction / options.friction

    def measure(mus):
        def work():
            return measured_rows(
                mus,
                source["particles"],
                source["seeds"],
                p_over_kn,
                k_n,
                k_t,
                source["max_strain"],
                source["cache"],
                lambda line: say("strength: " + line),
                ratio,
            )

        return _on_rank0(comm, stop, work)

    return measure


def _read(paths, p_over_kn, mu, rolling_ratio):
    """The rows of the user's curve (its files merged in order), checked against the slope
    (UserError naming the fix)."""
    try:
        curve = merge_curves([read_curve(p) for p in paths])
        Strength(curve, p_over_kn, mu, rolling_ratio=rolling_ratio)
    except (OSError, ValueError) as err:
        raise UserError(f"--strength {' '.join(paths)}: {err}") from None
    return curve


def _packing(a, options):
    try:
        return make_packing(a.particles, a.seed, a.packing, options.confinement / K_N)
    except PackingFileError as err:
        raise UserError(f"--packing: {err}") from err


def _on_rank0(comm, stop, work):
    """``work()`` on rank 0 (a signal interrupts it at once), its value or error on every
    rank."""
    value = failure = None
    if comm.rank == 0:
        try:
            with stop.raising():
                value = work()
        except Exception as err:  # every rank raises it, so that none waits in bcast
            value = failure = err
    value = comm.bcast(value, root=0)
    if isinstance(value, RunInterrupted):
        raise value
    if isinstance(value, Exception):
        raise failure or (value if isinstance(value, UserError) else UserError(str(value)))
    return value


def _resumed(a, comm, stop, say, started):
    """(run, finished trials) of the run in ``--resume DIR``; None where it was done."""
    try:
        state = _on_rank0(comm, stop, lambda: resume_state(a.resume))
    except ValueError as err:
        raise UserError(str(err)) from None
    record = state["record"]
    if record["status"] == "done":
        say(
            f"safety: the run in {a.resume} is done (factor of safety "
            f"{record['factor_of_safety']:.4g}); nothing to resume (its results are unchanged)"
        )
        return None
    source = {k: v for k, v in record["strength"].items() if k != "file"}
    measure = None
    if source["source"] == "measured":
        measure = _measurer(source, state["options"], comm, stop, say)
    ratio = state["options"].rolling_friction / record["mu"]
    strength = Strength(state["curve"], record["p_over_kn"], record["mu"], measure, ratio)
    run = SafetyRun(
        state["packing"],
        state["options"],
        strength,
        a.resume,
        comm,
        record["tolerance"],
        record["footing_scale"],
        source,
        stop,
        figure=not a.no_figure,
        say=say,
        started=started,
    )
    return run, state["trials"]
