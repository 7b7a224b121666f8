"""One rule for every command that writes its results into a folder (``--out``).

A folder that holds the command's files is refused, unless ``--force``: that removes those files,
and only those (a user's other files in the folder stay), before the run writes its own. The
check comes first, before any expensive work, and under MPI rank 0 decides for every rank (the
decision is broadcast, so that no rank waits for one that stopped). ``demos/slope.py`` follows
the same rule with its own resume-aware check (:mod:`dolfinx_granular.slope.cli`).

A command names its files as paths relative to the folder, shell patterns allowed
(``"fig*.png"``, ``"path_[0-9]*/summary.json"``); the leftovers of an atomic write that a killed
run left (``summary.json.tmp1234``, see :func:`~dolfinx_granular.io.atomic_file.atomic_write`)
count as its files too.
"""

from __future__ import annotations

import glob
import os
import sys
import tempfile
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterable

    from mpi4py.MPI import Comm

#: what a refusal tells the user to do
HINT = "add --force to replace it, or choose another --out"
#: file names listed in a refusal before "and N more"
LISTED = 8


class OutFolderError(OSError):
    """The output folder cannot take the run (it cannot be written, or it holds a run); the
    message is one line for the user."""


class RunExistsError(OutFolderError, FileExistsError):
    """The output folder holds a run of the command (``--force`` replaces it)."""


def default_out(command: str, small: bool = False) -> str:
    """``results/<command>``, or ``results/<command>-small`` for a reduced run (so that the
    full run after a small one does not find the folder taken)."""
    return os.path.join("results", f"{command}-small" if small else command)


def held_files(folder: str | os.PathLike[str], files: Iterable[str]) -> list[str]:
    """The command's files in ``folder`` (paths relative to it, sorted), atomic-write leftovers
    included; [] for a folder that does not exist."""
    root = glob.escape(os.fspath(folder))  # (a folder name is no pattern)
    found = set()
    for pattern in files:
        for p in (pattern, pattern + ".tmp*"):
            found.update(f for f in glob.glob(os.path.join(root, p)) if os.path.isfile(f))
    return sorted(os.path.relpath(f, folder) for f in found)


def clear_files(folder: str | os.PathLike[str], files: Iterable[str]) -> list[str]:
    """Remove the command's files from ``folder`` (:func:`held_files`), nothing else; returns
    what was removed."""
    held = held_files(folder, files)
    for name in held:
        os.remove(os.path.join(folder, name))
    return held


def writable(folder: str | os.PathLike[str]) -> None:
    """Create ``folder`` and prove that a file can be written there (:class:`OutFolderError`
    with the fix where it cannot)."""
    try:
        os.makedirs(folder, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):  # (unnamed where the OS can: nothing left)
            pass
    except OSError as err:
        raise OutFolderError(
            f"--out {folder!r} cannot be written ({err.strerror or err}); choose a writable folder"
        ) from None


def _claim(folder, files, force, command):
    """Rank 0's part of :func:`claim_out`."""
    writable(folder)
    if force:
        return clear_files(folder, files)
    held = held_files(folder, files)
    if held:
        listed = ", ".join(held[:LISTED])
        if len(held) > LISTED:
            listed += f" and {len(held) - LISTED} more"
        raise RunExistsError(f"--out {folder} holds a {command} run ({listed}): {HINT}")
    return []


def claim_out(
    folder: str | os.PathLike[str],
    files: Iterable[str],
    force: bool,
    command: str,
    comm: Comm | None = None,
) -> list[str]:
    """Make ``folder`` ready for a run of ``command`` that writes ``files`` (names or patterns):
    create it, refuse it if it holds any of them (:class:`RunExistsError`) unless ``force``,
    which removes them first. Returns the removed paths.

    Collective over ``comm`` (None: this process alone): rank 0 checks, and every rank returns
    alike or raises the same error (:class:`OutFolderError`: unwritable, or a run there)."""
    folder = os.fspath(folder)
    outcome = None
    if comm is None or comm.rank == 0:
        try:
            outcome = ("ok", _claim(folder, tuple(files), force, command))
        except OutFolderError as err:
            outcome = (type(err).__name__, str(err))
    if comm is not None:
        outcome = comm.bcast(outcome, root=0)
    kind, value = outcome
    if kind == "ok":
        return value
    raise (RunExistsError if kind == RunExistsError.__name__ else OutFolderError)(value)


def refused(err: OutFolderError, comm: Comm | None = None) -> int:
    """A command line's answer to ``err``: the line ``error: ...`` on rank 0's stderr; returns
    the exit status 2 (on every rank)."""
    if comm is None or comm.rank == 0:
        print(f"error: {err}", file=sys.stderr, flush=True)
    return 2


def claim_or_refuse(
    folder: str | os.PathLike[str],
    files: Iterable[str],
    force: bool,
    command: str,
    comm: Comm | None = None,
) -> int:
    """:func:`claim_out` for a command line: 0 if the folder is ready, else 2 after the one
    line ``error: ...`` (:func:`refused`). Collective over ``comm``."""
    try:
        claim_out(folder, files, force, command, comm)
    except OutFolderError as err:
        return refused(err, comm)
    return 0
