"""FIRE energy minimisation of soft disks or spheres in a periodic cell: the jamming dynamics of
the packing generator (:mod:`dolfinx_granular.packings.generation`, stage 2).

The particles interact through the harmonic overlap energy U = 1/2 sum max(0, r_i + r_j - d_ij)²
(k = 1). :func:`minimise` runs FIRE (Bitzek, Bitzer, Gumbsch, Moseler & Gähler, PRL 97, 170201,
2006) in a Numba kernel with a Verlet neighbour list (a cell list, rebuilt when a disk has moved
half the skin), in chunks of steps of about 0.1 s of wall time so that a caller can report
progress; the whole state is carried from chunk to chunk, so the trajectory does not depend on
the clock. Centres (N, d), radii (N,) and the cell (d,) are in mm, d = 2 or 3.
"""

from __future__ import annotations

import math
import time

import numpy as np
from numba import njit

from . import neighbours

# the wall time one chunk of FIRE steps aims at between two looks at the clock (s)
_CHUNK_SECONDS = 0.1

# FIRE parameters of Bitzek et al. (2006).
_N_MIN = 5
_F_INC = 1.1
_F_DEC = 0.5
_ALPHA0 = 0.1
_F_ALPHA = 0.99


# -- neighbour search ------------------------------------------------------------------------------


@njit(cache=True)
def wrap(x, box):
    """Wrap the centres x (N, d) into the cell [0, box) in place."""
    for i in range(x.shape[0]):
        for a in range(x.shape[1]):
            x[i, a] -= np.floor(x[i, a] / box[a]) * box[a]
            if x[i, a] >= box[a]:
                x[i, a] -= box[a]


@njit(cache=True)
def neighbour_list(x, r, box, skin):
    """Wrap the centres x (N, d) into the cell (in place) and list the pairs within ``skin``
    of contact: ``(m, pi, pj, ps)`` of :func:`~dolfinx_granular.packings.neighbours.find_pairs`
    (compiled, as FIRE's inner loop rebuilds the list through it)."""
    wrap(x, box)
    return neighbours.find_pairs(x, r, box, 1.0, skin, False)


def candidates(centers, radii, box, max_ratio):
    """Pairs with |L| <= max_ratio (r_i + r_j) and their overlap at F = I, in linear time: those
    of :func:`~dolfinx_granular.packings.neighbours.candidate_pairs`, so that eps = R - |L| decides
    "active" exactly as the Taylor RVE does.

    Returns:
        ``(ij, shift, eps)``: ij (M, 2) int64 particle indices, shift (M, d) int64 image offsets
        in cells, eps (M,) overlaps in mm (negative: a gap).
    """
    L, R, _, ij, shift = neighbours.candidate_pairs(centers, radii, box, max_ratio)
    d2 = L[:, 0] * L[:, 0]
    for k in range(1, L.shape[1]):
        d2 = d2 + L[:, k] * L[:, k]
    return ij, shift, R - np.sqrt(d2)


# -- FIRE ------------------------------------------------------------------------------------------


@njit(cache=True)
def forces(x, r, box, m, pi, pj, ps, f):
    """Harmonic overlap forces (k = 1) of the first m listed pairs into f (N, d).

    Returns the virial sum over the contacts of overlap * distance (mm²).
    """
    f[:, :] = 0.0
    vir = 0.0
    three = x.shape[1] == 3  # 2-D: dz = 0 adds exact zeros (the same sums to the bit)
    for c in range(m):
        i = pi[c]
        j = pj[c]
        dx = x[j, 0] + ps[c, 0] * box[0] - x[i, 0]
        dy = x[j, 1] + ps[c, 1] * box[1] - x[i, 1]
        dz = x[j, 2] + ps[c, 2] * box[2] - x[i, 2] if three else 0.0
        d2 = dx * dx + dy * dy + dz * dz
        rs = r[i] + r[j]
        if d2 < rs * rs:
            d = np.sqrt(d2)
            ov = rs - d
            vir += ov * d
            fx = ov * dx / d
            fy = ov * dy / d
            f[i, 0] -= fx
            f[i, 1] -= fy
            f[j, 0] += fx
            f[j, 1] += fy
            if three:
                fz = ov * dz / d
                f[i, 2] -= fz
                f[j, 2] += fz
    return vir


@njit(cache=True, inline="always")
def _dot(a, b, i):
    """a_i . b_i of two (N, d) arrays, d = 2 or 3 (2-D: the two products alone)."""
    s = a[i, 0] * b[i, 0] + a[i, 1] * b[i, 1]
    return s + a[i, 2] * b[i, 2] if a.shape[1] == 3 else s


@njit(cache=True)
def _fire_sums(f, v):
    """FIRE's reductions over the particles, in index order: (max |f|², |f|², |v|², f · v)."""
    fmax = 0.0
    fn2 = 0.0
    vn2 = 0.0
    power = 0.0
    for i in range(f.shape[0]):
        fi2 = _dot(f, f, i)
        if fi2 > fmax:
            fmax = fi2
        fn2 += fi2
        vn2 += _dot(v, v, i)
        power += _dot(f, v, i)
    return fmax, fn2, vn2, power


@njit(cache=True)
def _euler_step(x, v, f, x_ref, dt):
    """Semi-implicit Euler step of v and x (N, d), in place; returns the largest squared
    displacement from x_ref (N, d)."""
    moved2 = 0.0
    for i in range(x.shape[0]):
        di2 = 0.0
        for a in range(x.shape[1]):
            v[i, a] += dt * f[i, a]
            x[i, a] += dt * v[i, a]
            da = x[i, a] - x_ref[i, a]
            di2 += da * da
        moved2 = max(moved2, di2)
    return moved2


@njit(cache=True)
def fire_steps(x, r, box, skin, ftol, dt_max, stop, st, v, f, x_ref, nl):
    """FIRE steps on the centres x (N, d), in place, until max |f| < ftol or step ``stop``.

    Unit masses and stiffness. The state lives in the arguments, so that a minimisation can run
    in chunks with the same trajectory as in one go: velocities v and forces f (N, 2), the
    centres x_ref (N, d) at the last neighbour-list build, the list nl = (m, pi, pj, ps) and
    st = [dt, alpha, n_pos, step, virial, max |f|] (float64 (6,), updated).

    Returns:
        ``(nl, converged)``: the (possibly rebuilt) neighbour list and whether max |f| < ftol.
    """
    m, pi, pj, ps = nl
    dt, alpha, n_pos, step = st[0], st[1], int(st[2]), int(st[3])
    converged = False
    while step < stop:
        fmax2, fn2, vn2, power = _fire_sums(f, v)
        st[5] = np.sqrt(fmax2)
        if st[5] < ftol:
            converged = True
            break
        if power > 0.0:
            scale = alpha * np.sqrt(vn2 / fn2)
            for i in range(v.shape[0]):
                for a in range(v.shape[1]):
                    v[i, a] = (1.0 - alpha) * v[i, a] + scale * f[i, a]
            if n_pos > _N_MIN:
                dt = min(dt * _F_INC, dt_max)
                alpha *= _F_ALPHA
            n_pos += 1
        else:
            n_pos = 0
            dt *= _F_DEC
            alpha = _ALPHA0
            v[:, :] = 0.0
        if _euler_step(x, v, f, x_ref, dt) > (0.5 * skin) ** 2:
            m, pi, pj, ps = neighbour_list(x, r, box, skin)
            x_ref[:, :] = x
        st[4] = forces(x, r, box, m, pi, pj, ps, f)
        step += 1
    st[0], st[1], st[2], st[3] = dt, alpha, n_pos, step
    return (m, pi, pj, ps), converged


def minimise(x, r, box, skin, ftol, dt0, dt_max, max_steps, beat):
    """Minimise the overlap energy over the centres x (N, d) (in place) with FIRE.

    Stops when the largest force is below ``ftol`` or after ``max_steps`` steps. Runs the Numba
    kernel in chunks of ~0.1 s and calls ``beat(step, max_force)`` after each unfinished chunk.

    Returns:
        ``(steps, virial)``: virial = sum of overlap * distance over the contacts (mm²).
    """
    n = r.shape[0]
    nl = neighbour_list(x, r, box, skin)
    v = np.zeros((n, x.shape[1]))
    f = np.empty((n, x.shape[1]))
    x_ref = x.copy()
    st = np.array([dt0, _ALPHA0, 0.0, 0.0, 0.0, np.inf])
    st[4] = forces(x, r, box, *nl, f)
    chunk = 16
    while True:
        t0 = time.perf_counter()
        stop = min(int(st[3]) + chunk, max_steps)
        nl, converged = fire_steps(x, r, box, skin, ftol, dt_max, stop, st, v, f, x_ref, nl)
        if converged or int(st[3]) >= max_steps:
            return int(st[3]), st[4]
        beat(int(st[3]), st[5])
        elapsed = max(time.perf_counter() - t0, 1e-6)
        chunk = int(min(max(chunk * _CHUNK_SECONDS / elapsed, 16), 8 * chunk))


def virial_pressure(x, r, box):
    """Virial pressure p / k of the centres x (N, d) (wrapped in place) at radii r (N,):
    sum overlap * distance / (d V) (1 / mm in 3-D)."""
    m, pi, pj, ps = neighbour_list(x, r, box, 0.0)
    vir = forces(x, r, box, m, pi, pj, ps, np.empty_like(x))
    return vir / (x.shape[1] * math.prod(box))
