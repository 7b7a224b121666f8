"""The stress-free reference of a jammed packing (stage 3 of
:mod:`~dolfinx_granular.packings.generation`).

The contact network of a jammed state is kept and its overlaps set exactly: a minimum-norm Newton
correction of all centres and radii makes every contact between non-rattlers overlap by
``delta`` and opens the contacts of rattlers (particles with fewer than d + 1 contacts: 3 for
disks, 4 for spheres, removed recursively) to a small gap. A contact is identified by its
particles and their image shift between the unwrapped centres, so that a particle crossing the
cell boundary keeps it. The Newton steps solve their normal equations with
:mod:`~dolfinx_granular.packings.cholesky` (the same bits on every machine).
"""

from __future__ import annotations

import numpy as np

from .cholesky import minimum_norm_step, nested_dissection
from .fire import candidates
from .packing import Packing


class StressFreeError(RuntimeError):
    """The minimum-norm correction of stage 3 found no stress-free state."""


def rattlers(pairs, n, dim=2):
    """Boolean (n,) mask of particles with fewer than dim + 1 contacts (3 for disks, 4 for
    spheres: too few to be held in d dimensions), removed recursively."""
    rattler = np.zeros(n, bool)
    while True:
        keep = ~(rattler[pairs[:, 0]] | rattler[pairs[:, 1]])
        counts = np.bincount(pairs[keep].ravel(), minlength=n)
        new = (counts < dim + 1) & ~rattler
        if not new.any():
            return rattler
        rattler |= new


def _pair_keys(ij, shift, n):
    """One int64 key per pair (i, j, shift) (M, 2) + (M, d) of an N-particle packing."""
    s = shift + 64  # |shift| <= 2 here: a particle spans less than 80 % of the cell
    key = ij[:, 0] * n + ij[:, 1]
    for k in range(s.shape[1]):
        key = key * 129 + s[:, k]
    return key


def stress_free(x, r, box, delta, say):
    """Move centres and radii minimally so that contacts overlap by exactly ``delta``.

    Contacts between non-rattlers get eps = delta, contacts of rattlers a gap 1e5 * delta.

    Args:
        x: (N, d) jammed centres (mm); r: (N,) radii (mm); box: (d,) (mm); delta: overlap (mm);
        say: the :class:`_Reporter`.

    Returns:
        Wrapped ``(centers (N, d), radii (N,), box (d,))``.
    """
    n, dim = x.shape
    gap = 1e5 * delta
    centers = Packing(x, r, box).centers
    net_keys = np.empty(0, np.int64)  # the network's pairs, in the order they joined it
    net_eps = np.empty(0)  # and their target overlaps
    # cells by which each disk has been wrapped since the start: a pair is keyed by its image
    # shift between the unwrapped centres, which a disk crossing the cell boundary keeps
    wraps = np.zeros((n, dim), np.int64)
    for rnd in range(10):
        ij, shift, eps = candidates(centers, r, box, 1.02)
        keys = _pair_keys(ij, shift + wraps[ij[:, 0]] - wraps[ij[:, 1]], n)
        if net_keys.size == 0:
            new = eps > 0.0
            rattler = rattlers(ij[new], n, dim)
        else:
            # pairs that closed during the last correction join the network
            new = (eps > -0.5 * gap) & ~np.isin(keys, net_keys)
        bad = rattler[ij[new, 0]] | rattler[ij[new, 1]]
        net_keys = np.concatenate([net_keys, keys[new]])
        net_eps = np.concatenate([net_eps, np.where(bad, -gap, delta)])
        sorted_keys = np.argsort(keys)
        at = np.minimum(np.searchsorted(keys, net_keys, sorter=sorted_keys), keys.size - 1)
        found = keys[sorted_keys[at]] == net_keys
        sel, tgt = sorted_keys[at[found]], net_eps[found]
        free = np.ones(keys.size, bool)
        free[sel] = False
        ok_free = not np.any(eps[free] > -0.5 * gap)
        if ok_free and found.all() and np.all(np.abs(eps[sel] - tgt) <= 0.1 * delta):
            return centers, r, box
        say(
            "stress-free",
            rnd / (rnd + 2.0),
            f"stress-free correction, round {rnd + 1}: {sel.size} contacts ({say.elapsed():.1f} s)",
            heartbeat=True,
        )
        try:
            moved, r = _newton(centers, r, box, ij[sel], shift[sel], tgt, delta)
            centers = Packing(moved, r, box).centers
        except (ValueError, RuntimeError):  # diverged: singular equations, a radius <= 0, ...
            break
        wraps += np.rint((moved - centers) / box).astype(np.int64)
    raise StressFreeError(
        "the stress-free correction of the contact network did not converge; try another seed "
        "or a lower pressure"
    )


def _newton(x, r, box, ij, shift, target, delta):
    """Minimum-norm Newton steps on (x, r) for eps_c(x, r) = target_c over the given pairs.

    Args:
        x: (N, d) centres (mm); r: (N,) radii (mm); box: (d,) (mm); ij, shift: (M, 2) pairs
        and (M, d) image shifts (cells); target: (M,) overlaps (mm); delta: the tolerance scale
        (mm): stops when every |eps - target| <= 0.01 delta, or after 8 steps.

    Returns:
        The corrected ``(x, r)``.
    """
    x = x.copy()
    r = r.copy()
    i, j = ij[:, 0], ij[:, 1]
    n, dim = x.shape
    S = shift * box
    order = nested_dissection(x, ij)
    for _ in range(8):
        L = x[j] + S - x[i]
        d2 = L[:, 0] * L[:, 0]
        for k in range(1, dim):
            d2 = d2 + L[:, k] * L[:, k]
        d = np.sqrt(d2)
        if not np.all(d > 0.0):  # also NaN: the steps diverged
            raise ValueError("two disks of the contact network reached the same centre")
        g = r[i] + r[j] - d - target
        if np.all(np.abs(g) <= 0.01 * delta):
            break
        dx, dr = minimum_norm_step(ij, L / d[:, None], g, order, n)
        x += dx
        r += dr
    return x, r
