"""Numba kernels of the frictional Taylor RVE (model: ``shared/notes/friction-taylor.md``).

Notation as in :mod:`dolfinx_granular.kernel`: candidate c has reference branch vector L = (x, y),
radius sum R (the note's rho), l = F L, d = |l|, n = l / d, t = J n with J = [[0, -1], [1, 0]],
overlap eps = R - d. History per point: the committed F_n and the tangential forces f_t,n of the
candidates of its visited prefix (zero where a contact was not active at F_n).

Per active contact (tangential activity: eps > 0) the step from F_n to F is

    ds  = R (dphi - dtheta),  dphi = atan2(cross(l_n, l), dot(l_n, l)),  dtheta per point
    f*  = f_t,n + k_t ds;  stick if |f*| <= mu k_n eps (and mu k_n eps > 0), else f_t = ±mu k_n eps

With K_t = 1/V, Theta = dtheta/dF and H = d²theta/dF², every output is a contraction of moment sums
over the contacts (LL and LLLL products of the reference branch vector, as in the frictionless
kernel) with the per-point matrices F, JF = J F, Theta and H:

    S   = sum eps/d LL              U   = sum f_t R/d² LL          sR  = sum f_t R
    TN  = sum R/d³ LLLL             Tph = sum -f_t R/d⁴ LLLL       Tst = sum_stick k_t R²/d⁴ LLLL
    Tsl = sum_slip -s mu k_n R/d³ LLLL  (s = sign f*)
    Z1  = sum_stick k_t R²/d² LL    Z2  = sum_slip s mu k_n R/d LL  skr = sum_stick k_t R²

    P = -K F S + [JF U - sR Theta] / V
    A = K [F F TN - I S] + [JF F (Tph + Tsl) + F JF Tph + JF JF Tst - sR H
         - (JF Z1) x Theta - Theta x (JF Z1) + skr Theta x Theta + Theta x (F Z2)] / V

where ``X Y T`` means X_ae Y_cf T_efBD. The derivation: ds/dF = R [JF L x L / d² - Theta], the
second derivative of phi is -(t x n + n x t) L L / d², stick adds k_t ds/dF x ds/dF, slip adds
-s mu k_n ds/dF x (n x L) = -s mu k_n ds/dF x (F L x L) / d.

The contact loop has no function call (the angle uses the vectorisable :func:`atan2` below), so
LLVM vectorises it like the frictionless loop. Every point is computed independently with the same
code path, so results do not depend on how points are batched.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .kernel import _FASTMATH, OK, _check_F

# Cephes atan (S. L. Moshier), as in Go's math.Atan: rational approximation on |z| <= 0.66, peak
# relative error ~2e-16 over the whole line.
_P0 = -8.750608600031904122785e-01
_P1 = -1.615753718733365076637e01
_P2 = -7.500855792314704667340e01
_P3 = -1.228866684490136173410e02
_P4 = -6.485021904942025371773e01
_Q0 = 2.485846490142306297962e01
_Q1 = 1.650270098316988542046e02
_Q2 = 4.328810604912902668951e02
_Q3 = 4.853903996359136964868e02
_Q4 = 1.945506571482613964425e02
_MOREBITS = 6.123233995736765886130e-17  # pi/2 - fl(pi/2)
_PIO2 = 1.5707963267948966
_PIO4 = 0.7853981633974483
_PI = 3.141592653589793

# Layout of the per-point accumulator array (see the module docstring).
_E2, _S, _TN, _FT2, _DIS, _SR, _U, _TPH, _TST, _TSL, _Z1, _Z2, _SKR = (
    0, 1, 4, 9, 10, 11, 12, 15, 20, 25, 30, 33, 36)
N_ACC = 37


@njit(cache=True, inline="always")
def _atan2_unit(y, x):
    """atan2(y, x) in (-pi, pi] for max(|x|, |y|) of order 1 (not tiny, not huge), with selects
    only and one division, so that loops over it vectorise.

    Reduction to t = mn / mx = min(|x|, |y|) / max(|x|, |y|) in [0, 1] (t > 0.66:
    atan(t) = pi/4 + atan((mn - mx) / (mn + mx))), then Cephes' atan(z) = z + z z² P(z²) / Q(z²)
    written homogeneously in (num, den), z = num / den: num (Q^ + num² P^) / (den Q^) with
    P^ = den^8 P(z²), Q^ = den^10 Q(z²); all terms of P^ and of Q^ have one sign (no cancellation).
    """
    ax = abs(x)
    ay = abs(y)
    swap = ay > ax
    mx = ay if swap else ax
    mn = ax if swap else ay
    big = mn > 0.66 * mx
    num = mn - mx if big else mn
    den = mn + mx if big else mx
    n2 = num * num
    d2 = den * den
    d4 = d2 * d2
    d6 = d4 * d2
    d8 = d4 * d4
    p = (((_P0 * n2 + _P1 * d2) * n2 + _P2 * d4) * n2 + _P3 * d6) * n2 + _P4 * d8
    qq = ((((n2 + _Q0 * d2) * n2 + _Q1 * d4) * n2 + _Q2 * d6) * n2 + _Q3 * d8) * n2 + _Q4 * (d8 * d2)
    r = num * (qq + n2 * p) / (den * qq)
    r = r + (_PIO4 + 0.5 * _MOREBITS) if big else r
    r = (_PIO2 - r) + _MOREBITS if swap else r
    r = (_PI - r) + 2.0 * _MOREBITS if x < 0.0 else r
    return -r if y < 0.0 else r


@njit(cache=True, inline="always")
def atan2(y, x):
    """atan2(y, x) in (-pi, pi] for any finite (x, y) != (0, 0), to ~1 ulp (tests: <= 4 ulp)."""
    m = max(abs(x), abs(y))
    return _atan2_unit(y / m, x / m)


@njit(cache=True, fastmath=_FASTMATH, error_model="numpy")
def atan2_array(y, x, out, unit):
    """:func:`atan2` (``unit`` False) or :func:`_atan2_unit` (True) elementwise over (n,) arrays,
    compiled with the contact loop's flags (for tests)."""
    for i in range(y.shape[0]):
        out[i] = _atan2_unit(y[i], x[i]) if unit else atan2(y[i], x[i])


@njit(cache=True)
def prefix_lengths(F, rho, min_stretch, status, lengths):
    """Status code (n,) and the visited candidate count (n,) of each F (0 for a rejected F).

    The count is the prefix rho <= 1/s_min(F) that :func:`evaluate_batch` visits, and the length
    of the point's force array in the new state."""
    for q in range(F.shape[0]):
        code, limit = _check_F(F[q, 0, 0], F[q, 0, 1], F[q, 1, 0], F[q, 1, 1], min_stretch)
        status[q] = code
        lengths[q] = np.searchsorted(rho, limit, side="right") if code == OK else 0


@njit(cache=True, inline="always")
def _quadratic_forms(F00, F01, F10, F11, G00, G01, G10, G11, lmax2):
    """Coefficients of cross(G L, F L) and dot(G L, F L) as quadratic forms in (xx, xy, yy),
    scaled so that both are at most ~1 for |L|² <= lmax2 (the angle does not change)."""
    cxx = G00 * F10 - G10 * F00
    cxy = G00 * F11 + G01 * F10 - G10 * F01 - G11 * F00
    cyy = G01 * F11 - G11 * F01
    dxx = G00 * F00 + G10 * F10
    dxy = G00 * F01 + G01 * F00 + G10 * F11 + G11 * F10
    dyy = G01 * F01 + G11 * F11
    big = max(abs(cxx), abs(cxy), abs(cyy), abs(dxx), abs(dxy), abs(dyy))
    s = 1.0 / (big * lmax2)
    return cxx * s, cxy * s, cyy * s, dxx * s, dxy * s, dyy * s


@njit(cache=True, inline="always")
def _contact_law(ftn, ds, ee, kt, mukn):
    """Trial force, stick flag and new tangential force of one contact (closed form)."""
    fstar = ftn + kt * ds
    lim = mukn * ee
    stick = (abs(fstar) <= lim) & (lim > 0.0)  # mu = 0: no stick, the frictionless limit
    ft = fstar if stick else (lim if fstar >= 0.0 else -lim)
    return fstar, stick, ft


@njit(cache=True, fastmath=_FASTMATH, error_model="numpy")
def _contact_pass(F00, F01, F10, F11, cq, dth, X, Y, R, n_visit, kn, kt, mu, tangent, work,
                  acc):
    """Contact law and the stress sums of one point: e2, S, ft2, dis, sR, U into ``acc``.

    ``work`` (2, >= n_visit): row 0 holds f_t,n on entry and the new f_t on exit; row 1 gets 1/d
    (0 if open), negated unless the contact sticks, for :func:`_tangent_pass` (two short loops
    vectorise better than one with 37 running sums). Only these two rows are written: with more
    output arrays LLVM needs more runtime alias checks than it allows and leaves the loop scalar.
    ``tangent`` is unused (a branch in the loop would stop it vectorising too)."""
    cxx, cxy, cyy, dxx, dxy, dyy = cq
    mukn = mu * kn
    e2 = 0.0
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    ft2 = 0.0
    dis = 0.0
    sr = 0.0
    u0 = 0.0
    u1 = 0.0
    u2 = 0.0
    for c in range(n_visit):
        x = X[c]
        y = Y[c]
        r = R[c]
        lx = F00 * x + F01 * y  # same arithmetic as kernel._moment_sums: same active set
        ly = F10 * x + F11 * y
        d = np.sqrt(lx * lx + ly * ly)
        eps = r - d
        on = 1.0 if eps >= 0.0 else 0.0
        ee = eps if eps >= 0.0 else 0.0
        inv = on / d
        xx = x * x
        xy = x * y
        yy = y * y
        b = ee * inv
        e2 += ee * ee
        s0 += b * xx
        s1 += b * xy
        s2 += b * yy
        # sliding since F_n: branch rotation minus particle spin, both wrapped to (-pi, pi]
        dphi = _atan2_unit(cxx * xx + cxy * xy + cyy * yy, dxx * xx + dxy * xy + dyy * yy)
        fstar, stick, ft = _contact_law(work[0, c], r * (dphi - dth), ee, kt, mukn)
        work[0, c] = ft
        ft2 += ft * ft
        dis += abs(ft) * abs(fstar - ft)  # 0 in stick and for open contacts
        ftr = ft * r
        u = ftr * inv * inv
        sr += ftr
        u0 += u * xx
        u1 += u * xy
        u2 += u * yy
        work[1, c] = inv if stick else -inv
    acc[_E2] = e2
    acc[_S] = s0
    acc[_S + 1] = s1
    acc[_S + 2] = s2
    acc[_FT2] = ft2
    acc[_DIS] = dis
    acc[_SR] = sr
    acc[_U] = u0
    acc[_U + 1] = u1
    acc[_U + 2] = u2


# The tangent sums decide nothing (no active set), so they may use fused multiply-adds.
_FASTMATH_SUMS = _FASTMATH | {"contract"}


@njit(cache=True, fastmath=_FASTMATH_SUMS, error_model="numpy")
def _tangent_pass(X, Y, R, n_visit, work, kt, mukn, acc):
    """The tangent's moment sums TN, Tph, Tst, Tsl, Z1, Z2, skr of one point into ``acc``, from
    the new forces and the signed 1/d in ``work`` (see :func:`_contact_pass`).

    Stick: work[1] > 0, weight k_t R². Slip (sliding sign s = sign f_t, f_t = s mu k_n eps):
    work[1] < 0, weight s mu k_n R; f_t = 0 (open, eps = 0 or mu = 0) gives no slip weight."""
    n0 = n1 = n2 = n3 = n4 = 0.0
    h0 = h1 = h2 = h3 = h4 = 0.0
    k0 = k1 = k2 = k3 = k4 = 0.0
    p0 = p1 = p2 = p3 = p4 = 0.0
    z0 = z1 = z2 = 0.0
    w0 = w1 = w2 = 0.0
    skr = 0.0
    for c in range(n_visit):
        x = X[c]
        y = Y[c]
        r = R[c]
        ft = work[0, c]
        w = work[1, c]
        inv = abs(w)
        ws = kt * r * r if w > 0.0 else 0.0
        wl = mukn * r if ft > 0.0 else -mukn * r
        wl = wl if (w < 0.0) & (ft != 0.0) else 0.0
        xx = x * x
        xy = x * y
        yy = y * y
        q0 = xx * xx
        q1 = xx * xy
        q2 = xx * yy
        q3 = xy * yy
        q4 = yy * yy
        inv2 = inv * inv
        inv3 = inv2 * inv
        inv4 = inv2 * inv2
        g = r * inv3
        n0 += g * q0
        n1 += g * q1
        n2 += g * q2
        n3 += g * q3
        n4 += g * q4
        g = -ft * r * inv4
        h0 += g * q0
        h1 += g * q1
        h2 += g * q2
        h3 += g * q3
        h4 += g * q4
        g = ws * inv4
        k0 += g * q0
        k1 += g * q1
        k2 += g * q2
        k3 += g * q3
        k4 += g * q4
        g = -wl * inv3
        p0 += g * q0
        p1 += g * q1
        p2 += g * q2
        p3 += g * q3
        p4 += g * q4
        g = ws * inv2
        z0 += g * xx
        z1 += g * xy
        z2 += g * yy
        g = wl * inv
        w0 += g * xx
        w1 += g * xy
        w2 += g * yy
        skr += ws
    acc[_TN], acc[_TN + 1], acc[_TN + 2], acc[_TN + 3], acc[_TN + 4] = n0, n1, n2, n3, n4
    acc[_TPH], acc[_TPH + 1], acc[_TPH + 2], acc[_TPH + 3], acc[_TPH + 4] = h0, h1, h2, h3, h4
    acc[_TST], acc[_TST + 1], acc[_TST + 2], acc[_TST + 3], acc[_TST + 4] = k0, k1, k2, k3, k4
    acc[_TSL], acc[_TSL + 1], acc[_TSL + 2], acc[_TSL + 3], acc[_TSL + 4] = p0, p1, p2, p3, p4
    acc[_Z1], acc[_Z1 + 1], acc[_Z1 + 2] = z0, z1, z2
    acc[_Z2], acc[_Z2 + 1], acc[_Z2 + 2] = w0, w1, w2
    acc[_SKR] = skr


@njit(cache=True, inline="always")
def _rotation(F00, F01, F10, F11, G00, G01, G10, G11):
    """Rotation increment dtheta = wrap(theta(F) - theta(G)), Theta = dtheta/dF (4 entries, row
    major) and the coefficients (alpha, beta) of its Hessian
    H = alpha (J x J - I x I) + beta (J x I + I x J)."""
    a = F10 - F01
    b = F00 + F11
    an = G10 - G01
    bn = G00 + G11
    dth = atan2(a * bn - b * an, b * bn + a * an)
    r = np.sqrt(a * a + b * b)  # = tr U >= 2 s_min: never small for a supported F
    ca = a / r
    cb = b / r
    ir = 1.0 / r
    # Theta = (cb J - ca I) / r,  H = -(2 / r²) [ca cb (JxJ - IxI) + (cb² - ca²)/2 (JxI + IxJ)]
    th = (-ca * ir, -cb * ir, cb * ir, -ca * ir)
    alpha = -2.0 * ca * cb * ir * ir
    beta = -(cb * cb - ca * ca) * ir * ir
    return dth, th, alpha, beta


@njit(cache=True)
def _finish_point(q, Fq, acc, dth_data, K, inv_area, kt, tangent, W, P, A):
    """W[q], P[q] and (if ``tangent``) A[q] from the moment sums of point q."""
    th, alpha, beta = dth_data
    JF = np.empty((2, 2))
    JF[0, 0] = -Fq[1, 0]
    JF[0, 1] = -Fq[1, 1]
    JF[1, 0] = Fq[0, 0]
    JF[1, 1] = Fq[0, 1]
    Th = np.empty((2, 2))
    Th[0, 0], Th[0, 1], Th[1, 0], Th[1, 1] = th
    W[q] = 0.5 * K * acc[_E2] + (0.5 * acc[_FT2] / kt * inv_area if kt > 0.0 else 0.0)
    sr = acc[_SR]
    for a in range(2):
        for b in range(2):
            fric = JF[a, 0] * acc[_U + b] + JF[a, 1] * acc[_U + 1 + b] - sr * Th[a, b]
            P[q, a, b] = -K * (Fq[a, 0] * acc[_S + b] + Fq[a, 1] * acc[_S + 1 + b]) + inv_area * fric
    if not tangent:
        return
    # Z1 and Z2 contracted: JF Z1L, F Z2L
    Z1 = np.empty((2, 2))
    Z2 = np.empty((2, 2))
    for a in range(2):
        for b in range(2):
            Z1[a, b] = JF[a, 0] * acc[_Z1 + b] + JF[a, 1] * acc[_Z1 + 1 + b]
            Z2[a, b] = Fq[a, 0] * acc[_Z2 + b] + Fq[a, 1] * acc[_Z2 + 1 + b]
    I2 = ((1.0, 0.0), (0.0, 1.0))
    J2 = ((0.0, -1.0), (1.0, 0.0))
    skr = acc[_SKR]
    for a in range(2):
        for b in range(2):
            for c in range(2):
                for d in range(2):
                    nrm = 0.0
                    fr = 0.0
                    for e in range(2):
                        for f in range(2):
                            i = e + f + b + d
                            nrm += Fq[a, e] * Fq[c, f] * acc[_TN + i]
                            fr += (JF[a, e] * Fq[c, f] * (acc[_TPH + i] + acc[_TSL + i])
                                   + Fq[a, e] * JF[c, f] * acc[_TPH + i]
                                   + JF[a, e] * JF[c, f] * acc[_TST + i])
                    if a == c:
                        nrm -= acc[_S + b + d]
                    H = (alpha * (J2[a][b] * J2[c][d] - I2[a][b] * I2[c][d])
                         + beta * (J2[a][b] * I2[c][d] + I2[a][b] * J2[c][d]))
                    fr += (-sr * H - Z1[a, b] * Th[c, d] - Th[a, b] * Z1[c, d]
                           + skr * Th[a, b] * Th[c, d] + Th[a, b] * Z2[c, d])
                    A[q, a, b, c, d] = K * nrm + inv_area * fr


@njit(cache=True)
def evaluate_batch(F, X, Y, R, rho, lmax2, kn, kt, mu, inv_area, min_stretch, tangent,
                   Fn, off_n, f_n, D_n, off, f, W, P, A, D, status):
    """Energy, stress, tangent and the new history at n points, from their committed history.

    Args:
        F: (n, 2, 2) deformation gradients.
        X, Y, R, rho: (M,) candidate arrays of :func:`kernel.candidate_pairs` (L = (X, Y)).
        lmax2: max |L|² over the candidates (scales the angle computation).
        kn, kt, mu: normal stiffness, tangential stiffness (N/m²), friction coefficient.
        inv_area: 1 / V_rve.
        min_stretch: smallest supported singular value of F.
        tangent: compute A (else A is not touched and may have length 0).
        Fn: (n, 2, 2) committed F; off_n (n + 1,), f_n: committed tangential forces of point q
            at f_n[off_n[q]:off_n[q + 1]] (candidates in order; missing ones are 0); D_n (n,)
            committed dissipation (Pa).
        off: (n + 1,) offsets of the new forces, lengths from :func:`prefix_lengths`.
        f: out, new tangential forces (N per unit thickness).
        W, P, A: out, (n,) energy density, (n, 2, 2) first Piola stress, (n, 2, 2, 2, 2) dP/dF.
        D: out (n,), dissipation after the step (Pa).
        status: (n,) int8 out: OK or the reason F was rejected (outputs then zero).
    """
    K = kn * inv_area
    acc = np.zeros(N_ACC)
    work = np.empty((2, R.shape[0]))
    for q in range(F.shape[0]):
        F00, F01, F10, F11 = F[q, 0, 0], F[q, 0, 1], F[q, 1, 0], F[q, 1, 1]
        code, _ = _check_F(F00, F01, F10, F11, min_stretch)
        status[q] = code
        if code != OK:
            W[q] = 0.0
            P[q, :, :] = 0.0
            D[q] = 0.0
            if tangent:
                A[q, :, :, :, :] = 0.0
            continue
        o = off[q]
        n_visit = off[q + 1] - o
        m = min(n_visit, off_n[q + 1] - off_n[q])
        work[0, :m] = f_n[off_n[q]:off_n[q] + m]
        work[0, m:n_visit] = 0.0  # not stored: not active at F_n
        G00, G01, G10, G11 = Fn[q, 0, 0], Fn[q, 0, 1], Fn[q, 1, 0], Fn[q, 1, 1]
        dth, th, alpha, beta = _rotation(F00, F01, F10, F11, G00, G01, G10, G11)
        cq = _quadratic_forms(F00, F01, F10, F11, G00, G01, G10, G11, lmax2)
        _contact_pass(F00, F01, F10, F11, cq, dth, X, Y, R, n_visit, kn, kt, mu, tangent, work,
                      acc)
        f[o:o + n_visit] = work[0, :n_visit]
        if tangent:
            _tangent_pass(X, Y, R, n_visit, work, kt, mu * kn, acc)
        D[q] = D_n[q] + (acc[_DIS] / kt * inv_area if kt > 0.0 else 0.0)
        _finish_point(q, F[q], acc, (th, alpha, beta), K, inv_area, kt, tangent, W, P, A)


@njit(cache=True, fastmath=_FASTMATH, error_model="numpy")
def contact_step(F, Fn, X, Y, R, n_visit, lmax2, buf, kn, kt, mu, eps_out, stick_out):
    """Per-candidate step of one point (same arithmetic as :func:`_contact_pass`), for diagnostics.

    ``buf`` (n_visit,) holds f_t,n on entry and f_t on exit; ``eps_out`` gets the overlaps and
    ``stick_out`` 1 for a sticking contact, 0 otherwise."""
    F00, F01, F10, F11 = F[0, 0], F[0, 1], F[1, 0], F[1, 1]
    G00, G01, G10, G11 = Fn[0, 0], Fn[0, 1], Fn[1, 0], Fn[1, 1]
    dth = _rotation(F00, F01, F10, F11, G00, G01, G10, G11)[0]
    cxx, cxy, cyy, dxx, dxy, dyy = _quadratic_forms(F00, F01, F10, F11, G00, G01, G10, G11,
                                                    lmax2)
    for c in range(n_visit):
        x = X[c]
        y = Y[c]
        r = R[c]
        lx = F00 * x + F01 * y
        ly = F10 * x + F11 * y
        eps = r - np.sqrt(lx * lx + ly * ly)
        ee = eps if eps >= 0.0 else 0.0
        xx = x * x
        xy = x * y
        yy = y * y
        dphi = _atan2_unit(cxx * xx + cxy * xy + cyy * yy, dxx * xx + dxy * xy + dyy * yy)
        _, stick, ft = _contact_law(buf[c], r * (dphi - dth), ee, kt, mu * kn)
        buf[c] = ft
        eps_out[c] = eps
        stick_out[c] = 1 if stick else 0
