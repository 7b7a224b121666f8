"""Command lines under MPI: ``--help``, usage and argument errors printed once, by rank 0; the
output options every demo shares.

Every rank of ``mpirun -n 2 python demos/X.py --help`` parses the same arguments; argparse would
print the help on each of them. :class:`Parser` prints on rank 0 alone and exits on every rank
alike (status 0 for ``--help``, 2 for an error). :meth:`Parser.add_output` gives a command
``--out``, ``--force`` and ``--small`` with the rule of :mod:`.outfolder`;
:func:`checked_values` is an argument type whose error names the fix.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

from .outfolder import default_out

#: seconds the ranks other than 0 wait before they exit on an argument error
ERROR_GRACE = 1.0
#: environment variables in which MPI launchers give a process its rank (Open MPI, MPICH/PMI)
RANK_VARIABLES = ("OMPI_COMM_WORLD_RANK", "PMIX_RANK", "PMI_RANK")


def world_rank() -> int:
    """This process's rank in MPI_COMM_WORLD (0 outside MPI), without initialising MPI where
    mpi4py is not loaded yet (its launcher's environment says it)."""
    mpi = sys.modules.get("mpi4py.MPI")
    if mpi is not None:
        return mpi.COMM_WORLD.rank
    for name in RANK_VARIABLES:
        if os.environ.get(name, "").isdigit():
            return int(os.environ[name])
    return 0


def world_comm():
    """MPI.COMM_WORLD, or None without mpi4py (for commands that need no MPI)."""
    try:
        from mpi4py import MPI
    except ImportError:
        return None
    return MPI.COMM_WORLD


class Parser(argparse.ArgumentParser):
    """:class:`argparse.ArgumentParser` that prints (help, usage, errors) on rank 0 only."""

    _command = None  # (set by add_output)

    def _print_message(self, message, file=None):
        if world_rank() == 0:
            super()._print_message(message, file)

    def exit(self, status=0, message=None):
        """Exit with ``status`` on every rank; on an error the other ranks wait a moment, so
        that rank 0's message is out before a launcher (Open MPI 5's prterun) kills the job
        at the first rank to exit with an error (it lost the message now and then)."""
        if status and world_rank() != 0:
            time.sleep(ERROR_GRACE)
        super().exit(status, message)

    def add_output(self, command: str, small: str = "reduced run (tests; also DEMO_SMALL=1)"):
        """``--out`` (default ``results/<command>``, ``results/<command>-small`` with
        ``--small``: :func:`~.outfolder.default_out`), ``--force`` (replace the command's files
        in it, no others) and ``--small`` (also ``DEMO_SMALL=1``; help text ``small``);
        :meth:`parse_args` fills in the default ``out``."""
        self._command = command
        self.add_argument(
            "--out",
            help=f"output folder (default results/{command}, --small: results/{command}-small)",
        )
        self.add_argument(
            "--force", action="store_true", help="replace the run in --out (its files, no others)"
        )
        self.add_argument(
            "--small", action="store_true", default=os.environ.get("DEMO_SMALL") == "1", help=small
        )

    def parse_args(self, args=None, namespace=None):
        parsed = super().parse_args(args, namespace)
        if self._command is not None:
            parsed.out = parsed.out or default_out(self._command, parsed.small)
        return parsed


def checked_values(kind, ok, what, example, many=False):
    """An argparse type: a ``kind`` (int or float; with ``many`` a comma-separated tuple of
    distinct ones), each finite and passing ``ok``; otherwise an error that says ``what`` to
    give, e.g. ``example``."""

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
            if not (math.isfinite(v) and ok(v)):
                raise argparse.ArgumentTypeError(f"{v!r} is out of range: {fix}")
        if len(set(values)) < len(values):
            raise argparse.ArgumentTypeError(f"{text!r} repeats a value: {fix}")
        return tuple(values) if many else values[0]

    return convert
