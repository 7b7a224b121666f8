"""Command lines under MPI: ``--help``, usage and argument errors printed once, by rank 0.

Every rank of ``mpirun -n 2 python demos/X.py --help`` parses the same arguments; argparse would
print the help on each of them. :class:`Parser` prints on rank 0 alone and exits on every rank
alike (status 0 for ``--help``, 2 for an error).
"""

from __future__ import annotations

import argparse
import os
import sys

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


class Parser(argparse.ArgumentParser):
    """:class:`argparse.ArgumentParser` that prints (help, usage, errors) on rank 0 only."""

    def _print_message(self, message, file=None):
        if world_rank() == 0:
            super()._print_message(message, file)
