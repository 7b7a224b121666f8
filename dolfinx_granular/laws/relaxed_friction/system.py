"""The frictional relaxed cell's equations: the generalised forces of every disk, their
Jacobian, the stress and the mixed derivatives, summed over the contacts
(:mod:`~dolfinx_granular.laws.relaxed_friction.contact_law`).

The unknowns of disk k are (w_k (2,), theta_k), numbered 3k, 3k + 1, 3k + 2; forces are
divided by the cell's reference area V here (Pa per length, Pa), as the frictionless relaxed
RVE's are. The Jacobian is written as coordinates (rows, cols, values), duplicates summed by
the caller's sparse matrix.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .contact_law import OPEN, SLIP, STICK, jacobian, local, mixed_terms, mixed_work, scratch
from .rolling import add_jacobian, add_mixed, add_rolling, radius, stiffness

#: how a contact enters the Jacobian (:func:`equations`)
SKIPPED, EXACT = 0, 2


@njit(cache=True)
def balance(pi, pj, lx, ly, d, e, ft, mr, R, radii, kn, n_disks):
    """The net force (N, 2) and moment (N,) on every disk in the current frame (N, N m per
    unit thickness), with the rolling moments mr (m,) (:mod:`.rolling`), the mean normal force
    over the contacts (N; 0 without one) and their number."""
    f = np.zeros((n_disks, 2))
    M = np.zeros(n_disks)
    total, count = 0.0, 0
    for c in range(e.shape[0]):
        if e[c] <= 0.0:
            continue
        i, j = pi[c], pj[c]
        nx, ny = lx[c] / d[c], ly[c] / d[c]
        fn = kn * e[c]
        lever = R[c] / d[c]
        fx = fn * nx + ft[c] * lever * ny  # on j: f_n n - f_t (R/d) t, t = (-n_y, n_x)
        fy = fn * ny - ft[c] * lever * nx
        f[j, 0] += fx
        f[j, 1] += fy
        f[i, 0] -= fx
        f[i, 1] -= fy
        M[i] += radii[i] * ft[c] - mr[c]
        M[j] += radii[j] * ft[c] + mr[c]
        total += fn
        count += 1
    return f, M, (total / count if count else 0.0), count


@njit(cache=True)
def equations(F, qx, qy, lx, ly, d, e, ft, fstar, status, mr, mstar, rstatus, pi, pj, R, radii,
              kn, kt, mu, kr, mu_r, inv_area, n_disks, mode, jacobian, rows, cols,
              vals):  # fmt: skip
    """The gradient r (N, 3) of the incremental potential in (w, theta) (Pa per length; the
    moments' rows in Pa), and the stress P (2, 2), over the contacts (e > 0), with their
    rolling moments (:mod:`.rolling`).

    With ``jacobian``, writes dr/dq as 36 coordinates per contact into ``rows``, ``cols``,
    ``vals`` (>= 36 m,) and returns their number, by ``mode`` (m,) int8: EXACT contacts with
    their exact derivatives, SKIPPED ones not at all (r and P always hold every contact)."""
    r = np.zeros((n_disks, 3))
    P = np.zeros((2, 2))
    out = scratch()
    nnz = 0
    for c in range(e.shape[0]):
        if status[c] == OPEN:
            continue
        i, j = pi[c], pj[c]
        exact = 1 if jacobian and mode[c] == EXACT else 0  # (the Jacobian alone)
        local(F, qx[c], qy[c], lx[c], ly[c], d[c], e[c], ft[c], fstar[c], status[c], R[c],
              radii[i], radii[j], kn, kt, mu, exact, out)  # fmt: skip
        if rstatus[c] != OPEN:  # (no call without rolling resistance: the loop is hot)
            add_rolling(mr[c], rstatus[c], radii[i], radii[j], kn, kr, mu_r, out[8][2],
                        out[8][3][:4], exact, out)  # fmt: skip
        idx = (3 * i, 3 * i + 1, 3 * i + 2, 3 * j, 3 * j + 1, 3 * j + 2)
        for u in range(6):
            r[idx[u] // 3, idx[u] % 3] += inv_area * out[0][u]
        for a in range(4):
            P[a // 2, a % 2] += inv_area * out[1][a]
        if not jacobian or mode[c] == SKIPPED:
            continue
        K = out[2]
        for u in range(6):
            for v in range(6):
                rows[nnz], cols[nnz], vals[nnz] = idx[u], idx[v], inv_area * K[u, v]
                nnz += 1
    return r, P, nnz


@njit(cache=True)
def forces(F, qx, qy, lx, ly, d, e, ft, status, mr, rstatus, pi, pj, R, radii, kn, inv_area,
           n_disks):  # fmt: skip
    """:func:`equations` without the Jacobian: ``(r (N, 3), P (2, 2))``, the same sums in the
    same order (bit for bit), inline: the residual of every Newton iterate and line-search
    trial."""
    r = np.zeros((n_disks, 3))
    P = np.zeros((2, 2))
    for c in range(e.shape[0]):
        if status[c] == OPEN:
            continue
        i, j = pi[c], pj[c]
        nx, ny = lx[c] / d[c], ly[c] / d[c]
        fn = kn * e[c]
        lever = R[c] / d[c]
        gx = -fn * nx + ft[c] * lever * -ny  # (local's g with t = (-n_y, n_x))
        gy = -fn * ny + ft[c] * lever * nx
        Fg0 = F[0, 0] * gx + F[1, 0] * gy
        Fg1 = F[0, 1] * gx + F[1, 1] * gy
        mi, mj = -radii[i] * ft[c], -radii[j] * ft[c]
        if rstatus[c] != OPEN:  # (add_rolling's couple)
            mi += mr[c]
            mj -= mr[c]
        r[i, 0] += inv_area * -Fg0
        r[i, 1] += inv_area * -Fg1
        r[i, 2] += inv_area * mi
        r[j, 0] += inv_area * Fg0
        r[j, 1] += inv_area * Fg1
        r[j, 2] += inv_area * mj
        P[0, 0] += inv_area * (gx * qx[c])
        P[0, 1] += inv_area * (gx * qy[c])
        P[1, 0] += inv_area * (gy * qx[c])
        P[1, 1] += inv_area * (gy * qy[c])
    return r, P


@njit(cache=True)
def jacobian_blocks(F, lx, ly, d, e, ft, status, mr, rstatus, pi, pj, R, radii, kn, kt, mu, kr,
                    mu_r, inv_area, contacts):  # fmt: skip
    """(k, 6, 6) dr/dq of each of the ``contacts`` (k,) with its exact derivatives (rows and
    columns (w_i, theta_i, w_j, theta_j)): :func:`equations`' Jacobian as blocks for the block
    assembly (:func:`.contact_law.jacobian`, :func:`.rolling.add_jacobian`), bit for bit,
    without its coordinates and residual."""
    K = np.empty((contacts.shape[0], 6, 6))
    Kc, de, work, G = np.empty((6, 6)), np.empty(6), np.empty(6), np.empty((2, 2))
    for t in range(contacts.shape[0]):
        c = contacts[t]
        i, j = pi[c], pj[c]
        jacobian(F, lx[c], ly[c], d[c], e[c], ft[c], status[c], R[c], radii[i], radii[j], kn, kt,
                 mu, Kc, de, work, G)  # fmt: skip
        if rstatus[c] != OPEN:
            add_jacobian(mr[c], rstatus[c], radii[i], radii[j], kn, kr, mu_r, de, Kc)
        for u in range(6):
            for v in range(6):
                K[t, u, v] = inv_area * Kc[u, v]
    return K


@njit(cache=True)
def mixed(F, qx, qy, lx, ly, d, e, ft, fstar, status, mr, mstar, rstatus, pi, pj, R, radii, kn,
          kt, mu, kr, mu_r, inv_area, n_disks, use):  # fmt: skip
    """``(K_FF (4, 4), K_Fq (4, 3N), K_qF (3N, 4))`` over the contacts ``use`` (m,) bool: dP/dF
    at fixed (w, theta), dP/dq and dr/dF (F flattened row-major), per area."""
    KFF = np.zeros((4, 4))
    KFq = np.zeros((4, 3 * n_disks))
    KqF = np.zeros((3 * n_disks, 4))
    kFF, kFu, kuF, deF = np.empty((4, 4)), np.empty((4, 6)), np.empty((6, 4)), np.empty(4)
    work = mixed_work()
    for c in range(e.shape[0]):
        if status[c] == OPEN or not use[c]:
            continue
        i, j = pi[c], pj[c]
        mixed_terms(F, qx[c], qy[c], lx[c], ly[c], d[c], e[c], ft[c], status[c], R[c], radii[i],
                    radii[j], kn, kt, mu, kFF, kFu, kuF, deF, work)  # fmt: skip
        if rstatus[c] != OPEN:
            add_mixed(mr[c], rstatus[c], radii[i], radii[j], kn, mu_r, deF, kuF)
        idx = (3 * i, 3 * i + 1, 3 * i + 2, 3 * j, 3 * j + 1, 3 * j + 2)
        for a in range(4):
            for b in range(4):
                KFF[a, b] += inv_area * kFF[a, b]
            for u in range(6):
                KFq[a, idx[u]] += inv_area * kFu[a, u]
                KqF[idx[u], a] += inv_area * kuF[u, a]
    return KFF, KFq, KqF


@njit(cache=True)
def rolling_springs(pi, pj, radii, e, kn, kr, mu_r):
    """``(caps (m,), stiffnesses (m,))`` of the rolling springs of the contacts with overlaps e
    (:mod:`.rolling`; empty without rolling resistance): the caps frozen at e."""
    if mu_r == 0.0:
        return np.zeros(0), np.zeros(0)
    m = e.shape[0]
    caps, k = np.empty(m), np.empty(m)
    for c in range(m):
        ri, rj = radii[pi[c]], radii[pj[c]]
        caps[c] = mu_r * radius(ri, rj) * kn * max(e[c], 0.0)
        k[c] = stiffness(ri, rj, kr)
    return caps, k


@njit(cache=True)
def potential(e, fstar, caps, kn, kt, mstar, rcaps, kr):
    """The increment's potential (N m) at the overlaps e (m,) and trial forces f* (m,) with
    the Coulomb caps frozen at ``caps`` (N; beyond its length zero): k_n e^2 / 2 + H_c(f*) /
    k_t over the contacts, H_c the Huber function (x^2 / 2 inside the cap, c |x| - c^2 / 2
    beyond), and H_c(m*) / k_r of the trial rolling moments m* with their caps ``rcaps`` and
    stiffnesses ``kr`` (:func:`rolling_springs`; none where empty). With the caps of a state,
    the residual there is its gradient (times 1 / V)."""
    z = np.zeros(0)
    return potential_change(z, z, e, fstar, caps, kn, kt, z, mstar, rcaps, kr)


@njit(cache=True)
def potential_change(e0, f0, e1, f1, caps, kn, kt, m0, m1, rcaps, kr):
    """:func:`potential` at (e1, f1, m1) minus at (e0, f0, m0) (candidates beyond an array's
    length: open), summed contact by contact: a disk that barely touches changes it by less
    than the round-off of the whole sum."""
    total = 0.0
    rolling = rcaps.shape[0] > 0
    for c in range(max(e0.shape[0], e1.shape[0])):
        a = e0[c] if c < e0.shape[0] else 0.0
        b = e1[c] if c < e1.shape[0] else 0.0
        if a <= 0.0 and b <= 0.0:
            continue
        on0, on1 = a > 0.0, b > 0.0
        a, b = max(a, 0.0), max(b, 0.0)
        total += 0.5 * kn * (b - a) * (b + a)
        cap = caps[c] if c < caps.shape[0] else 0.0
        total += _spring_change(f0, f1, c, on0, on1, cap) / kt
        if rolling:
            cap = rcaps[c] if c < rcaps.shape[0] else 0.0
            total += _spring_change(m0, m1, c, on0, on1, cap) / kr[c]
    return total


@njit(cache=True, inline="always")
def _spring_change(f0, f1, c, on0, on1, cap):
    """k H_cap(f1) - k H_cap(f0) of one capped spring times its stiffness k (f0, f1: trial
    forces or moments; a side that is open: zero)."""
    x = abs(f0[c]) if on0 else 0.0
    y = abs(f1[c]) if on1 else 0.0
    if x <= cap and y <= cap:
        return 0.5 * (y - x) * (y + x)
    if x > cap and y > cap:
        return cap * (y - x)
    return _huber(y, cap) - _huber(x, cap)


@njit(cache=True, inline="always")
def _huber(x, cap):
    return 0.5 * x * x if x <= cap else cap * x - 0.5 * cap * cap


@njit(cache=True)
def energy(e, ft, status, kn, kt, inv_area, mr, rstatus, kr):
    """The stored energy sum [k_n e^2 / 2 + f_t^2 / (2 k_t) + m_r^2 / (2 k_r)] / V (Pa) over
    the contacts (the rolling moments mr with their stiffnesses kr, :func:`rolling_springs`;
    none where empty)."""
    s = 0.0
    for c in range(e.shape[0]):
        if status[c] != OPEN:
            s += 0.5 * kn * e[c] * e[c]
            if kt > 0.0:
                s += 0.5 * ft[c] * ft[c] / kt
            if c < rstatus.shape[0] and rstatus[c] != OPEN:
                s += 0.5 * mr[c] * mr[c] / kr[c]
    return s * inv_area


@njit(cache=True)
def dissipation(ft, fstar, status, kt, inv_area, mr, mstar, rstatus, kr):
    """The energy dissipated by sliding and rolling over the increment, sum [f_t (f* - f_t) /
    k_t + m_r (m* - m_r) / k_r] / V (Pa): the force times the slip (f* - f_t) / k_t, the moment
    times the plastic rolling angle; >= 0 where every slipping contact's trial force (moment)
    lies outside its cap (the return map's)."""
    s = 0.0
    for c in range(ft.shape[0]):
        if kt > 0.0 and status[c] != OPEN and status[c] != STICK:
            s += ft[c] * (fstar[c] - ft[c]) / kt
        if c < rstatus.shape[0] and rstatus[c] == SLIP:
            s += mr[c] * (mstar[c] - mr[c]) / kr[c]
    return s * inv_area
