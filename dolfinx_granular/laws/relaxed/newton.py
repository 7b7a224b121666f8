"""The relaxed RVE's Newton loop, compiled: one point's steps from a start to its equilibrium.

Each step reads the contact state at the iterate (overlaps, rattlers, the network), the net
forces and the residual; factorises the stiffness where the chord rule asks for it (assembled
straight into the block pattern's values, :mod:`~dolfinx_granular.laws.relaxed.block_ldlt`,
shifted by Levenberg-Marquardt where it is not positive definite); solves for the direction;
and takes a backtracking line search on the energy (doubled where the step was shifted).
:mod:`~dolfinx_granular.laws.relaxed.equilibrium` drives this loop. In detail:

* between non-rattlers the stiffness is exact; a contact that touches a rattler (fewer than 3
  contacts, removed recursively, recomputed at every step) enters by its positive part
  K n n^T, and the rattlers' unknowns get an extra diagonal, their net force over
  :data:`RATTLER_REACH` mean overlaps (a small floor where that is smaller), so that a rattler
  is pushed out of its overlaps (it ends force-free) without flying across its cage;
* where the stiffness is not positive definite (the network buckles: a rearrangement), the
  step is taken on H + mu I (Levenberg-Marquardt, in effect a trust region), mu the first of
  a ladder of decades that makes the factorisation positive definite (the rungs below a bound
  read off the failed factorisation, :func:`shift_bound`, skipped); the next step tries plain
  Newton again;
* while the rattlers stay the same and the forces fall fast, the last factorisation is reused
  (a chord step: one solve instead of a factorisation).

The loop runs until it converges or fails, or until it needs Python for something it cannot do
itself; it then returns a status, and everything it needs to go on is in its arguments:

* :data:`NEED_PATTERN`: the factorisation needs a block pattern for another pinned disk or a
  longer prefix of the candidates, one that holds every contact (``request`` holds both);
* :data:`NEED_LIST`: the iterate or a trial position of its line search reaches past the
  candidate list (the Verlet list must grow, around the iterate ``w``); the step in progress
  is taken again after that.

Arguments, by the tuples :class:`~dolfinx_granular.laws.relaxed.cell.Cell` builds:

* ``geo``: the cell, ``(pi, pj, X, Y, R, ratio, n_sorted, n_candidates, inv_min_stretch,
  R_min, n_disks, K)``;
* ``verlet``: the candidate list's Verlet reference ``(w (N, 2), s_min, skin, valid)``;
* ``pat``: a block pattern ``(pinned, covered prefix, n, perm, Lp, Li, Rp, Rc, Rq, Ap, Ai,
  diag_slot, pair_slot)`` and ``fac`` its numeric arrays ``(values, Lx, D, Dinv, y)``;
* ``tol``: ``(force_tol, rattler_shift, chord_rate)``; ``budget`` Newton steps; ``stall``;
* ``solver``: (4,) float ``(mu, last residual, factorised?, final residual)`` and ``key``
  (N,) bool the rattlers of the last factorisation: the chord rule's memory; ``counts`` (6,)
  int ``(steps, factorisations, shifted, numeric factorisations, solves, trial states)``; all
  updated in place.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .assembly import assemble as assemble_blocks
from .block_ldlt import numeric_factorisation, substitute
from .cell import reach_prefix
from .contact_state import MIN_CONTACTS, contact_state, energy, forces, non_rattlers

#: what :func:`newton` stopped at
CONVERGED, NEED_PATTERN, NEED_LIST, NO_CONTACT = 0, 1, 2, 3
NO_EQUILIBRIUM, LINE_SEARCH, NOT_SHIFTABLE = 4, 5, 6

#: Newton counts as stalled (FIRE takes over) when after this many steps the largest force is
#: still above this part of the mean contact force
STALLED_AFTER, STALLED_ABOVE = 40, 1e-2
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
_DIMS = (0, 1)


@njit(cache=True)
def visited(F_smin, w, geo, verlet):
    """The candidates (a prefix) that can touch at fluctuations w (N, 2), as
    :meth:`Cell.visited`; -1 where the list must grow first."""
    ratio, n_sorted, n_all, inv_min_stretch, R_min = geo[5], geo[6], geo[7], geo[8], geo[9]
    m = reach_prefix(F_smin, w, ratio, n_sorted, inv_min_stretch, R_min)
    if m >= 0:
        return m
    vw, vsmin, vskin, valid = verlet
    if not valid or F_smin < vsmin:
        return -1
    moved = w - vw
    mean = moved.sum(axis=0) / w.shape[0]
    big = 0.0
    for i in range(w.shape[0]):
        vx, vy = moved[i, 0] - mean[0], moved[i, 1] - mean[1]
        big = max(big, vx * vx + vy * vy)
    return n_all if big <= (0.5 * vskin) ** 2 else -1


@njit(cache=True)
def _overlaps(F, w, m, geo):
    """``(lx, ly, d, e, on)`` of the first m candidates at w."""
    _, _, lx, ly, d, e = contact_state(F, w, geo[0], geo[1], geo[2], geo[3], geo[4], m)
    return lx, ly, d, e, e > 0.0


@njit(cache=True)
def _energy_at(F, w, m, geo):
    """The contact energy of the first m candidates at w (Pa), without the arrays of
    :func:`_overlaps` (a line search's trial needs its energy alone)."""
    pi, pj, X, Y, R = geo[0], geo[1], geo[2], geo[3], geo[4]
    s = 0.0
    for c in range(m):
        i, j = pi[c], pj[c]
        x = X[c] + w[j, 0] - w[i, 0]
        y = Y[c] + w[j, 1] - w[i, 1]
        a = F[0, 0] * x + F[0, 1] * y
        b = F[1, 0] * x + F[1, 1] * y
        e = R[c] - np.sqrt(a * a + b * b)
        if e > 0.0:
            s += e * e
    return 0.5 * geo[11] * s


@njit(cache=True)
def _largest_force(f):
    big = 0.0
    for i in range(f.shape[0]):
        big = max(big, f[i, 0] * f[i, 0] + f[i, 1] * f[i, 1])
    return np.sqrt(big)


@njit(cache=True)
def _mean_overlap(e, on):
    s, k = 0.0, 0
    for c in range(e.shape[0]):
        if on[c]:
            s += e[c]
            k += 1
    return s / k if k else 0.0


@njit(cache=True)
def factorise_shifted(pat, fac, total, mu, n_disks, counts):
    """L D L^T of the values plus ``total`` + mu on every disk's diagonal: positive definite?"""
    counts[3] += 1
    shift = np.empty((n_disks, 2))
    for i in range(n_disks):
        shift[i, 0] = total[i] + mu
        shift[i, 1] = total[i] + mu
    ok, _, neg, zero = numeric_factorisation(
        _DIMS, pat[2], pat[3], pat[9], pat[10], fac[0], shift, pat[4], pat[5], pat[6], pat[7],
        pat[8], fac[1], fac[2], fac[3], fac[4],
    )  # fmt: skip
    return ok and neg == 0 and zero == 0


@njit(cache=True)
def factorise_newton(
    F, m, lx, ly, d, e, on, keep, network, g, geo, pat, fac, rattler_shift, solver, counts
):
    """Factorise the Newton stiffness (exact between non-rattlers, positive part at the
    rattlers, the rattlers shifted by their force over :data:`RATTLER_REACH` mean overlaps),
    shifted by mu I until positive definite: ``(ok, shifted)``, ok False where no shift up to
    1e6 of the diagonal's scale makes it so."""
    pi, pj, R, K, N = geo[0], geo[1], geo[4], geo[11], geo[10]
    assemble_blocks(
        F, pi[:m], pj[:m], lx, ly, d, e, R[:m], K, on, network, pat[11], pat[12], fac[0]
    )
    reach = RATTLER_REACH * _mean_overlap(e, on)
    total = np.zeros(N)
    for i in range(N):
        if not keep[i]:
            force = np.sqrt(g[i, 0] * g[i, 0] + g[i, 1] * g[i, 1])
            total[i] = max(rattler_shift * K, force / reach)
    total[pat[0]] = K  # the pinned disk is out of the pattern (no entry is read)
    if factorise_shifted(pat, fac, total, 0.0, N, counts):
        solver[0] = 0.0
        return True, False
    n, perm, values = pat[2], pat[3], fac[0]
    acc, count = 0.0, 0
    for k in range(n):
        for a in range(2):
            v = values[k, a, a] + total[perm[k]]
            if v > 0.0:
                acc += v
                count += 1
    scale = acc / count if count else K
    # the shift a buckling network needs changes little from one step to the next: start a
    # decade below the last one (each try is a factorisation); a rung at or below the bound
    # the failed factorisation gives (shift_bound) is not positive definite either: skipped
    mu = max(1e-8 * scale, 0.1 * solver[0])
    tried, bound = 0.0, shift_bound(pat, fac)
    while mu <= 1e6 * scale:
        if mu > tried + bound:
            if factorise_shifted(pat, fac, total, mu, N, counts):
                solver[0] = mu
                return True, True
            tried, bound = mu, shift_bound(pat, fac)
        mu *= 10.0
    return False, True


@njit(cache=True)
def shift_bound(pat, fac):
    """A shift the last factorisation's matrix M needs at least to be positive definite, from
    its first D block that is not (0 if none): where the blocks before it are positive
    definite, the vector v = (y, x), x (|x| = 1) the eigenvector of that block's least
    eigenvalue lam and y = -L_11^-T L_k^T x (L_11 L's leading blocks, L_k row k of L), has
    v^T M v = lam, so that M's least eigenvalue is at most lam / (1 + |y|^2): M + t I is not
    positive definite for any t at or below -lam / (1 + |y|^2)."""
    n, Lp, Li, Rp, Rc, Rq = pat[2], pat[4], pat[5], pat[6], pat[7], pat[8]
    Lx, D = fac[1], fac[2]
    for k in range(n):
        a, b, c = D[k, 0, 0], D[k, 0, 1], D[k, 1, 1]
        lam = 0.5 * (a + c) - np.sqrt((0.5 * (a - c)) ** 2 + b * b)
        if lam > 0.0:
            continue
        if not np.isfinite(lam):
            return 0.0
        x0, x1 = b, lam - a  # the eigenvector of lam, the better conditioned of two forms
        if x0 * x0 + x1 * x1 < (lam - c) ** 2 + b * b:
            x0, x1 = lam - c, b
        norm = np.sqrt(x0 * x0 + x1 * x1)
        if norm == 0.0:
            x0, x1, norm = (1.0, 0.0, 1.0) if a <= c else (0.0, 1.0, 1.0)
        x0, x1 = x0 / norm, x1 / norm
        y = np.zeros((k, 2))
        for t in range(Rp[k], Rp[k + 1]):  # L_k^T x
            q, i = Rq[t], Rc[t]
            y[i, 0] = Lx[q, 0, 0] * x0 + Lx[q, 1, 0] * x1
            y[i, 1] = Lx[q, 0, 1] * x0 + Lx[q, 1, 1] * x1
        for j in range(k - 1, -1, -1):  # L_11^T y = L_k^T x
            for q in range(Lp[j], Lp[j + 1]):
                r = Li[q]
                if r >= k:
                    break  # (rows increase down a column)
                y[j, 0] -= Lx[q, 0, 0] * y[r, 0] + Lx[q, 1, 0] * y[r, 1]
                y[j, 1] -= Lx[q, 0, 1] * y[r, 0] + Lx[q, 1, 1] * y[r, 1]
        return -lam / (1.0 + (y * y).sum())
    return 0.0


@njit(cache=True)
def held(use, pi, pj, m):
    """The prefix of the candidates that holds the contacts ``use`` (m,) a pattern must hold
    (a disk's contact with its own image has no block)."""
    for c in range(m - 1, -1, -1):
        if use[c] and pi[c] != pj[c]:
            return c + 1
    return 0


@njit(cache=True)
def _direction(pat, fac, g, n_disks):
    """-H^-1 g (N, 2) on the factorisation in ``fac``, zero at the pinned disk."""
    b = np.empty((n_disks, 2, 1))
    b[:, :, 0] = g
    x = np.zeros((n_disks, 2, 1))
    substitute(_DIMS, pat[2], pat[3], pat[4], pat[5], fac[1], fac[3], b, x)
    return -x[:, :, 0]


@njit(cache=True)
def line_search(F, F_smin, w, delta, g, E0, r0, expand, geo, verlet, trial, counts):
    """Backtracking (Armijo) on the energy from a step that moves no disk by more than
    :data:`MAX_STEP` of the smallest radius sum, then doubled while the energy falls where
    ``expand`` and the first step was taken whole: ``(status, new w, its prefix m)``; status
    NEED_LIST (``trial`` (N, 2) is the work space of the trial positions), or LINE_SEARCH."""
    R_min = geo[9]
    slope = (g * delta).sum()
    longest = _largest_force(delta)
    alpha = first = min(1.0, MAX_STEP * R_min / longest) if longest > 0.0 else 1.0
    for _ in range(60):
        counts[5] += 1
        trial[:] = w + alpha * delta
        m = visited(F_smin, trial, geo, verlet)
        if m < 0:
            return NEED_LIST, w, 0
        E = _energy_at(F, trial, m, geo)
        if E <= E0 + 1e-4 * alpha * slope:
            if expand and alpha == first:
                return _expand(
                    F, F_smin, w, delta, alpha, E, m, longest, geo, verlet, trial, counts
                )
            return CONVERGED, trial.copy(), m
        # where the decrease a step promises is below the energy's round-off, the energy
        # cannot tell: take the step if it lowers the largest force
        if -alpha * slope <= ROUND_OFF * abs(E0):
            lx, ly, d, e, on = _overlaps(F, trial, m, geo)
            if _balance(F, m, lx, ly, d, e, on, geo)[1] < r0:
                return CONVERGED, trial.copy(), m
        alpha *= 0.5
    return LINE_SEARCH, w, 0


@njit(cache=True)
def _expand(F, F_smin, w, delta, alpha, E, m, longest, geo, verlet, trial, counts):
    """Double the taken step alpha delta (energy E) while the energy falls and no disk moves by
    more than :data:`MAX_STEP` of the smallest radius sum."""
    best = trial.copy()
    while 2.0 * alpha * longest <= MAX_STEP * geo[9]:
        counts[5] += 1
        trial[:] = w + 2.0 * alpha * delta
        m2 = visited(F_smin, trial, geo, verlet)
        if m2 < 0:
            return NEED_LIST, w, 0
        E2 = _energy_at(F, trial, m2, geo)
        if not E2 < E:
            break
        alpha, E, m = 2.0 * alpha, E2, m2
        best[:] = trial
    return CONVERGED, best, m


@njit(cache=True)
def newton(F, F_smin, w, pi, pj, X, Y, R, ratio, n_sorted, n_all, inv_min_stretch, R_min,
           n_disks, K, vw, vsmin, vskin, valid, pinned, cover, n, perm, Lp, Li, Rp, Rc, Rq, Ap,
           Ai, diag_slot, pair_slot, values, Lx, D, Dinv, y, force_tol, rattler_shift,
           chord_rate, budget, stall, solver, key, counts, request, trial):  # fmt: skip
    """:func:`run_newton` with its tuples flattened (the dispatcher types a tuple argument in
    Python: about 0.25 ms a call here, against 5 µs for the flat arguments)."""
    return run_newton(
        F, F_smin, w,
        (pi, pj, X, Y, R, ratio, n_sorted, n_all, inv_min_stretch, R_min, n_disks, K),
        (vw, vsmin, vskin, valid),
        (pinned, cover, n, perm, Lp, Li, Rp, Rc, Rq, Ap, Ai, diag_slot, pair_slot),
        (values, Lx, D, Dinv, y),
        (force_tol, rattler_shift, chord_rate), budget, stall, solver, key, counts, request,
        trial,
    )  # fmt: skip


@njit(cache=True)
def run_newton(F, F_smin, w, geo, verlet, pat, fac, tol, budget, stall, solver, key, counts,
               request, trial):  # fmt: skip
    """Newton steps from w (N, 2), updated in place, until equilibrium: a status (the module's
    docstring); at CONVERGED, w is the equilibrium, ``request[1]`` its prefix m and
    ``solver[3]`` its residual."""
    force_tol, rattler_shift, chord_rate = tol
    K, N = geo[11], geo[10]
    m = visited(F_smin, w, geo, verlet)
    if m < 0:
        trial[:] = w
        return NEED_LIST
    while True:
        lx, ly, d, e, on = _overlaps(F, w, m, geo)
        if not on.any():
            return NO_CONTACT
        g, residual, floor = _balance(F, m, lx, ly, d, e, on, geo)
        if residual <= max(force_tol, floor):
            request[1], solver[3] = m, residual
            return CONVERGED
        steps = counts[0]
        if steps == budget or (stall and steps >= STALLED_AFTER and residual > STALLED_ABOVE):
            return NO_EQUILIBRIUM
        keep = non_rattlers(geo[0], geo[1], e, N, MIN_CONTACTS)
        renew = solver[2] == 0.0 or residual > chord_rate * solver[1]
        for i in range(N):
            renew = renew or keep[i] != key[i]
        shifted = False
        if renew:
            status, shifted = _refactorise(
                F, m, lx, ly, d, e, on, keep, g, geo, pat, fac, rattler_shift, solver, key,
                counts, request,
            )  # fmt: skip
            if status != CONVERGED:
                return status
        solver[1] = residual
        delta = _direction(pat, fac, g, N)
        counts[4] += 1
        E0 = energy(e, K, on)
        status, w_new, m = line_search(
            F, F_smin, w, delta, g, E0, residual, shifted, geo, verlet, trial, counts
        )
        if status != CONVERGED:
            return status
        w[:] = w_new
        counts[0] += 1
        counts[1] += 1 if renew else 0
        counts[2] += 1 if shifted else 0


@njit(cache=True)
def _balance(F, m, lx, ly, d, e, on, geo):
    """``(g, residual, floor)`` at a contact state: the energy's gradient (N, 2), the largest
    net force over the mean contact force (inf without contacts), and :data:`RESOLVED` times
    the resolution of the contact forces (:meth:`ContactState.resolution`), below which the
    residual means nothing."""
    K = geo[11]
    g, f = forces(F, geo[0], geo[1], lx, ly, d, e, K, geo[10], on)
    mean_overlap = _mean_overlap(e, on)
    if mean_overlap == 0.0:
        return g, np.inf, np.inf
    R_on = 0.0
    for c in range(m):
        if on[c]:
            R_on += geo[4][c]
    resolution = np.finfo(np.float64).eps * R_on / on.sum() / mean_overlap
    return g, _largest_force(f) / (K * mean_overlap), RESOLVED * resolution


@njit(cache=True)
def _refactorise(F, m, lx, ly, d, e, on, keep, g, geo, pat, fac, rattler_shift, solver, key,
                 counts, request):  # fmt: skip
    """Factorise the stiffness at this state (:func:`factorise_newton`) where ``pat`` fits it
    (its pinned disk the first non-rattler, its prefix holding the contacts): ``(status,
    shifted)``, status CONVERGED (factorised), NEED_PATTERN or NOT_SHIFTABLE."""
    pinned = np.argmax(keep)
    held_prefix = held(on, geo[0], geo[1], m)
    if pinned != pat[0] or held_prefix > pat[1]:
        request[0], request[1] = pinned, held_prefix
        return NEED_PATTERN, False
    network = on & keep[geo[0][:m]] & keep[geo[1][:m]]
    ok, shifted = factorise_newton(
        F, m, lx, ly, d, e, on, keep, network, g, geo, pat, fac, rattler_shift, solver, counts
    )
    if not ok:
        return NOT_SHIFTABLE, shifted
    key[:] = keep
    solver[2] = 1.0
    return CONVERGED, shifted
