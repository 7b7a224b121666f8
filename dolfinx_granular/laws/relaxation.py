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

from . import relaxed_kernel as rk
from . import relaxed_newton as rn
from . import taylor_kernel
from .relaxed_cell import Cell, ContactState, RelaxationError
from .relaxed_newton import RATTLER_REACH, RESOLVED  # noqa: F401 (the solver's constants)
from .tools import singular_values_2x2

#: FIRE counts the cell as unjammed once its energy falls below this part of the start's
UNJAMMED = 1e-12
#: FIRE steps between two updates of the candidate list
FIRE_CHUNK = 200


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
    """

    force_tol: float = 1e-10
    max_iterations: int = 60
    fire_tol: float = 1e-5
    fire_steps: int = 100_000
    rattler_shift: float = 1e-8
    chord_rate: float = 0.2


@dataclass
class Equilibrium:
    """A relaxed point: fluctuations, energy, stress and (if asked) tangent.

    Attributes:
        w: (N, 2) fluctuations. W: energy (Pa). P: (2, 2) first Piola stress (Pa).
        A: (2, 2, 2, 2) tangent dP/dF (Pa) or None. sensitivity: (N, 2, 4) dw/dF
        (:func:`condensation`) with A, else None. network: candidate indices of the
        contacts between non-rattlers. rattlers: their number. steps: Newton steps (over
        every start), factorisations: of them those that factorised the stiffness (the others
        reused the last factorisation), shifted: of which shifted. fire_steps: FIRE steps
        before Newton took up again (0: Newton alone). residual: largest net force over the
        mean contact force. numeric_factorisations: every factorisation done, the shifted
        tries and the tangent's included; solves: solves for a Newton direction (the
        tangent's one solve for its 4 right-hand sides not counted); trial_states: contact
        states of the line searches.
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
    numeric_factorisations: int = 0
    solves: int = 0
    trial_states: int = 0


#: the compiled loop's counts (:func:`~dolfinx_granular.laws.relaxed_newton.newton`), by their
#: :class:`Equilibrium` names
_COUNTS = ("steps", "factorisations", "shifted", "numeric_factorisations", "solves",
           "trial_states")  # fmt: skip


def _largest(f, disks):
    """max |f_i| over the disks ``disks`` (N,) bool (0 if none)."""
    return float(np.sqrt((f[disks] ** 2).sum(axis=1).max())) if disks.any() else 0.0


def _residual(cell, F, s):
    """Largest net force over the mean contact force at the contact state s."""
    _, f = s.forces(cell, F, s.on)
    return _largest(f, np.ones(cell.n_disks, np.bool_)) / s.force_scale(cell)


def _pattern(cell, pinned, m):
    """The block pattern for the pinned disk and prefix m as the compiled loop takes it
    (``pat``, ``fac``: :mod:`~dolfinx_granular.laws.relaxed_newton`)."""
    p, f, cover = cell.block_pattern(pinned, m)
    pat = (p.pinned, cover, p.n, p.perm, p.Lp, p.Li, p.Rp, p.Rc, p.Rq, p.Ap, p.Ai,
           p.diag_slot, p.pair_slot)  # fmt: skip
    return pat, (f.values, f.Lx, f.D, f.Dinv, f.y)


#: re-entries of the compiled loop (a new pattern, a longer list) before it counts as stuck
_REENTRIES = 100


def _newton(cell, F, w, settings, budget, counts, stall=True):
    """Newton from w until equilibrium (:func:`~dolfinx_granular.laws.relaxed_newton.newton`):
    ``(w, state, residual)``, adding to ``counts`` (6,) (:data:`_COUNTS`); RelaxationError
    after ``budget``
    steps, a failed line search or a shift that never makes the stiffness positive definite."""
    F = np.ascontiguousarray(F, dtype=np.float64)
    w = np.array(w, dtype=np.float64)
    s_min = float(singular_values_2x2(F[None])[1][0])
    solver = np.array([0.0, np.inf, 0.0, np.inf])
    counts[0] = 0  # the step budget is per start; the other counts add up
    key = np.zeros(cell.n_disks, np.bool_)
    request, trial = np.zeros(2, np.int64), np.empty_like(w)
    pat, fac = _pattern(cell, *cell.__dict__.get("_last_request", (0, 0)))
    tol = (settings.force_tol, settings.rattler_shift, settings.chord_rate)
    for _ in range(_REENTRIES):
        status = rn.newton(
            F, s_min, w, *cell.geometry(), *cell.verlet(), *pat, *fac, *tol, budget, stall,
            solver, key, counts, request, trial,
        )  # fmt: skip
        if status == rn.NEED_PATTERN:
            cell._last_request = (int(request[0]), int(request[1]))
            pat, fac = _pattern(cell, *cell._last_request)
        elif status == rn.NEED_LIST:
            cell.grow(F, trial)
            solver[2] = 0.0  # the step is taken again: factorise afresh
        else:
            break
    else:
        raise RelaxationError("the micro solver kept asking for new patterns")
    if status == rn.CONVERGED:
        s = ContactState(cell, F, w, int(request[1]))
        return w, s, float(solver[3])
    if status == rn.NO_CONTACT:
        raise RigidityLostError("no two disks touch (the cell has come apart)")
    if status == rn.NO_EQUILIBRIUM:
        residual = _residual(cell, F, ContactState(cell, F, w))
        raise RelaxationError(
            f"no equilibrium after {counts[0]} Newton steps (largest net force "
            f"{residual:.3g} of the mean contact force)"
        )
    if status == rn.LINE_SEARCH:
        raise RelaxationError("the line search found no lower energy")
    raise RelaxationError("the shifted stiffness never became positive definite")


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
    fire_steps, counts, steps = 0, np.zeros(len(_COUNTS), np.int64), 0
    starts = [w0] if fallback is None else [w0, np.array(fallback, dtype=np.float64)]
    for start in starts:
        try:
            w, s, residual = _newton(cell, F, start, settings, settings.max_iterations, counts)
            break
        except RelaxationError:
            steps += int(counts[0])
            continue
    else:  # FIRE from where Newton last started, not from where it strayed
        w, fire_steps = fire(cell, F, starts[-1], settings)
        w, s, residual = _newton(cell, F, w, settings, settings.max_iterations, counts, False)
    counts[0] += steps
    return _equilibrium(cell, F, w, s, tangent, residual, counts, fire_steps)


def _equilibrium(cell, F, w, s, tangent, residual, counts, fire_steps=0):
    """The :class:`Equilibrium` at the contact state s (``counts``: see :data:`_COUNTS`,
    the tangent's factorisation added here)."""
    if not s.keep.any():
        raise RigidityLostError("no disk has 3 contacts or more (all are rattlers)")
    A, dw = condensation(cell, F, s, counts) if tangent else (None, None)
    W, P = stress(cell, F, s)
    network = np.flatnonzero(s.network)
    n = dict(zip(_COUNTS, (int(c) for c in counts)))
    return Equilibrium(
        w, W, P, A, dw, network, int((~s.keep).sum()), fire_steps=fire_steps,
        residual=residual, **n,
    )  # fmt: skip


def at_rest(cell: Cell, F: np.ndarray, w: np.ndarray, tangent: bool) -> Equilibrium:
    """The :class:`Equilibrium` of disks at rest at F by construction, not relaxed again: a
    committed equilibrium at the same F, or the stress-free packing at F = I (whose contacts
    have overlaps of ~1e-11 of a diameter that mark them, not forces in balance)."""
    s = ContactState(cell, F, w)
    if not s.on.any():
        raise RigidityLostError("no two disks touch (the cell has come apart)")
    w = np.array(w, dtype=np.float64)
    counts = np.zeros(len(_COUNTS), np.int64)
    return _equilibrium(cell, F, w, s, tangent, _residual(cell, F, s), counts)


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
    cell: Cell, F: np.ndarray, s: ContactState, counts: np.ndarray | None = None
) -> tuple:
    """``(A, dw)`` at an equilibrium s: the tangent A (2, 2, 2, 2) and the sensitivities
    dw/dF = -W_ww^-1 W_wF (N, 2, 4) of the fluctuations (F flattened row-major; zero for the
    rattlers and the pinned disk), both from one factorisation of the network's stiffness
    (added to ``counts``, :data:`_COUNTS`, if given); :class:`RigidityLostError` where it is
    not positive definite."""
    A = _affine(cell, F, s)
    N = cell.n_disks
    if s.keep.sum() < 2:  # one non-rattler, pinned: nothing to condense
        return A, np.zeros((N, 2, 4))
    pat, fac = _pattern(cell, int(np.argmax(s.keep)), s.m)
    pd, B, X = rn.network_tangent(
        F,
        s.m,
        s.qx,
        s.qy,
        s.lx,
        s.ly,
        s.d,
        s.e,
        s.keep,
        s.network,
        *cell.geometry(),
        *pat,
        *fac,
        np.zeros(len(_COUNTS), np.int64) if counts is None else counts,
    )
    if not pd:
        raise RigidityLostError(
            "the non-rattlers' stiffness (one disk pinned) is not positive definite"
        )
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
