"""Generated packings kept on disk, so that studies pay for the jamming of each packing once.

:class:`PackingCache` is shared by the RVE-size study (``demos/rve_study.py``), the friction study
(``demos/friction_study.py``) and the performance report (``benchmarks/report.py``): they ask for
packings by particle count and seed, and the RVE-size study and the report also report how long
generating each one took.
"""

from __future__ import annotations

import json
import os
import time
from typing import TYPE_CHECKING

from ..io.atomic_file import atomic_write
from .generation import generate_packing
from .packing import Packing

if TYPE_CHECKING:
    from os import PathLike


class PackingCache:
    """Packings of :func:`~dolfinx_granular.generate_packing` by (particles, seed) and, where
    given, the pressure p / k_n they are jammed at, stored as ``DIR/n{n}_s{seed}.npz`` (the
    generator's default pressure) or ``DIR/n{n}_s{seed}_p{pressure}.npz``.

    :meth:`get` loads a packing this cache generated before (in this process or an earlier one,
    if ``use_cache``); otherwise it generates the packing, saves it and records the generation
    time (wall seconds) in ``DIR/generation_times.json``. A file without a recorded time (from
    elsewhere) is generated afresh, so that every packing has its time.

    Args:
        directory: the folder of the files (created).
        use_cache: False: generate every packing once more (files and times are replaced).

    Attributes:
        directory, use_cache: as given.
        times: ``{"n/seed": seconds}``, the generation time of every packing generated into
            ``directory`` (wall time, on the machine that generated it).
    """

    TIMES_FILE = "generation_times.json"

    def __init__(self, directory: str | PathLike[str], use_cache: bool = True) -> None:
        self.directory = str(directory)
        self.use_cache = bool(use_cache)
        os.makedirs(self.directory, exist_ok=True)
        self._times_path = os.path.join(self.directory, self.TIMES_FILE)
        self.times = {}
        if self.use_cache and os.path.isfile(self._times_path):
            with open(self._times_path) as f:
                self.times = json.load(f)
        self._loaded = {}  # (n, seed) -> Packing, so that repeated gets do not reread the file

    @staticmethod
    def _key(n, seed, pressure=None) -> str:
        key = f"{int(n)}/{int(seed)}"
        return key if pressure is None else f"{key}/{float(pressure):g}"

    def path(self, n: int, seed: int = 0, pressure: float | None = None) -> str:
        """The file of the packing with ``n`` particles and ``seed`` (jammed at ``pressure``,
        p / k_n; None: the generator's default)."""
        jammed = "" if pressure is None else f"_p{float(pressure):g}"
        return os.path.join(self.directory, f"n{int(n)}_s{int(seed)}{jammed}.npz")

    def get(self, n: int, seed: int = 0, pressure: float | None = None) -> Packing:
        """The packing of ``n`` particles and ``seed``, jammed at ``pressure`` (p / k_n, as
        :func:`~dolfinx_granular.generate_packing` takes it; None: its default): from memory,
        from its file, or generated (then saved and its generation time recorded)."""
        key = (int(n), int(seed), None if pressure is None else float(pressure))
        if key in self._loaded:
            return self._loaded[key]
        path = self.path(n, seed, pressure)
        if self.use_cache and os.path.isfile(path) and self._key(*key) in self.times:
            packing = Packing.load(path)
        else:
            t0 = time.perf_counter()
            jammed = {} if pressure is None else {"pressure": float(pressure)}
            packing = generate_packing(int(n), seed=int(seed), **jammed)
            self.times[self._key(*key)] = time.perf_counter() - t0
            packing.save(path)
            # atomic: a study killed while writing leaves the previous times, not half a file
            atomic_write(self._times_path, json.dumps(self.times, indent=1))
        self._loaded[key] = packing
        return packing

    def generation_time(self, n: int, seed: int = 0, pressure: float | None = None) -> float:
        """Wall seconds it took to generate the packing (after :meth:`get`)."""
        return float(self.times[self._key(n, seed, pressure)])
