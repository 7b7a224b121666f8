"""Where an element test stands between its steps, kept on disk, so that a test stopped by its
time budget (or killed) goes on from its last step instead of from the start.

A :class:`Progress` holds what :func:`~.element_tests.load_test`'s loop carries from one step
to the next: the committed point (F and the law's state), the confined state it started from,
the strains still to reach with the halvings already spent on the next one, the rows so far
and the wall seconds spent. :func:`save` writes it as one ``.npz`` (atomically),
:func:`load` reads it back and checks it against the test's key.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..io.atomic_file import atomic_write

if TYPE_CHECKING:
    from os import PathLike

#: the scalars of a :class:`Progress` as stored (0-d arrays)
_SCALARS = ("dissipation_c", "done", "cuts", "left", "seconds")


@dataclass
class Progress:
    """An element test after its last committed step.

    Attributes:
        rows: the step rows so far (row 0: the confined state).
        F: (2, 2) the committed deformation gradient; state: the law's committed state of one
            point (a ``HistoryState``).
        Fc: (2, 2) the confined state's F; dissipation_c: its dissipation (Pa).
        targets: the strains still to reach (the next first, halvings of a failed step
            included); done: the strain of the last step; cuts: halvings spent on the next
            target; left: targets left when the halvings were last reset.
        seconds: wall seconds spent on the test so far (confinement included).
    """

    rows: list
    F: np.ndarray
    state: Any
    Fc: np.ndarray
    dissipation_c: float
    targets: list
    done: float
    cuts: int
    left: int
    seconds: float


def save(path: str | PathLike[str], progress: Progress, key: dict) -> None:
    """Write ``progress`` of the test ``key`` (a dict of plain values) to ``path`` (``.npz``),
    replacing it atomically: a run killed while writing leaves the last complete file."""
    arrays = {f"state/{k}": v for k, v in progress.state.to_arrays().items()}
    arrays.update(F=progress.F, Fc=progress.Fc, targets=np.asarray(progress.targets, float))
    arrays.update({k: np.asarray(getattr(progress, k)) for k in _SCALARS})
    arrays["rows"] = np.asarray(json.dumps(progress.rows, default=plain))
    arrays["key"] = np.asarray(json.dumps(key, sort_keys=True))
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    atomic_write(path, buffer.getvalue())


def load(path: str | PathLike[str], key: dict, state_type: type) -> Progress | None:
    """The :class:`Progress` saved at ``path`` for the test ``key`` (its law's state read as
    ``state_type.from_arrays``); None where there is no file, or it is damaged or belongs to
    another key (the test then starts afresh)."""
    if not os.path.isfile(path):
        return None
    try:
        with np.load(path, allow_pickle=False) as f:
            a = {k: f[k] for k in f.files}
        if json.loads(str(a["key"])) != json.loads(json.dumps(key, sort_keys=True)):
            return None
        state = state_type.from_arrays(
            {k.split("/", 1)[1]: v for k, v in a.items() if k.startswith("state/")}
        )
        return Progress(
            json.loads(str(a["rows"])), a["F"], state, a["Fc"], float(a["dissipation_c"]),
            [float(t) for t in a["targets"]], float(a["done"]), int(a["cuts"]), int(a["left"]),
            float(a["seconds"]),
        )  # fmt: skip
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError):
        return None  # (damaged: the test is run again, and the file replaced)


def plain(value):
    """A JSON value of a NumPy scalar (json takes float subclasses, not np.integer or bool_)."""
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot store {type(value).__name__} in the test cache")
