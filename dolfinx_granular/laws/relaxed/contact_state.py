"""The contacts of a relaxed cell at (F, w): overlaps, forces, energy, rattlers and the network.

Every disk i sits at x_i = F (X_i + w_i): X_i its reference centre, w_i its fluctuation in the
reference frame (its fractional coordinates are fixed when F changes). A candidate contact c of
disks (i, j) with reference branch vector L_c has the relaxed reference branch vector
Q_c = L_c + w_j - w_i, the current one l_c = F Q_c, d = |l|, n = l / d and the overlap
e = R - d; it is a contact when e > 0. With K = k_n / V its energy is phi = K/2 e^2 and
g_c = dphi/dl = -K e n; dphi/dw_j = F^T g = -dphi/dw_i.

The kernels compute these over a prefix of the cell's candidates
(:meth:`~dolfinx_granular.laws.relaxed.cell.Cell.visited`); :class:`ContactState` holds them at
one (F, w) with the rattlers (fewer than :data:`MIN_CONTACTS` contacts, removed recursively) and
the network of the others.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .cell import Cell

#: contacts a disk needs to be no rattler (d + 1 in d = 2 dimensions)
MIN_CONTACTS = 3


@njit(cache=True)
def contact_state(F, w, pi, pj, X, Y, R, m):
    """Overlaps of the first m candidates at F (2, 2) and fluctuations w (N, 2).

    Returns:
        ``(qx, qy, lx, ly, d, e)``, each (m,): Q = L + w_j - w_i, l = F Q, d = |l|, e = R - d.
    """
    qx = np.empty(m)
    qy = np.empty(m)
    lx = np.empty(m)
    ly = np.empty(m)
    d = np.empty(m)
    e = np.empty(m)
    for c in range(m):
        i = pi[c]
        j = pj[c]
        x = X[c] + w[j, 0] - w[i, 0]
        y = Y[c] + w[j, 1] - w[i, 1]
        a = F[0, 0] * x + F[0, 1] * y
        b = F[1, 0] * x + F[1, 1] * y
        qx[c] = x
        qy[c] = y
        lx[c] = a
        ly[c] = b
        d[c] = np.sqrt(a * a + b * b)
        e[c] = R[c] - d[c]
    return qx, qy, lx, ly, d, e


@njit(cache=True)
def energy(e, K, use):
    """K/2 sum over the contacts ``use`` (m,) bool (all with e > 0) of e^2 (Pa)."""
    s = 0.0
    for c in range(e.shape[0]):
        if use[c]:
            s += e[c] * e[c]
    return 0.5 * K * s


@njit(cache=True)
def forces(F, pi, pj, lx, ly, d, e, K, n_disks, use):
    """Over the contacts ``use`` (m,) bool (all with e > 0): the gradient of their energy with
    respect to the fluctuations, (N, 2) (Pa per length), and the net contact force on each
    disk in the current frame, (N, 2), in units of K times length (sum of K e n over the
    disk's contacts, pushing it away from each partner)."""
    g = np.zeros((n_disks, 2))
    f = np.zeros((n_disks, 2))
    for c in range(e.shape[0]):
        if not use[c]:
            continue
        i = pi[c]
        j = pj[c]
        if i == j:
            continue  # a disk against its own image: no net force, no gradient
        s = K * e[c] / d[c]
        fx = s * lx[c]  # force on j, along n (from i to j), K e n
        fy = s * ly[c]
        f[j, 0] += fx
        f[j, 1] += fy
        f[i, 0] -= fx
        f[i, 1] -= fy
        # dphi/dw_j = F^T g_c with g_c = -K e n = -(fx, fy)
        gx = -(F[0, 0] * fx + F[1, 0] * fy)
        gy = -(F[0, 1] * fx + F[1, 1] * fy)
        g[j, 0] += gx
        g[j, 1] += gy
        g[i, 0] -= gx
        g[i, 1] -= gy
    return g, f


@njit(cache=True)
def non_rattlers(pi, pj, e, n_disks, min_contacts):
    """(N,) bool: the disks left after removing, recursively, every disk with fewer than
    ``min_contacts`` contacts (e > 0) with disks that are left. Contacts of a disk with its own
    image do not count."""
    keep = np.ones(n_disks, np.bool_)
    count = np.zeros(n_disks, np.int64)
    changed = True
    while changed:
        changed = False
        count[:] = 0
        for c in range(e.shape[0]):
            i = pi[c]
            j = pj[c]
            if e[c] > 0.0 and i != j and keep[i] and keep[j]:
                count[i] += 1
                count[j] += 1
        for k in range(n_disks):
            if keep[k] and count[k] < min_contacts:
                keep[k] = False
                changed = True
    return keep


class ContactState:
    """The contacts of a cell at F (2, 2) and fluctuations w (N, 2) over the first m candidates
    (by default :meth:`Cell.visited`).

    Attributes:
        m: candidates visited (a prefix of the cell's list).
        qx, qy, lx, ly, d, e: (m,) relaxed reference branch Q, current branch l = F Q, |l| and
            the overlap e = R - |l|.
        on: (m,) contacts, e > 0.
        mean_overlap: mean e over the contacts (0 without contacts).
        keep: (N,) the non-rattlers.
        network: (m,) contacts between two non-rattlers.
        rattling: (m,) contacts that touch a rattler.
    """

    def __init__(self, cell: Cell, F: np.ndarray, w: np.ndarray, m: int | None = None) -> None:
        self.m = m = cell.visited(F, w) if m is None else m
        self.qx, self.qy, self.lx, self.ly, self.d, self.e = contact_state(
            F, w, cell.pi, cell.pj, cell.X, cell.Y, cell.R, m
        )
        self.on = self.e > 0.0
        self.mean_overlap = float(self.e[self.on].mean()) if self.on.any() else 0.0
        self.keep = non_rattlers(cell.pi, cell.pj, self.e, cell.n_disks, MIN_CONTACTS)
        both = self.both(cell, self.keep)
        self.network = self.on & both
        self.rattling = self.on & ~both

    def both(self, cell: Cell, keep: np.ndarray) -> np.ndarray:
        """(m,) candidates whose two disks are in ``keep`` (N,)."""
        return keep[cell.pi[: self.m]] & keep[cell.pj[: self.m]]

    def forces(self, cell: Cell, F: np.ndarray, use: np.ndarray) -> tuple:
        """``(g, f)`` (N, 2) each over the contacts ``use``: see :func:`forces`."""
        return forces(
            F, cell.pi, cell.pj, self.lx, self.ly, self.d, self.e, cell.K, cell.n_disks, use
        )

    def energy(self, cell: Cell, use: np.ndarray) -> float:
        """Energy of the contacts ``use`` (Pa)."""
        return energy(self.e, cell.K, use)

    def resolution(self, cell: Cell) -> float:
        """The net force, relative to the mean contact force, below which (F, w) resolve no
        more: an overlap is the difference of lengths of the order of R, good to eps R, so a
        contact force is good to eps R / e of itself (~ eps mean R / mean e; inf without
        contacts)."""
        if not self.on.any():
            return np.inf
        return float(np.finfo(float).eps * cell.R[: self.m][self.on].mean() / self.mean_overlap)

    def force_scale(self, cell: Cell) -> float:
        """Mean contact force K e over the contacts (K times length; 0 without contacts)."""
        return cell.K * self.mean_overlap
