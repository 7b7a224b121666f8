"""The relaxed RVE's micro solver: static equilibrium of one periodic cell at a given F, and the
condensed tangent there.

Unknowns: the fluctuations w (N, 2) of the disks in the reference frame (x_i = F (X_i + w_i),
:mod:`~dolfinx_granular.laws.relaxed_kernel`). The energy W(F, w) is minimised by Newton with a
sparse factorisation of the stiffness per step and a backtracking line search on W. One disk is
pinned (the rigid translation). Rattlers (fewer than 3 contacts, removed recursively) are relaxed
with the rest: their unknowns get a small extra diagonal so that the step stays defined, and they
end force-free. Where the stiffness is not positive definite (the contact network buckles: a
rearrangement), the step is taken on a shifted stiffness H + mu I (Levenberg-Marquardt, a trust
region in effect), mu growing until the factorisation is positive definite; the next step tries
plain Newton again.

At the equilibrium, the tangent of the relaxed response is

    A = W_FF - W_Fw W_ww^-1 W_wF

over the non-rattlers' contacts and unknowns only (rattlers add nothing), with W_FF the Taylor
(Born) tangent at the relaxed branch vectors. Positive definiteness of W_ww there, one disk
pinned, is the cell's rigidity; without it (or without non-rattlers) the point fails with a
:class:`RigidityLostError`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.linalg import splu

from ..packings import neighbours
from . import relaxed_kernel as rk
from . import taylor_kernel
from .protocol import LawEvaluationError

#: contacts a disk needs to be no rattler (d + 1 in d = 2 dimensions)
MIN_CONTACTS = 3
#: longest move of a disk in one Newton step, relative to the smallest radius sum
MAX_STEP = 0.1


class RelaxationError(LawEvaluationError):
    """The micro solver could not relax a point (it did not reach equilibrium, or its candidate
    contacts no longer cover the fluctuations)."""


class RigidityLostError(RelaxationError):
    """The relaxed cell has no rigid contact network left: no non-rattler disk, or a stiffness
    of the non-rattlers (one disk pinned) that is not positive definite (tension, a buckled
    network)."""


@dataclass
class Settings:
    """Tolerances of the micro solver.

    Attributes:
        force_tol: equilibrium when every disk's net force is at most this times the mean
            contact force.
        max_iterations: Newton steps per point before a :class:`RelaxationError`.
        rattler_shift: extra diagonal of the rattlers' unknowns, relative to the mean diagonal
            of the stiffness.
    """

    force_tol: float = 1e-10
    max_iterations: int = 200
    rattler_shift: float = 1e-8


@dataclass
class Cell:
    """One RVE's candidate contacts as the kernels take them (the first m are visited)."""

    pi: np.ndarray
    pj: np.ndarray
    X: np.ndarray
    Y: np.ndarray
    R: np.ndarray
    ratio: np.ndarray
    n_disks: int
    K: float
    min_stretch: float

    box: np.ndarray
    centers: np.ndarray
    radii: np.ndarray
    shift: np.ndarray

    @classmethod
    def of(cls, candidates, packing, stiffness_per_area):
        """The cell of a packing's :class:`~dolfinx_granular.ContactCandidates`."""
        X, Y = candidates.components
        pairs = candidates.pairs
        return cls(
            np.ascontiguousarray(pairs[:, 0]),
            np.ascontiguousarray(pairs[:, 1]),
            X,
            Y,
            candidates.radius_sum,
            candidates.ratio,
            packing.radii.shape[0],
            float(stiffness_per_area),
            candidates.min_stretch,
            packing.box,
            packing.centers,
            packing.radii,
            candidates.shift,
        )

    def visited(self, F, w):
        """How many candidates (a prefix) can be in contact at F with fluctuations w.

        |F Q| < R needs |L| / R < 1 / s_min(F) + 2 max|w - mean w| / min R (a common translation
        changes no branch vector). Where that reaches past the candidate list, the whole list is
        visited and :meth:`check_complete` makes sure no pair outside it can touch."""
        s_min = np.linalg.svd(F, compute_uv=False)[-1]
        v = w - w.mean(axis=0)
        reach = 1.0 / s_min + 2.0 * np.sqrt((v * v).sum(axis=1).max()) / self.R.min()
        if reach > 1.0 / self.min_stretch:
            self.check_complete(w, s_min)
        return int(np.searchsorted(self.ratio, reach, side="right"))

    def check_complete(self, w, s_min):
        """RelaxationError if two disks that are no candidate pair can touch: relaxed reference
        distance below (r_i + r_j) / s_min(F)."""
        x = self.centers + w
        wraps = np.floor(x / self.box).astype(np.int64)
        m, pi, pj, ps = neighbours.find_pairs(
            x - wraps * self.box, self.radii, self.box, 1.0 / s_min, 0.0, True
        )
        i, j = pi[:m].astype(np.int64), pj[:m].astype(np.int64)
        shift = ps[:m] + wraps[j] - wraps[i]
        flip = j < i
        i[flip], j[flip], shift[flip] = j[flip], i[flip], -shift[flip]
        known = self._keys()
        for a, b, (sx, sy) in zip(i.tolist(), j.tolist(), shift.tolist()):
            if (a, b, sx, sy) not in known and (a != b or (b, a, -sx, -sy) not in known):
                raise RelaxationError(
                    f"disks {a} and {b} moved into reach of each other but are no candidate "
                    f"pair (built for min_stretch = {self.min_stretch}); build the RelaxedRVE "
                    "with a smaller min_stretch"
                )

    def _keys(self):
        if not hasattr(self, "_known"):
            self._known = set(
                zip(self.pi.tolist(), self.pj.tolist(), *np.asarray(self.shift).T.tolist())
            )
        return self._known


@dataclass
class Equilibrium:
    """A relaxed point: fluctuations, energy, stress and (if asked) tangent."""

    w: np.ndarray  # (N, 2)
    W: float
    P: np.ndarray  # (2, 2)
    A: np.ndarray | None  # (2, 2, 2, 2)
    contacts: np.ndarray  # (k,) candidate indices with e > 0
    network: np.ndarray  # (k',) those between two non-rattlers
    rattlers: int
    iterations: int
    shifted_steps: int
    residual: float


class ContactState:
    """Contact state of a cell at (F, w): overlaps, forces, non-rattlers."""

    def __init__(self, cell, F, w):
        self.m = m = cell.visited(F, w)
        self.qx, self.qy, self.lx, self.ly, self.d, self.e = rk.contact_state(
            F, w, cell.pi, cell.pj, cell.X, cell.Y, cell.R, m
        )
        self.on = self.e > 0.0
        self.W = rk.energy(self.e, cell.K)
        self.g, self.f = rk.forces(
            F, cell.pi, cell.pj, self.lx, self.ly, self.d, self.e, cell.K, cell.n_disks
        )
        self.keep = rk.non_rattlers(cell.pi, cell.pj, self.e, cell.n_disks, MIN_CONTACTS)

    def residual(self, cell):
        """max |net force| / mean contact force (inf without contacts)."""
        if not self.on.any():
            return np.inf
        mean = cell.K * self.e[self.on].mean()
        return float(np.sqrt((self.f * self.f).sum(axis=1).max()) / mean)


def _unknowns(keep, pinned):
    """dof (N,) int64: the unknown pair of each disk, -1 for the pinned one."""
    dof = np.cumsum(np.ones(keep.shape[0], np.int64)) - 1
    dof[pinned + 1 :] -= 1
    dof[pinned] = -1
    return dof


def _matrix(cell, F, s, use, dof, n):
    """Stiffness over the contacts ``use``: exact between non-rattlers, positive part else."""
    exact = s.keep[cell.pi[: s.m]] & s.keep[cell.pj[: s.m]]
    rows, cols, vals = rk.stiffness(
        F,
        cell.pi[: s.m],
        cell.pj[: s.m],
        s.lx,
        s.ly,
        s.d,
        s.e,
        cell.R[: s.m],
        cell.K,
        use,
        exact,
        dof,
    )
    ok = (rows >= 0) & (cols >= 0)
    return coo_matrix((vals[ok], (rows[ok], cols[ok])), shape=(n, n)).tocsc()


def _factorise(H):
    """SuperLU of a symmetric matrix with symmetric (diagonal) pivoting, and whether it is
    positive definite (all pivots > 0: Sylvester's law of inertia); None if singular."""
    try:
        lu = splu(
            H, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
        )
    except RuntimeError:
        return None, False
    pd = bool(np.array_equal(lu.perm_r, lu.perm_c) and np.all(lu.U.diagonal() > 0.0))
    return lu, pd


def _step(cell, F, s, settings):
    """Newton (or shifted Newton) direction on every disk but one pinned non-rattler."""
    pinned = int(np.argmax(s.keep))
    dof = _unknowns(s.keep, pinned)
    n = 2 * (cell.n_disks - 1)
    H = _matrix(cell, F, s, s.on, dof, n)
    diag = H.diagonal()
    scale = diag[diag > 0].mean() if np.any(diag > 0) else cell.K
    rattler = np.repeat(~s.keep, 2)
    rattler = np.delete(rattler, [2 * pinned, 2 * pinned + 1])
    H = H + _diagonal(settings.rattler_shift * scale * rattler)
    g = np.delete(s.g.reshape(-1), [2 * pinned, 2 * pinned + 1])
    lu, pd = _factorise(H)
    shifted = False
    mu = 1e-8 * scale
    while not pd:
        shifted = True
        lu, pd = _factorise(H + _diagonal(np.full(n, mu)))
        mu *= 10.0
        if mu > 1e6 * scale:
            raise RelaxationError("the shifted stiffness never became positive definite")
    delta = np.insert(-lu.solve(g), 2 * pinned, [0.0, 0.0]).reshape(-1, 2)
    return delta, shifted


def _diagonal(v):
    from scipy.sparse import diags

    return diags(v, format="csc")


def _line_search(cell, F, w, s, delta):
    """Backtracking on the energy (Armijo), from a step that moves no disk by more than
    ``MAX_STEP`` of the smallest radius sum; near the solution, where energy differences reach
    round-off, a step that lowers the largest force is taken as well."""
    slope = float((s.g * delta).sum())
    r0 = s.residual(cell)
    longest = np.sqrt((delta * delta).sum(axis=1).max())
    alpha = min(1.0, MAX_STEP * cell.R.min() / longest) if longest > 0 else 1.0
    for _ in range(60):
        try:
            trial = ContactState(cell, F, w + alpha * delta)
        except RelaxationError:  # beyond the candidates: a shorter step
            alpha *= 0.5
            continue
        if trial.W <= s.W + 1e-4 * alpha * slope + 1e-13 * abs(s.W):
            return w + alpha * delta, trial
        if trial.residual(cell) < 0.5 * r0 and abs(trial.W - s.W) <= 1e-12 * abs(s.W):
            return w + alpha * delta, trial
        alpha *= 0.5
    raise RelaxationError("the line search found no lower energy")


def condensed_tangent(cell, F, s):
    """(2, 2, 2, 2) condensed tangent at an equilibrium; RigidityLostError without rigidity."""
    use = s.on & s.keep[cell.pi[: s.m]] & s.keep[cell.pj[: s.m]]
    nr = np.flatnonzero(s.keep)
    pinned = int(nr[0])
    dof = -np.ones(cell.n_disks, np.int64)
    dof[nr[1:]] = np.arange(nr.size - 1)
    n = 2 * (nr.size - 1)
    A = _affine(cell, F, s, use)
    if n == 0:
        return A
    H = _matrix(cell, F, s, use, dof, n)
    lu, pd = _factorise(H)
    if not pd:
        raise RigidityLostError(
            f"the non-rattlers' stiffness (disk {pinned} pinned) is not positive definite"
        )
    B = rk.mixed(
        F,
        cell.pi[: s.m],
        cell.pj[: s.m],
        s.qx,
        s.qy,
        s.lx,
        s.ly,
        s.d,
        s.e,
        cell.R[: s.m],
        cell.K,
        use,
        dof,
        n,
    )
    return A - (B.T @ lu.solve(B)).reshape(2, 2, 2, 2)


def _affine(cell, F, s, use):
    """Born part: the Taylor tangent (eqs. 12-13) over the contacts ``use`` at branch Q."""
    acc = np.empty(9)
    X, Y, R = s.qx[use].copy(), s.qy[use].copy(), cell.R[: s.m][use].copy()
    taylor_kernel.moment_sums(F[0, 0], F[0, 1], F[1, 0], F[1, 1], X, Y, R, X.shape[0], True, acc)
    return taylor_tangent(F, acc, cell.K)


def taylor_tangent(F, acc, K):
    """A_abcd = K [F_ae F_cf T_efbd - delta_ac S_bd] (2, 2, 2, 2) from the Taylor kernel's
    moment sums ``acc`` (9,) (S in acc[1:4] by b + d, T in acc[4:9] by e + f + b + d)."""
    S, T = acc[1:4], acc[4:9]
    idx = np.add.outer(np.add.outer(np.arange(2), np.arange(2)), np.arange(2))
    T4 = T[np.add.outer(idx, np.arange(2))]  # T4[e, f, b, d] = T[e + f + b + d]
    S2 = S[np.add.outer(np.arange(2), np.arange(2))]
    A = np.einsum("ae,cf,efbd->abcd", F, F, T4) - np.einsum("ac,bd->abcd", np.eye(2), S2)
    return K * A


def stress(cell, F, s):
    """(W, P (2, 2)) at the contact state s: P = -K F S(Q) over the contacts."""
    on = s.on
    b = s.e[on] / s.d[on]
    qx, qy = s.qx[on], s.qy[on]
    S = np.array(
        [[np.dot(b, qx * qx), np.dot(b, qx * qy)], [np.dot(b, qx * qy), np.dot(b, qy * qy)]]
    )
    return s.W, -cell.K * F @ S


def relax(cell, F, w0, tangent, settings):
    """Relax one cell at F (2, 2) from the fluctuations w0 (N, 2): an :class:`Equilibrium`."""
    w = np.array(w0, dtype=np.float64)
    s = ContactState(cell, F, w)
    shifted_steps = 0
    for it in range(settings.max_iterations + 1):
        if not s.keep.any():
            raise RigidityLostError("no disk has 3 contacts or more (all are rattlers)")
        r = s.residual(cell)
        if r <= settings.force_tol:
            W, P = stress(cell, F, s)
            A = condensed_tangent(cell, F, s) if tangent else None
            network = s.on & s.keep[cell.pi[: s.m]] & s.keep[cell.pj[: s.m]]
            return Equilibrium(
                w,
                W,
                P,
                A,
                np.flatnonzero(s.on),
                np.flatnonzero(network),
                int((~s.keep).sum()),
                it,
                shifted_steps,
                r,
            )
        if it == settings.max_iterations:
            break
        delta, shifted = _step(cell, F, s, settings)
        shifted_steps += shifted
        w, s = _line_search(cell, F, w, s, delta)
    raise RelaxationError(
        f"no equilibrium after {settings.max_iterations} Newton steps (largest net force "
        f"{r:.3g} of the mean contact force)"
    )
