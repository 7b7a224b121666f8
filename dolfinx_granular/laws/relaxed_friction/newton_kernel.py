"""The frictional relaxed micro Newton loop, compiled: the steps of
:func:`~dolfinx_granular.laws.relaxed_friction.newton.solve` (the return map, the residual, the
Jacobian on the block LU, the line search on the squared residual, chord steps, the cone's edge,
stall detection) without Python between them.

Where the candidate list must grow (a disk moved past its Verlet skin) or a contact lies beyond
the block pattern's prefix, it hands back to :func:`run`, which grows the list or takes a
longer pattern and goes on from the last iterate.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..relaxed.cell import SKIN, smallest_stretch
from ..relaxed.newton import visited
from ..tools import chunks
from .block_lu import BlockLU, assemble, numeric, refined_solve
from .cell_state import RATTLER_REACH, RATTLER_SHIFT, diagonal, equilibrium_residual, holding
from .contact_law import OPEN, SLIP, STICK, return_map
from .rolling import radius
from .system import EXACT, SKIPPED, balance, forces, jacobian_blocks

#: longest move of a disk in one step (its centre, or its surface by turning), relative to the
#: smallest radius sum
MAX_STEP = 0.1
#: a contact whose trial force is within this part of its cap of the cone's edge can take
#: either side's Jacobian: where no step on the Jacobian lowers the residual, the step is
#: tried again with those contacts' other side
EDGE = 0.05
#: Newton counts as stalled where its residual fell by less than STALL_RATE over the last
#: STALL_STEPS steps
STALL_STEPS, STALL_RATE = 4, 0.5
#: a step that cut the residual to below this part takes the next on the same factorisation
#: (a chord step) while no contact has changed its status since it
CHORD_RATE = 0.1
#: below this residual a chord step is tried even where contacts have changed their status
#: since the factorisation: those left to change lie near their cone's edge, where the two
#: sides' Jacobians give nearly the same step
CHORD_NEAR = 1e-5

#: what :func:`newton` ends with
CONVERGED, FAILED, RIGIDITY_LOST, HAND_BACK = 0, 1, 2, 3
#: why it failed (``FAILED``) or handed back (``HAND_BACK``)
STALLED, NO_DESCENT, GROW_LIST, BEYOND_PATTERN, SINGULAR_PIVOT = 1, 2, 3, 4, 5


@njit(cache=True)
def cell_state(F, w, th, inc, cell, springs, m):
    """The return map and balance at (F, w, theta) over the first m candidates, as
    :class:`~dolfinx_granular.laws.relaxed_friction.cell_state.CellState`: ``(qx, qy, lx, ly,
    d, e, ft, fstar, status, keep, f, M, mean_force, count, r, mr, mstar, rstatus)``."""
    F0, w0, th0, ft0, mr0 = inc
    pi, pj, X, Y, R, radii = cell
    kn, kt, mu, inv_area, kr, mu_r = springs
    N = radii.shape[0]
    qx, qy, lx, ly, d, e, ft, fstar, status, mr, mstar, rstatus = return_map(
        F, w, th, F0, w0, th0, ft0, mr0, pi, pj, X, Y, R, radii, m, kn, kt, mu, kr, mu_r
    )
    keep = holding(pi, pj, e, N)
    f, M, mean_force, count = balance(pi, pj, lx, ly, d, e, ft, mr, R, radii, kn, N)
    r, _ = forces(F, qx, qy, lx, ly, d, e, ft, status, mr, rstatus, pi, pj, R, radii, kn,
                  inv_area, N)  # fmt: skip
    return (qx, qy, lx, ly, d, e, ft, fstar, status, keep, f, M, mean_force, count, r, mr, mstar,
            rstatus)  # fmt: skip


@njit(cache=True)
def residual(s, R, radii):
    """``(residual, floor)`` of a :func:`cell_state`, as ``CellState.residual``."""
    e, status, f, M, mean_force, count = s[5], s[8], s[10], s[11], s[12], s[13]
    return equilibrium_residual(f, M, mean_force, count, e, status, R, radii)


@njit(cache=True)
def merit(s, held, mean_radius):
    """Half the squared residual, the rotations' rows over the mean radius, the held out."""
    r = s[14]
    total = 0.0
    for k in range(r.shape[0]):
        for a in range(3):
            if not held[3 * k + a]:
                v = r[k, a] / mean_radius if a == 2 else r[k, a]
                total += v * v
    return 0.5 * total


@njit(cache=True)
def step_limit(F, dq, radii, R_min, max_step):
    """The largest step length <= 1 along dq (N, 3) that moves no disk's centre nor its
    surface by turning by more than ``max_step`` of the smallest radius sum."""
    big = 0.0
    for k in range(dq.shape[0]):
        ux = F[0, 0] * dq[k, 0] + F[0, 1] * dq[k, 1]
        uy = F[1, 0] * dq[k, 0] + F[1, 1] * dq[k, 1]
        big = max(big, np.sqrt(ux * ux + uy * uy), abs(dq[k, 2]) * radii[k])
    return min(1.0, max_step * R_min / big) if big > 0.0 else 1.0


@njit(cache=True)
def factorise(F, s, cell, springs, pattern, lu, edge, tangent, free_rotation, shift=0.0):
    """The Jacobian at s assembled and factorised on the block LU: ``(code, held (3N,),
    statuses (2m,): the sliding's, then the rolling's)``, code 0, BEYOND_PATTERN or
    SINGULAR_PIVOT. Newton's (``tangent`` False): every
    contact, contacts near the cone's edge within ``edge`` of their cap taking the other side's,
    the pinned disk's translation held. The tangent's: the network's contacts, the rattlers'
    unknowns held too. ``free_rotation`` scales the diagonal of the rotations no sticking contact
    holds (:func:`~dolfinx_granular.laws.relaxed_friction.cell_state.diagonal`). ``shift`` adds
    ``shift`` k_n / V to every translation's diagonal and ``shift`` k_n r^2 / V to every
    rotation's (the pseudo-time steps of :mod:`.pseudo_time`)."""
    pi, pj, X, Y, R, radii = cell
    kn, kt, mu, inv_area, kr, mu_r = springs
    n, _, diag_slot, pair_slot, pair_flip, cover, Ap, Ai, Lp, Li, Rp, Rc, Rq = pattern
    values, Lx, Ux, Dinv = lu
    qx, qy, lx, ly, d, e, ft, fstar, status, keep, _, _, _, _, r, mr, mstar, rstatus = s
    N, m = radii.shape[0], status.shape[0]
    rcaps = _rolling_caps(pi, pj, radii, e, kn, mu_r)
    status = _edge_flipped(status, fstar, mu * kn * e, edge)
    rstatus = _edge_flipped(rstatus, mstar, rcaps, edge)
    statuses = np.concatenate((status, rstatus))
    network = np.zeros(m, np.bool_)
    mode = np.full(m, EXACT, np.int8)
    sum_e, n_on = 0.0, 0
    for c in range(m):
        network[c] = status[c] != OPEN and keep[pi[c]] and keep[pj[c]]
        if status[c] != OPEN:
            sum_e += e[c]
            n_on += 1
            if tangent and not network[c]:
                mode[c] = SKIPPED
            elif c >= cover:
                return BEYOND_PATTERN, np.zeros(3 * N, np.bool_), statuses
    contacts = np.flatnonzero((status != OPEN) & (mode == EXACT))
    K = jacobian_blocks(F, lx, ly, d, e, ft, status, mr, rstatus, pi, pj, R, radii, kn, kt, mu,
                        kr, mu_r, inv_area, contacts)  # fmt: skip
    pinned = np.argmax(keep)
    reach = RATTLER_REACH * sum_e / n_on
    diag = diagonal(status, rstatus, network, keep, pi[:m], pj[:m], radii, r, fstar, mstar, e,
                    kn, kt, mu, kr, mu_r, inv_area, pinned, reach, RATTLER_SHIFT, tangent,
                    free_rotation)  # fmt: skip
    if shift > 0.0:
        for k in range(N):
            diag[3 * k] += shift * kn * inv_area
            diag[3 * k + 1] += shift * kn * inv_area
            diag[3 * k + 2] += shift * kn * inv_area * radii[k] ** 2
    held = np.zeros(3 * N, np.bool_)
    held[3 * pinned] = held[3 * pinned + 1] = True
    if tangent:
        for k in range(N):
            if not keep[k]:
                held[3 * k] = held[3 * k + 1] = held[3 * k + 2] = True
    assemble(n, diag_slot, pair_slot, pair_flip, pi, pj, contacts, K, held,
             diag, values)  # fmt: skip
    if not numeric(n, Ap, Ai, values, Lp, Li, Rp, Rc, Rq, Lx, Ux, Dinv):
        return SINGULAR_PIVOT, held, statuses
    return 0, held, statuses


@njit(cache=True)
def _rolling_caps(pi, pj, radii, e, kn, mu_r):
    """(m,) the rolling moments' caps mu_r r_eff k_n e (:mod:`.rolling`)."""
    caps = np.zeros(e.shape[0])
    if mu_r > 0.0:
        for c in range(e.shape[0]):
            caps[c] = mu_r * radius(radii[pi[c]], radii[pj[c]]) * kn * max(e[c], 0.0)
    return caps


@njit(cache=True, inline="always")
def _at_edge(status, trial, cap, edge):
    """A sticking or slipping spring whose trial force (or moment) lies within ``edge`` of its
    cap from the cap's edge."""
    return (status == STICK or status == SLIP) and abs(abs(trial) - cap) <= edge * cap


@njit(cache=True)
def _edge_flipped(status, trial, caps, edge):
    """A copy of the statuses, the springs :func:`_at_edge` turned to the other side (none
    for edge = 0)."""
    out = status.copy()
    if edge > 0.0:
        for c in range(status.shape[0]):
            if _at_edge(status[c], trial[c], caps[c], edge):
                out[c] = SLIP if status[c] == STICK else STICK
    return out


def cell_arrays(cell) -> tuple:
    """The cell's candidates as the compiled loop takes them: ``(pi, pj, X, Y, R, radii)``."""
    return cell.pi, cell.pj, cell.X, cell.Y, cell.R, cell.radii


def spring_arrays(springs) -> tuple:
    """``(k_n, k_t, mu, 1 / V, kr, mu_r)``."""
    return springs.kn, springs.kt, springs.mu, springs.inv_area, springs.kr, springs.mu_r


def pattern_arrays(p, cover) -> tuple:
    """A 3 x 3 block pattern (on the first ``cover`` candidates) as the compiled loop takes
    it."""
    return (p.n, p.perm, p.diag_slot, p.pair_slot, p.pair_flip, cover, p.Ap, p.Ai, p.Lp, p.Li,
            p.Rp, p.Rc, p.Rq)  # fmt: skip


@njit(cache=True)
def direction(s, held, pattern, lu):
    """The Newton direction (N, 3) of the residual at s on the factorisation."""
    n, perm, _, _, _, _, Ap, Ai, Lp, Li, _, _, _ = pattern
    values, Lx, Ux, Dinv = lu
    r = s[14]
    N = r.shape[0]
    b = np.empty((N, 3, 1))
    for k in range(N):
        for a in range(3):
            b[k, a, 0] = 0.0 if held[3 * k + a] else r[k, a]
    x = np.zeros_like(b)
    refined_solve(n, perm, Ap, Ai, Lp, Li, values, Lx, Ux, Dinv, b, x)
    return -x[:, :, 0]


@njit(cache=True)
def line_search(F, F_smin, w, th, s, dq, held, inc, cell, springs, geo, verlet):
    """Backtracking on the squared residual along dq: ``(code, w, th, state)``, code 0 (found),
    NO_DESCENT or GROW_LIST (the trial (w, th) returned needs a longer candidate list)."""
    pi, pj, X, Y, R, radii = cell
    mean_radius = radii.mean()
    phi0 = merit(s, held, mean_radius)
    alpha = step_limit(F, dq, radii, geo[9], MAX_STEP)
    finite = np.isfinite(dq).all()
    for _ in range(30 if finite else 0):
        wt = w + alpha * dq[:, :2]
        tt = th + alpha * dq[:, 2]
        m = visited(F_smin, wt, geo, verlet)
        if m < 0:
            return GROW_LIST, wt, tt, s
        trial = cell_state(F, wt, tt, inc, cell, springs, m)
        if merit(trial, held, mean_radius) <= (1.0 - 2e-4 * alpha) * phi0:
            return 0, wt, tt, trial
        alpha *= 0.5
    return NO_DESCENT, w, th, s


@njit(cache=True)
def _same(a, b):
    """a and b (int8 arrays) have the same length and entries."""
    if a.shape[0] != b.shape[0]:
        return False
    for c in range(a.shape[0]):
        if a[c] != b[c]:
            return False
    return True


@njit(cache=True)
def _near_edge(s, cell, springs, edge):
    """Some sticking or slipping contact of s has its trial force (or rolling moment) within
    ``edge`` of its cap from the cap's edge."""
    e, fstar, status, mstar, rstatus = s[5], s[7], s[8], s[16], s[17]
    kn, _, mu, _, _, mu_r = springs
    rcaps = _rolling_caps(cell[0], cell[1], cell[5], e, kn, mu_r)
    for c in range(status.shape[0]):
        if _at_edge(status[c], fstar[c], mu * kn * e[c], edge) or _at_edge(
            rstatus[c], mstar[c], rcaps[c], edge
        ):
            return True
    return False


@njit(cache=True)
def _statuses(s):
    """(2m,) the sliding statuses of a cell state, then the rolling ones."""
    return np.concatenate((s[8], s[17]))


@njit(cache=True)
def newton(F, F_smin, w, th, inc, cell, springs, geo, verlet, pattern, lu, force_tol,
           max_iterations, history, counts):  # fmt: skip
    """Newton from (w, th) as :func:`~dolfinx_granular.laws.relaxed_friction.newton.solve`:
    ``(code, why, w, th, w_reached)``: (w, th) the last iterate, w_reached the furthest
    positions tried (where the list must grow: GROW_LIST), the residuals in ``history``
    (``counts[3]`` of them) and ``counts`` (4,) += steps, factorisations, chord steps. A block
    pivot that is singular counts as no factorisation there (the step at the cone's edge, else
    NO_DESCENT, is tried)."""
    pi, pj, X, Y, R, radii = cell
    if inc[3].shape[0] < pi.shape[0] or inc[4].shape[0] < pi.shape[0]:
        raise ValueError(
            "a committed tangential force (or rolling moment) is missing for a candidate contact"
        )
    m = visited(F_smin, w, geo, verlet)
    if m < 0:
        return HAND_BACK, GROW_LIST, w, th, w
    s = cell_state(F, w, th, inc, cell, springs, m)
    chord, chord_status, chord_held = False, _statuses(s), np.zeros(3 * radii.shape[0], np.bool_)
    first = counts[3]  # (the stall test looks at this call's residuals only)
    for step in range(max_iterations + 1):
        if s[13] == 0:
            return RIGIDITY_LOST, 0, w, th, w
        res, floor = residual(s, R, radii)
        nh = counts[3]
        history[nh] = res
        counts[3] += 1
        if res <= max(force_tol, floor):
            return CONVERGED, 0, w, th, w
        if step == max_iterations or (
            nh - first >= STALL_STEPS and res > STALL_RATE * history[nh - STALL_STEPS]
        ):
            return FAILED, STALLED, w, th, w
        code, wt, tt, trial = NO_DESCENT, w, th, s
        if chord and (res <= CHORD_NEAR or _same(chord_status, _statuses(s))):
            dq = direction(s, chord_held, pattern, lu)
            code, wt, tt, trial = line_search(F, F_smin, w, th, s, dq, chord_held, inc, cell,
                                              springs, geo, verlet)  # fmt: skip
            counts[2] += code == 0
        for edge in (0.0, EDGE):
            if code != NO_DESCENT or (edge > 0.0 and not _near_edge(s, cell, springs, edge)):
                break
            why, held, status = factorise(F, s, cell, springs, pattern, lu, edge, False, 1.0)
            if why == BEYOND_PATTERN:
                return HAND_BACK, why, w, th, w
            if why == SINGULAR_PIVOT:
                continue
            counts[1] += 1
            dq = direction(s, held, pattern, lu)
            code, wt, tt, trial = line_search(F, F_smin, w, th, s, dq, held, inc, cell, springs,
                                              geo, verlet)  # fmt: skip
            chord, chord_status, chord_held = True, status, held
        if code == GROW_LIST:
            return HAND_BACK, GROW_LIST, w, th, wt
        if code != 0:
            return FAILED, NO_DESCENT, w, th, w
        if residual(trial, R, radii)[0] > CHORD_RATE * res:
            chord = False  # (a chord step would converge slowly: factorise at the next)
        w, th, s = wt, tt, trial
        counts[0] += 1
    return FAILED, STALLED, w, th, w


@njit(cache=True)
def newton_entry(F, F_smin, w, th, inc0, inc1, cell0, cell1, springs, geo0, geo1, geo2,
                 verlet, pat0, pat1, pat2, pat3, lu, force_tol, max_iterations, history,
                 counts):  # fmt: skip
    """:func:`newton` from Python: its long tuples in chunks (:func:`~dolfinx_granular.laws.
    tools.chunks`: the increment's 5 arrays, the cell's 6, the geometry's 12, the pattern's
    13)."""
    return newton(F, F_smin, w, th, inc0 + inc1, cell0 + cell1, springs, geo0 + geo1 + geo2,
                  verlet, pat0 + pat1 + pat2 + pat3, lu, force_tol, max_iterations, history,
                  counts)  # fmt: skip


@njit(cache=True)
def factorise_entry(F, s0, s1, s2, s3, s4, cell0, cell1, springs, pat0, pat1, pat2, pat3, lu,
                    edge, tangent, free_rotation):  # fmt: skip
    """:func:`factorise` from Python: the cell state's 18 arrays, the cell's 6 and the
    pattern's 13 in chunks (:func:`~dolfinx_granular.laws.tools.chunks`)."""
    return factorise(F, s0 + s1 + s2 + s3 + s4, cell0 + cell1, springs,
                     pat0 + pat1 + pat2 + pat3, lu, edge, tangent, free_rotation)  # fmt: skip


#: hand-backs (the list grown, a longer pattern) of one solve before it counts as failed
HAND_BACKS = 20


def run(cell, springs, F, w, th, inc, settings, counts, kernel=None, max_steps=None,
        extra=()) -> tuple:  # fmt: skip
    """``kernel`` (:func:`newton_entry`, or one with its arguments and outcome and ``extra``
    ones after them) at most ``max_steps`` (``settings.max_iterations``) steps on the cell's block
    pattern for the candidates visited at (F, w), the list grown and the pattern lengthened
    where it hands back: ``(code, why, w, th)``, the residuals appended to
    ``counts.history``."""
    kernel = newton_entry if kernel is None else kernel
    max_steps = settings.max_iterations if max_steps is None else max_steps
    F = np.ascontiguousarray(F, dtype=np.float64)
    F_smin = float(smallest_stretch(F))
    history = np.empty(HAND_BACKS * (max_steps + 1))
    tally = np.zeros(4, np.int64)
    need = cell.visited(F, w)  # (grows the list where it must)
    for _ in range(HAND_BACKS):
        # (after the list grew: a force and moment for every candidate)
        committed = inc.arrays(cell.pi.shape[0])
        p, lu, cover = cell.block_pattern(-1, max(need, 1), d=3, new_factor=BlockLU.on)
        code, why, w, th, reached = kernel(
            F, F_smin, w, th, *chunks(committed), *chunks(cell_arrays(cell)),
            spring_arrays(springs), *chunks(cell.geometry()), cell.verlet(),
            *chunks(pattern_arrays(p, cover)), lu.arrays(), settings.force_tol, max_steps,
            history, tally, *extra,
        )  # fmt: skip
        if code != HAND_BACK:
            break
        if why == GROW_LIST:
            _grow(cell, F, w, reached)
        need = cell.pi.shape[0] if why == BEYOND_PATTERN else cell.visited(F, w)
    else:
        code, why = FAILED, STALLED
    counts.history.extend(history[: tally[3]].tolist())
    counts.steps += int(tally[0])
    counts.factorisations += int(tally[1])
    counts.chord_steps += int(tally[2])
    return code, why, w, th


def _grow(cell, F, w, reached):
    """Grow the candidate list around the iterate w and the positions ``reached`` from it
    (N, 2), with a Verlet skin that holds both and every trial between."""
    move = reached - w
    move -= move.mean(axis=0)
    reach = float(np.sqrt((move * move).sum(axis=1).max()))
    cell.grow(F, 0.5 * (w + reached), SKIN * cell.R.min() + 2.0 * reach)
