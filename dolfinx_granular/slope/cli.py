"""The slope benchmark's command line: ``python -m dolfinx_granular.slope`` or ``demos/slope.py``.

Bad input (options, packing files, ``--out``, restart files, meshes) is one line ``error: ...``
on stderr and exit status 2 (``--debug`` shows the traceback), on every rank alike under MPI.
Exit status 0: every load step converged, or the run stopped where ``--stop-after`` asked; 1: it
stopped at a load step that did not converge (e.g. at a limit load); 130 (SIGINT, Ctrl-C) or 143
(SIGTERM): interrupted, after the load step in progress (:mod:`.interrupt`).

A new run refuses an ``--out`` that holds a run's files unless ``--force`` (which removes those
files, and only those, first) or ``--resume`` (which continues it).

``--factor-of-safety`` runs the strength reduction of the contact friction instead
(:mod:`.safety_cli`); its own options are refused without it.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from typing import TYPE_CHECKING

import numpy as np
from mpi4py import MPI

from ..fem.compat import show_warnings
from ..io.commandline import Parser
from ..io.outfolder import writable
from ..io.runwriter import RestartError
from ..packings.packing import PackingFileError
from .arguments import UserError, make_packing, options_of
from .geometry import SlopeGeometry
from .interrupt import SIGNALS, RunInterrupted, StopRequest, exit_status
from .options import K_N, LINEAR_SOLVERS, PHASES, RVES
from .run import (
    clear_run,
    converged_steps,
    is_complete,
    load_restart,
    run_files,
    run_slope,
)

if TYPE_CHECKING:
    from collections.abc import Sequence


#: what a resumed run takes from the command line; its other options are those stored
RESUME_OPTIONS = ("resume", "no_figure", "stop_after", "debug")


class _Parser(Parser):
    """argparse that raises :class:`UserError` (one line) instead of printing the usage block."""

    def error(self, message):
        raise UserError(f"{message} (see '{self.prog} --help')")


def _int_at_least(low):
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {value}")
        return value

    return parse


def _finite(low=None):
    def parse(text):
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not np.isfinite(value) or (low is not None and value < low):
            raise argparse.ArgumentTypeError(
                f"must be a finite number{f' >= {low}' if low is not None else ''}, got {text!r}"
            )
        return value

    return parse


def _slope_ratio(text):
    """The slope's run over its rise: a finite number > 0 (argparse type; whether its run fits
    the columns, :meth:`SlopeGeometry.with_slope_ratio` says)."""
    value = _finite()(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(
            f"the slope's run over its rise must be a finite number > 0 (1: 45°, 2: 26.6°), "
            f"got {text!r}"
        )
    return value


def build_parser(prog: str = "demos/slope.py") -> argparse.ArgumentParser:
    p = _Parser(
        prog=prog,
        allow_abbrev=False,  # (--particle 50 is no --particles 50)
        description="Slope stability benchmark (section 5 of Meier, "
        "Steinmann & Kuhl): dead load, then an eccentric strip footing in load steps, a "
        "Taylor RVE at every Gauss point.",
    )
    _add_packing_and_output(p)
    _add_model(p)
    _add_path_and_run(p)
    _add_safety(p)
    return p


def _add_packing_and_output(p: argparse.ArgumentParser) -> None:
    """The packing's and the output's options."""
    p.add_argument(
        "--particles",
        type=_int_at_least(2),
        default=700,
        help="particles per RVE, >= 2 (default 700: with seed 0 the packing shipped with the "
        "package, the same on every installation)",
    )
    p.add_argument(
        "--seed", type=_int_at_least(0), default=0, help="packing generator seed (default 0)"
    )
    p.add_argument("--packing", help="load the packing from this .npz file instead of generating")
    p.add_argument(
        "--steps", type=_int_at_least(1), default=20, help="footing load steps (default 20)"
    )
    p.add_argument(
        "--gravity-steps",
        type=_int_at_least(1),
        default=1,
        help="steps of the gravity phase (default 1: the whole weight at once)",
    )
    p.add_argument(
        "--out",
        default="results/slope",
        help="output folder (default results/slope); one that holds a run is refused "
        "unless --force",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="replace the run in --out (removes the files a run writes there, no others)",
    )
    p.add_argument("--no-figure", action="store_true", help="skip slope.png")


def _add_model(p: argparse.ArgumentParser) -> None:
    """The options of the model: loads, law, solver."""
    p.add_argument(
        "--load-factor",
        type=_finite(),
        default=1.0,
        help="multiplies the footing load (2: doubled, -0.25: uplift; default 1)",
    )
    p.add_argument(
        "--stabilise",
        type=_finite(0.0),
        default=0.0,
        help="stiffness where an RVE has no loaded contact, relative to the eq. 15 "
        "modulus (default 0: off)",
    )
    p.add_argument(
        "--line-search",
        choices=["basic", "bt", "l2", "cp"],
        default="basic",
        help="SNES line search (default basic: full Newton steps)",
    )
    p.add_argument(
        "--residual-tolerance",
        type=_finite(0.0),
        default=0.0,
        metavar="R",
        help="where Newton no longer halves the residual (it cycles as relaxed RVEs "
        "rearrange), accept a residual of at most R times the force scale, an out-of-balance "
        "force carried into the next step (default 0: none; e.g. 1e-4)",
    )
    p.add_argument(
        "--linear-solver",
        choices=LINEAR_SOLVERS,
        default="direct",
        help="linear solver of Newton: direct (MUMPS LU, default) or iterative (GMRES with "
        "algebraic multigrid; faster on fine meshes, not with --path-following)",
    )
    p.add_argument(
        "--friction",
        type=_finite(0.0),
        default=0.0,
        metavar="MU",
        help="Coulomb friction coefficient of the contacts (default 0: frictionless, "
        "the paper's model)",
    )
    p.add_argument(
        "--rolling-friction",
        type=_finite(0.0),
        default=0.0,
        metavar="MU_R",
        help="rolling friction of the contacts, with --rve relaxed: a rolling moment capped "
        "at MU_R r_eff f_n, r_eff = r_i r_j / (r_i + r_j) (default 0: none)",
    )
    p.add_argument(
        "--tangential-stiffness",
        type=_finite(0.0),
        metavar="KT",
        help="tangential contact stiffness k_t in N/m² (default: the normal one, "
        "2.8e7, where --friction > 0; no effect with --friction 0)",
    )
    p.add_argument(
        "--rve",
        choices=RVES,
        default="taylor",
        help="the RVE: taylor (every disk follows F, the paper's model; default) or relaxed "
        "(the disks in static equilibrium, and with --friction > 0 turning too; needs "
        "--confinement)",
    )
    p.add_argument(
        "--confinement",
        type=_finite(0.0),
        default=0.0,
        metavar="P",
        help="confining pressure in Pa (default 0: none): the packing is generated jammed at "
        "it, compressed to it and relaxed, and the boundaries hold it",
    )
    p.add_argument(
        "--allow-overlaps",
        action="store_true",
        help="accept a packing whose disks overlap by more than 5 %% of their radius sums "
        "(prestressed as it is; default: refused, relax it instead)",
    )


def _add_path_and_run(p: argparse.ArgumentParser) -> None:
    """The options of the load path, the mesh and the run (stop, resume)."""
    p.add_argument(
        "--unload",
        action="store_true",
        help="after the footing load, remove it again in as many steps",
    )
    p.add_argument(
        "--path-following",
        nargs="?",
        const="footing",
        choices=PHASES,
        metavar="PHASE",
        help="take the footing load (PHASE footing, the default) or the weight (gravity: "
        "the run ends there) by arc length (Riks/Crisfield): through the limit load and down "
        "the softening branch to 0.9 x the peak",
    )
    p.add_argument(
        "--max-increments",
        type=_int_at_least(1),
        default=100,
        metavar="N",
        help="most arc-length increments, with --path-following only (default 100)",
    )
    p.add_argument(
        "--slope-ratio",
        type=_slope_ratio,
        default=1.0,
        metavar="N",
        help="the slope's run over its rise, a multiple of 0.2 (default 1: 45°; 2: 26.6°, "
        "3: 18.4°, 4: 14.0°); the crest with the footing and the ground past the toe stay, "
        "the domain widens",
    )
    p.add_argument(
        "--refine",
        type=_int_at_least(1),
        default=1,
        metavar="K",
        help="mesh refinement: K times the columns and rows (K² x 380 cells at --slope-ratio 1)",
    )
    p.add_argument(
        "--rows",
        type=_int_at_least(1),
        default=SlopeGeometry.rows,
        metavar="N",
        help=f"rows of cells over the slope's height before --refine (default "
        f"{SlopeGeometry.rows}, the paper's mesh; 2: a coarse mesh for quick runs)",
    )
    p.add_argument(
        "--stop-after",
        type=_int_at_least(1),
        metavar="K",
        help="stop after K converged load steps (resume later with --resume)",
    )
    p.add_argument(
        "--resume",
        metavar="DIR",
        help="continue the run in DIR from its restart.npz, with its options and packing "
        "(of the options above only --no-figure and --stop-after apply)",
    )
    p.add_argument("--debug", action="store_true", help="show the traceback of an error")


#: the options of the factor of safety alone (refused without --factor-of-safety)
SAFETY_OPTIONS = (
    "footing_scale",
    "fs_tolerance",
    "strength",
    "strength_seeds",
    "strength_strain",
    "continuation",
    "reduction_steps",
)


def _fraction(text):
    """A number in (0, 1) (argparse type)."""
    value = _finite()(text)
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"must be a number in (0, 1), got {text!r}")
    return value


def _shown(value):
    """A default as the command line takes it (2.8e5 as 280000)."""
    return f"{value:g}" if isinstance(value, float) else str(value)


def _add_safety(p: argparse.ArgumentParser) -> None:
    """The options of the factor of safety (:mod:`.safety_cli`)."""
    from .safety_cli import DEFAULTS

    g = p.add_argument_group("factor of safety (strength reduction of the contact friction)")
    g.add_argument(
        "--factor-of-safety",
        action="store_true",
        help="find the factor of safety: trials from the start of the load path at reduced "
        "friction mu_f, bisected between a failing and a passing one; FS = tan phi(mu) / tan "
        "phi(mu_f) from the strength curve; with --resume DIR it goes on with a run's "
        "finished trials. Unless given here: "
        + " ".join(f"--{k.replace('_', '-')} {_shown(v)}" for k, v in DEFAULTS.items()),
    )
    g.add_argument(
        "--footing-scale",
        type=_finite(0.0),
        default=0.0,
        metavar="S",
        help="the share of the footing load on the load path after the weight (default 0: the "
        "weight alone)",
    )
    g.add_argument(
        "--fs-tolerance",
        type=_fraction,
        default=0.01,
        metavar="TOL",
        help="bisect until the factors of safety of the bracket's ends differ by at most TOL "
        "(relative; default 0.01)",
    )
    g.add_argument(
        "--continuation",
        action="store_true",
        help="one run instead of trials: the whole load at mu under load control, then mu "
        "lowered at that load (geometrically to mu / 64) until no equilibrium is found after "
        "every cut-back; the bracket is the last friction carried and the one that failed",
    )
    g.add_argument(
        "--reduction-steps",
        type=_int_at_least(1),
        default=16,
        metavar="N",
        help="with --continuation: nominal steps from mu to mu / 64, each lowering mu by the "
        "same factor (default 16; cut-backs halve a step 6 times before the run stops)",
    )
    g.add_argument(
        "--strength",
        metavar="CSV",
        nargs="+",
        help="the strength curve from this CSV ('python -m dolfinx_granular strength' wrote "
        "it; it must cover mu at the slope's p/k_n), or from several: a later file's row "
        "replaces an earlier file's at the same mu, mu_r and p/k_n (more seeds there); "
        "default: measured with the slope's RVE",
    )
    g.add_argument(
        "--strength-seeds",
        type=_int_at_least(1),
        default=3,
        metavar="N",
        help="packings per friction of the measured curve: seeds --seed .. --seed + N - 1 "
        "(default 3)",
    )
    g.add_argument(
        "--strength-strain",
        type=_fraction,
        default=0.05,
        metavar="EPS",
        help="the measured curve's biaxial tests go to this axial strain in steps of 0.005 "
        "(default 0.05)",
    )


def given_options(argv: Sequence[str], prog: str = "demos/slope.py") -> set[str]:
    """The destinations of the options that ``argv`` names (whatever values they are given)."""
    parser, unset = build_parser(prog), object()
    parser.set_defaults(**{dest: unset for dest in vars(parser.parse_args([]))})
    return {dest for dest, value in vars(parser.parse_args(argv)).items() if value is not unset}


def check_combination(a: argparse.Namespace, given: set[str]) -> None:
    """Refuse options that would be ignored (UserError naming them and the fix)."""
    if a.resume:
        ignored = sorted(given - set(RESUME_OPTIONS))
        if ignored:
            names = ", ".join("--" + d.replace("_", "-") for d in ignored)
            raise UserError(
                f"--resume continues the run in {a.resume} with the options it was started "
                f"with: drop {names} (only --no-figure and --stop-after apply), or start a new "
                "run with --out"
            )
    elif "max_increments" in given and not a.path_following:
        raise UserError(
            "--max-increments applies to --path-following only (load control takes --steps "
            "steps): add --path-following or drop --max-increments"
        )
    elif a.path_following == "gravity" and given & {"steps", "load_factor"}:
        footing_only = sorted(given & {"steps", "load_factor"})
        names = ", ".join("--" + d.replace("_", "-") for d in footing_only)
        raise UserError(
            f"--path-following gravity ends the run with the weight (no footing load): drop "
            f"{names}, or follow the footing's path with --path-following footing"
        )


def _claim_out(out, force):
    """A new run's ``out``: refused if it holds a run that converged a load step, unless
    ``force``; then cleared of the run's files (a run with no converged step has nothing to
    lose)."""
    writable(out)
    held = run_files(out)
    if held and not force and converged_steps(out):
        raise UserError(
            f"--out {out} holds a slope run ({', '.join(held)}): add --force to replace it, "
            f"use --resume {out} to continue it, or choose another --out"
        )
    clear_run(out)


def _prepare(a):
    """Rank 0's part of the set-up: the restart dict for ``--resume``, else the packing (after
    the output folder's checks: before any expensive work)."""
    if a.resume:
        try:
            restart = load_restart(a.resume)
        except RestartError as err:
            raise UserError(f"--resume: {err}") from err
        writable(a.resume)
        return restart
    _claim_out(a.out, a.force)
    try:
        # a confined packing keeps the contact network it jammed with: jam it at its pressure
        pressure = a.confinement / K_N if a.confinement > 0.0 else None
        return make_packing(a.particles, a.seed, a.packing, pressure)
    except PackingFileError as err:
        raise UserError(
            f"--packing: {err}; give a .npz written by 'python -m dolfinx_granular "
            "generate' or Packing.save"
        ) from err


def _shared(a, comm, stop):
    """Rank 0 prepares, every rank gets the result (or the error, so that none waits); a
    signal interrupts the preparation at once (no collective call is in progress there)."""
    value = failure = None
    if comm.rank == 0:
        try:
            with stop.raising():
                value = _prepare(a)
        except Exception as err:  # let the other ranks stop too instead of waiting in bcast
            value = failure = err
    value = comm.bcast(value, root=0)  # every rank must use the identical RVE
    if isinstance(value, RunInterrupted):
        raise value
    if isinstance(value, Exception):
        raise failure or UserError(str(value))  # rank 0: the original, with its cause
    return value


def _resume(a, comm, started, stop):
    restart = _shared(a, comm, stop)
    if is_complete(restart):
        if comm.rank == 0:
            print(
                f"slope: the run in {a.resume} completed all {restart['state']['step']} load "
                "steps; nothing to resume (its results are unchanged)",
                flush=True,
            )
        return {"status": "converged"}
    return run_slope(
        restart["packing"],
        out=a.resume,
        comm=comm,
        figure=not a.no_figure,
        restart=restart,
        stop_after=a.stop_after,
        started=started,
        stop_request=stop,
    )


def _run(a, argv, prog, comm, started, stop):
    """The run that the parsed arguments ``a`` ask for; its summary dict."""
    given = given_options(argv, prog)
    if a.factor_of_safety:
        from .safety_cli import run_safety

        return run_safety(a, given, comm, stop, started)
    only = sorted(given & set(SAFETY_OPTIONS))
    if only:
        names = ", ".join("--" + d.replace("_", "-") for d in only)
        raise UserError(f"{names} apply to --factor-of-safety only: add it, or drop them")
    check_combination(a, given)
    if a.resume:
        return _resume(a, comm, started, stop)
    options = options_of(a)
    packing = _shared(a, comm, stop)
    return run_slope(
        packing,
        options,
        out=a.out,
        comm=comm,
        figure=not a.no_figure,
        stop_after=a.stop_after,
        started=started,
        stop_request=stop,
    )


def _setup_stop_line(signum):
    return (
        f"slope: {signal.Signals(signum).name}: stopping before the first load step; nothing "
        "is lost: run the same command again"
    )


def main(argv: Sequence[str] | None = None, prog: str = "demos/slope.py") -> int:
    """Command line entry: returns the exit status (0, 1 or 2, see the module docstring)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    comm = MPI.COMM_WORLD
    started = time.perf_counter()
    show_warnings()  # e.g. a prestressed packing's PrestressWarning, on every DOLFINx release
    stop = StopRequest(verbose=comm.rank == 0)
    try:
        with stop.installed():
            if comm.rank == 0:
                stop.announce({s: _setup_stop_line(s) for s in SIGNALS})
            a = build_parser(prog).parse_args(argv)
            summary = _run(a, argv, prog, comm, started, stop)
    except RunInterrupted as err:  # in the set-up (the native handler said so at once)
        return exit_status(err.signum)
    except (ValueError, OSError) as err:  # user errors: bad options, files, meshes
        if "--debug" in argv:
            raise
        if comm.rank == 0:
            print(f"error: {err}", file=sys.stderr, flush=True)
        return 2
    if summary["status"] == "interrupted":
        return exit_status(signal.Signals[summary["interrupted_by"]])
    return 0 if summary["status"] in ("converged", "stopped") else 1
