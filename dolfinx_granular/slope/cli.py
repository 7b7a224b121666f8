"""The slope benchmark's command line: ``python -m dolfinx_granular.slope`` or ``demos/slope.py``.

Bad input (options, packing files, ``--out``, restart files, meshes) is one line ``error: ...``
on stderr and exit status 2 (``--debug`` shows the traceback), on every rank alike under MPI.
Exit status 0: every load step converged, or the run stopped where ``--stop-after`` asked; 1: it
stopped at a load step that did not converge (e.g. at a limit load).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import TYPE_CHECKING

import numpy as np
from mpi4py import MPI

from .._dolfinx import show_warnings
from ..packing import Packing, PackingFileError
from ..runwriter import RestartError
from .geometry import SlopeGeometry
from .run import SlopeOptions, is_complete, load_restart, run_slope

if TYPE_CHECKING:
    from collections.abc import Sequence
    from os import PathLike


class UserError(ValueError):
    """Bad input (options, files): reported as one line ``error: ...`` with exit status 2."""


class _Parser(argparse.ArgumentParser):
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


def build_parser(prog: str = "demos/slope.py") -> argparse.ArgumentParser:
    p = _Parser(
        prog=prog,
        description="Slope stability benchmark (section 5 of Meier, "
        "Steinmann & Kuhl): dead load, then an eccentric strip footing in load steps, a "
        "Taylor RVE at every Gauss point.",
    )
    p.add_argument(
        "--particles",
        type=_int_at_least(2),
        default=700,
        help="particles per RVE, >= 2 (default 700)",
    )
    p.add_argument(
        "--seed", type=_int_at_least(0), default=0, help="packing generator seed (default 0)"
    )
    p.add_argument("--packing", help="load the packing from this .npz file instead of generating")
    p.add_argument(
        "--steps", type=_int_at_least(1), default=20, help="footing load steps (default 20)"
    )
    p.add_argument("--out", default="results/slope", help="output folder (default results/slope)")
    p.add_argument("--no-figure", action="store_true", help="skip slope.png")
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
        "--friction",
        type=_finite(0.0),
        default=0.0,
        metavar="MU",
        help="Coulomb friction coefficient of the contacts (default 0: frictionless, "
        "the paper's model)",
    )
    p.add_argument(
        "--tangential-stiffness",
        type=_finite(0.0),
        metavar="KT",
        help="tangential contact stiffness k_t in N/m² (default: the normal one, "
        "2.8e7, where --friction > 0)",
    )
    p.add_argument(
        "--unload",
        action="store_true",
        help="after the footing load, remove it again in as many steps",
    )
    p.add_argument(
        "--path-following",
        action="store_true",
        help="take the footing load by arc length (Riks/Crisfield): through the limit "
        "load and down the softening branch to 0.9 x the peak",
    )
    p.add_argument(
        "--max-increments",
        type=_int_at_least(1),
        default=100,
        metavar="N",
        help="most arc-length increments with --path-following (default 100)",
    )
    p.add_argument(
        "--refine",
        type=_int_at_least(1),
        default=1,
        metavar="K",
        help="mesh refinement: K times the columns and rows (K² x 380 cells)",
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
        help="continue the run in DIR from its restart.npz (its options and packing; "
        "the options above are ignored except --no-figure and --stop-after)",
    )
    p.add_argument("--debug", action="store_true", help="show the traceback of an error")
    return p


def options_of(a: argparse.Namespace) -> SlopeOptions:
    """The run's options from parsed command-line arguments."""
    if a.tangential_stiffness is not None and a.friction == 0.0:
        raise UserError(
            "--tangential-stiffness needs --friction MU > 0 (frictionless contacts "
            "carry no tangential force)"
        )
    geometry = SlopeGeometry().refined(a.refine)
    try:
        return SlopeOptions(
            steps=a.steps,
            load_factor=a.load_factor,
            stabilise=a.stabilise,
            petsc_options={"snes_linesearch_type": a.line_search},
            friction=a.friction,
            tangential_stiffness=a.tangential_stiffness,
            unload=a.unload,
            path_following=a.path_following,
            max_increments=a.max_increments,
            geometry=geometry,
        )
    except ValueError as err:
        raise UserError(str(err)) from None


def make_packing(
    particles: int, seed: int | None, packing_file: str | PathLike[str] | None = None
) -> Packing:
    """The RVE's packing: from ``packing_file`` if given, else ``generate_packing``."""
    if packing_file:
        return Packing.load(packing_file)
    from ..generation import generate_packing

    return generate_packing(particles, seed=seed)


def _check_out(out):
    """Create ``out`` and prove that a file can be written there (before any work is done)."""
    try:
        os.makedirs(out, exist_ok=True)
        probe = os.path.join(out, f".write-test-{os.getpid()}")
        with open(probe, "w"):
            pass
        os.remove(probe)
    except OSError as err:
        raise UserError(
            f"--out {out!r} cannot be written ({err.strerror or err}); choose a writable folder"
        ) from None


def _prepare(a):
    """Rank 0's part of the set-up: the restart dict for ``--resume``, else the packing."""
    if a.resume:
        try:
            restart = load_restart(a.resume)
        except RestartError as err:
            raise UserError(f"--resume: {err}") from err
        _check_out(a.resume)
        return restart
    _check_out(a.out)
    try:
        return make_packing(a.particles, a.seed, a.packing)
    except PackingFileError as err:
        raise UserError(
            f"--packing: {err}; give a .npz written by 'python -m dolfinx_granular "
            "generate' or Packing.save"
        ) from err


def _shared(a, comm):
    """Rank 0 prepares, every rank gets the result (or the error, so that none waits)."""
    value = failure = None
    if comm.rank == 0:
        try:
            value = _prepare(a)
        except Exception as err:  # let the other ranks stop too instead of waiting in bcast
            value = failure = err
    value = comm.bcast(value, root=0)  # every rank must use the identical RVE
    if isinstance(value, Exception):
        raise failure or UserError(str(value))  # rank 0: the original, with its cause
    return value


def _resume(a, comm, started):
    restart = _shared(a, comm)
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
    )


def main(argv: Sequence[str] | None = None, prog: str = "demos/slope.py") -> int:
    """Command line entry: returns the exit status (0, 1 or 2, see the module docstring)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    comm = MPI.COMM_WORLD
    started = time.perf_counter()
    show_warnings()  # e.g. a prestressed packing's PrestressWarning, on every DOLFINx release
    try:
        a = build_parser(prog).parse_args(argv)
        if a.resume:
            summary = _resume(a, comm, started)
        else:
            options = options_of(a)
            packing = _shared(a, comm)
            summary = run_slope(
                packing,
                options,
                out=a.out,
                comm=comm,
                figure=not a.no_figure,
                stop_after=a.stop_after,
                started=started,
            )
    except (ValueError, OSError) as err:  # user errors: bad options, files, meshes
        if "--debug" in argv:
            raise
        if comm.rank == 0:
            print(f"error: {err}", file=sys.stderr, flush=True)
        return 2
    return 0 if summary["status"] in ("converged", "stopped") else 1
