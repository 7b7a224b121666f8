"""One relaxed point: static equilibrium of a periodic cell at a given F, and what it gives.

Unknowns: the fluctuations w (N, 2) of the disks in the reference frame (x_i = F (X_i + w_i),
:mod:`~dolfinx_granular.laws.relaxed.contact_state`), one disk pinned (the rigid translation).
:func:`relax` runs the compiled Newton loop (:mod:`~dolfinx_granular.laws.relaxed.newton`:
a block L D L^T of the stiffness, a Levenberg-Marquardt shift where the network buckles, chord
steps while the forces fall fast, a backtracking line search on the energy), serves what it
asks for on the way (a block pattern for another pinned disk or a longer prefix of the
candidates, a longer candidate list), and where Newton stalls (far from the equilibrium, where
the network rearranges) lets FIRE (:mod:`~dolfinx_granular.laws.relaxed.fire`) relax the disks
towards it before Newton takes up again. The :class:`Equilibrium` holds the stress and the
condensed tangent there (:mod:`~dolfinx_granular.laws.relaxed.tangent`) and the solver's counts.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from . import newton as rn
from .cell import SKIN, Cell, smallest_stretch
from .contact_state import ContactState
from .errors import CameApart, RelaxationError, RigidityLostError
from .fire import fire
from .settings import Settings
from .tangent import condensation, stress


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
        states of the line searches. floating: the cell has come apart (:func:`floating`).
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
    floating: bool = False


#: the compiled loop's counts (:func:`~dolfinx_granular.laws.relaxed.newton.newton`), by their
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


#: re-entries of the compiled loop (a new pattern, a longer list) before it counts as stuck
_REENTRIES = 100


def _newton(cell, F, w, settings, budget, counts, stall=True):
    """Newton from w until equilibrium (:func:`~dolfinx_granular.laws.relaxed.newton.newton`):
    ``(w, state, residual)``, adding to ``counts`` (6,) (:data:`_COUNTS`); RelaxationError
    after ``budget`` steps, a failed line search or a shift that never makes the stiffness
    positive definite."""
    F = np.ascontiguousarray(F, dtype=np.float64)
    w = np.array(w, dtype=np.float64)
    s_min = float(smallest_stretch(F))
    solver = np.array([0.0, np.inf, 0.0, np.inf])
    counts[0] = 0  # the step budget is per start; the other counts add up
    key = np.zeros(cell.n_disks, np.bool_)
    request, trial = np.zeros(2, np.int64), np.empty_like(w)
    pat, fac = cell.kernel_pattern(*cell.pattern_hint)
    tol = (settings.force_tol, settings.rattler_shift, settings.chord_rate)
    for _ in range(_REENTRIES):
        status = rn.newton(
            F, s_min, w, *cell.geometry(), *cell.verlet(), *pat, *fac, *tol, budget, stall,
            solver, key, counts, request, trial,
        )  # fmt: skip
        if status == rn.NEED_PATTERN:
            cell.pattern_hint = (int(request[0]), int(request[1]))
            pat, fac = cell.kernel_pattern(*cell.pattern_hint)
        elif status == rn.NEED_LIST:
            # at the iterate, so that every trial of its line search stays on the list: each
            # moves a disk by at most MAX_STEP of the smallest radius sum, twice that relative
            # to the mean move (a list grown at the trial sent the next trial off it again)
            cell.grow(F, w, max(SKIN, 4.0 * rn.MAX_STEP) * cell.R.min())
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
    relaxes the cell from there (from w0 without it) before Newton takes up again. Where the
    cell comes apart there (FIRE opens its contacts, or no disk keeps 3 contacts where it and
    Newton came to rest), the result is :func:`floating`. Newton alone is not believed where
    it ends without a network (its steps can carry the disks far, next to a jump): the damped
    motion from the committed positions decides."""
    w0 = np.array(w0, dtype=np.float64)
    fire_steps, counts, steps = 0, np.zeros(len(_COUNTS), np.int64), 0
    starts = [w0] if fallback is None else [w0, np.array(fallback, dtype=np.float64)]
    for start in starts:
        try:
            w, s, residual = _newton(cell, F, start, settings, settings.max_iterations, counts)
            if s.keep.any():
                break
        except RelaxationError:
            pass
        steps += int(counts[0])
    else:  # FIRE from where Newton last started, not from where it strayed
        try:
            w, s, residual, fire_steps = _fire_rounds(cell, F, starts[-1], settings, counts)
        except CameApart as apart:
            return floating(cell, F, apart.w, counts)
        if not s.keep.any():
            return floating(cell, F, w, counts)
    counts[0] += steps
    return _equilibrium(cell, F, w, s, tangent, residual, counts, fire_steps)


def floating(cell: Cell, F: np.ndarray, w: np.ndarray, counts: np.ndarray) -> Equilibrium:
    """The cell come apart at F (a loose cell that collapsed): its disks at w (N, 2) where the
    motion left them, W and P of the overlaps left there (round-off), no tangent, no
    sensitivities (zero: the path goes on from w as it is), no network. A quasi-static path
    goes on from it (:func:`~dolfinx_granular.laws.relaxed.path.follow`); the law raises
    :class:`~dolfinx_granular.laws.relaxed.errors.CellFloats` where the path ends in it."""
    w = np.array(w, dtype=np.float64)
    W, P = stress(cell, F, ContactState(cell, F, w))
    n = dict(zip(_COUNTS, (int(c) for c in counts)))
    return Equilibrium(
        w, W, P, None, np.zeros((cell.n_disks, 2, 4)), np.zeros(0, np.int64), cell.n_disks,
        fire_steps=0, residual=0.0, floating=True, **n,
    )  # fmt: skip


#: rounds of FIRE, then Newton: where Newton fails from FIRE's positions (a nearly floppy
#: network: 70 disks without friction beyond 15 % biaxial strain, a net force of 0.04-0.7 of
#: the mean after 60 steps), FIRE goes on from where it stopped to a thousandth of its last
#: tolerance
FIRE_ROUNDS = 3


def _fire_rounds(cell, F, w, settings, counts) -> tuple:
    """FIRE from w, then Newton, :data:`FIRE_ROUNDS` times: ``(w, state, residual, FIRE
    steps)``; the last round's RelaxationError where all fail.

    Where FIRE runs out of steps, Newton takes its last try from there, without the stall
    limit and for ``settings.final_iterations`` steps: FIRE runs out where it lingers near a
    saddle of the energy (a network that buckles in a rearrangement: 70 disks at p / k_n =
    1e-3, the net forces 2e-5 of the mean for 100,000 steps), whose unstable mode is too soft
    for damped dynamics to leave in time; Newton's shifted steps, doubled while the energy
    falls, leave it along that mode."""
    tol, fire_steps = settings.fire_tol, 0
    for k in range(FIRE_ROUNDS):
        w, steps, converged = fire(cell, F, w, replace(settings, fire_tol=tol))
        fire_steps += steps
        budget = settings.max_iterations if converged else settings.final_iterations
        try:
            return (*_newton(cell, F, w, settings, budget, counts, False), fire_steps)
        except RigidityLostError:
            raise
        except RelaxationError as err:
            if not converged:
                raise RelaxationError(
                    f"FIRE did not relax the cell in {fire_steps} steps, nor Newton from where "
                    f"it stopped: {err}"
                ) from None
            if k == FIRE_ROUNDS - 1:
                raise
            tol = max(1e-3 * tol, settings.force_tol)
    raise AssertionError("unreachable")


def _equilibrium(cell, F, w, s, tangent, residual, counts, fire_steps=0):
    """The :class:`Equilibrium` at the contact state s, which has non-rattlers (where it has
    none, the callers float: :func:`floating`; ``counts``: see :data:`_COUNTS`, the tangent's
    factorisation added here)."""
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
    w = np.array(w, dtype=np.float64)
    counts = np.zeros(len(_COUNTS), np.int64)
    if not s.keep.any():  # (a cell committed where it came apart floats there)
        return floating(cell, F, w, counts)
    return _equilibrium(cell, F, w, s, tangent, _residual(cell, F, s), counts)
