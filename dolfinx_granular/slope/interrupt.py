"""Ctrl-C and ``kill``: SIGINT and SIGTERM ask a slope run to stop at its next safe point.

A signal only sets a flag on the rank that receives it (nothing collective can run in a signal
handler: the other ranks may be inside an MPI call); the run asks :meth:`StopRequest.agreed`
(an allreduce) after every converged load step, so that every rank stops after the same step
with it on disk. A second signal ends the process at once (exit status 128 + the signal).

Launchers differ: MPICH's ``mpiexec`` forwards SIGINT and SIGTERM to the ranks and waits; Open
MPI's ``mpirun`` sends the ranks SIGTERM and SIGKILL one second later (its MCA parameter
``odls_base_sigkill_timeout``). A Python handler runs only between bytecodes, too late for that
when a rank is inside a compiled kernel or a collective, so what must not be lost (the resume
hint on the console, ``summary.json`` marked interrupted) is prepared beforehand with
:meth:`StopRequest.announce` and :meth:`StopRequest.keep` and written by a C-level handler the
instant the signal arrives (:mod:`.interrupt_native`), which then hands the signal on to the
Python handler here.

Exit status: a serial run and MPICH's ``mpiexec`` return 130 (SIGINT) or 143 (SIGTERM); Open
MPI's ``mpirun`` returns 1 whenever it is interrupted itself, whatever its ranks return.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from typing import TYPE_CHECKING

from mpi4py import MPI

from .interrupt_native import NativeHandler

if TYPE_CHECKING:
    from collections.abc import Iterator

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
    """

    def __init__(self, verbose: bool = True) -> None:
        self.verbose = verbose
        self.signum = 0
        self._raising = False
        self._previous: dict = {}
        self._native: NativeHandler | None = None

    @contextlib.contextmanager
    def installed(self) -> Iterator[StopRequest]:
        """Handle SIGINT and SIGTERM inside the block (only the main thread can: elsewhere the
        signals keep their handlers)."""
        main = threading.current_thread() is threading.main_thread()
        if main:
            self._previous = {s: signal.signal(s, self._handle) for s in SIGNALS}
            self._native = NativeHandler()
            self._native.install()
        try:
            yield self
        finally:
            if self._native is not None:
                self.announce(None)
                self.keep(None)
            for s, handler in self._previous.items():
                signal.signal(s, handler)  # (Python's C handler again, over the native one)
            self._previous, self._native = {}, None

    def reinstall(self) -> None:
        """Handle SIGINT and SIGTERM again after a library reset them (if :meth:`installed`):
        ``gmsh.initialize`` of gmsh 4.15 (PyPI) resets every signal to its default at the C
        level while Python still names its handler."""
        for s in self._previous:
            signal.signal(s, self._handle)
        if self._native is not None:
            self._native.install(fresh=False)

    def announce(self, lines: dict[int, str] | None) -> None:
        """The line that a first signal puts on stdout at once, by signal number (None: none);
        nothing outside :meth:`installed`."""
        if self._native is not None:
            self._native.say(lines)

    def keep(self, path: str | None, contents: dict[int, str] | None = None) -> None:
        """The file that a first signal writes at once (atomically) at ``path``, its content by
        signal number; None: no file. Nothing outside :meth:`installed`."""
        if self._native is not None:
            self._native.keep(path, contents)

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


def write_line(line: str) -> None:
    """``line`` on stdout, unbuffered (safe in a signal handler, unlike print)."""
    os.write(1, (line + "\n").encode())
