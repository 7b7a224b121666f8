"""The relaxed RVE's micro solver: static equilibrium of one periodic cell at a given F, and the
condensed tangent there.

Unknowns: the fluctuations w (N, 2) of the disks in the reference frame (x_i = F (X_i + w_i),
:mod:`~dolfinx_granular.laws.relaxed_kernel`), one disk pinned (the rigid translation). Newton
minimises the contact energy with a sparse factorisation of the stiffness (a block LDL^T in 2 x 2
blocks, :mod:`~dolfinx_granular.laws.block_ldlt`, on the pattern of the candidate pairs, analysed
once per candidate list; SciPy's SuperLU with ``Settings.factorisation = "superlu"``) and a
backtracking line search on the energy:

* between non-rattlers the stiffness is exact; a contact that touches a rattler (fewer than 3
  contacts, removed recursively) enters by its positive part K n n^T, and the rattlers'
  unknowns get an extra diagonal, their net force over :data:`RATTLER_REACH` mean overlaps
  (a small floor where that is smaller), so that a rattler is pushed out of its overlaps (it
  ends force-free) without flying across its cage, and one without contacts stays where it is;
* where the stiffness is not positive definite (the network buckles: a rearrangement), the step
  is taken on H + mu I (Levenberg-Marquardt, in effect a trust region), mu growing until the
  factorisation is positive definite; the next step tries plain Newton again;
* while the rattlers stay the same and the forces fall fast, the last factorisation is reused
  (a chord step: one solve instead of a factorisation);
* where Newton stalls (far from the equilibrium, where the network rearranges), FIRE (Bitzek et
  al. 2006) relaxes the disks towards it, and Newton takes up again from there.

The rattler set is recomputed at every step (a disk the network presses into joins it). At the
equilibrium the factorisation of the network's stiffness gives the tangent of the relaxed
response,

    A = W_FF - W_Fw W_ww^-1 W_wF,

over the network only (rattlers add nothing), W_FF the Taylor (Born) tangent at the relaxed
branch vectors. Its positive definiteness is the cell's rigidity; without it (or without
non-rattlers) the point fails with a :class:`RigidityLostError`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, diags
from scipy.sparse.linalg import splu

from . import block_ldlt, taylor_kernel
from . import relaxed_kernel as rk
from .relaxed_cell import Cell, ContactState, RelaxationError

#: Newton counts as stalled (FIRE takes over) when after this many steps the largest force is
#: still above this part of the mean contact force
STALLED_AFTER, STALLED_ABOVE = 40, 1e-2
#: FIRE counts the cell as unjammed once its energy falls below this part of the start's
UNJAMMED = 1e-12
#: FIRE steps between two updates of the candidate list
FIRE_CHUNK = 200
#: relative round-off of the energy: a smaller promised decrease is judged by the forces
ROUND_OFF = 1e-12
#: longest move of a disk in one step, relative to the smallest radius sum
MAX_STEP = 0.1
#: equilibrium also when the net forces are within this many times the round-off of the
#: contact forces (:meth:`ContactState.resolution`): near F = I the overlaps are so small
#: that no position resolves a net force of ``force_tol`` (Newton stalls at ~4 times it)
RESOLVED = 30.0
#: a rattler's Newton move is at most about this many mean overlaps: its unknowns are shifted
#: by its net force over that length (a disk squeezed between two partners has no stiffness
#: across them, and one such disk moving far would cut the whole network's line search); the
#: shift stays in a reused factorisation, so that a shorter reach slows the chord steps
RATTLER_REACH = 300.0


class RigidityLostError(RelaxationError):
    """The relaxed cell has no rigid contact network left: no non-rattler disk, or a stiffness
    of the non-rattlers (one disk pinned) that is not positive definite (tension, a buckled
    network)."""


@dataclass
class Settings:
    """Tolerances of the micro solver.

    Attributes:
        force_tol: equilibrium when every disk's net force is at most this times the mean
            contact force, or :data:`RESOLVED` times the round-off of the contact forces
            where that is larger (overlaps below ~1e-5 of the radii).
        max_iterations: Newton steps before FIRE takes over (and again after it).
        fire_tol, fire_steps: FIRE stops at this largest net force relative to the mean
            contact force, or fails after that many steps.
        rattler_shift: least extra diagonal of the rattlers' unknowns, relative to K (a
            rattler without contacts stays where it is).
        chord_rate: a factorisation is reused while the largest force falls at least by this
            factor per step and the contacts stay the same.
        factorisation: ``"block"``, the block LDL^T in 2 x 2 blocks on the candidates' pattern
            (:mod:`~dolfinx_granular.laws.block_ldlt`), or ``"superlu"``, SciPy's SuperLU
            (the earlier solver, kept for comparison).
    """

    force_tol: float = 1e-10
    max_iterations: int = 60
    fire_tol: float = 1e-5
    fire_steps: int = 100_000
    rattler_shift: float = 1e-8
    chord_rate: float = 0.2
    factorisation: str = "block"


@dataclass
class Equilibrium:
    """A relaxed point: fluctuations, energy, stress and (if asked) tangent.

    Attributes:
        w: (N, 2) fluctuations. W: energy (Pa). P: (2, 2) first Piola stress (Pa).
        A: (2, 2, 2, 2) tangent dP/dF (Pa) or None. sensitivity: (N, 2, 4) dw/dF
        (:func:`condensation`) with A, else None. network: candidate indices of the
        contacts between non-rattlers. rattlers: their number. steps: Newton steps,
        factorisations: stiffness factorisations for them, shifted: of which shifted.
        fire_steps: FIRE steps before Newton took up again (0: Newton alone).
        residual: largest net force over the mean contact force.
    """

    w: np.ndarray
    W: float
    P: np.ndarray
    A: np.ndarray | None
    sensitivity: np.ndarray | None
    network: np.ndarray
    rattlers: int
    steps: int
    factorisations: int
    shifted: int
    fire_steps: int
    residual: float


def _largest(f, disks):
    """max |f_i| over the disks ``disks`` (N,) bool (0 if none)."""
    return float(np.sqrt((f[disks] ** 2).sum(axis=1).max())) if disks.any() else 0.0


def _matrix(cell, F, s, use, exact, dof, n):
    """(n, n) CSC stiffness over the contacts ``use`` on the unknowns ``dof``."""
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
    positive definite (every pivot > 0: Sylvester's law of inertia)."""
    try:
        lu = splu(
            H, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
        )
    except RuntimeError:  # exactly singular
        return None, False
    pd = bool(np.array_equal(lu.perm_r, lu.perm_c) and np.all(lu.U.diagonal() > 0.0))
    return lu, pd


class _BlockStiffness:
    """The stiffness in 2 x 2 blocks on the cell's candidate pattern
    (:meth:`Cell.block_pattern`), assembled straight into the pattern's values; the disks with
    no unknowns but the pinned one (the rattlers of the network's stiffness) keep K I alone on
    their diagonal."""

    def __init__(self, cell):
        self.cell, self.factor = cell, None

    def assemble(self, F, s, use, exact, pinned, free):
        """The stiffness over the contacts ``use`` (``exact``: see :func:`_matrix`) on the
        unknowns of the disks ``free`` (N,) bool, ``pinned`` not among them."""
        p, c = self.cell.block_pattern(pinned), self.cell
        if self.factor is None or self.factor.pattern is not p:
            self.values, self.factor = p.zeros(), p.new_factor()
        self.pattern, self.fixed = p, ~free
        block_ldlt.assemble(
            F, c.pi[: s.m], c.pj[: s.m], s.lx, s.ly, s.d, s.e, c.R[: s.m], c.K, use, exact,
            p.diag_slot, p.pair_slot, self.values,
        )  # fmt: skip

    def diagonal(self, shift):
        """The diagonal (n,) of the stiffness plus ``shift`` (N,) on the free unknowns."""
        p = self.pattern
        d = self.values[: p.n][:, [0, 1], [0, 1]] + shift[p.perm, None]
        return d[~self.fixed[p.perm]].ravel()

    def factorise(self, shift=None, mu=0.0):
        """Factorise the stiffness plus ``shift`` (N,) per disk plus mu I; positive definite?"""
        total = np.full(self.cell.n_disks, mu) if shift is None else shift + mu
        total[self.fixed] = self.cell.K
        block_ldlt.factorise(self.pattern, self.values, self.factor, total)
        return self.factor.positive_definite

    def solve(self, b):
        """The last factorisation's solution for b (N, 2, ...), zero at the fixed disks."""
        return block_ldlt.solve(self.factor.pattern, self.factor, b)


class _SuperLUStiffness:
    """The same with SciPy's SuperLU on the free disks' unknowns (:func:`_matrix`)."""

    def __init__(self, cell):
        self.cell, self.lu = cell, None

    def assemble(self, F, s, use, exact, pinned, free):
        self.dof = -np.ones(self.cell.n_disks, np.int64)
        self.dof[free] = np.arange(int(free.sum()))
        self.n = 2 * int(free.sum())
        self.H = _matrix(self.cell, F, s, use, exact, self.dof, self.n)
        self.free = free

    def _shifted(self, shift):
        return self.H + diags(np.repeat(shift[self.free], 2), format="csc")

    def diagonal(self, shift):
        return self._shifted(shift).diagonal()

    def factorise(self, shift=None, mu=0.0):
        H = self.H if shift is None else self._shifted(shift)
        if mu:
            H = H + diags(np.full(self.n, mu), format="csc")
        self.lu, pd = _factorise(H)
        return pd

    def solve(self, b):
        return _scatter(self.lu.solve(_gather(b, self.dof, self.n)), self.dof, b.shape[0])


def _stiffness(cell, settings):
    """The stiffness and its factorisation of ``settings.factorisation``."""
    kind = "block" if settings is None else settings.factorisation
    if kind not in ("block", "superlu"):
        raise ValueError(f"unknown factorisation {kind!r}: 'block' or 'superlu'")
    return _BlockStiffness(cell) if kind == "block" else _SuperLUStiffness(cell)


class _Network:
    """The non-rattlers' exact stiffness at an equilibrium (one disk pinned) and its
    factorisation: the condensation of the tangent and the rigidity test."""

    def __init__(self, cell, F, s, settings=None):
        nr = np.flatnonzero(s.keep)
        self.n = 2 * (nr.size - 1)
        self.stiffness, self.pd = _stiffness(cell, settings), True
        if self.n:
            free = s.keep.copy()
            free[nr[0]] = False
            self.stiffness.assemble(F, s, s.network, s.network, int(nr[0]), free)
            self.pd = self.stiffness.factorise()


class _Stepper:
    """Newton directions on every disk but one pinned non-rattler. An H that is not positive
    definite gets the smallest shift mu I (Levenberg-Marquardt) that makes it so; a
    factorisation is reused (a chord step, damped if it was shifted) while the rattlers stay
    the same and the largest force falls by ``chord_rate`` per step."""

    def __init__(self, cell, settings):
        self.cell, self.settings = cell, settings
        self.stiffness = _stiffness(cell, settings)
        self.key = None
        self.last = np.inf
        self.mu = 0.0  # the last shift that made H positive definite (0: none needed)

    def direction(self, F, s, g, residual):
        """Direction (N, 2) for the gradient g (N, 2) at state s; ``(delta, factorised,
        shifted)``."""
        key = np.packbits(s.keep).tobytes()
        factorised = shifted = False
        if self.key is None or key != self.key or residual > self.settings.chord_rate * self.last:
            shifted = self._factorise(F, s, g)
            factorised, self.key = True, key
        self.last = residual
        return -self.stiffness.solve(g), factorised, shifted

    def _factorise(self, F, s, g):
        """Factorise the stiffness; True if it had to be shifted."""
        cell, st = self.cell, self.stiffness
        pinned = int(np.argmax(s.keep))
        free = np.ones(cell.n_disks, np.bool_)
        free[pinned] = False
        st.assemble(F, s, s.on, s.network, pinned, free)
        shift = np.zeros(cell.n_disks)
        r = np.flatnonzero(~s.keep)
        reach = RATTLER_REACH * s.mean_overlap
        force = np.sqrt((g[r] ** 2).sum(axis=1))
        shift[r] = np.maximum(self.settings.rattler_shift * cell.K, force / reach)
        if st.factorise(shift):
            self.mu = 0.0
            return False
        diag = st.diagonal(shift)
        scale = diag[diag > 0].mean() if np.any(diag > 0) else cell.K
        # the shift a buckling network needs changes little from one step to the next: start
        # a decade below the last one (each try is a factorisation)
        mu = max(1e-8 * scale, 0.1 * self.mu)
        while True:
            if mu > 1e6 * scale:
                raise RelaxationError("the shifted stiffness never became positive definite")
            if st.factorise(shift, mu):
                self.mu = mu
                return True
            mu *= 10.0


def _gather(g, dof, n):
    """The entries of g (N, 2, ...) at the unknowns ``dof`` as (n, ...)."""
    v = np.zeros((n,) + g.shape[2:])
    k = dof >= 0
    v[2 * dof[k]] = g[k, 0]
    v[2 * dof[k] + 1] = g[k, 1]
    return v


def _scatter(v, dof, N):
    """Values (n, ...) on the unknowns ``dof`` as (N, 2, ...), zero at the fixed disks."""
    x = np.zeros((N, 2) + v.shape[1:])
    k = dof >= 0
    x[k, 0] = v[2 * dof[k]]
    x[k, 1] = v[2 * dof[k] + 1]
    return x


def _residual(cell, F, s):
    """Largest net force over the mean contact force at the contact state s."""
    _, f = s.forces(cell, F, s.on)
    return _largest(f, np.ones(cell.n_disks, np.bool_)) / s.force_scale(cell)


def _line_search(cell, F, w, s, delta, g, expand=False):
    """Backtracking (Armijo) on the energy, from a step that moves no disk by more than
    ``MAX_STEP`` of the smallest radius sum; ``(w, state, cut)``, cut the factor the line
    search took off that first step. With ``expand`` (a shifted step, whose length says little)
    a first step that is taken whole is doubled while the energy keeps falling (:func:`_expand`):
    a buckling network leaves its saddle in a few steps, not in many short ones."""
    E0 = s.energy(cell, s.on)
    r0 = _residual(cell, F, s)
    slope = float((g * delta).sum())
    longest = np.sqrt((delta * delta).sum(axis=1).max())
    alpha = first = min(1.0, MAX_STEP * cell.R.min() / longest) if longest > 0 else 1.0
    for _ in range(60):
        try:
            trial = ContactState(cell, F, w + alpha * delta)
        except RelaxationError:  # beyond the candidate list: a shorter step
            alpha *= 0.5
            continue
        E = trial.energy(cell, trial.on)
        if E <= E0 + 1e-4 * alpha * slope:
            if expand and alpha == first:
                return _expand(cell, F, w, delta, alpha, trial, E, longest)
            return w + alpha * delta, trial, alpha / first
        # where the decrease a step promises is below the energy's round-off, the energy
        # cannot tell: take the step if it lowers the largest force
        if -alpha * slope <= ROUND_OFF * abs(E0) and _residual(cell, F, trial) < r0:
            return w + alpha * delta, trial, alpha / first
        alpha *= 0.5
    raise RelaxationError("the line search found no lower energy")


def _expand(cell, F, w, delta, alpha, state, E, longest):
    """Double the step alpha delta (taken, energy E at ``state``) while the energy falls and no
    disk moves by more than ``MAX_STEP`` of the smallest radius sum; ``(w, state, cut)``."""
    first = alpha
    while 2.0 * alpha * longest <= MAX_STEP * cell.R.min():
        try:
            trial = ContactState(cell, F, w + 2.0 * alpha * delta)
        except RelaxationError:
            break
        E2 = trial.energy(cell, trial.on)
        if not E2 < E:
            break
        alpha, state, E = 2.0 * alpha, trial, E2
    return w + alpha * delta, state, alpha / first


def _newton(cell, F, w, settings, budget, stall=True):
    """Newton from w until equilibrium: ``(w, state, residual, steps, factorisations,
    shifted)``; RelaxationError after ``budget`` steps or a failed line search."""
    s = ContactState(cell, F, w)
    stepper = _Stepper(cell, settings)
    steps = factorisations = shifted = 0
    while True:
        if not s.on.any():
            raise RigidityLostError("no two disks touch (the cell has come apart)")
        g, f = s.forces(cell, F, s.on)
        residual = _largest(f, np.ones(cell.n_disks, np.bool_)) / s.force_scale(cell)
        if residual <= max(settings.force_tol, RESOLVED * s.resolution(cell)):
            return w, s, residual, steps, factorisations, shifted
        if steps == budget or (stall and steps >= STALLED_AFTER and residual > STALLED_ABOVE):
            raise RelaxationError(
                f"no equilibrium after {steps} Newton steps (largest net force "
                f"{residual:.3g} of the mean contact force)"
            )
        delta, factorised, was_shifted = stepper.direction(F, s, g, residual)
        w, s, _ = _line_search(cell, F, w, s, delta, g, expand=was_shifted)
        steps, factorisations = steps + 1, factorisations + factorised
        shifted += was_shifted


def relax(
    cell: Cell,
    F: np.ndarray,
    w0: np.ndarray,
    tangent: bool,
    settings: Settings,
    fallback: np.ndarray | None = None,
) -> Equilibrium:
    """Relax one cell at F (2, 2) from the fluctuations w0 (N, 2): an :class:`Equilibrium`.
    Where Newton stalls, it starts again from ``fallback`` (N, 2) if given, and then FIRE
    relaxes the cell from there (from w0 without it) before Newton takes up again."""
    w0 = np.array(w0, dtype=np.float64)
    fire_steps = 0
    starts = [w0] if fallback is None else [w0, np.array(fallback, dtype=np.float64)]
    for start in starts:
        try:
            w, s, residual, steps, factorisations, shifted = _newton(
                cell, F, start, settings, settings.max_iterations
            )
            break
        except RelaxationError:
            continue
    else:  # FIRE from where Newton last started, not from where it strayed
        w, fire_steps = fire(cell, F, starts[-1], settings)
        w, s, residual, steps, factorisations, shifted = _newton(
            cell, F, w, settings, settings.max_iterations, stall=False
        )
    return _equilibrium(
        cell, F, w, s, tangent, settings, residual, steps, factorisations, shifted, fire_steps
    )


def _equilibrium(cell, F, w, s, tangent, settings, residual, *counts):
    """The :class:`Equilibrium` at the contact state s (``counts``: steps, factorisations,
    shifted, fire_steps)."""
    if not s.keep.any():
        raise RigidityLostError("no disk has 3 contacts or more (all are rattlers)")
    A, dw = condensation(cell, F, s, settings) if tangent else (None, None)
    W, P = stress(cell, F, s)
    network = np.flatnonzero(s.network)
    return Equilibrium(w, W, P, A, dw, network, int((~s.keep).sum()), *counts, residual)


def at_rest(
    cell: Cell, F: np.ndarray, w: np.ndarray, tangent: bool, settings: Settings | None = None
) -> Equilibrium:
    """The :class:`Equilibrium` of disks at rest at F by construction, not relaxed again: a
    committed equilibrium at the same F, or the stress-free packing at F = I (whose contacts
    have overlaps of ~1e-11 of a diameter that mark them, not forces in balance); the tangent
    with ``settings.factorisation`` (default: the block LDL^T)."""
    s = ContactState(cell, F, w)
    if not s.on.any():
        raise RigidityLostError("no two disks touch (the cell has come apart)")
    w = np.array(w, dtype=np.float64)
    return _equilibrium(cell, F, w, s, tangent, settings, _residual(cell, F, s), 0, 0, 0, 0)


def fire(cell: Cell, F: np.ndarray, w: np.ndarray, settings: Settings) -> tuple:
    """FIRE on the current positions x = F (X + w) (unit masses, the contact forces) until
    the largest net force is ``settings.fire_tol`` of the mean contact force: ``(w, steps)``.

    The steps run in Numba (:func:`relaxed_kernel.fire_chunk`) in chunks of
    :data:`FIRE_CHUNK`; between chunks the candidate list is brought up to the disks' new
    positions (:meth:`Cell.visited`)."""
    Finv = np.linalg.inv(F)
    u = np.ascontiguousarray(w @ F.T)  # fluctuations in the current frame
    v = np.zeros_like(u)
    params = np.array([0.1 / np.sqrt(cell.K), 0.1, 0.0, 1.0 / np.sqrt(cell.K)])
    s = ContactState(cell, F, w)
    if not s.on.any():
        raise RigidityLostError("the cell unjammed: relaxation opens its contacts")
    E0, steps = s.energy(cell, s.on), 0
    while steps < settings.fire_steps:
        m = cell.visited(F, u @ Finv.T)
        status, taken = rk.fire_chunk(
            F, Finv, u, v, cell.pi, cell.pj, cell.X, cell.Y, cell.R, cell.K, m,
            cell.n_disks, params, min(FIRE_CHUNK, settings.fire_steps - steps),
            settings.fire_tol, E0, UNJAMMED,
        )  # fmt: skip
        steps += taken
        if status == rk.FIRE_UNJAMMED:
            raise RigidityLostError("the cell unjammed: relaxation opens its contacts")
        if status == rk.FIRE_CONVERGED:
            return u @ Finv.T, steps
    raise RelaxationError(f"FIRE did not relax the cell in {settings.fire_steps} steps")


def condensation(
    cell: Cell, F: np.ndarray, s: ContactState, settings: Settings | None = None
) -> tuple:
    """``(A, dw)`` at an equilibrium s: the tangent A (2, 2, 2, 2) and the sensitivities
    dw/dF = -W_ww^-1 W_wF (N, 2, 4) of the fluctuations (F flattened row-major; zero for the
    rattlers and the pinned disk), both from one factorisation of the network's stiffness
    (``settings.factorisation``); :class:`RigidityLostError` where it is not positive
    definite."""
    A = _affine(cell, F, s)
    net = _Network(cell, F, s, settings)
    N = cell.n_disks
    if net.n == 0:
        return A, np.zeros((N, 2, 4))
    if not net.pd:
        raise RigidityLostError(
            "the non-rattlers' stiffness (one disk pinned) is not positive definite"
        )
    # W_wF on every disk's rows (zero but at the non-rattlers; the solve ignores the pinned one)
    B = rk.mixed(
        F, cell.pi[: s.m], cell.pj[: s.m], s.qx, s.qy, s.lx, s.ly, s.d, s.e, cell.R[: s.m],
        cell.K, s.network, np.arange(N, dtype=np.int64), 2 * N,
    ).reshape(N, 2, 4)  # fmt: skip
    X = net.stiffness.solve(B)
    return A - (B.reshape(-1, 4).T @ X.reshape(-1, 4)).reshape(2, 2, 2, 2), -X


def _affine(cell, F, s):
    """Born part: the Taylor tangent (eqs. 12-13) over the network at the branch vectors Q."""
    acc = np.empty(9)
    use = s.network
    X, Y, R = s.qx[use].copy(), s.qy[use].copy(), cell.R[: s.m][use].copy()
    taylor_kernel.moment_sums(F[0, 0], F[0, 1], F[1, 0], F[1, 1], X, Y, R, X.shape[0], True, acc)
    return taylor_tangent(F, acc, cell.K)


def taylor_tangent(F: np.ndarray, acc: np.ndarray, K: float) -> np.ndarray:
    """A_abcd = K [F_ae F_cf T_efbd - delta_ac S_bd] (2, 2, 2, 2) from the Taylor kernel's
    moment sums ``acc`` (9,) (S in acc[1:4] by b + d, T in acc[4:9] by e + f + b + d)."""
    S, T = acc[1:4], acc[4:9]
    i = np.arange(2)
    T4 = T[
        i[:, None, None, None]
        + i[None, :, None, None]
        + i[None, None, :, None]
        + i[None, None, None, :]
    ]
    S2 = S[i[:, None] + i[None, :]]
    A = np.einsum("ae,cf,efbd->abcd", F, F, T4) - np.einsum("ac,bd->abcd", np.eye(2), S2)
    return K * A


def stress(cell: Cell, F: np.ndarray, s: ContactState) -> tuple[float, np.ndarray]:
    """(W, P (2, 2)) at the contact state s: W = K/2 sum e^2 and P = -K F S(Q) over every
    contact (e > 0)."""
    on = s.on
    b = s.e[on] / s.d[on]
    qx, qy = s.qx[on], s.qy[on]
    sxy = np.dot(b, qx * qy)
    S = np.array([[np.dot(b, qx * qx), sxy], [sxy, np.dot(b, qy * qy)]])
    return s.energy(cell, on), -cell.K * F @ S
