"""The frictional relaxed cell at (F, w, theta) after an increment: its contacts, rattlers,
balance and the equations' arrays (:mod:`~dolfinx_granular.laws.relaxed_friction.system`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..relaxed.cell import Cell
from ..relaxed.contact_state import non_rattlers
from .contact_law import OPEN, SLIP, STICK, return_map
from .rolling import radius
from .system import balance, dissipation, energy, equations, forces, rolling_springs

#: a disk needs this many contacts with the other non-rattlers to be no rattler: with friction
#: two contacts can hold a disk, with forces along the chord between them (while that chord
#: lies in both cones)
MIN_CONTACTS = 2
#: a contact whose overlap is below this part of the mean overlap does not count towards
#: MIN_CONTACTS: a disk that only barely touches (two slipping contacts at 1e-10 of the radii,
#: their caps ~1e-7 of the mean force) is loose, and held as a rattler it is pushed off them;
#: held as a disk, Newton and the continuation crawled at a residual of 1e-7
RATTLER_OVERLAP = 1e-6
#: equilibrium also within this many times the round-off of the contact forces (as the
#: frictionless relaxed RVE's :data:`~dolfinx_granular.laws.relaxed.newton.RESOLVED`)
RESOLVED = 30.0
#: least extra diagonal of a rattler's unknowns in Newton, relative to k_n / V
RATTLER_SHIFT = 1e-8
#: a rattler's Newton move is at most about this many mean overlaps (its unknowns are
#: shifted by its net force over that length, as in the frictionless solver)
RATTLER_REACH = 300.0


@dataclass(frozen=True)
class Springs:
    """The contact law: k_n, k_t (N/m²), mu, 1 / V (1 / the cell's reference area), and the
    rolling springs (:mod:`.rolling`): kr = beta k_t (N/m²; k_r = kr r_eff^2) and their cap
    mu_r (0: none)."""

    kn: float
    kt: float
    mu: float
    inv_area: float
    kr: float = 0.0
    mu_r: float = 0.0


@dataclass
class Increment:
    """The committed side of an increment: F0 (2, 2), w0 (N, 2), theta0 (N,), the
    tangential forces ft0 (M,) of the cell's candidates (N; zero where no contact was),
    ``chain``, their derivatives with respect to the path's final F
    (:class:`~dolfinx_granular.laws.relaxed_friction.path_tangent.Chain`; None: zero, the
    macro-committed state), and the rolling moments mr0 (M,) (N m; None: zero)."""

    F0: np.ndarray
    w0: np.ndarray
    th0: np.ndarray
    ft0: np.ndarray
    chain: object = None
    mr0: np.ndarray | None = None

    def forces(self, n: int) -> np.ndarray:
        """ft0 for a list of n >= len(ft0) candidates (a grown list's new pairs: zero)."""
        if self.ft0.shape[0] < n:
            self.ft0 = np.concatenate([self.ft0, np.zeros(n - self.ft0.shape[0])])
        return self.ft0

    def moments(self, n: int) -> np.ndarray:
        """mr0 for a list of n candidates (new pairs: zero)."""
        if self.mr0 is None:
            self.mr0 = np.zeros(n)
        elif self.mr0.shape[0] < n:
            self.mr0 = np.concatenate([self.mr0, np.zeros(n - self.mr0.shape[0])])
        return self.mr0

    def arrays(self, n: int) -> tuple:
        """``(F0, w0, theta0, ft0, mr0)`` for n candidates, as the compiled loops take them."""
        F0 = np.asarray(self.F0, np.float64)
        return F0, self.w0, self.th0, self.forces(n), self.moments(n)


class CellState:
    """The cell at (F, w, theta) after the increment ``inc``
    (:func:`~dolfinx_granular.laws.relaxed_friction.contact_law.return_map`).

    Attributes:
        m: candidates visited; qx ... status, mr, mstar, rstatus: the return map's arrays
            (m,) (the rolling moments', :mod:`.rolling`).
        keep: (N,) the non-rattlers; network: (m,) contacts between two of them;
            :attr:`apart`: no disk keeps two contacts.
        f, M: (N, 2), (N,) net force and moment on each disk (N, N m per unit thickness).
        mean_force: mean normal force over the contacts; count: their number.
        r: (N, 3) the equations' residual (gradient of the incremental potential, per area);
        P: (2, 2) the stress (Pa).
    """

    def __init__(self, cell: Cell, springs: Springs, F, w, th, inc: Increment) -> None:
        self.m = m = cell.visited(F, w)
        F0, w0, th0, ft0, mr0 = inc.arrays(cell.pi.shape[0])
        sp = springs
        (self.qx, self.qy, self.lx, self.ly, self.d, self.e, self.ft, self.fstar, self.status,
         self.mr, self.mstar, self.rstatus) = return_map(
            F, w, th, F0, w0, th0, ft0, mr0, cell.pi, cell.pj, cell.X, cell.Y, cell.R,
            cell.radii, m, sp.kn, sp.kt, sp.mu, sp.kr, sp.mu_r,
        )  # fmt: skip
        self.on = self.status != OPEN
        self.keep = holding(cell.pi, cell.pj, self.e, cell.n_disks)
        self.network = self.on & self.keep[cell.pi[:m]] & self.keep[cell.pj[:m]]
        self.f, self.M, self.mean_force, self.count = balance(
            cell.pi, cell.pj, self.lx, self.ly, self.d, self.e, self.ft, self.mr, cell.R,
            cell.radii, sp.kn, cell.n_disks,
        )  # fmt: skip
        self.r, self.P = forces(
            F, self.qx, self.qy, self.lx, self.ly, self.d, self.e, self.ft, self.status,
            self.mr, self.rstatus, cell.pi, cell.pj, cell.R, cell.radii, sp.kn, sp.inv_area,
            cell.n_disks,
        )  # fmt: skip

    @property
    def apart(self) -> bool:
        """The cell has come apart: fewer than two disks are no rattlers (no network)."""
        return bool(self.keep.sum() < 2)

    def equations(self, cell, springs, F, mode, jacobian):
        """``(r (N, 3), P (2, 2), (rows, cols, values))`` (:func:`system.equations`; the
        Jacobian's coordinates with ``jacobian``, by ``mode`` (m,) int8)."""
        m, sp = self.m, springs
        size = 36 * m if jacobian else 0
        rows, cols, vals = np.empty(size, np.int64), np.empty(size, np.int64), np.empty(size)
        mode = np.zeros(m, np.int8) if mode is None else mode
        r, P, nnz = equations(
            F, *self.contact_arrays(), cell.pi, cell.pj, cell.R, cell.radii, sp.kn, sp.kt,
            sp.mu, sp.kr, sp.mu_r, sp.inv_area, cell.n_disks, mode, jacobian, rows, cols, vals,
        )  # fmt: skip
        return r, P, (rows[:nnz], cols[:nnz], vals[:nnz])

    def contact_arrays(self) -> tuple:
        """The return map's arrays ``(qx, qy, lx, ly, d, e, ft, fstar, status, mr, mstar,
        rstatus)``, as :mod:`.system` takes them."""
        return (self.qx, self.qy, self.lx, self.ly, self.d, self.e, self.ft, self.fstar,
                self.status, self.mr, self.mstar, self.rstatus)  # fmt: skip

    def arrays(self) -> tuple:
        """The state as the compiled Newton loop's cell states
        (:func:`~dolfinx_granular.laws.relaxed_friction.newton_kernel.cell_state`)."""
        return (self.qx, self.qy, self.lx, self.ly, self.d, self.e, self.ft, self.fstar,
                self.status, self.keep, self.f, self.M, self.mean_force, self.count,
                self.r, self.mr, self.mstar, self.rstatus)  # fmt: skip

    def energies(self, cell: Cell, springs: Springs) -> tuple[float, float]:
        """``(W, D)`` (Pa): the stored energy here and the energy the increment's return map
        dissipated (:func:`~dolfinx_granular.laws.relaxed_friction.system.energy`,
        :func:`~dolfinx_granular.laws.relaxed_friction.system.dissipation`)."""
        sp = springs
        _, kr = rolling_springs(cell.pi, cell.pj, cell.radii, self.e, sp.kn, sp.kr, sp.mu_r)
        W = energy(self.e, self.ft, self.status, sp.kn, sp.kt, sp.inv_area, self.mr,
                   self.rstatus, kr)  # fmt: skip
        D = dissipation(self.ft, self.fstar, self.status, sp.kt, sp.inv_area, self.mr,
                        self.mstar, self.rstatus, kr)  # fmt: skip
        return W, D

    def held_rotations(self, cell: Cell) -> np.ndarray:
        """(N,) disks with a sticking contact (sliding or rolling) in the network: their
        rotation has stiffness."""
        held = np.zeros(cell.n_disks, bool)
        stick = self.network & ((self.status == STICK) | (self.rstatus == STICK))
        held[cell.pi[: self.m][stick]] = True
        held[cell.pj[: self.m][stick]] = True
        return held

    def residual(self, cell: Cell) -> tuple[float, float]:
        """``(residual, floor)``: the larger of the largest net force over the mean contact
        force and the largest net moment over the mean contact force times the mean radius
        (inf without contacts), and the round-off below which it means nothing."""
        return equilibrium_residual(self.f, self.M, self.mean_force, self.count, self.e,
                                    self.status, cell.R, cell.radii)  # fmt: skip


@njit(cache=True)
def equilibrium_residual(f, M, mean_force, count, e, status, R, radii):
    """``(residual, floor)`` of net forces f (N, 2) and moments M (N,) over the contacts of
    overlaps e and statuses (m,) (as :meth:`CellState.residual`)."""
    if count == 0 or mean_force == 0.0:
        return np.inf, np.inf
    fmax = 0.0
    for k in range(f.shape[0]):
        fmax = max(fmax, f[k, 0] ** 2 + f[k, 1] ** 2)
    Mmax = np.abs(M).max()
    sum_e, sum_R = 0.0, 0.0
    for c in range(e.shape[0]):
        if status[c] != OPEN:
            sum_e += e[c]
            sum_R += R[c]
    floor = RESOLVED * np.finfo(np.float64).eps * sum_R / sum_e
    return max(np.sqrt(fmax) / mean_force, Mmax / (mean_force * radii.mean())), floor


@njit(cache=True)
def holding(pi, pj, e, n_disks):
    """(N,) the disks that are no rattlers: :data:`MIN_CONTACTS` contacts or more with other
    such disks, each with an overlap of at least :data:`RATTLER_OVERLAP` of the mean."""
    total, count = 0.0, 0
    for c in range(e.shape[0]):
        if e[c] > 0.0:
            total += e[c]
            count += 1
    floor = RATTLER_OVERLAP * total / count if count else 0.0
    return non_rattlers(pi, pj, np.where(e > floor, e, 0.0), n_disks, MIN_CONTACTS)


@njit(cache=True)
def overlap_ratio(F, w, pi, pj, X, Y, R, m):
    """The mean overlap over the mean radius sum of the contacts among the first m candidates
    at (F, w) (0 without a contact)."""
    sum_e, sum_R = 0.0, 0.0
    for c in range(m):
        x = X[c] + w[pj[c], 0] - w[pi[c], 0]
        y = Y[c] + w[pj[c], 1] - w[pi[c], 1]
        a = F[0, 0] * x + F[0, 1] * y
        b = F[1, 0] * x + F[1, 1] * y
        e = R[c] - np.sqrt(a * a + b * b)
        if e > 0.0:
            sum_e += e
            sum_R += R[c]
    return sum_e / sum_R if sum_R > 0.0 else 0.0


@njit(cache=True)
def diagonal(status, rstatus, network, keep, pi, pj, radii, r, fstar, mstar, e, kn, kt, mu, kr,
             mu_r, inv_area, pinned, reach, rattler_shift, tangent, free_rotation):  # fmt: skip
    """The extra diagonal (3N,) of the Jacobian.

    * The pinned disk's translation: k_n / V (its rows and columns are dropped).
    * A rattler's translation: its net force over ``reach`` (at least ``rattler_shift`` k_n /
      V) in Newton, k_n / V (held fixed) for the ``tangent``.
    * A rotation that no sticking contact of the network resists (neither sliding nor rolling,
      :mod:`.rolling`; and a rattler's): k_t r^2 per slipping contact / V (at least one). Its
      column of the Jacobian is zero elsewhere, so this value changes only that rotation's own
      step, neither the other unknowns' nor the condensed tangent. In Newton, where its moment
      can turn a slipping contact back into the cone, the value that does so
      (:func:`_cone_rotations`)."""
    n = radii.shape[0]
    K = kn * inv_area
    out = np.zeros(3 * n)
    held = np.zeros(n, np.bool_)
    slips = np.zeros(n)
    for c in range(status.shape[0]):
        if not network[c]:
            continue
        for k in (pi[c], pj[c]):
            if status[c] == STICK or rstatus[c] == STICK:
                held[k] = True
            elif status[c] == SLIP:
                slips[k] += 1.0
    spring = kt if kt > 0.0 else kn
    for k in range(n):
        if not keep[k]:
            force = np.sqrt(r[k, 0] ** 2 + r[k, 1] ** 2)
            shift = K if tangent else max(rattler_shift * K, force / reach)
            out[3 * k] = out[3 * k + 1] = shift
        if not held[k] or not keep[k]:
            out[3 * k + 2] = free_rotation * spring * radii[k] ** 2 * max(slips[k], 1.0) * inv_area
    if not tangent:
        _cone_rotations(out, status, rstatus, network, keep, held, pi, pj, radii, r, fstar, mstar,
                        e, kn, kt, mu, kr, mu_r)  # fmt: skip
    out[3 * pinned] = out[3 * pinned + 1] = K
    return out


#: :func:`_cone_rotations` turns a disk until a slipping contact's trial force is this part of
#: its cap inside the cone
DEPTH = 0.5


@njit(cache=True)
def _cone_rotations(out, status, rstatus, network, keep, held, pi, pj, radii, r, fstar, mstar, e,
                    kn, kt, mu, kr, mu_r):  # fmt: skip
    """Newton's diagonal (in ``out``) of each rotation that only slipping contacts touch: its
    step -M / diag turns the disk until the first contact whose trial force (or rolling
    moment) the turn lowers is :data:`DEPTH` into its cap (the caps do not resist the turn:
    another value would turn it by an arbitrary angle, and a disk whose moment no slipping
    contact can balance would crawl towards the cone over many steps). d f* / d theta_k =
    -k_t r_k; d m* / d theta_i = k_r = -d m* / d theta_j."""
    n = radii.shape[0]
    turn = np.full(n, np.inf)
    for c in range(status.shape[0]):
        if not network[c]:
            continue
        for side, k in ((1.0, pi[c]), (-1.0, pj[c])):
            if not keep[k] or held[k]:
                continue
            if status[c] == SLIP and r[k, 2] * fstar[c] < 0.0:
                inside = abs(fstar[c]) - (1.0 - DEPTH) * mu * kn * e[c]
                turn[k] = min(turn[k], inside / (kt * radii[k]))
            if rstatus[c] == SLIP and side * r[k, 2] * mstar[c] > 0.0:
                reff = radius(radii[pi[c]], radii[pj[c]])
                inside = abs(mstar[c]) - (1.0 - DEPTH) * mu_r * reff * kn * e[c]
                turn[k] = min(turn[k], inside / (kr * reff * reff))
    for k in range(n):
        if np.isfinite(turn[k]) and turn[k] > 0.0:
            out[3 * k + 2] = max(abs(r[k, 2]) / turn[k], 1e-6 * out[3 * k + 2])
