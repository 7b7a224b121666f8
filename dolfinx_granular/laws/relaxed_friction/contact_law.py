"""One frictional contact of the relaxed cell: kinematics, the Coulomb return map, and its
derivatives.

Disks i, j (radii r_i, r_j, R = r_i + r_j) sit at x = F (X + w) and have turned by theta
(counter-clockwise, absolute). A candidate c has the reference branch L, the relaxed reference
branch Q = L + w_j - w_i, the current branch l = F Q, d = |l|, n = l / d, t = (-n_y, n_x) and
the overlap e = R - d (a contact where e > 0; f_n = k_n e).

Sliding over an increment from the committed state (subscript 0) is measured with lever arms
r_i, r_j about the centres:

    ds = r_i psi_i + r_j psi_j,  psi_k = the angle from Rot(theta_k - theta_0k) l_0 to l,

wrapped once into (-pi, pi]: the relative tangential motion of j's surface against i's along t
(a rigid rotation of the pair slides nothing; j rolling on i without slip neither). The trial
force f* = f_t0 + k_t ds sticks where |f*| <= mu f_n, else f_t = mu f_n sign(f*) (backward
Euler). The generalised forces, the derivatives of the incremental potential k_n e^2/2 +
f*^2 / (2 k_t) (in stick) with u = (w_i, theta_i, w_j, theta_j):

    dW/du = B^T g + a f_t,   g = -f_n n + f_t (R / d) t,

B = dl/du (2, 6) = [-F, 0, F, 0], a = d ds/dtheta = (0, 0, -r_i, 0, 0, -r_j). So disk j feels
the force f_n n - f_t (R/d) t and the moment r_j f_t, disk i the opposite force and the moment
r_i f_t: ``tangential`` = -f_t is the Coulomb-capped force on j along t, which the balance of
forces takes times R / d (the lever-arm convention; it differs from a force at the contact
point by O(e / R)). The stress is P = B_F^T g with B_F = dl/dF (2, 4), B_F[a, 2c + d] =
delta_ac Q_d; every quantity here is per contact and in N (the caller divides by the cell's
area).

The derivatives (s = d ds/du = B^T (R/d) t + a; de/du = -B^T n):

    d2W/du2 = B^T H B + s (x) df,  H = k_n n n^T - (f_n / d) t t^T - (f_t R / d^2)(n t^T + t n^T),
    df = k_t s (stick), mu sign(f*) k_n de/du (slip),

and the same with B_F for F, plus the terms from Q's and B's own dependence (g_a dQ_b/du,
delta_bd g_c); symmetric in stick, not in slip.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .rolling import rolling_map

#: a contact's status in :func:`return_map`
OPEN, STICK, SLIP = 0, 1, 2


@njit(cache=True)
def angle(ax, ay, bx, by):
    """The angle from a to b in (-pi, pi]."""
    return np.arctan2(ax * by - ay * bx, ax * bx + ay * by)


@njit(cache=True)
def sliding(F, w, th, F0, w0, th0, i, j, X, Y, ri, rj, lx, ly):
    """ds of one contact (current branch (lx, ly)) from its committed branch F0 (L + w0_j -
    w0_i) and rotations."""
    x0 = X + w0[j, 0] - w0[i, 0]
    y0 = Y + w0[j, 1] - w0[i, 1]
    ax = F0[0, 0] * x0 + F0[0, 1] * y0
    ay = F0[1, 0] * x0 + F0[1, 1] * y0
    s = 0.0
    for k, r in ((i, ri), (j, rj)):
        a = th[k] - th0[k]
        ca, sa = np.cos(a), np.sin(a)
        s += r * angle(ca * ax - sa * ay, sa * ax + ca * ay, lx, ly)
    return s


@njit(cache=True)
def return_map(F, w, th, F0, w0, th0, ft0, mr0, pi, pj, X, Y, R, radii, m, kn, kt, mu, kr,
               mu_r):  # fmt: skip
    """The contacts of the first m candidates at (F, w, theta) after the increment from the
    committed (F0, w0, theta0) with tangential forces ft0 and rolling moments mr0 (>= m,) (N,
    N m; zero for a new contact), the rolling springs ``kr`` = beta k_t and ``mu_r``
    (:mod:`.rolling`).

    Returns:
        ``(qx, qy, lx, ly, d, e, ft, fstar, status, mr, mstar, rstatus)``, each (m,): the
        branches, the overlap, the new tangential force f_t and the trial f* (N), OPEN / STICK /
        SLIP, and the same for the rolling moment (OPEN everywhere without rolling resistance).
    """
    qx, qy, lx, ly = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    d, e = np.empty(m), np.empty(m)
    ft, fstar = np.zeros(m), np.zeros(m)
    status = np.zeros(m, np.int8)
    mr, mstar = np.zeros(m), np.zeros(m)
    rstatus = np.zeros(m, np.int8)
    for c in range(m):
        i, j = pi[c], pj[c]
        x = X[c] + w[j, 0] - w[i, 0]
        y = Y[c] + w[j, 1] - w[i, 1]
        a = F[0, 0] * x + F[0, 1] * y
        b = F[1, 0] * x + F[1, 1] * y
        qx[c], qy[c], lx[c], ly[c] = x, y, a, b
        d[c] = np.sqrt(a * a + b * b)
        e[c] = R[c] - d[c]
        if e[c] <= 0.0:
            continue
        ds = sliding(F, w, th, F0, w0, th0, i, j, X[c], Y[c], radii[i], radii[j], a, b)
        fs = ft0[c] + kt * ds
        cap = mu * kn * e[c]
        fstar[c] = fs
        if abs(fs) <= cap and cap > 0.0:  # (mu = 0: never sticks)
            ft[c], status[c] = fs, STICK
        else:
            ft[c], status[c] = (cap if fs >= 0.0 else -cap), SLIP
        if mu_r > 0.0:
            mr[c], mstar[c], rstatus[c] = rolling_map(
                th, th0, mr0[c], i, j, radii[i], radii[j], e[c], kn, kr, mu_r
            )
    return qx, qy, lx, ly, d, e, ft, fstar, status, mr, mstar, rstatus


@njit(cache=True)
def local(F, qx, qy, lx, ly, d, e, ft, fstar, status, R, ri, rj, kn, kt, mu, tangent, out):
    """One contact's generalised force (6,) and stress (4,) and its derivatives (N; the
    module's formulas) by ``tangent``: 0 none, 1 Kuu (the Jacobian), 2 all. ``out`` is a
    tuple of scratch arrays (:func:`scratch`) written in place: r (6,), P (4,), Kuu (6, 6),
    KFF (4, 4), KFu (4, 6), KuF (6, 4), then work arrays."""
    r, P = out[0], out[1]
    nx, ny, tx, ty, fn, lever = _frame(lx, ly, d, e, R, kn)
    gx = -fn * nx + ft * lever * tx
    gy = -fn * ny + ft * lever * ty
    # B^T g: w_i gets -F^T g, w_j +F^T g
    Fg0 = F[0, 0] * gx + F[1, 0] * gy
    Fg1 = F[0, 1] * gx + F[1, 1] * gy
    r[0], r[1], r[2] = -Fg0, -Fg1, -ri * ft
    r[3], r[4], r[5] = Fg0, Fg1, -rj * ft
    P[0], P[1], P[2], P[3] = gx * qx, gx * qy, gy * qx, gy * qy
    if tangent == 0:
        return
    Kuu, KFF, KFu, KuF = out[2], out[3], out[4], out[5]
    B = out[6]  # (2, 6)
    BF = out[7]  # (2, 4)
    s = out[8][0]  # (6,) d ds/du
    sF = out[8][1][:4]
    de = out[8][2]
    deF = out[8][3][:4]
    df = out[8][4]
    dfF = out[8][5][:4]
    B[:] = 0.0
    for a in range(2):
        for b in range(2):
            B[a, b] = -F[a, b]
            B[a, 3 + b] = F[a, b]
    BF[:] = 0.0
    BF[0, 0], BF[0, 1], BF[1, 2], BF[1, 3] = qx, qy, qx, qy
    h00, h01, h11 = _hessian(nx, ny, tx, ty, fn, ft, lever, d, kn)
    for u in range(6):
        s[u] = lever * (B[0, u] * tx + B[1, u] * ty)
        de[u] = -(B[0, u] * nx + B[1, u] * ny)
    s[2] -= ri
    s[5] -= rj
    for u in range(4):
        sF[u] = lever * (BF[0, u] * tx + BF[1, u] * ty)
        deF[u] = -(BF[0, u] * nx + BF[1, u] * ny)
    if status == 1:  # stick
        for u in range(6):
            df[u] = kt * s[u]
        for u in range(4):
            dfF[u] = kt * sF[u]
    else:
        k = mu * kn if ft >= 0.0 else -mu * kn  # (f_t = +-mu f_n: its sign is the slip's)
        for u in range(6):
            df[u] = k * de[u]
        for u in range(4):
            dfF[u] = k * deF[u]
    _quadratic(B, B, h00, h01, h11, s, df, Kuu)
    if tangent == 1:
        return
    _quadratic(BF, BF, h00, h01, h11, sF, dfF, KFF)
    _quadratic(BF, B, h00, h01, h11, sF, df, KFu)
    _quadratic(B, BF, h00, h01, h11, s, dfF, KuF)
    _add_branch_terms(KFu, KuF, gx, gy)


@njit(cache=True, inline="always")
def jacobian(F, lx, ly, d, e, ft, status, R, ri, rj, kn, kt, mu, K, de, s, G):
    """:func:`local`'s Kuu (6, 6) into K and de/du (6,) into ``de``, written out: B = [-F, 0,
    F, 0] makes each 2 x 2 block of B^T H B F^T H F up to its sign (the same products and sums
    as :func:`local`'s, bit for bit; its scratch arrays, zeros and calls cost 5 times as much
    in the Newton loop). s (6,) and G (2, 2): work arrays (allocated once for all contacts)."""
    nx, ny, tx, ty, fn, lever = _frame(lx, ly, d, e, R, kn)
    h00, h01, h11 = _hessian(nx, ny, tx, ty, fn, ft, lever, d, kn)
    for b in range(2):  # (the translations of j: B's columns F[:, b]; i's: their negatives)
        s[3 + b] = lever * (F[0, b] * tx + F[1, b] * ty)
        de[3 + b] = -(F[0, b] * nx + F[1, b] * ny)
        s[b], de[b] = -s[3 + b], -de[3 + b]
    s[2], s[5], de[2], de[5] = -ri, -rj, 0.0, 0.0
    if status == STICK:
        k = kt
        df = s
    else:
        k = mu * kn if ft >= 0.0 else -mu * kn
        df = de
    for a in range(2):
        a0 = F[0, a] * h00 + F[1, a] * h01
        a1 = F[0, a] * h01 + F[1, a] * h11
        for b in range(2):
            G[a, b] = a0 * F[0, b] + a1 * F[1, b]
    for u in range(6):
        for v in range(6):
            g = 0.0
            if u % 3 < 2 and v % 3 < 2:
                g = G[u % 3, v % 3] if (u < 3) == (v < 3) else -G[u % 3, v % 3]
            K[u, v] = g + s[u] * (k * df[v])


@njit(cache=True, inline="always")
def _add_branch_terms(KFu, KuF, gx, gy):
    """The mixed terms from Q's and B's own dependence on u and F: P_ab = g_a Q_b with
    dQ/dw_i = -I, dQ/dw_j = I adds g_a dQ_b/du to KFu; r_(w_j, e) = F_ae g_a adds delta_de g_c
    to KuF (minus for w_i)."""
    for a, ga in ((0, gx), (1, gy)):
        for b in range(2):
            KFu[2 * a + b, b] -= ga
            KFu[2 * a + b, 3 + b] += ga
    for e_ in range(2):
        for c, gc in ((0, gx), (1, gy)):
            KuF[3 + e_, 2 * c + e_] += gc
            KuF[e_, 2 * c + e_] -= gc


@njit(cache=True, inline="always")
def _frame(lx, ly, d, e, R, kn):
    """The contact's frame and force: ``(n_x, n_y, t_x, t_y, f_n, R / d)``, t = (-n_y, n_x)."""
    nx, ny = lx / d, ly / d
    return nx, ny, -ny, nx, kn * e, R / d


@njit(cache=True, inline="always")
def _hessian(nx, ny, tx, ty, fn, ft, lever, d, kn):
    """H's entries (h00, h01, h11): k_n n n^T - (f_n / d) t t^T - (f_t R / d^2)(n t^T + t n^T)."""
    h00 = kn * nx * nx - fn / d * tx * tx - 2.0 * ft * lever / d * nx * tx
    h01 = kn * nx * ny - fn / d * tx * ty - ft * lever / d * (nx * ty + tx * ny)
    h11 = kn * ny * ny - fn / d * ty * ty - 2.0 * ft * lever / d * ny * ty
    return h00, h01, h11


@njit(cache=True, inline="always")
def _entry(b1, b2, h00, h01, h11, s1, df2):
    """One entry of B1^T H B2 + s1 (x) df2 from B1's and B2's columns b1, b2 (2-tuples), as
    :func:`_quadratic` sums it."""
    a0 = b1[0] * h00 + b1[1] * h01
    a1 = b1[0] * h01 + b1[1] * h11
    return a0 * b2[0] + a1 * b2[1] + s1 * df2


@njit(cache=True)
def mixed_terms(F, qx, qy, lx, ly, d, e, ft, status, R, ri, rj, kn, kt, mu, KFF, KFu, KuF,
                deF, work):  # fmt: skip
    """:func:`local`'s KFF (4, 4), KFu (4, 6) and KuF (6, 4) into the arrays given, and de/dF
    (4,) into ``deF``: the same products and sums, bit for bit, with B's and B_F's columns as
    tuples (the condensed tangent's mixed terms, without Kuu). ``work``: :func:`mixed_work`
    (allocated once for all contacts: 5 allocations a contact cost as much as its sums)."""
    nx, ny, tx, ty, fn, lever = _frame(lx, ly, d, e, R, kn)
    gx = -fn * nx + ft * lever * tx
    gy = -fn * ny + ft * lever * ty
    h00, h01, h11 = _hessian(nx, ny, tx, ty, fn, ft, lever, d, kn)
    B = ((-F[0, 0], -F[1, 0]), (-F[0, 1], -F[1, 1]), (0.0, 0.0), (F[0, 0], F[1, 0]),
         (F[0, 1], F[1, 1]), (0.0, 0.0))  # fmt: skip
    BF = ((qx, 0.0), (qy, 0.0), (0.0, qx), (0.0, qy))
    s, de, df, sF, dfF = work
    k = kt if status == STICK else (mu * kn if ft >= 0.0 else -mu * kn)
    for u in range(6):
        s[u] = lever * (B[u][0] * tx + B[u][1] * ty)
        de[u] = -(B[u][0] * nx + B[u][1] * ny)
    s[2] -= ri
    s[5] -= rj
    for u in range(4):
        sF[u] = lever * (BF[u][0] * tx + BF[u][1] * ty)
        deF[u] = -(BF[u][0] * nx + BF[u][1] * ny)
    for u in range(6):
        df[u] = k * (s[u] if status == STICK else de[u])
    for u in range(4):
        dfF[u] = k * (sF[u] if status == STICK else deF[u])
    for u in range(4):
        for v in range(4):
            KFF[u, v] = _entry(BF[u], BF[v], h00, h01, h11, sF[u], dfF[v])
        for v in range(6):
            KFu[u, v] = _entry(BF[u], B[v], h00, h01, h11, sF[u], df[v])
            KuF[v, u] = _entry(B[v], BF[u], h00, h01, h11, s[v], dfF[u])
    _add_branch_terms(KFu, KuF, gx, gy)


@njit(cache=True)
def mixed_work():
    """The work arrays of :func:`mixed_terms`: ``(s, de, df (6,), sF, dfF (4,))``."""
    return np.empty(6), np.empty(6), np.empty(6), np.empty(4), np.empty(4)


@njit(cache=True)
def _quadratic(B1, B2, h00, h01, h11, s1, df2, out):
    """out = B1^T H B2 + s1 (x) df2 (H symmetric 2 x 2)."""
    for u in range(B1.shape[1]):
        a0 = B1[0, u] * h00 + B1[1, u] * h01
        a1 = B1[0, u] * h01 + B1[1, u] * h11
        for v in range(B2.shape[1]):
            out[u, v] = a0 * B2[0, v] + a1 * B2[1, v] + s1[u] * df2[v]


@njit(cache=True)
def scratch():
    """The work arrays :func:`local` writes into."""
    return (
        np.zeros(6), np.zeros(4), np.zeros((6, 6)), np.zeros((4, 4)), np.zeros((4, 6)),
        np.zeros((6, 4)), np.zeros((2, 6)), np.zeros((2, 4)), np.zeros((6, 6)),
    )  # fmt: skip
