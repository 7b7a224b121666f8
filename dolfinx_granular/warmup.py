"""Fill the JIT caches during set-up, so that the first run does not spend its time compiling.

``python -m dolfinx_granular.warmup [--force]`` (run by ``scripts/setup.sh`` and
``scripts/setup-current.sh``) runs the package's real code paths once on a tiny packing
(:data:`PARTICLES` disks), serially:

* the usual API (:func:`warm_api`): ``generate_packing`` and ``relax_overlaps`` (generation
  kernels), ``TaylorRVE.evaluate`` / ``stress`` / ``cauchy`` / ``spatial_tangent`` /
  ``overlap_statistics`` and ``FrictionalRVE.evaluate`` / ``stress`` on plain arrays, the
  relaxed RVE's micro solver (:func:`warm_relaxed`: Newton, the condensed tangent and the FIRE
  fallback, as ``demos/relaxed_study.py`` and ``--rve relaxed`` use them) and the 3-D Taylor
  kernels on :data:`SPHERES` spheres;
* the slope benchmark (:func:`warm_slope`): its gravity step, frictionless (the demo) and with
  friction, figure included: the material's kernel specialisations on DOLFINx quadrature data,
  and the slope's forms, elements and expressions (FFCx).

Two caches keep what it compiles. Numba's (``cache=True``) lives in the ``__pycache__`` folder
beside each kernel's source (or in ``$NUMBA_CACHE_DIR``) and is keyed to each source file's
modification time and to the CPU. A kernel's cache holds the kernels it calls compiled into it,
and Numba does not see those change when they live in another file: after an edit (a ``git
pull`` of an editable install) the old callee would still run, inside a caller whose own file did
not change. So a warm-up that finds the sources changed since the last one first removes every
cached kernel of the package (:func:`clear_numba_cache`), then compiles afresh. FFCx's cache
lives in ``~/.cache/fenics`` (``$XDG_CACHE_HOME/fenics``) and is keyed to the form.

A run whose inputs have not changed since the last one (the package's sources, the interpreter,
Numba, the cache locations: :func:`fingerprint`) does nothing, so that a repeated set-up stays
quick; the record is ``warmup.<python tag>.json`` next to Numba's cache, and goes with it.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .io.commandline import Parser

if TYPE_CHECKING:
    from .packings.packing import Packing

#: disks of the warm-up packing: the same kernels as any size, compiled in seconds of run time
PARTICLES = 30
#: spheres of the 3-D warm-up packing (fewer would not fit the sieve curve's largest grain)
SPHERES = 100
_PACKAGE = Path(__file__).resolve().parent


def warm_api(particles: int = PARTICLES) -> None:
    """Run the public material-point API once on a tiny generated packing (every Numba kernel
    specialisation that plain-array calls use)."""
    from .laws.friction import FrictionalRVE
    from .laws.taylor import TaylorRVE
    from .packings.generation import generate_packing, relax_overlaps
    from .packings.packing import Packing

    packing = generate_packing(particles, seed=0)
    # the overlapping copy that relax_overlaps exists for (radii x 1.02, as in the README)
    swollen = Packing(packing.centers, 1.02 * packing.radii, packing.box)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # its PrestressWarning is expected
        relax_overlaps(swollen)
    F = np.array([[[0.99, 0.002], [0.0, 1.0]], [[1.0, 0.0], [0.001, 0.995]]])
    rve = TaylorRVE(packing, 2.8e7)
    for method in (rve.evaluate, rve.stress, rve.cauchy, rve.spatial_tangent):
        method(F)
    rve.overlap_statistics(F)
    frictional = FrictionalRVE(packing, 2.8e7, 2.8e7, 0.5)
    state = frictional.initial_state(len(F))
    for method in (frictional.evaluate, frictional.stress):
        method(F, state)
    warm_relaxed(packing, F)
    spheres = TaylorRVE(generate_packing(SPHERES, seed=0, dim=3), 1e5)  # the 3-D kernels
    F3 = np.stack([np.diag([0.99, 1.0, 1.0]), np.eye(3) + 1e-3 * np.eye(3)[::-1]])
    for method in (spheres.evaluate, spheres.stress, spheres.cauchy, spheres.spatial_tangent):
        method(F3)
    spheres.overlap_statistics(F3)


def warm_relaxed(packing: Packing, F: np.ndarray) -> None:
    """The relaxed RVE's kernels (``demos/relaxed_study.py``, ``--rve relaxed``):
    ``RelaxedRVE.evaluate`` at F (n, 2, 2) (Newton, the condensed tangent, and the block LDL^T
    they factorise with: its analysis, assembly, factorisation and solves) and the micro solver's
    FIRE fallback (:func:`~dolfinx_granular.laws.relaxed.fire.fire`, which runs only where Newton
    stalls), each on a cell as built and on one whose candidate list grew."""
    from .laws.relaxed import RelaxedRVE, Settings, at_rest
    from .laws.relaxed.fire import FIRE_CHUNK, fire

    built, grown = RelaxedRVE(packing, 2.8e7), RelaxedRVE(packing, 2.8e7)
    # A list grows (Cell.extend) where a disk moves out of reach of its candidates, in a
    # rearrangement: its arrays are then writeable copies of the read-only ones it was built
    # with, a second specialisation of every kernel, compiled mid-study unless here. One disk
    # moved by half the box grows the list for certain.
    w = np.zeros((packing.n_particles, 2))
    w[0] = 0.5 * packing.box
    grown.cell.visited(np.eye(2), w)
    settings = Settings(fire_steps=FIRE_CHUNK)
    for rve in (built, grown):
        _, _, _, state = rve.evaluate(F, rve.initial_state(len(F)))
        rve.evaluate(F, state)  # at rest: the committed positions, in the batch
        at_rest(rve.cell, F[0], state.w[0], True)  # and on the Python path
        # one chunk of FIRE steps from the affine positions of a compression (relaxed or not)
        fire(rve.cell, np.diag([0.99, 0.995]), np.zeros_like(w), settings)


def warm_slope(particles: int = PARTICLES) -> None:
    """Run the slope benchmark's gravity step on a tiny packing, frictionless and with friction,
    serially into a temporary folder (its kernels on quadrature data, its FFCx forms)."""
    from mpi4py import MPI

    from .packings.generation import generate_packing
    from .slope import SlopeOptions, run_slope

    packing = generate_packing(particles, seed=0)
    for friction in (0.0, 0.5):
        options = SlopeOptions(steps=1, friction=friction)
        with tempfile.TemporaryDirectory(prefix="dolfinx-granular-warmup-") as out:
            run_slope(packing, options, out, MPI.COMM_SELF, verbose=False, stop_after=1)


def _ffcx_cache_dir() -> Path:
    """The FFCx cache of DOLFINx's default JIT options (every supported release)."""
    return Path(os.getenv("XDG_CACHE_HOME", Path.home() / ".cache")) / "fenics"


def stamp_path() -> Path:
    """Where the record of the last warm-up lives: beside Numba's cache of this package, so that
    clearing that cache clears the record too."""
    folder = os.getenv("NUMBA_CACHE_DIR") or _PACKAGE / "__pycache__"
    return Path(folder) / f"warmup.{sys.implementation.cache_tag}.json"


def fingerprint() -> dict:
    """What the caches' validity depends on: the sources (path: [mtime_ns, size]), the
    interpreter, Numba's version, the CPU and the cache locations (an absent FFCx cache counts
    as a change)."""
    import numba
    from llvmlite import binding

    sources = {
        str(p.relative_to(_PACKAGE)): [p.stat().st_mtime_ns, p.stat().st_size]
        for p in sorted(_PACKAGE.rglob("*.py"))
        if "__pycache__" not in p.parts
    }
    ffcx = _ffcx_cache_dir()
    return {
        "python": sys.executable,
        "numba": numba.__version__,
        "cpu": binding.get_host_cpu_name(),
        "numba_cache_dir": os.getenv("NUMBA_CACHE_DIR", ""),
        "ffcx_cache_dir": str(ffcx) if ffcx.is_dir() else None,
        "sources": sources,
    }


def sources_changed(path: Path | None = None) -> bool:
    """True where the last warm-up's record (at ``path``, default :func:`stamp_path`) lists
    other sources than now (False without a record)."""
    path = stamp_path() if path is None else path
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return record.get("sources") != fingerprint()["sources"]


def numba_cache_files() -> list[Path]:
    """The package's compiled Numba kernels on disk (``*.nbi`` indexes, ``*.nbc`` data), where
    Numba keeps them: in ``$NUMBA_CACHE_DIR`` if set (one folder per source folder, named as
    Numba names it: the folder's name and the SHA-1 of its path), else in the ``__pycache__``
    folders beside the sources."""
    folders = sorted({p.parent for p in _PACKAGE.rglob("*.py") if "__pycache__" not in p.parts})
    roots = [d / "__pycache__" for d in folders]
    if os.getenv("NUMBA_CACHE_DIR"):
        base = Path(os.environ["NUMBA_CACHE_DIR"])
        roots = [base / f"{d.name}_{hashlib.sha1(str(d).encode()).hexdigest()}" for d in folders]
    return [p for root in roots if root.is_dir() for p in root.iterdir()
            if p.suffix in (".nbi", ".nbc")]  # fmt: skip


def clear_numba_cache() -> int:
    """Remove the package's compiled Numba kernels (:func:`numba_cache_files`); their number."""
    files = numba_cache_files()
    for p in files:
        p.unlink(missing_ok=True)
    return len(files)


def is_current(path: Path | None = None) -> bool:
    """True if the last warm-up's record matches :func:`fingerprint` now."""
    path = stamp_path() if path is None else path
    try:
        return json.loads(path.read_text()) == fingerprint()
    except (OSError, ValueError):
        return False


def warm_up(force: bool = False, stamp: Path | None = None, say=print) -> bool:
    """Compile what a first run would (:func:`warm_api`, :func:`warm_slope`) unless the last
    warm-up recorded in ``stamp`` (default :func:`stamp_path`) is still current, or ``force``;
    returns True if it ran."""
    path = stamp_path() if stamp is None else Path(stamp)
    if not force and is_current(path):
        say("warmup: the JIT caches are current (nothing to compile)")
        return False
    if sources_changed(path):
        removed = clear_numba_cache()
        say(
            f"warmup: the sources changed since the last warm-up: {removed} cached Numba files "
            "removed (a kernel's cache holds its callees, and Numba does not see those change)"
        )
    say(
        "warmup: compiling the Numba kernels and the slope's forms into their caches (about a "
        "minute, once per change of the sources)"
    )
    t0 = time.perf_counter()
    warm_api()
    warm_slope()
    say(f"warmup: Numba and FFCx caches filled in {time.perf_counter() - t0:.1f} s")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(fingerprint(), indent=1))
    except OSError as err:  # an unwritable cache folder: the caches work, the next run repeats
        say(f"warmup: could not record the warm-up in {path} ({err.strerror or err})")
    return True


def main(argv: list[str] | None = None) -> int:
    """Command line: ``python -m dolfinx_granular.warmup [--force]``."""
    parser = Parser(
        prog="python -m dolfinx_granular.warmup",
        description="Compile the Numba kernels and the slope's forms into their caches "
        "(once per change of the sources), so that the first run does not compile.",
    )
    parser.add_argument("--force", action="store_true", help="warm up even if current")
    a = parser.parse_args(argv)
    warm_up(force=a.force)
    return 0


if __name__ == "__main__":
    sys.exit(main())
