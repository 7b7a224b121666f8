"""Ctrl-C and ``kill``: SIGINT and SIGTERM ask a slope run to stop at its next safe point.

A signal only sets a flag on the rank that receives it (nothing collective can run in a signal
handler: the other ranks may be inside an MPI call); the run asks :meth:`StopRequest.agreed`
(an allreduce) after every converged load step, so that every rank stops after the same step
with it on disk. A second signal ends the process at once (exit status 128 + the signal).

Launchers differ: MPICH's ``mpiexec`` forwards SIGINT and SIGTERM to the ranks and waits; Open
MPI's ``mpirun`` sends the ranks SIGTERM and SIGKILL one second later (its MCA parameter
``odls_base_sigkill_timeout``), so whatever must not be lost is written at once by the
``on_signal`` callback (rank 0 marks ``summary.json`` as interrupted).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from typing import TYPE_CHECKING

from mpi4py import MPI

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class RunInterrupted(Exception):
    """A signal arrived where the run cannot stop at a load step (its set-up on rank 0)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)  # (args: what pickling, e.g. an MPI bcast, passes back)
        self.signum = signum

    def __str__(self) -> str:
        return f"interrupted by {signal_name(self.signum)}"


def signal_name(signum: int) -> str:
    return signal.Signals(signum).name


def exit_status(signum: int) -> int:
    """The shell's convention for a process ended by a signal: 128 + its number (130: SIGINT)."""
    return 128 + int(signum)


class StopRequest:
    """SIGINT and SIGTERM handlers of one run (installed by :meth:`installed`).

    Args:
        verbose: say so on stdout when a second signal ends the process (rank 0).

    Attributes:
        signum: the first signal this rank received (0: none).
        on_signal: ``on_signal(signum)`` is called by the first signal's handler (it must not
            communicate, nor print through ``sys.stdout``: the interrupted code may be inside
            a print); set by the run once it has something to write.
    """

    def __init__(self, verbose: bool = True) -> None:
        self.verbose = verbose
        self.signum = 0
        self.on_signal: Callable[[int], object] | None = None
        self._raising = False
        self._previous: dict = {}

    @contextlib.contextmanager
    def installed(self) -> Iterator[StopRequest]:
        """Handle SIGINT and SIGTERM inside the block (only the main thread can: elsewhere the
        signals keep their handlers)."""
        main = threading.current_thread() is threading.main_thread()
        if main:
            self._previous = {s: signal.signal(s, self._handle) for s in SIGNALS}
        try:
            yield self
        finally:
            for s, handler in self._previous.items():
                signal.signal(s, handler)
            self._previous = {}

    def reinstall(self) -> None:
        """Handle SIGINT and SIGTERM again after a library reset them (if :meth:`installed`):
        ``gmsh.initialize`` of gmsh 4.15 (PyPI) resets every signal to its default at the C
        level while Python still names its handler."""
        for s in self._previous:
            signal.signal(s, self._handle)

    @contextlib.contextmanager
    def raising(self) -> Iterator[None]:
        """Inside the block a signal raises :class:`RunInterrupted` at once (work that has no
        safe point and no collective calls, e.g. generating the packing on rank 0)."""
        if self.signum:
            raise RunInterrupted(self.signum)
        self._raising = True
        try:
            yield
        finally:
            self._raising = False

    def agreed(self, comm: MPI.Comm) -> int:
        """Collective: the largest signal number any rank has received (0: go on)."""
        return comm.allreduce(self.signum, op=MPI.MAX)

    def _handle(self, signum, frame):
        if self.signum:  # the second signal: no waiting for the load step in progress
            if self.verbose:
                write_line(f"slope: {signal_name(signum)} again: stopping at once")
            os._exit(exit_status(signum))
        self.signum = signum
        if self._raising:
            raise RunInterrupted(signum)
        if self.on_signal is not None:
            self.on_signal(signum)


def write_line(line: str) -> None:
    """``line`` on stdout, unbuffered (safe in a signal handler, unlike print)."""
    os.write(1, (line + "\n").encode())
