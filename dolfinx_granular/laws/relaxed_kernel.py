"""Numba kernels of the relaxed RVE: contact state, energy, forces, rattlers and stiffness.

Every disk i sits at x_i = F (X_i + w_i): X_i its reference centre, w_i its fluctuation in the
reference frame (its fractional coordinates are fixed when F changes). A candidate contact c of
disks (i, j) with reference branch vector L_c has the relaxed reference branch vector
Q_c = L_c + w_j - w_i, the current one l_c = F Q_c, d = |l|, n = l / d and the overlap
e = R - d; it is a contact when e > 0. With K = k_n / V its energy is phi = K/2 e^2, and

    g_c = dphi/dl = -K e n,        H_c = d2phi/dl2 = K [(R/d) n n^T - (e/d) I].

Derivatives with respect to the fluctuations (reference frame, per disk, 2 components each):
dphi/dw_j = F^T g = -dphi/dw_i, and the stiffness blocks +-F^T H F. The mixed derivative with
respect to F (flattened row-major, ab -> 2a + b) of dphi/dw_(j, k) is
delta_bk g_a + (F^T H)_ka Q_b (minus for disk i). The energy at fixed w is the Taylor energy with
L replaced by Q, so the affine (Born) part of the tangent is the Taylor kernel's moment sums over Q.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def contact_state(F, w, pi, pj, X, Y, R, m):
    """Overlaps of the first m candidates at F (2, 2) and fluctuations w (N, 2).

    Returns:
        ``(qx, qy, lx, ly, d, e)``, each (m,): Q = L + w_j - w_i, l = F Q, d = |l|, e = R - d.
    """
    qx = np.empty(m)
    qy = np.empty(m)
    lx = np.empty(m)
    ly = np.empty(m)
    d = np.empty(m)
    e = np.empty(m)
    for c in range(m):
        i = pi[c]
        j = pj[c]
        x = X[c] + w[j, 0] - w[i, 0]
        y = Y[c] + w[j, 1] - w[i, 1]
        a = F[0, 0] * x + F[0, 1] * y
        b = F[1, 0] * x + F[1, 1] * y
        qx[c] = x
        qy[c] = y
        lx[c] = a
        ly[c] = b
        d[c] = np.sqrt(a * a + b * b)
        e[c] = R[c] - d[c]
    return qx, qy, lx, ly, d, e


@njit(cache=True)
def energy(e, K, use):
    """K/2 sum over the contacts ``use`` (m,) bool (all with e > 0) of e^2 (Pa)."""
    s = 0.0
    for c in range(e.shape[0]):
        if use[c]:
            s += e[c] * e[c]
    return 0.5 * K * s


@njit(cache=True)
def forces(F, pi, pj, lx, ly, d, e, K, n_disks, use):
    """Over the contacts ``use`` (m,) bool (all with e > 0): the gradient of their energy with
    respect to the fluctuations, (N, 2) (Pa per length), and the net contact force on each
    disk in the current frame, (N, 2), in units of K times length (sum of K e n over the
    disk's contacts, pushing it away from each partner)."""
    g = np.zeros((n_disks, 2))
    f = np.zeros((n_disks, 2))
    for c in range(e.shape[0]):
        if not use[c]:
            continue
        i = pi[c]
        j = pj[c]
        if i == j:
            continue  # a disk against its own image: no net force, no gradient
        s = K * e[c] / d[c]
        fx = s * lx[c]  # force on j, along n (from i to j), K e n
        fy = s * ly[c]
        f[j, 0] += fx
        f[j, 1] += fy
        f[i, 0] -= fx
        f[i, 1] -= fy
        # dphi/dw_j = F^T g_c with g_c = -K e n = -(fx, fy)
        gx = -(F[0, 0] * fx + F[1, 0] * fy)
        gy = -(F[0, 1] * fx + F[1, 1] * fy)
        g[j, 0] += gx
        g[j, 1] += gy
        g[i, 0] -= gx
        g[i, 1] -= gy
    return g, f


@njit(cache=True)
def non_rattlers(pi, pj, e, n_disks, min_contacts):
    """(N,) bool: the disks left after removing, recursively, every disk with fewer than
    ``min_contacts`` contacts (e > 0) with disks that are left. Contacts of a disk with its own
    image do not count."""
    keep = np.ones(n_disks, np.bool_)
    count = np.zeros(n_disks, np.int64)
    changed = True
    while changed:
        changed = False
        count[:] = 0
        for c in range(e.shape[0]):
            i = pi[c]
            j = pj[c]
            if e[c] > 0.0 and i != j and keep[i] and keep[j]:
                count[i] += 1
                count[j] += 1
        for k in range(n_disks):
            if keep[k] and count[k] < min_contacts:
                keep[k] = False
                changed = True
    return keep


@njit(cache=True)
def _contact_hessian(F, lx, ly, d, e, R, K, c, geometric):
    """The 2x2 stiffness F^T H_c F of contact c in the reference frame, and F^T H_c; without
    ``geometric``, H_c keeps only its positive part (R/d) n n^T (a Gauss-Newton block)."""
    nx = lx[c] / d[c]
    ny = ly[c] / d[c]
    b = K * e[c] / d[c] if geometric else 0.0
    a = K * R[c] / d[c] if geometric else K
    h00 = a * nx * nx - b
    h01 = a * nx * ny
    h11 = a * ny * ny - b
    # F^T H (2x2), then (F^T H) F
    t00 = F[0, 0] * h00 + F[1, 0] * h01
    t01 = F[0, 0] * h01 + F[1, 0] * h11
    t10 = F[0, 1] * h00 + F[1, 1] * h01
    t11 = F[0, 1] * h01 + F[1, 1] * h11
    k00 = t00 * F[0, 0] + t01 * F[1, 0]
    k01 = t00 * F[0, 1] + t01 * F[1, 1]
    k10 = t10 * F[0, 0] + t11 * F[1, 0]
    k11 = t10 * F[0, 1] + t11 * F[1, 1]
    return k00, k01, k10, k11, t00, t01, t10, t11


@njit(cache=True)
def stiffness(F, pi, pj, lx, ly, d, e, R, K, use, exact, dof):
    """COO entries of the stiffness d2W/dw2 over the contacts ``use`` (m,) bool, on the
    unknowns ``dof`` (N,) (disk k has unknowns 2 dof[k], 2 dof[k] + 1; dof < 0: fixed).
    Contacts not ``exact`` (m,) bool contribute their positive part only.

    Returns:
        ``(rows, cols, vals)``, duplicates to be summed.
    """
    m = e.shape[0]
    nnz = 0
    for c in range(m):
        if use[c] and pi[c] != pj[c]:
            nnz += 16
    rows = np.empty(nnz, np.int64)
    cols = np.empty(nnz, np.int64)
    vals = np.empty(nnz)
    t = 0
    for c in range(m):
        i = pi[c]
        j = pj[c]
        if not use[c] or i == j:
            continue
        k00, k01, k10, k11, _, _, _, _ = _contact_hessian(F, lx, ly, d, e, R, K, c, exact[c])
        for p in range(2):
            a = i if p == 0 else j
            for q in range(2):
                b = i if q == 0 else j
                sign = 1.0 if p == q else -1.0
                da = dof[a]
                db = dof[b]
                for r in range(2):
                    for s in range(2):
                        rows[t] = 2 * da + r if da >= 0 else -1
                        cols[t] = 2 * db + s if db >= 0 else -1
                        if r == 0:
                            v = k00 if s == 0 else k01
                        else:
                            v = k10 if s == 0 else k11
                        vals[t] = sign * v
                        t += 1
    return rows, cols, vals


@njit(cache=True)
def mixed(F, pi, pj, qx, qy, lx, ly, d, e, R, K, use, dof, n_unknowns):
    """d2W / dw dF over the contacts ``use``: (n_unknowns, 4), F flattened row-major."""
    B = np.zeros((n_unknowns, 4))
    for c in range(e.shape[0]):
        i = pi[c]
        j = pj[c]
        if not use[c] or i == j:
            continue
        _, _, _, _, t00, t01, t10, t11 = _contact_hessian(F, lx, ly, d, e, R, K, c, True)
        s = K * e[c] / d[c]
        g0 = -s * lx[c]
        g1 = -s * ly[c]
        q = (qx[c], qy[c])
        g = (g0, g1)
        T = ((t00, t01), (t10, t11))
        for p in range(2):
            disk = i if p == 0 else j
            if dof[disk] < 0:
                continue
            sign = -1.0 if p == 0 else 1.0
            for k in range(2):
                row = 2 * dof[disk] + k
                for a in range(2):
                    for b in range(2):
                        v = T[k][a] * q[b]
                        if b == k:
                            v += g[a]
                        B[row, 2 * a + b] += sign * v
    return B


#: what :func:`fire_chunk` stopped at
FIRE_RUNNING, FIRE_CONVERGED, FIRE_UNJAMMED = 0, 1, 2


@njit(cache=True)
def fire_chunk(F, Finv, u, v, pi, pj, X, Y, R, K, m, n_disks, params, n_steps, tol, E0, floor):
    """Up to ``n_steps`` FIRE steps (unit masses) on the current-frame fluctuations u (N, 2)
    with velocities v (N, 2), both updated in place, over the first m candidates.

    ``params`` (4,) = (dt, alpha, steps since the power was last negative, dt_max), updated in
    place. Stops when the largest net force is at most ``tol`` times the mean contact force
    (FIRE_CONVERGED), or when no two disks touch or the energy falls below ``floor`` times
    ``E0`` (FIRE_UNJAMMED). Returns ``(status, steps taken)``."""
    dt, alpha, since, dt_max = params[0], params[1], params[2], params[3]
    w = np.empty_like(u)
    status, step = FIRE_RUNNING, 0
    while step < n_steps:
        for i in range(n_disks):
            w[i, 0] = Finv[0, 0] * u[i, 0] + Finv[0, 1] * u[i, 1]
            w[i, 1] = Finv[1, 0] * u[i, 0] + Finv[1, 1] * u[i, 1]
        _, _, lx, ly, d, e = contact_state(F, w, pi, pj, X, Y, R, m)
        on = e > 0.0
        n_on = on.sum()
        if n_on == 0 or energy(e, K, on) < floor * E0:
            status = FIRE_UNJAMMED
            break
        _, f = forces(F, pi, pj, lx, ly, d, e, K, n_disks, on)
        mean_force = K * (e * on).sum() / n_on
        largest = np.sqrt((f * f).sum(axis=1).max())
        if largest <= tol * mean_force:
            status = FIRE_CONVERGED
            break
        power = (f * v).sum()
        if power > 0.0:
            fn = np.sqrt((f * f).sum())
            vn = np.sqrt((v * v).sum())
            v[:] = (1.0 - alpha) * v + alpha * vn * f / max(fn, 1e-300)
            since += 1.0
            if since > 5.0:
                dt = min(1.1 * dt, dt_max)
                alpha *= 0.99
        else:
            v[:] = 0.0
            dt, alpha, since = 0.5 * dt, 0.1, 0.0
        v += dt * f
        u += dt * v
        step += 1
    params[0], params[1], params[2] = dt, alpha, since
    return status, step
