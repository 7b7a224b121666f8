"""A rank's relaxed points in one compiled call: the common path of
:meth:`~dolfinx_granular.laws.relaxed.law.RelaxedRVE.evaluate`.

For each point, as :func:`~dolfinx_granular.laws.relaxed.path.follow` and
:func:`~dolfinx_granular.laws.relaxed.equilibrium.relax` do it: a committed F is not relaxed
again; otherwise the quasi-static path in substeps of the right stretch, each relaxation Newton
(:func:`~dolfinx_granular.laws.relaxed.newton.run_newton`) from the first-order predicted
start; at the equilibrium the stress, the condensed tangent with its sensitivities
(:mod:`~dolfinx_granular.laws.relaxed.tangent`), the network's fingerprint and the point's
fluctuation. A point that needs more (another block pattern, a longer candidate list, Newton
from its fallback start, FIRE, a cell that lost its rigidity) stops the call: Python relaxes it
on its own path, which does all of that, and calls again from the next point.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .cell import Cell, fingerprint, smallest_stretch
from .contact_state import MIN_CONTACTS, contact_state, non_rattlers
from .newton import CONVERGED, run_newton, visited
from .path import MAX_SUBSTEP, predicted, stretches_between
from .settings import Settings
from .tangent import condense, stress_at, tangent_pattern


class Outputs:
    """What :func:`relax_points` writes for n points of N disks: ``W`` (n,), ``P`` (n, 2, 2),
    ``A`` (n, 2, 2, 2, 2), ``w`` (n, N, 2), ``dw`` (n, N, 2, 4) (zero without the tangent),
    ``moved`` (n,) and ``network`` (n,) uint64 (see
    :class:`~dolfinx_granular.laws.relaxed.law.RelaxedState`)."""

    def __init__(self, n: int, n_disks: int) -> None:
        self.W, self.P, self.A = np.empty(n), np.empty((n, 2, 2)), np.zeros((n, 2, 2, 2, 2))
        self.w, self.dw = np.empty((n, n_disks, 2)), np.zeros((n, n_disks, 2, 4))
        self.moved, self.network = np.empty(n), np.zeros(n, np.uint64)

    def arrays(self) -> tuple:
        return self.W, self.P, self.A, self.w, self.dw, self.moved, self.network


def relax_points(
    cell: Cell, settings: Settings, F, state, tangent: bool, q0: int, out: Outputs
) -> int:
    """Points q0, q0 + 1, ... of F (n, 2, 2) relaxed from the committed ``state`` into ``out``
    until one needs Python: its index (n where none did)."""
    pat, fac = cell.kernel_pattern(*cell.pattern_hint)
    return _relax_points(
        F, state.w, state.sensitivity, state.F, tangent, q0, *cell.geometry(), *cell.verlet(),
        *pat, *fac, settings.force_tol, settings.rattler_shift, settings.chord_rate,
        settings.max_iterations, MAX_SUBSTEP, np.ascontiguousarray(cell.shift, dtype=np.int64),
        float(cell.radii.mean()), *out.arrays(),
    )  # fmt: skip


@njit(cache=True)
def _relax_points(F, wc, dwc, Fc, tangent, q0, pi, pj, X, Y, R, ratio, n_sorted, n_all,
                  inv_min_stretch, R_min, n_disks, K, vw, vsmin, vskin, valid, pinned, cover, n,
                  perm, Lp, Li, Rp, Rc, Rq, Ap, Ai, diag_slot, pair_slot, values, Lx, D, Dinv, y,
                  force_tol, rattler_shift, chord_rate, budget, longest, shift, mean_radius, W,
                  P, A, w, dw, moved, network):  # fmt: skip
    """:func:`relax_points` with the cell, its Verlet reference, the pattern and the settings
    flattened (as :func:`~dolfinx_granular.laws.relaxed.newton.newton`'s)."""
    geo = (pi, pj, X, Y, R, ratio, n_sorted, n_all, inv_min_stretch, R_min, n_disks, K)
    verlet = (vw, vsmin, vskin, valid)
    pat = (pinned, cover, n, perm, Lp, Li, Rp, Rc, Rq, Ap, Ai, diag_slot, pair_slot)
    fac = (values, Lx, D, Dinv, y)
    tol = (force_tol, rattler_shift, chord_rate)
    out = (W, P, A, w, dw, network, shift)
    for q in range(q0, F.shape[0]):
        if not _point(F[q], wc[q], dwc[q], Fc[q], tangent, geo, verlet, pat, fac, tol, budget,
                      longest, q, out):  # fmt: skip
            return q
        u2 = 0.0
        for i in range(n_disks):
            u0 = F[q, 0, 0] * w[q, i, 0] + F[q, 0, 1] * w[q, i, 1]
            u1 = F[q, 1, 0] * w[q, i, 0] + F[q, 1, 1] * w[q, i, 1]
            u2 += u0 * u0 + u1 * u1
        moved[q] = np.sqrt(u2 / n_disks) / mean_radius
    return F.shape[0]


@njit(cache=True)
def _point(F, w, dw, Fc, tangent, geo, verlet, pat, fac, tol, budget, longest, q, out):
    """One point along its path into row q of ``out`` (W, P, A, w, dw, network, the candidates'
    shifts): False where it needs Python."""
    if (F == Fc).all():  # the committed positions are at rest
        m = visited(smallest_stretch(F), w, geo, verlet)
        return m >= 0 and _finish(F, w.copy(), m, tangent, geo, pat, fac, q, out)
    Us = stretches_between(Fc, F, longest)
    for k in range(Us.shape[0] + 1):
        target = Us[k] if k < Us.shape[0] else F
        last = k == Us.shape[0]
        start = predicted(w, dw, Fc, target) if dw.any() else w.copy()
        m = _newton(target, start, geo, verlet, pat, fac, tol, budget)
        if m < 0 or not _finish(target, start, m, tangent or not last, geo, pat, fac, q, out):
            return False
        w, dw, Fc = out[3][q], out[4][q], target
    return True


@njit(cache=True)
def _newton(F, w, geo, verlet, pat, fac, tol, budget):
    """Newton from w (updated in place) at F, stalls counted: the equilibrium's prefix m of
    the candidates, -1 where it did not converge."""
    N = geo[10]
    request = np.zeros(2, np.int64)
    status = run_newton(
        F, smallest_stretch(F), w, geo, verlet, pat, fac, tol, budget, True,
        np.array([0.0, np.inf, 0.0, np.inf]), np.zeros(N, np.bool_), np.zeros(6, np.int64),
        request, np.empty_like(w),
    )  # fmt: skip
    return request[1] if status == CONVERGED else -1


@njit(cache=True)
def _finish(F, w, m, tangent, geo, pat, fac, q, out):
    """The equilibrium w at F (its first m candidates) into row q of ``out``: stress, the
    network's fingerprint, and with ``tangent`` the condensed tangent and sensitivities (zero
    without); False where it needs Python (no contact or no non-rattler, another pattern, a
    tangent that is not positive definite)."""
    W, P, A, w_out, dw_out, network, shift = out
    pi, pj, K, N = geo[0], geo[1], geo[11], geo[10]
    qx, qy, lx, ly, d, e = contact_state(F, w, pi, pj, geo[2], geo[3], geo[4], m)
    keep = non_rattlers(pi, pj, e, N, MIN_CONTACTS)
    if not keep.any() or not (e > 0.0).any():
        return False
    net = (e > 0.0) & keep[pi[:m]] & keep[pj[:m]]
    if tangent:
        pinned, prefix = tangent_pattern(keep, net, pi, pj, m)
        if keep.sum() > 1 and (pinned != pat[0] or prefix > pat[1]):
            return False
        ok, Aq, dwq = condense(F, m, qx, qy, lx, ly, d, e, keep, net, geo, pat, fac,
                               np.zeros(6, np.int64))  # fmt: skip
        if not ok:
            return False
        A[q] = Aq
        dw_out[q] = dwq
    else:
        A[q] = 0.0
        dw_out[q] = 0.0
    Wq, Pq = stress_at(F, e, d, qx, qy, K)
    W[q] = Wq
    P[q] = Pq
    w_out[q] = w
    network[q] = fingerprint(pi, pj, shift, np.flatnonzero(net), N)
    return True
