"""Jammed periodic disk packings from a grain size distribution (paper section 4).

Algorithm (:func:`generate_packing`):

1. **Sizes.** Diameters are drawn from the sieve curve above the cut size ``d_min``
   (:meth:`~dolfinx_granular.gsd.SieveCurve.sample_diameters`; percent passing read as area
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
   The Taylor model needs no force equilibrium in the reference state, only this geometry.
4. **Acceptance.** A network with more than ``max_rattlers`` (15 %) rattlers or a mean
   coordination of the non-rattlers below 3.8 is rejected and the same disks are jammed again
   from new random centres (a few percent of 70-disk cells need this).

Everything is deterministic for a given ``seed`` (one ``numpy.random.Generator``; the Numba
kernels are serial).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numba import njit

from . import kernel
from .gsd import DEFAULT_D_MIN, as_sieve_curve
from .packing import Packing

# FIRE parameters of Bitzek et al. (2006).
_N_MIN = 5
_F_INC = 1.1
_F_DEC = 0.5
_ALPHA0 = 0.1
_F_ALPHA = 0.99


# -- neighbour list ---------------------------------------------------------------------------------


@njit(cache=True)
def _append_pair(m, pi, pj, sh, i, j, sx, sy):
    """Store pair number m (i, j, shift (sx, sy)), doubling the buffers when full; returns them."""
    if m == pi.shape[0]:
        cap = 2 * m
        pi2 = np.empty(cap, np.int64)
        pj2 = np.empty(cap, np.int64)
        sh2 = np.empty((cap, 2))
        pi2[:m] = pi
        pj2[:m] = pj
        sh2[:m] = sh
        pi, pj, sh = pi2, pj2, sh2
    pi[m] = i
    pj[m] = j
    sh[m, 0] = sx
    sh[m, 1] = sy
    return pi, pj, sh


@njit(cache=True)
def _build_pairs(x, r, box, skin):
    """Pairs (i, j, image shift of j) with |x_j + shift - x_i| < r_i + r_j + skin.

    Wraps ``x`` into the cell in place first. Uses a cell list with the minimum image when the
    cell holds at least 3 cells per side, else all pairs and images (tiny cells).

    Returns:
        ``(m, pi, pj, sh)``: count and arrays of capacity >= m; sh (cap, 2) shift in length units.
    """
    n = r.shape[0]
    for i in range(n):
        for a in range(2):
            x[i, a] -= np.floor(x[i, a] / box[a]) * box[a]
            if x[i, a] >= box[a]:
                x[i, a] -= box[a]
    rmax = r.max()
    cut = 2.0 * rmax + skin
    ncx = int(box[0] / cut)
    ncy = int(box[1] / cut)
    cap = 16 * n + 16
    pi = np.empty(cap, np.int64)
    pj = np.empty(cap, np.int64)
    sh = np.empty((cap, 2))
    m = 0
    if ncx >= 3 and ncy >= 3:
        head = -np.ones(ncx * ncy, np.int64)
        nxt = np.empty(n, np.int64)
        for i in range(n):
            cx = min(int(x[i, 0] / box[0] * ncx), ncx - 1)
            cy = min(int(x[i, 1] / box[1] * ncy), ncy - 1)
            c = cx * ncy + cy
            nxt[i] = head[c]
            head[c] = i
        for cx in range(ncx):
            for cy in range(ncy):
                i = head[cx * ncy + cy]
                while i >= 0:
                    for ox in range(-1, 2):
                        for oy in range(-1, 2):
                            c2 = ((cx + ox) % ncx) * ncy + (cy + oy) % ncy
                            j = head[c2]
                            while j >= 0:
                                if j > i:
                                    dx = x[j, 0] - x[i, 0]
                                    dy = x[j, 1] - x[i, 1]
                                    sx = -np.round(dx / box[0]) * box[0]
                                    sy = -np.round(dy / box[1]) * box[1]
                                    dx += sx
                                    dy += sy
                                    rc = r[i] + r[j] + skin
                                    if dx * dx + dy * dy < rc * rc:
                                        pi, pj, sh = _append_pair(m, pi, pj, sh, i, j, sx, sy)
                                        m += 1
                                j = nxt[j]
                    i = nxt[i]
    else:
        kx = int(np.ceil(cut / box[0]))
        ky = int(np.ceil(cut / box[1]))
        for i in range(n):
            for j in range(i + 1, n):
                rc = r[i] + r[j] + skin
                for ix in range(-kx, kx + 1):
                    for iy in range(-ky, ky + 1):
                        dx = x[j, 0] + ix * box[0] - x[i, 0]
                        dy = x[j, 1] + iy * box[1] - x[i, 1]
                        if dx * dx + dy * dy < rc * rc:
                            pi, pj, sh = _append_pair(m, pi, pj, sh, i, j, ix * box[0], iy * box[1])
                            m += 1
    return m, pi, pj, sh


@njit(cache=True)
def _forces(x, r, m, pi, pj, sh, f):
    """Harmonic overlap forces (k = 1) into f (N, 2); returns (energy, virial sum f·l, max overlap)."""
    f[:, :] = 0.0
    e = 0.0
    vir = 0.0
    omax = 0.0
    for c in range(m):
        i = pi[c]
        j = pj[c]
        dx = x[j, 0] + sh[c, 0] - x[i, 0]
        dy = x[j, 1] + sh[c, 1] - x[i, 1]
        d2 = dx * dx + dy * dy
        rs = r[i] + r[j]
        if d2 < rs * rs:
            d = np.sqrt(d2)
            ov = rs - d
            e += 0.5 * ov * ov
            vir += ov * d
            if ov > omax:
                omax = ov
            fx = ov * dx / d
            fy = ov * dy / d
            f[i, 0] -= fx
            f[i, 1] -= fy
            f[j, 0] += fx
            f[j, 1] += fy
    return e, vir, omax


@njit(cache=True)
def _fire(x, r, box, skin, ftol, dt0, dt_max, max_steps):
    """Minimise the overlap energy over the centres x (N, 2) (in place) with FIRE.

    Unit masses and stiffness; stops when the largest force is below ``ftol``.

    Returns:
        ``(steps, energy, virial, max_force)``.
    """
    n = r.shape[0]
    v = np.zeros((n, 2))
    f = np.empty((n, 2))
    x_ref = x.copy()
    m, pi, pj, sh = _build_pairs(x, r, box, skin)
    x_ref[:, :] = x
    dt = dt0
    alpha = _ALPHA0
    n_pos = 0
    e, vir, omax = _forces(x, r, m, pi, pj, sh, f)
    fmax = 0.0
    step = 0
    half2 = (0.5 * skin) ** 2
    while step < max_steps:
        fmax = 0.0
        fn2 = 0.0
        vn2 = 0.0
        power = 0.0
        for i in range(n):
            fi2 = f[i, 0] * f[i, 0] + f[i, 1] * f[i, 1]
            if fi2 > fmax:
                fmax = fi2
            fn2 += fi2
            vn2 += v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1]
            power += f[i, 0] * v[i, 0] + f[i, 1] * v[i, 1]
        fmax = np.sqrt(fmax)
        if fmax < ftol:
            break
        if power > 0.0:
            scale = alpha * np.sqrt(vn2 / fn2)
            for i in range(n):
                v[i, 0] = (1.0 - alpha) * v[i, 0] + scale * f[i, 0]
                v[i, 1] = (1.0 - alpha) * v[i, 1] + scale * f[i, 1]
            if n_pos > _N_MIN:
                dt = min(dt * _F_INC, dt_max)
                alpha *= _F_ALPHA
            n_pos += 1
        else:
            n_pos = 0
            dt *= _F_DEC
            alpha = _ALPHA0
            v[:, :] = 0.0
        moved2 = 0.0
        for i in range(n):
            v[i, 0] += dt * f[i, 0]
            v[i, 1] += dt * f[i, 1]
            x[i, 0] += dt * v[i, 0]
            x[i, 1] += dt * v[i, 1]
            dxr = x[i, 0] - x_ref[i, 0]
            dyr = x[i, 1] - x_ref[i, 1]
            d2 = dxr * dxr + dyr * dyr
            if d2 > moved2:
                moved2 = d2
        if moved2 > half2:
            m, pi, pj, sh = _build_pairs(x, r, box, skin)
            x_ref[:, :] = x
        e, vir, omax = _forces(x, r, m, pi, pj, sh, f)
        step += 1
    return step, e, vir, fmax


# -- public API --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class NetworkStats:
    """Contact network of a packing at F = I under the kernel's rule eps >= 0.

    Attributes:
        volume_fraction: disk area / cell area.
        n_contacts: active contacts (periodic images included), all disks.
        rattlers: (k,) indices of rattlers (fewer than 3 contacts, removed recursively).
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
    """Contacts, rattlers and coordination of ``packing`` at F = I (see :class:`NetworkStats`)."""
    from .rve import TaylorRVE

    rve = TaylorRVE(packing, 1.0, min_stretch=0.99)
    cs = rve.contacts(np.eye(2))
    rattler = _rattlers(cs.pairs, packing.n_particles)
    keep = ~(rattler[cs.pairs[:, 0]] | rattler[cs.pairs[:, 1]])
    counts = np.bincount(cs.pairs[keep].ravel(), minlength=packing.n_particles)[~rattler]
    d_mean = 2.0 * packing.radii.mean()
    return NetworkStats(
        volume_fraction=packing.volume_fraction,
        n_contacts=int(cs.pairs.shape[0]),
        rattlers=np.flatnonzero(rattler),
        rattler_fraction=float(rattler.mean()),
        coordination=float(counts.mean()) if counts.size else 0.0,
        min_coordination=int(counts.min()) if counts.size else 0,
        max_overlap=float(cs.overlap.max() / d_mean) if cs.overlap.size else 0.0,
    )


def generate_packing(
    n_particles: int,
    gsd=None,
    seed: int = 0,
    *,
    d_min: float | None = DEFAULT_D_MIN,
    aspect: float = 1.0,
    pressure: float = 1e-4,
    contact_overlap: float = 1e-11,
    max_rattlers: float = 0.15,
    max_attempts: int = 5,
    progress=None,
) -> Packing:
    """A jammed, stress-free periodic packing of disks sized by a sieve curve.

    See the module docstring for the algorithm (FIRE soft-disk jamming, O'Hern et al. 2003;
    Bitzek et al. 2006) and its references.

    Args:
        n_particles: number of disks N >= 2.
        gsd: :class:`~dolfinx_granular.gsd.SieveCurve`, an ``(aperture_mm, passing_percent)``
            pair, or None for the shipped CEN standard sand.
        seed: seed of the random generator; equal arguments give identical arrays.
        d_min: cut size in mm; grains finer than this are left out (None: keep the whole curve).
            The default 0.5 mm keeps the CEN sand at a 4:1 size span.
        aspect: cell height / width (1 = square).
        pressure: target jamming pressure p / k_n (dimensionless) of stage 2, in (0, 1e-2].
        contact_overlap: overlap of every contact in the returned packing, relative to the mean
            diameter, in (0, 1e-8].
        max_rattlers: acceptance limit on the rattler fraction. A jammed state with more
            rattlers (or a mean coordination of the non-rattlers below 3.8) is rejected and the
            disks are jammed again from new random centres, at most ``max_attempts`` times in
            all; the attempt with the fewest rattlers is returned. Small cells (N ~ 70)
            need a second attempt for a few percent of the seeds.
        max_attempts: >= 1, see ``max_rattlers``.
        progress: optional callable taking one status string per stage (for slow cases).

    Returns:
        :class:`~dolfinx_granular.packing.Packing` with radii in mm.

    Raises:
        ValueError: N < 2, a bad sieve curve (not monotone, not reaching 100 %, non-positive
            apertures) or a parameter out of range.
    """
    try:
        n = int(n_particles)
    except (TypeError, ValueError):
        raise ValueError(f"n_particles must be an integer >= 2, got {n_particles!r}") from None
    if n != n_particles or n < 2:
        raise ValueError(f"n_particles must be an integer >= 2, got {n_particles!r}")
    curve = as_sieve_curve(gsd)
    if not (np.isfinite(aspect) and 0.1 <= aspect <= 10.0):
        raise ValueError(f"aspect (cell height / width) must lie in [0.1, 10], got {aspect}")
    if not (0.0 < pressure <= 1e-2):
        raise ValueError(f"pressure (p / k_n) must lie in (0, 1e-2], got {pressure}")
    if not (0.0 <= max_rattlers <= 1.0):
        raise ValueError(f"max_rattlers must lie in [0, 1], got {max_rattlers}")
    if int(max_attempts) != max_attempts or max_attempts < 1:
        raise ValueError(f"max_attempts must be an integer >= 1, got {max_attempts}")
    if not (0.0 < contact_overlap <= 1e-8):
        raise ValueError(f"contact_overlap must lie in (0, 1e-8], got {contact_overlap}")
    say = progress if progress is not None else (lambda msg: None)
    t0 = time.perf_counter()

    rng = np.random.default_rng(seed)
    diam = curve.sample_diameters(n, rng, d_min=d_min)
    rng.shuffle(diam)
    r0 = 0.5 * diam
    d_mean = float(diam.mean())
    if 2 * n < 2:  # pragma: no cover - guarded above
        raise ValueError
    # Cell sized for phi ~ 0.84 at the sampled radii; stage 2 scales the radii, stage 3 scales back.
    area = np.pi * np.sum(r0**2) / 0.84
    box = np.array([np.sqrt(area / aspect), np.sqrt(area * aspect)])
    if 2.0 * r0.max() >= 0.8 * box.min():
        raise ValueError(
            f"{n} disks are too few for this size span: the largest grain "
            f"({2 * r0.max():.3g} mm) would span 80 % of the cell; use more particles or a "
            "narrower grading (larger d_min)"
        )
    best = None
    for attempt in range(max_attempts):
        x = rng.random((n, 2)) * box
        x, scale, p = _jam(x, r0, box, pressure, d_mean, say)
        say(f"jammed at phi = {np.pi * np.sum((scale * r0) ** 2) / box.prod():.4f}, "
            f"p/k = {p:.2e} ({time.perf_counter() - t0:.1f} s)")
        centers, radii, cell = _stress_free(x / scale, r0.copy(), box / scale,
                                            contact_overlap * d_mean)
        packing = Packing(centers, radii, cell)
        stats = network_stats(packing)
        if best is None or stats.rattler_fraction < best[1].rattler_fraction:
            best = (packing, stats)
        if stats.rattler_fraction <= max_rattlers and stats.coordination >= 3.8:
            break
        say(f"attempt {attempt + 1}: {100 * stats.rattler_fraction:.1f} % rattlers, "
            f"Z = {stats.coordination:.2f}; jamming again from new random centres")
    packing, stats = best
    say(f"done: {n} disks, phi = {packing.volume_fraction:.4f}, "
        f"{100 * stats.rattler_fraction:.1f} % rattlers ({time.perf_counter() - t0:.1f} s)")
    return packing


# -- stage 2: jamming --------------------------------------------------------------------------------


def _jam(x, r0, box, p_target, d_mean, say):
    """Scale radii and minimise until the pressure p / k is within a factor 1.5 of ``p_target``.

    Returns ``(x, scale, p)`` with the jammed centres at radii ``scale * r0``.
    """
    phi0 = np.pi * np.sum(r0**2) / box.prod()
    skin = 0.3 * d_mean
    ftol = 1e-3 * p_target * d_mean
    area = box.prod()
    phi = 0.86
    lo, hi = None, None  # (phi, p) bracket: unjammed / jammed
    jammed = []
    p = 0.0
    for it in range(60):
        scale = np.sqrt(phi / phi0)
        r = scale * r0
        steps, e, vir, fmax = _fire(x, r, box, skin, ftol, 0.05 * d_mean, 0.5 * d_mean,
                                    2_000_000)
        p = vir / (2.0 * area)
        say(f"  phi = {phi:.5f}: p/k = {p:.3e} after {steps} FIRE steps")
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
            phi = hi
            scale = np.sqrt(phi / phi0)
            _fire(x, scale * r0, box, skin, ftol, 0.05 * d_mean, 0.5 * d_mean, 2_000_000)
            return x, scale, _pressure(x, scale * r0, box)
        # next phi: secant on the last two jammed states (p is ~ linear in phi above jamming),
        # else a slope guess; bisect when the step leaves the bracket.
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
        phi = new
    raise RuntimeError(f"jamming did not reach p/k = {p_target:g} (last p/k = {p:.3g})")


# -- stage 3: stress-free reference ------------------------------------------------------------------


def _pressure(x, r, box):
    """Virial pressure p / k of centres x at radii r."""
    m, pi, pj, sh = _build_pairs(x, r, box, 0.0)
    e, vir, omax = _forces(x, r, m, pi, pj, sh, np.empty_like(x))
    return vir / (2.0 * box.prod())


def _rattlers(pairs, n):
    """Boolean (n,) mask of disks with fewer than 3 contacts, removed recursively."""
    rattler = np.zeros(n, bool)
    while True:
        keep = ~(rattler[pairs[:, 0]] | rattler[pairs[:, 1]])
        counts = np.bincount(pairs[keep].ravel(), minlength=n)
        new = (counts < 3) & ~rattler
        if not new.any():
            return rattler
        rattler |= new


def _overlaps(centers, radii, box, L_only=False):
    """Candidate pairs near contact with the kernel's arithmetic: (ij, shift, eps)."""
    L, R, rho, ij, shift = kernel.candidate_pairs(centers, radii, box, 1.02)
    eps = R - np.sqrt(L[:, 0] * L[:, 0] + L[:, 1] * L[:, 1])
    return ij, shift, eps


def _stress_free(x, r, box, delta):
    """Move centres and radii minimally so that contacts overlap by exactly ``delta``.

    Contacts between non-rattlers get eps = delta, contacts of rattlers a gap 1e5 * delta.
    Returns wrapped ``(centers, radii, box)``.
    """
    n = r.size
    gap = 1e5 * delta
    centers = Packing(x, r, box).centers
    targets = {}  # (i, j, sx, sy) -> target eps
    for _round in range(10):
        ij, shift, eps = _overlaps(centers, r, box)
        keys = [(int(a), int(b), int(c), int(d)) for (a, b), (c, d) in zip(ij, shift)]
        if not targets:
            on = eps > 0.0
            rattler = _rattlers(ij[on], n)
            for k, key in enumerate(keys):
                if on[k]:
                    bad = rattler[key[0]] or rattler[key[1]]
                    targets[key] = -gap if bad else delta
        else:
            # pairs that closed during the last correction join the network
            for k, key in enumerate(keys):
                if key not in targets and eps[k] > -0.5 * gap:
                    bad = rattler[key[0]] or rattler[key[1]]
                    targets[key] = -gap if bad else delta
        index = {key: k for k, key in enumerate(keys)}
        sel = np.array([index[key] for key in targets if key in index], dtype=np.int64)
        tgt = np.array([targets[key] for key in targets if key in index])
        free = np.ones(len(keys), bool)
        free[sel] = False
        ok_free = not np.any(eps[free] > -0.5 * gap)
        resid = eps[sel] - tgt
        if ok_free and sel.size == len(targets) and np.all(np.abs(resid) <= 0.1 * delta):
            return centers, r, box
        centers, r = _newton(centers, r, box, ij[sel], shift[sel], tgt, delta)
        centers = Packing(centers, r, box).centers
    raise RuntimeError("the stress-free correction of the contact network did not converge")


def _newton(x, r, box, ij, shift, target, delta):
    """Minimum-norm Newton steps on (x, r) for eps_c(x, r) = target_c over the given pairs."""
    x = x.copy()
    r = r.copy()
    i, j = ij[:, 0], ij[:, 1]
    m = i.size
    n = r.size
    S = shift * box
    rows = np.repeat(np.arange(m), 6)
    for _ in range(8):
        L = x[j] + S - x[i]
        d = np.sqrt(L[:, 0] * L[:, 0] + L[:, 1] * L[:, 1])
        g = r[i] + r[j] - d - target
        if np.all(np.abs(g) <= 0.01 * delta):
            break
        nv = L / d[:, None]
        # unknowns: x (2n, interleaved) then r (n); deps/dx_i = n, deps/dx_j = -n, deps/dr = 1
        cols = np.stack([2 * i, 2 * i + 1, 2 * j, 2 * j + 1, 2 * n + i, 2 * n + j], axis=1)
        vals = np.stack([nv[:, 0], nv[:, 1], -nv[:, 0], -nv[:, 1], np.ones(m), np.ones(m)], axis=1)
        J = sp.csr_matrix((vals.ravel(), (rows, cols.ravel())), shape=(m, 3 * n))
        JJt = (J @ J.T).tocsc()
        JJt = JJt + sp.identity(m, format="csc") * 1e-12 * JJt.diagonal().mean()
        lam = spla.splu(JJt).solve(-g)
        dz = J.T @ lam
        x += dz[: 2 * n].reshape(n, 2)
        r += dz[2 * n:]
    return x, r
