"""Jammed periodic packings of disks (2-D) or spheres (3-D) from a grain size distribution (paper
section 4).

The steps below are written for disks; with ``dim=3`` every one holds for spheres: the passing is
read as volume fraction, the cell is a box, a rattler has fewer than 4 contacts, the pressure is
p d_mean / k_n (k_n in N/m), and a network is accepted from a mean coordination of 5.5.

Algorithm (:func:`generate_packing`):

1. **Sizes.** Diameters are drawn from the sieve curve above the cut size ``d_min``
   (:meth:`~dolfinx_granular.SieveCurve.sample_diameters`; percent passing read as area
   fraction). Radii are d / 2 in mm; the Taylor stress does not depend on the absolute size.
2. **Jamming by soft-disk energy minimisation** (O'Hern, Silbert, Liu & Nagel, PRE 68, 011306,
   2003). Random centres in a periodic square (or ``aspect``) cell; the disks interact through
   the harmonic overlap energy U = 1/2 sum max(0, r_i + r_j - d_ij)². U is minimised with FIRE
   (Bitzek, Bitzer, Gumbsch, Moseler & Gähler, PRL 97, 170201, 2006) in a Numba kernel with a
   Verlet neighbour list (cell list build, rebuilt when a disk has moved half the skin). The
   radii are scaled (an isotropic compression or decompression of the cell) and the packing
   re-minimised until the virial pressure lies near the target ``pressure`` (p / k_n, default
   1e-4): a root search on p(phi) with secant steps inside a bracket. This gives a mechanically
   stable, jammed contact network (Z close to 4 for non-rattlers).
3. **Stress-free reference.** The contact network of the jammed state is kept and its small
   overlaps (~p / k_n) removed: a minimum-norm Newton correction of all centres and radii makes
   every contact between non-rattlers overlap by exactly ``contact_overlap`` (1e-11 of the mean
   diameter: active under the kernel's rule eps >= 0, but with a stress ~1e-9 of that at 1 %
   compression) and opens contacts of rattlers (disks with fewer than 3 contacts, removed
   recursively) to a small gap. Centres and radii move by ~1e-4 of a diameter. Near contacts
   that close during the correction are added to the network and the correction repeated.
   A contact is identified by its disks and their image shift between the unwrapped centres,
   so that a disk crossing the cell boundary (likelier at higher ``pressure``) keeps it.
   The Taylor model needs no force equilibrium in the reference state, only this geometry.
4. **Acceptance.** A network with more than ``max_rattlers`` (15 %) rattlers or a mean
   coordination of the non-rattlers below 3.8 is rejected and the same disks are jammed again
   from new random centres (a few percent of 70-disk cells need this).

Cost. Every neighbour search is a cell list
(:func:`~dolfinx_granular.packings.neighbours.find_pairs`), so one FIRE step, one stress-free round
and :func:`network_stats` cost O(N); the sparse normal equations of the Newton correction are
factorised in a fill-reducing order (nested dissection, :mod:`.cholesky`). What stays
super-linear is the number of FIRE steps a minimisation needs, which grows like N^0.4 to N^0.6
(seed 0: 32 000 steps in all at 2800 disks, 126 000 at 45000; the slowest elastic mode of the
cell relaxes on a time ~ its width), and a step's cost per disk at large N, which grows with the
cache misses: the total grew like N^1.6 from 2800 to 11200 disks and N^1.5 from 11200 to 45000
(``benchmarks/generation.py`` measures it). Above
``CELL_ORDER_ABOVE`` disks the initial centres are numbered along the cells, so that a step's
memory access stays local (1.4x faster steps at 45000 disks).

Everything is deterministic for a given ``seed`` (one ``numpy.random.Generator``; the Numba
kernels are serial; FIRE runs in chunks of steps whose length depends on the wall clock, but the
whole state is carried from chunk to chunk, so the trajectory does not), and the same bits on
every CPU and numpy release: the arithmetic is IEEE's correctly rounded +, -, *, / and sqrt, and
the few logarithms, cube roots and sums come from :mod:`.portable`, not from numpy's ``exp``,
``log`` and ``pow``, the C library or the BLAS, whose last bits the jamming would amplify.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from . import neighbours, portable
from .fire import candidates, minimise, virial_pressure
from .gsd import DEFAULT_D_MIN, as_sieve_curve
from .packing import Packing, check_dimension, require_disks, solid_measure
from .stress_free import StressFreeError, rattlers, stress_free

if TYPE_CHECKING:
    from collections.abc import Callable

    from numpy.typing import ArrayLike

    from .gsd import SieveCurve

# Above this many disks the initial centres are numbered along the cells: FIRE's arrays (~140 B
# per disk with the neighbour list) outgrow a core's L2 cache (~1 MiB) from ~8000 disks, and
# with random numbering a step then waits on memory (measured here: 66 against 48 ns per disk
# and step at 45000 disks, no difference at 11200). Smaller packings keep the order in which
# their centres are drawn, and so the packings that their seeds have always given.
CELL_ORDER_ABOVE = 8192

# the shortest time between two intermediate progress lines (s)
PROGRESS_INTERVAL = 1.0

#: largest pressure p / k_n a packing is jammed or confined at: beyond it the contacts' overlaps
#: pass 10 % of a radius, outside the linear springs' range
MAX_PRESSURE = 1e-2

#: per dimension: the volume fraction the first cell is sized for, where the jamming search
#: starts, and the least mean coordination of the non-rattlers a generated network must have
#: (4 and 6 are isostatic; a jammed state above them has a few more)
START_FRACTION = {2: 0.84, 3: 0.64}
FIRST_GUESS = {2: 0.86, 3: 0.64}
MIN_COORDINATION = {2: 3.8, 3: 5.5}


# -- progress --------------------------------------------------------------------------------------


class ProgressLine(str):
    """One progress message of :func:`generate_packing`: a ``str`` (the line to print) with

    Attributes:
        stage: ``"jamming"``, ``"stress-free"``, ``"checking"`` or ``"done"``.
        fraction: rough estimate of the finished share of the work, in [0, 1]; never decreases
            within a call and is exactly 1.0 on the final ``"done"`` line only.
        heartbeat: True for a line that only says that a long minimisation or correction is
            still running; False for a stage event (a minimisation's result, the jammed state,
            a rejected attempt, the end), which a reader should not miss.
    """

    stage: str
    fraction: float
    heartbeat: bool

    def __new__(
        cls, text: str, stage: str, fraction: float, heartbeat: bool = False
    ) -> ProgressLine:
        line = super().__new__(cls, text)
        line.stage = stage
        line.fraction = fraction
        line.heartbeat = heartbeat
        return line


class _Reporter:
    """Turns stage events and heartbeats into :class:`ProgressLine` calls of ``callback``.

    Within one jamming attempt the work is weighted 0.90 jamming, 0.07 stress-free correction,
    0.02 checking; a further attempt shares out what is left of [0, 1).
    """

    _SPANS = {"jamming": (0.0, 0.90), "stress-free": (0.90, 0.97), "checking": (0.97, 0.99)}

    def __init__(self, callback):
        self.callback = callback
        self.t0 = time.perf_counter()
        self.last = self.t0  # time of the last line (heartbeats start after one interval)
        self.fraction = 0.0
        self.base = 0.0  # fraction at the start of the current attempt

    def new_attempt(self):
        self.base = self.fraction

    def elapsed(self):
        return time.perf_counter() - self.t0

    def __call__(self, stage, within, text, heartbeat=False):
        """Report ``text``; ``within`` in [0, 1] is the progress inside ``stage``. A heartbeat
        is dropped unless PROGRESS_INTERVAL has passed since the last line."""
        if self.callback is None:
            return
        now = time.perf_counter()
        if heartbeat and now - self.last < PROGRESS_INTERVAL:
            return
        if stage == "done":
            self.fraction = 1.0
        else:
            lo, hi = self._SPANS[stage]
            share = lo + (hi - lo) * min(max(within, 0.0), 1.0)
            self.fraction = max(self.fraction, self.base + (1.0 - self.base) * share)
        self.last = now
        percent = int(100 * self.fraction)  # 100 on the last line only
        self.callback(ProgressLine(f"{text} [{percent} %]", stage, self.fraction, heartbeat))


# -- public API ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class NetworkStats:
    """Contact network of a packing at F = I under the kernel's rule eps >= 0.

    Attributes:
        volume_fraction: particle area / cell area (2-D), particle / cell volume (3-D).
        n_contacts: active contacts (periodic images included), all particles.
        rattlers: (k,) indices of rattlers (fewer than d + 1 contacts: 3 for disks, 4 for
            spheres, removed recursively).
        rattler_fraction: k / N.
        coordination: mean contacts per non-rattler, counting contacts between non-rattlers.
        min_coordination: fewest contacts of a non-rattler (0 when all are rattlers).
        max_overlap: largest eps at F = I relative to the mean diameter.
    """

    volume_fraction: float
    n_contacts: int
    rattlers: np.ndarray
    rattler_fraction: float
    coordination: float
    min_coordination: int
    max_overlap: float


def network_stats(packing: Packing) -> NetworkStats:
    """Contacts, rattlers and coordination of ``packing`` at F = I (see :class:`NetworkStats`).

    The contacts are those of ``TaylorRVE(packing, k).contacts(np.eye(2))`` (same pairs, same
    arithmetic), found in O(N) time.
    """
    ij, _, eps = candidates(packing.centers, packing.radii, packing.box, 1.0 / 0.99)
    on = eps >= 0.0
    pairs, overlap = ij[on], eps[on]
    n = packing.n_particles
    rattler = rattlers(pairs, n, packing.dim)
    keep = ~(rattler[pairs[:, 0]] | rattler[pairs[:, 1]])
    counts = np.bincount(pairs[keep].ravel(), minlength=n)[~rattler]
    d_mean = 2.0 * packing.radii.mean()
    return NetworkStats(
        volume_fraction=packing.volume_fraction,
        n_contacts=int(pairs.shape[0]),
        rattlers=np.flatnonzero(rattler),
        rattler_fraction=float(rattler.mean()),
        coordination=float(counts.mean()) if counts.size else 0.0,
        min_coordination=int(counts.min()) if counts.size else 0,
        max_overlap=float(overlap.max() / d_mean) if overlap.size else 0.0,
    )


def generate_packing(
    n_particles: int,
    gsd: SieveCurve | tuple[ArrayLike, ArrayLike] | None = None,
    seed: int | None = 0,
    *,
    d_min: float | None = DEFAULT_D_MIN,
    aspect: float = 1.0,
    pressure: float = 1e-4,
    contact_overlap: float = 1e-11,
    max_rattlers: float = 0.15,
    max_attempts: int = 5,
    progress: Callable[[ProgressLine], object] | None = None,
    dim: int = 2,
) -> Packing:
    """A jammed, stress-free periodic packing of disks (``dim=2``) or spheres (``dim=3``) sized
    by a sieve curve.

    See the module docstring for the algorithm (FIRE soft-disk jamming, O'Hern et al. 2003;
    Bitzek et al. 2006) and its references.

    Args:
        n_particles: number of particles N >= 2.
        gsd: :class:`~dolfinx_granular.SieveCurve`, an ``(aperture_mm, passing_percent)``
            pair, or None for the shipped CEN standard sand.
        seed: seed of the random generator; equal arguments give identical arrays.
        d_min: cut size in mm; grains finer than this are left out (None: keep the whole curve).
            The default 0.5 mm keeps the CEN sand at a 4:1 size span.
        aspect: cell height / width (1 = square); in 3-D the box's Lz / Lx (Ly = Lx).
        pressure: target jamming pressure of stage 2, dimensionless, in (0, 1e-2]: p / k_n
            in 2-D (k_n in N/m²), p d_mean / k_n in 3-D (k_n in N/m).
        contact_overlap: overlap of every contact in the returned packing, relative to the mean
            diameter, in (0, 1e-8].
        max_rattlers: acceptance limit on the rattler fraction. A jammed state with more
            rattlers (or a mean coordination of the non-rattlers below 3.8 in 2-D, 5.5 in 3-D;
            :data:`MIN_COORDINATION`) is rejected and the
            disks are jammed again from new random centres, at most ``max_attempts`` times in
            all; the attempt with the fewest rattlers is returned. Small cells (N ~ 70)
            need a second attempt for a few percent of the seeds.
        max_attempts: >= 1, see ``max_rattlers``.
        progress: optional callable of one argument, a :class:`ProgressLine`: a ``str`` to
            print (it ends in the percentage) with attributes ``stage`` and ``fraction`` (a
            rough, never decreasing estimate of the finished share of the work; 1.0 on the last
            line, whose stage is ``"done"``). It is called at every stage event (each
            minimisation of the jamming search, the jammed state, each rejected attempt, the
            end) and, during long minimisations and corrections, at most once per
            ``PROGRESS_INTERVAL`` (1 s) in between. It does not change the result.
        dim: 2 (disks, the paper's RVE) or 3 (spheres).

    Returns:
        :class:`~dolfinx_granular.Packing` with radii in mm.

    Raises:
        ValueError: N < 2, a bad sieve curve (not monotone, not reaching 100 %, non-positive
            apertures) or a parameter out of range.
    """
    n, curve = _check_arguments(
        n_particles, gsd, d_min, aspect, pressure, max_rattlers, max_attempts, contact_overlap
    )
    dim = check_dimension(dim)
    say = _Reporter(progress)
    rng = np.random.default_rng(_seed(seed))
    r0, box = _radii_and_cell(curve, n, rng, d_min, aspect, dim)
    delta = contact_overlap * 2.0 * portable.mean(r0)
    best = None
    for attempt in range(max_attempts):
        say.new_attempt()
        packing, stats = _attempt(rng, r0, box, pressure, delta, say)
        if best is None or stats.rattler_fraction < best[1].rattler_fraction:
            best = (packing, stats)
        if stats.rattler_fraction <= max_rattlers and stats.coordination >= MIN_COORDINATION[dim]:
            break
        say(
            "checking",
            1.0,
            f"attempt {attempt + 1}: {100 * stats.rattler_fraction:.1f} % "
            f"rattlers, Z = {stats.coordination:.2f}; jamming again from new random centres",
        )
    packing, stats = best
    say(
        "done",
        1.0,
        f"done: {n} {'disks' if dim == 2 else 'spheres'}, phi = {packing.volume_fraction:.4f}, "
        f"{100 * stats.rattler_fraction:.1f} % rattlers ({say.elapsed():.1f} s)",
    )
    return packing


def _radii_and_cell(curve, n, rng, d_min, aspect, dim):
    """Stage 1: the radii r0 (n,) in mm, sampled from the curve in a random order, and a cell
    (dim,) in mm sized for phi ~ :data:`START_FRACTION` at them (stage 2 scales the radii,
    stage 3 scales back)."""
    diam = curve.sample_diameters(n, rng, d_min=d_min, dim=dim)
    rng.shuffle(diam)
    r0 = 0.5 * diam
    V = solid_measure(r0, dim) / START_FRACTION[dim]
    if dim == 2:
        box = np.array([np.sqrt(V / aspect), np.sqrt(V * aspect)])
    else:
        w = portable.root(V / aspect, 3)
        box = np.array([w, w, w * aspect])
    if 2.0 * r0.max() >= 0.8 * box.min():
        raise ValueError(
            f"{n} particles are too few for this size span: the largest grain "
            f"({2 * r0.max():.3g} mm) would span 80 % of the cell; use more particles or a "
            "narrower grading (larger d_min)"
        )
    return r0, box


def _attempt(rng, r0, box, pressure, delta, say):
    """Stages 2 and 3 from new random centres: the stress-free packing and its
    :class:`NetworkStats`; ``delta`` is the contact overlap in mm."""
    n = r0.size
    x = rng.random((n, box.size)) * box
    if n > CELL_ORDER_ABOVE:
        # the random centres numbered along the cells (the radii keep their random order:
        # the same distribution), so that FIRE's force loop finds neighbours near in memory
        x = x[neighbours.cell_list(x, box, 2.0 * r0.max())[2]]
    x, scale, p = _jam(x, r0, box, pressure, 2.0 * portable.mean(r0), say)
    say(
        "jamming",
        1.0,
        f"jammed at phi = {solid_measure(scale * r0, box.size) / math.prod(box):.4f}"
        f", p/k = {p:.2e} ({say.elapsed():.1f} s)",
    )
    centers, radii, cell = stress_free(x / scale, r0.copy(), box / scale, delta, say)
    packing = Packing(centers, radii, cell)
    say("checking", 0.0, f"checking the contact network ({say.elapsed():.1f} s)", True)
    return packing, network_stats(packing)


def relax_overlaps(
    packing: Packing,
    contact_overlap: float = 1e-11,
    progress: Callable[[ProgressLine], object] | None = None,
) -> Packing:
    """A stress-free packing next to ``packing``: the generator's last stage applied to it.

    The disks that overlap at F = I form the contact network (disks with fewer than three of its
    contacts are rattlers and are moved clear); centres and radii move by the least amount
    (minimum-norm Newton steps) that makes every network contact overlap by ``contact_overlap``
    of the mean diameter, the cell unchanged. The reference stress P(I) then vanishes to
    ~1e-11 of the modulus, as for a generated packing.

    Overlaps too large for such small moves (the Newton steps diverge; e.g. the radii of a
    700-disk generated packing x 1.3) are removed as the generator does: the disks are jammed
    afresh from their centres in the same cell, at radii scaled by one common factor
    (p / k_n = 1e-4, stage 2), and that network is corrected.

    Args:
        packing: a packing whose disks overlap (a prestressed reference state).
        contact_overlap: overlap of every network contact, relative to the mean diameter.
        progress: callable receiving :class:`ProgressLine` s, or None.

    Raises:
        ValueError: ``contact_overlap`` out of range, or neither way found a stress-free state.
    """
    if not isinstance(packing, Packing):
        raise TypeError(f"packing must be a dolfinx_granular.Packing, got {type(packing).__name__}")
    require_disks(packing, "relax_overlaps")
    _check_contact_overlap(contact_overlap)
    delta = contact_overlap * 2.0 * portable.mean(packing.radii)
    say = _Reporter(progress)
    x, r, box = packing.centers.copy(), packing.radii.copy(), packing.box.copy()
    try:
        return Packing(*stress_free(x, r, box, delta, say))
    except StressFreeError:
        pass
    say("stress-free", 0.0, "the overlaps are too large for small moves: jamming afresh")
    try:
        x, scale, _ = _jam(packing.centers.copy(), r, box, 1e-4, 2.0 * portable.mean(r), say)
        return Packing(*stress_free(x, scale * r, box, scale * delta, say))
    except RuntimeError as err:  # the jamming search or the correction failed
        raise ValueError(
            f"relax_overlaps found no stress-free state next to this packing ({err}); "
            "generate a new one with generate_packing (python -m dolfinx_granular generate)"
        ) from None


def _check_arguments(
    n_particles, gsd, d_min, aspect, pressure, max_rattlers, max_attempts, contact_overlap
):
    """Validate the arguments of :func:`generate_packing`; returns ``(n, sieve curve)``."""
    n, curve = _check_sizes(n_particles, gsd, d_min, aspect)
    if not (0.0 < pressure <= MAX_PRESSURE):
        raise ValueError(f"pressure (p / k_n) must lie in (0, {MAX_PRESSURE:g}], got {pressure}")
    if not (0.0 <= max_rattlers <= 1.0):
        raise ValueError(f"max_rattlers must lie in [0, 1], got {max_rattlers}")
    if int(max_attempts) != max_attempts or max_attempts < 1:
        raise ValueError(f"max_attempts must be an integer >= 1, got {max_attempts}")
    _check_contact_overlap(contact_overlap)
    return n, curve


def _check_sizes(n_particles, gsd, d_min, aspect):
    """Validate the count, sieve curve, cut size and cell shape of :func:`generate_packing`
    before any work (the command line, before it looks at its output file); ``(n, curve)``."""
    try:
        n = int(n_particles)
    except (TypeError, ValueError):
        raise ValueError(f"n_particles must be an integer >= 2, got {n_particles!r}") from None
    if n != n_particles or n < 2:
        raise ValueError(f"n_particles must be an integer >= 2, got {n_particles!r}")
    curve = as_sieve_curve(gsd)
    curve.classes(d_min)  # its ValueError for a d_min that cuts off the curve
    if not (np.isfinite(aspect) and 0.1 <= aspect <= 10.0):
        raise ValueError(f"aspect (cell height / width) must lie in [0.1, 10], got {aspect}")
    return n, curve


def _check_contact_overlap(contact_overlap):
    """The range check of ``contact_overlap`` (generate_packing, relax_overlaps)."""
    if not (0.0 < contact_overlap <= 1e-8):
        raise ValueError(f"contact_overlap must lie in (0, 1e-8], got {contact_overlap}")


def _seed(seed):
    """``seed`` for numpy's generator: None or an integer >= 0 (a clear error otherwise)."""
    if seed is None:
        return None
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0 (or None for a fresh one), got {seed!r}")
    return int(seed)


# -- stage 2: jamming ------------------------------------------------------------------------------


def _jam(x, r0, box, p_target, d_mean, say):
    """Scale radii and minimise until the pressure (p / k, 3-D: p d_mean / k) is within a
    factor 1.5 of ``p_target``.

    Args:
        x: (N, d) initial centres (mm); r0: (N,) radii (mm) at which the cell holds
            phi0 (area or volume fraction); box: (d,) (mm); d_mean: mean diameter (mm);
        say: the :class:`_Reporter`.

    Returns:
        ``(x, scale, p)`` with the jammed centres (N, d) at radii ``scale * r0``.
    """
    dim = box.size
    phi0 = solid_measure(r0, dim) / math.prod(box)
    skin = 0.3 * d_mean
    ftol = 1e-3 * p_target * d_mean
    phi = FIRST_GUESS[dim]
    lo, hi = None, None  # (phi, p) bracket: unjammed / jammed
    jammed = []
    p = 0.0
    for it in range(60):
        scale = portable.root(phi / phi0, dim)
        steps, p = _minimise_reporting(x, scale * r0, box, skin, ftol, d_mean, say, phi, it)
        say(
            "jamming",
            (it + 1) / max(4.0, it + 1.5),
            f"  phi = {phi:.5f}: p/k = {p:.3e} after {steps} FIRE steps",
        )
        if p_target / 1.5 <= p <= 1.5 * p_target:
            return x, scale, p
        if p > p_target:
            hi = phi if hi is None else min(hi, phi)
        else:
            lo = phi if lo is None else max(lo, phi)
        if p > 1e-2 * p_target:
            jammed.append((phi, p))
        if lo is not None and hi is not None and hi - lo < 1e-9:
            # p jumps across the target (small N): accept the jammed state at the upper bound
            scale = portable.root(hi / phi0, dim)
            _minimise_reporting(x, scale * r0, box, skin, ftol, d_mean, say, hi, it)
            return x, scale, virial_pressure(x, scale * r0, box) * _pressure_unit(d_mean, dim)
        phi = _next_phi(phi, jammed, lo, hi, p_target)
    raise RuntimeError(f"jamming did not reach p/k = {p_target:g} (last p/k = {p:.3g})")


def _minimise_reporting(x, r, box, skin, ftol, d_mean, say, phi, it):
    """FIRE minimisation number ``it`` of the jamming search, with heartbeats; ``(steps, p / k)``.

    The heartbeat's progress inside the minimisation is log(f0 / f) / log(f0 / ftol) for the
    largest force f (f0 at the first heartbeat).
    """
    f0 = []

    def beat(step, fmax):
        if not f0:
            f0.append(fmax)
        g = math.log(f0[0] / fmax) / math.log(f0[0] / ftol) if f0[0] > ftol and fmax > 0 else 0.0
        say(
            "jamming",
            (it + max(g, 0.0)) / max(4.0, it + 1.5),
            f"jamming: phi = {phi:.5f}, FIRE step {step}, largest force {fmax / ftol:.3g} x "
            "the tolerance",
            heartbeat=True,
        )

    steps, vir = minimise(x, r, box, skin, ftol, 0.05 * d_mean, 0.5 * d_mean, 2_000_000, beat)
    dim = box.size
    return steps, vir / (dim * math.prod(box)) * _pressure_unit(d_mean, dim)  # dimensionless


def _pressure_unit(d_mean, dim):
    """The factor that makes p / k dimensionless: 1 in 2-D (k in N/m²), d_mean in 3-D (N/m)."""
    return d_mean if dim == 3 else 1.0


def _next_phi(phi, jammed, lo, hi, p_target):
    """Next packing fraction of the root search on p(phi) = p_target.

    A secant step on the last two jammed states (p is ~ linear in phi above jamming), else a
    slope guess; a bisection of the bracket (lo, hi) when the step leaves it.
    """
    if len(jammed) >= 2 and jammed[-1][1] != jammed[-2][1] and jammed[-1][0] != jammed[-2][0]:
        (f1, p1), (f2, p2) = jammed[-2], jammed[-1]
        slope = max((p2 - p1) / (f2 - f1), 1e-3)
        new = f2 + (p_target - p2) / slope
    elif jammed:
        new = jammed[-1][0] + (p_target - jammed[-1][1]) / 0.3
    else:
        new = phi + 0.005
    if hi is None:
        new = max(new, phi + 1e-4)
    elif lo is None:
        new = min(new, phi - 1e-4)
    elif not (lo < new < hi):
        new = 0.5 * (lo + hi)
    return new


# -- stage 3: stress-free reference ----------------------------------------------------------------
