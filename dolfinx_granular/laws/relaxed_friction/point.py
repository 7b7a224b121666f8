"""One frictional relaxed point: an increment solved (Newton, its fallbacks), the stress and
tangent there, and the quasi-static path from the committed state to a new F in substeps.

The path is followed in substeps of the right stretch U = (F^T F)^(1/2) at most
``settings.substep`` apart, as the frictionless relaxed RVE's; each substep is one
backward-Euler increment of the contact law from the last one (its tangential forces
committed), so the substep length is part of the model. Every solve starts from the last
positions carried to the new F to first order (the sensitivities of the last tangent; the
rotations also turn with F's polar rotation).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..relaxed.cell import Cell
from ..relaxed.errors import CameApart, RelaxationError, RigidityLostError
from ..relaxed.path import stretches_between
from .cell_state import CellState, Increment, Springs, overlap_ratio
from .fire import fire, settle
from .newton import Counts, solve
from .path_tangent import Chain, stretch_derivative
from .settings import Settings
from .tangent import path_condensation

#: the shortest substep, relative to ``Settings.substep``
MIN_SUBSTEP = 1e-2
#: a committed force cut to a lowered cap by more than this part of the mean contact force
#: (a committed moment: times the mean radius) puts the point out of equilibrium
#: (:func:`within_cones`); the same law cuts none by more than round-off
CONE_SLACK = 1e-9
#: rounds of the fallback (each ``Settings.fire_steps`` FIRE steps from where the last ended,
#: then Newton): FIRE's last approach to a stiff cell's equilibrium is slow (200 disks at
#: p / k_n = 1e-3: a residual of 4e-4 after 20,000 steps, 1e-5 after 400,000), and Newton
#: takes over from a state that one round may not yet reach
FIRE_ROUNDS = 5
#: ``tangent`` of :func:`relax` and :func:`finish` beside False (P alone) and True (A and the
#: predictor's sensitivities too): those and the solution's :class:`Chain`, which a later
#: substep of the path starts from
CHAINED = 2


@dataclass
class Equilibrium:
    """A frictional relaxed point at F after its increment.

    Attributes:
        w: (N, 2) fluctuations; theta: (N,) rotations; W: stored energy (Pa); P: (2, 2);
        A: (2, 2, 2, 2) or None; sensitivity: (N, 3, 4) d(w, theta)/dF or zeros;
        state: the :class:`CellState` (contacts, forces, statuses); dissipated: the energy the
        increment dissipated (Pa); residual: the largest net force or moment over the mean
        contact force (and radius); counts: the solver's :class:`Counts`; chain: the
        solution's derivatives with respect to the path's end (with A; :mod:`.path_tangent`);
        rested: the committed state itself (:func:`at_rest`), nothing solved.
        floating: the cell has come apart (no disk keeps two contacts): its disks float at P
            of round-off, A None, no sensitivities, no chain (:func:`follow` goes on from it
            along the path; the law raises where the path ends in it).
    """

    w: np.ndarray
    theta: np.ndarray
    W: float
    P: np.ndarray
    A: np.ndarray | None
    sensitivity: np.ndarray
    state: CellState
    dissipated: float
    residual: float
    counts: Counts
    chain: Chain | None = None
    rested: bool = False
    floating: bool = False


def polar_angle(F) -> float:
    """The angle of F's polar rotation, atan2(F21 - F12, F11 + F22)."""
    return float(np.arctan2(F[1, 0] - F[0, 1], F[0, 0] + F[1, 1]))


def carried(w, th, Fc, F):
    """(w, th) at Fc carried to F at fixed fluctuations: the rotations turned by F's polar
    rotation."""
    return w, th + polar_angle(F) - polar_angle(Fc)


def predicted(w, th, dq, Fc, F):
    """(w, th) at Fc carried to F: the sensitivities dq (N, 3, 4) times the rotation-free
    increment dF_C = Fc^-T (C - C_c) / 2 added to :func:`carried`."""
    dF = 0.5 * np.linalg.solve(Fc.T, F.T @ F - Fc.T @ Fc)
    move = dq.reshape(-1, 4) @ dF.ravel()
    move = move.reshape(-1, 3)
    return carried(w + move[:, :2], th + move[:, 2], Fc, F)


def relax(cell: Cell, springs: Springs, G, DG, inc: Increment, dq, settings: Settings,
          tangent: int) -> Equilibrium:  # fmt: skip
    """The equilibrium of the increment from ``inc`` to G (2, 2) (dG/dF = DG (4, 4), F the
    path's end): Newton from the predicted start. Where it fails, pseudo-transient
    continuation (:mod:`.pseudo_time`: implicit damped steps that lower the increment's
    potential) from the committed positions and rotations carried to G (turned by its polar
    rotation), then from the predicted start; where that fails too, FIRE relaxes the cell
    under the same increment from there to ``settings.fire_tol`` and Newton goes on; where
    Newton fails again, FIRE goes on (to a thousandth of its tolerance where it reached it),
    :data:`FIRE_ROUNDS` times in all. The fallbacks solve the same increment: they do not
    change the path, so the answer stays the model's (a halved increment would commit a
    midpoint, another path, and make P jump with F where Newton's success does). Where the
    increment has no equilibrium they find, the cell rearranges (:func:`rearranged`): a dynamic
    event, the friction integrated along it.

    A cell may come apart (a loose frictional cell that collapses: no disk keeps two
    contacts). Where Newton from the predicted start ends so, only the continuation from the
    committed positions is believed; where that or the damped motion ends so, the result is
    ``floating`` (:class:`Equilibrium`): the disks where the motion left them, no stress."""
    counts = Counts()
    try:
        done, start = _solved(cell, springs, G, DG, inc, dq, settings, tangent, counts)
        if done is not None:
            return done
        return _damped(cell, springs, G, DG, inc, *start, settings, tangent, counts)
    except CameApart as apart:
        s = CellState(cell, springs, G, apart.w, apart.th, inc)
        return finish(cell, springs, G, DG, inc, apart.w, apart.th, s, 0.0, counts, tangent)


def _solved(cell, springs, G, DG, inc, dq, settings, tangent, counts) -> tuple:
    """Newton from the predicted start, then the continuation from the committed positions
    carried to G and from the predicted start: ``(Equilibrium or None, the (w, th) FIRE
    starts from where none was found)``."""
    w, th = predicted(inc.w0, inc.th0, dq, inc.F0, G)
    # (the continuation relaxes the cell first from its last equilibrium carried to G: the
    # predictor extrapolates soft modes far, and damped motion from there is the physical
    # relaxation; then from the predicted start)
    starts = [carried(inc.w0, inc.th0, inc.F0, G), (w, th)]
    lost = False
    try:
        done = _newton(cell, springs, G, DG, inc, w, th, settings, counts, tangent)
    except RigidityLostError:
        done, lost = None, True
    if done is not None and not done.floating:
        return done, None
    if lost or done is not None:
        # (next to a jump the sensitivities are huge: the predicted start can lie so far off
        # that Newton ends in a cell come apart; only damped motion from the committed
        # positions tells whether it does)
        starts = starts[:1]
    for w, th in starts:
        done = _newton(cell, springs, G, DG, inc, w, th, settings, counts, tangent, True)
        if done is not None:
            return done, None
    return None, (w, th)


def _damped(cell, springs, G, DG, inc, w, th, settings, tangent, counts) -> Equilibrium:
    """FIRE from (w, th) and Newton from where it stops, :data:`FIRE_ROUNDS` times; then the
    rearrangement."""
    tol = settings.fire_tol
    for _ in range(FIRE_ROUNDS):
        w, th, steps, converged = fire(
            cell, springs, G, w, th, inc, replace(settings, fire_tol=tol)
        )
        counts.fire_steps += steps
        done = _newton(cell, springs, G, DG, inc, w, th, settings, counts, tangent)
        if done is not None:
            return done
        if converged:  # (Newton failed from there: FIRE goes closer)
            tol = max(1e-3 * tol, settings.force_tol)
    return rearranged(cell, springs, G, DG, w, th, inc, settings, counts, tangent)


def rearranged(cell, springs, G, DG, w, th, inc, settings, counts, tangent) -> Equilibrium:
    """The equilibrium at G where the increment from ``inc`` has none that the solvers find:
    the cell rearranges from (w, th) as a DEM cell does (:func:`.fire.settle`), and Newton
    (then the continuation) finishes from where it came to rest, an increment of no strain
    from that state committed; where both fail there (contacts at their caps, whose statuses
    flip), the cell settles closer, to a thousandth of the last tolerance, :data:`FIRE_ROUNDS`
    times in all. Its ``dissipated`` is all the event released (no work is done at the fixed
    G)."""
    base, available, steps = settle(cell, springs, G, w, th, inc, settings)
    counts.fire_steps += steps
    counts.rearrangements += 1
    tol = settings.fire_tol
    for _ in range(FIRE_ROUNDS):
        for pseudo in (False, True):
            done = _newton(cell, springs, G, DG, base, base.w0, base.th0, settings, counts,
                           tangent, pseudo)  # fmt: skip
            if done is not None:
                done.dissipated = available - done.W
                return done
        tol = max(1e-3 * tol, settings.force_tol)
        base, _, steps = settle(cell, springs, G, base.w0, base.th0, base,
                                replace(settings, fire_tol=tol))  # fmt: skip
        counts.fire_steps += steps
    raise RelaxationError(
        f"no equilibrium: Newton failed where the rearranged cell came to rest (after "
        f"{counts.fire_steps} FIRE steps)"
    )


def _newton(cell, springs, G, DG, inc, w, th, settings, counts, tangent, pseudo=False):
    """The :class:`Equilibrium` Newton (``pseudo``: pseudo-transient continuation) reaches from
    (w, th), or None where it fails."""
    try:
        found = solve(cell, springs, G, w, th, inc, settings, counts, pseudo)
    except RigidityLostError:
        raise
    except RelaxationError:
        return None
    return finish(cell, springs, G, DG, inc, *found, counts, tangent)


def finish(cell, springs, G, DG, inc, w, th, s, residual, counts, tangent) -> Equilibrium:
    """The :class:`Equilibrium` at the solved state s of the increment to G."""
    A, dq, chain = None, np.zeros((cell.n_disks, 3, 4)), None
    if s.apart:  # (no network to condense: the disks float)
        W, D = s.energies(cell, springs)
        return Equilibrium(w, th, W, s.P, A, dq, s, D, residual, counts, floating=True)
    if tangent:
        A, dq, chain = path_condensation(cell, springs, G, s, inc, inc.chain, DG,
                                         chained=tangent == CHAINED)  # fmt: skip
    W, D = s.energies(cell, springs)
    return Equilibrium(w, th, W, s.P, A, dq, s, D, residual, counts, chain)


def at_rest(cell: Cell, springs: Springs, F, inc: Increment, s: CellState,
            tangent: bool) -> Equilibrium:  # fmt: skip
    """The committed state itself (F = F0), ``s`` from :func:`rest_state`: nothing moves, every
    contact's trial force is its committed one (a contact at the cone sticks there)."""
    residual, _ = s.residual(cell)
    eq = finish(cell, springs, F, np.eye(4), inc, inc.w0, inc.th0, s, residual, Counts(),
                tangent)  # fmt: skip
    eq.rested = True
    return eq


def rest_state(cell: Cell, springs: Springs, F, inc: Increment) -> CellState:
    """The committed positions and rotations of ``inc`` at F, each contact's trial force its
    committed one (cut to the law's cap)."""
    return CellState(cell, springs, F, inc.w0, inc.th0, inc)


def within_cones(s: CellState, inc: Increment, mean_radius: float) -> bool:
    """True where the committed tangential forces and rolling moments of ``inc`` lie in the
    cones of the law at rest (``s`` from :func:`rest_state`): none was cut to its cap by more
    than :data:`CONE_SLACK` of the mean contact force (times ``mean_radius`` for a moment).
    False once the friction was lowered below what the committed state carries: it is no
    longer in equilibrium and must be relaxed at its F."""
    on, m = s.on, s.m
    slack = CONE_SLACK * s.mean_force
    ft0, mr0 = inc.forces(m)[:m], inc.moments(m)[:m]
    if np.any(np.abs(ft0[on]) - np.abs(s.ft[on]) > slack):
        return False
    return not np.any(np.abs(mr0[on]) - np.abs(s.mr[on]) > slack * mean_radius)


def committed(cell: Cell, eq: Equilibrium, F) -> Increment:
    """The next substep's committed side: this equilibrium's positions, tangential forces and
    rolling moments (those of open contacts dropped), with their derivatives."""
    ft, mr = np.zeros(cell.pi.shape[0]), np.zeros(cell.pi.shape[0])
    on = eq.state.on
    ft[: on.shape[0]][on] = eq.state.ft[on]
    mr[: on.shape[0]][on] = eq.state.mr[on]
    return Increment(np.array(F, dtype=np.float64), eq.w, eq.theta, ft, eq.chain, mr)


def follow(cell: Cell, springs: Springs, F, inc: Increment, dq, settings: Settings,
           tangent: bool) -> tuple[Equilibrium, float]:  # fmt: skip
    """The equilibrium at F reached from ``inc`` along the quasi-static path, and the energy
    dissipated on the way (Pa); its A is the derivative of P at F through the path. Where the
    path ends in a cell come apart, the equilibrium is ``floating`` (the law raises
    :class:`~dolfinx_granular.laws.relaxed.errors.CellFloats` on it)."""
    dissipated = 0.0
    stretches = stretches_between(inc.F0, F, substep(cell, springs, inc, F, settings))
    dU = stretch_derivative(F) if len(stretches) else None  # (one substep: not needed)
    for k, Uk in enumerate(stretches, start=1):
        eq = relax(cell, springs, Uk, k / (len(stretches) + 1) * dU, inc, dq, settings, CHAINED)
        dissipated += eq.dissipated
        inc, dq = committed(cell, eq, Uk), eq.sensitivity
    eq = relax(cell, springs, F, np.eye(4), inc, dq, settings, tangent)
    return eq, dissipated + eq.dissipated


def substep(cell: Cell, springs: Springs, inc: Increment, F, settings: Settings) -> float:
    """The path's longest substep from the committed state ``inc`` to F: ``settings.substep``,
    and ``settings.substep_overlap`` times the mean overlap over the mean radius sum (the
    larger of the committed state's and of its positions carried to F: a stress-free start
    takes the target's), but at least :data:`MIN_SUBSTEP` of ``settings.substep``."""
    ratio = 0.0
    for G in (inc.F0, F):
        G = np.ascontiguousarray(G, dtype=np.float64)
        m = cell.visited(G, inc.w0)
        ratio = max(ratio, overlap_ratio(G, inc.w0, cell.pi, cell.pj, cell.X, cell.Y, cell.R, m))
    if ratio == 0.0:
        return settings.substep
    # (a floor: near a stress-free packing the overlaps are ~1e-11 of the radii)
    return min(
        settings.substep, max(settings.substep_overlap * ratio, MIN_SUBSTEP * settings.substep)
    )
