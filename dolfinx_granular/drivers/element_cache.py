"""Element tests kept on disk, so that a long study interrupted and started again goes on where it
stopped.

:class:`ElementTestCache` runs :func:`~.element_tests.load_test` once per key and stores its
step rows and stop message as ``DIR/<law>_<test>_n<N>_s<seed>_p<p>_mu<mu>_<digest>.json``
(``..._mu<mu>_mur<mu_r>_...`` with rolling resistance); a later call with the same key (in this
process or another) reads them back instead. The key (:meth:`ElementTestCache.key`) holds
everything that changes the answer: the law and its settings (e.g. the frictional relaxed RVE's
substep), k_n, k_t, mu, the rolling friction and stiffness, min_stretch, the packing (particles,
seed and a digest of its disks), p / k_n, the loading and its target strains, the halvings of a
failed step, and a digest of the sources that compute it (the laws and the material-point
drivers), so that a changed solver runs its tests afresh.

While a test runs, its progress after every step is kept beside it
(``..._<digest>.progress.npz``, :mod:`.element_progress`): a test killed, or stopped by its time
budget and asked for again under a larger one (or none), goes on from its last step rather than
from the start. The file is removed when the test ends otherwise.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..io.atomic_file import atomic_write
from . import element_progress
from .element_progress import plain
from .element_tests import BUDGET_STOP, MAX_CUTS, load_test

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from os import PathLike

    from ..packings.packing import Packing
    from .element_tests import Loading

#: the sources a test's answer comes from (relative to the package), digested into the key
SOURCES = ("laws", "drivers/material_point.py", "drivers/confinement.py",
           "drivers/element_tests.py")  # fmt: skip
_PACKAGE = Path(__file__).resolve().parent.parent


def source_digest() -> str:
    """SHA-256 (hex) of the :data:`SOURCES` (every ``.py`` file, in sorted order)."""
    h = hashlib.sha256()
    for name in SOURCES:
        path = _PACKAGE / name
        files = sorted(path.rglob("*.py")) if path.is_dir() else [path]
        for f in files:
            h.update(f.relative_to(_PACKAGE).as_posix().encode())
            h.update(f.read_bytes())
    return h.hexdigest()


def packing_digest(packing: Packing) -> str:
    """SHA-256 (hex, 16 digits) of a packing's centres, radii and box."""
    h = hashlib.sha256()
    for a in (packing.centers, packing.radii, packing.box):
        h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


@dataclass(frozen=True)
class ElementTestRun:
    """One test's outcome: ``rows`` and ``stop`` as :func:`~.element_tests.load_test` returns
    them, ``seconds`` the wall time of the runs that computed them, ``cached`` True where they
    were read back from the cache, ``resumed_rows`` the rows this run went on from (0: none, a
    test run from the start or read back)."""

    rows: list
    stop: str
    seconds: float
    cached: bool
    resumed_rows: int = 0


class ElementTestCache:
    """Results of :func:`~.element_tests.load_test` in ``directory`` (created), one JSON file a
    test.

    A test stopped by its time budget is taken from the cache only under a budget no larger than
    the one it ran under (under a larger budget, or none, it goes on from its last step); every
    other stop (the micro solver's or the driver's, where the cell rearranges) is part of the
    answer and is kept.
    """

    def __init__(self, directory: str | PathLike[str]) -> None:
        self.directory = str(directory)
        os.makedirs(self.directory, exist_ok=True)
        self._sources = source_digest()  # (once: the sources of this process)

    def key(self, loading: Loading, law, packing: Packing, seed: int, pressure: float,
            targets: Sequence[float]) -> dict:  # fmt: skip
        """The key of one test: a dict of plain values (what the file records)."""
        settings = getattr(law, "settings", None)
        return {
            "law": type(law).__name__,
            "settings": dataclasses.asdict(settings) if settings is not None else {},
            "k_n": float(law.normal_stiffness),
            "k_t": float(law.tangential_stiffness),
            "mu": float(law.friction),
            "mu_r": float(getattr(law, "rolling_friction", 0.0)),
            "rolling_stiffness": float(getattr(law, "rolling_stiffness", 0.0)),
            "min_stretch": float(law.min_stretch),
            "particles": int(packing.n_particles),
            "seed": int(seed),
            "packing": packing_digest(packing),
            "p_over_kn": float(pressure),
            "loading": loading.test,
            "targets": [float(t) for t in targets],
            "max_cuts": MAX_CUTS,
            "sources": self._sources,
        }

    def path(self, key: dict) -> str:
        """The file of ``key``: readable names, and a digest of the whole key."""
        digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
        rolling = f"_mur{key['mu_r']:g}" if key["mu_r"] else ""
        name = (f"{key['law']}_{key['loading']}_n{key['particles']}_s{key['seed']}_"
                f"p{key['p_over_kn']:g}_mu{key['mu']:g}{rolling}_{digest}.json")  # fmt: skip
        return os.path.join(self.directory, name)

    def lookup(self, key: dict, budget: float | None = None) -> ElementTestRun | None:
        """The stored test of ``key`` (None where there is none, or it was stopped by a smaller
        time budget than ``budget``; None: no limit)."""
        path = self.path(key)
        if not os.path.isfile(path):
            return None
        try:
            with open(path) as f:
                record = json.load(f)
        except ValueError:  # (not JSON: a file damaged by hand is run again, and replaced)
            return None
        if record.get("key") != key:  # (a digest collision, or a file edited by hand)
            return None
        ran_under = record["budget"]
        if record["stop"].startswith(f"stopped: {BUDGET_STOP}") and (
            budget is None or budget > ran_under
        ):
            return None
        return ElementTestRun(record["rows"], record["stop"], record["seconds"], True)

    def progress_path(self, key: dict) -> str:
        """The file of ``key``'s :class:`~.element_progress.Progress` (``.npz`` beside its rows):
        there while the test runs, and after it stopped on its time budget."""
        return self.path(key)[: -len(".json")] + ".progress.npz"

    def run(self, loading: Loading, law, packing: Packing, seed: int, pressure: float,
            targets: Sequence[float], budget: float | None = None,
            on_step: Callable[[dict], None] | None = None) -> ElementTestRun:  # fmt: skip
        """:func:`~.element_tests.load_test` of ``law`` (an RVE of ``packing``, the packing of
        ``seed``) confined at ``pressure`` (p / k_n) to ``targets``, from the cache or run and
        stored. A test that a time budget stopped, or that was killed, goes on from its last
        step (its progress file), its seconds counted in ``budget``. ``on_step`` is called with
        each row the run adds (the confined state's first)."""
        key = self.key(loading, law, packing, seed, pressure, targets)
        found = self.lookup(key, budget)
        if found is not None:
            return found
        progress = self.progress_path(key)
        resume = element_progress.load(progress, key, type(law.initial_state(1)))
        went_on = len(resume.rows) if resume is not None else 0
        kept, kept_rows = [resume], [went_on]  # (the last progress kept, and its rows)

        def keep(at):
            element_progress.save(progress, at, key)
            if on_step is not None and len(at.rows) > kept_rows[0]:
                on_step(at.rows[-1])
            kept[0], kept_rows[0] = at, len(at.rows)

        t0 = time.perf_counter()
        rows, stop = load_test(loading, law, pressure, targets, budget, resume, keep)
        seconds = kept[0].seconds if kept[0] is not None else time.perf_counter() - t0
        record = dict(key=key, rows=rows, stop=stop, seconds=seconds, budget=budget)
        # atomic: a study killed while writing leaves no half file to read back
        atomic_write(self.path(key), json.dumps(record, default=plain, indent=None))
        if not stop.startswith(f"stopped: {BUDGET_STOP}") and os.path.exists(progress):
            os.remove(progress)  # (the test has ended: nothing to go on from)
        return ElementTestRun(rows, stop, seconds, False, went_on)
