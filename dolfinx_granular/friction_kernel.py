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
def atan2(y, x):
    """atan2(y, x) in (-pi, pi] without a libm call (selects only, so loops vectorise).

    Reduction to t = min(|x|, |y|) / max(|x|, |y|) in [0, 1]; t > 0.66 uses
    atan(t) = pi/4 + atan((t - 1) / (t + 1)). Not defined for x = y = 0.
    """
    ax = abs(x)
    ay = abs(y)
    swap = ay > ax
    mx = ay if swap else ax
    mn = ax if swap else ay
    big = mn > 0.66 * mx
    num = mn - mx if big else mn
    den = mn + mx if big else mx
    z = num / den
    zz = z * z
    p = (((_P0 * zz + _P1) * zz + _P2) * zz + _P3) * zz + _P4
    qq = ((((zz + _Q0) * zz + _Q1) * zz + _Q2) * zz + _Q3) * zz + _Q4
    r = z * (zz * p / qq) + z
    r = r + (_PIO4 + 0.5 * _MOREBITS) if big else r
    r = (_PIO2 - r) + _MOREBITS if swap else r
    r = (_PI - r) + 2.0 * _MOREBITS if x < 0.0 else r
    return -r if y < 0.0 else r


@njit(cache=True, fastmath=_FASTMATH, error_model="numpy")
def atan2_array(y, x, out):
    """:func:`atan2` elementwise over arrays of equal shape (n,), compiled with the kernel's flags."""
    for i in range(y.shape[0]):
        out[i] = atan2(y[i], x[i])


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
def _quadratic_forms(F00, F01, F10, F11, G00, G01, G10, G11):
    """Coefficients of cross(G L, F L) and dot(G L, F L) as quadratic forms in (xx, xy, yy)."""
    cxx = G00 * F10 - G10 * F00
    cxy = G00 * F11 + G01 * F10 - G10 * F01 - G11 * F00
    cyy = G01 * F11 - G11 * F01
    dxx = G00 * F00 + G10 * F10
    dxy = G00 * F01 + G01 * F00 + G10 * F11 + G11 * F10
    dyy = G01 * F01 + G11 * F11
    return cxx, cxy, cyy, dxx, dxy, dyy


@njit(cache=True, inline="always")
def _contact_law(ftn, ds, ee, kt, mukn):
    """Trial force, stick flag and new tangential force of one contact (closed form)."""
    fstar = ftn + kt * ds
    lim = mukn * ee
    stick = (abs(fstar) <= lim) & (lim > 0.0)  # mu = 0: no stick, the frictionless limit
    ft = fstar if stick else (lim if fstar >= 0.0 else -lim)
    return fstar, stick, ft


@njit(cache=True, fastmath=_FASTMATH, error_model="numpy")
def _friction_sums(F00, F01, F10, F11, G00, G01, G10, G11, dth, X, Y, R, n_visit, buf,
                   kn, kt, mu, tangent, acc):
    """Accumulate the moment sums of one point into ``acc`` (N_ACC,).

    ``buf[c]`` holds f_t,n of candidate c on entry and the new f_t on exit, c < n_visit (a
    contiguous view: an offset index would stop LLVM from vectorising); G = F_n. See the module
    docstring for the sums."""
    cxx, cxy, cyy, dxx, dxy, dyy = _quadratic_forms(F00, F01, F10, F11, G00, G01, G10, G11)
    mukn = mu * kn
    e2 = s0 = s1 = s2 = 0.0
    n0 = n1 = n2 = n3 = n4 = 0.0
    ft2 = dis = sr = u0 = u1 = u2 = 0.0
    h0 = h1 = h2 = h3 = h4 = 0.0
    k0 = k1 = k2 = k3 = k4 = 0.0
    p0 = p1 = p2 = p3 = p4 = 0.0
    z0 = z1 = z2 = w0 = w1 = w2 = skr = 0.0
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
        ds = r * (atan2(cxx * xx + cxy * xy + cyy * yy, dxx * xx + dxy * xy + dyy * yy) - dth)
        fstar, stick, ft = _contact_law(buf[c], ds, ee, kt, mukn)
        buf[c] = ft
        ft2 += ft * ft
        dis += abs(ft) * abs(fstar - ft)  # 0 in stick and for open contacts
        ftr = ft * r
        inv2 = inv * inv
        u = ftr * inv2
        sr += ftr
        u0 += u * xx
        u1 += u * xy
        u2 += u * yy
        if tangent:
            q0 = xx * xx
            q1 = xx * xy
            q2 = xx * yy
            q3 = xy * yy
            q4 = yy * yy
            g = r * inv * inv * inv
            n0 += g * q0
            n1 += g * q1
            n2 += g * q2
            n3 += g * q3
            n4 += g * q4
            gp = -u * inv2
            h0 += gp * q0
            h1 += gp * q1
            h2 += gp * q2
            h3 += gp * q3
            h4 += gp * q4
            kr2 = kt * r * r if stick else 0.0
            wst = kr2 * inv2
            skr += kr2
            z0 += wst * xx
            z1 += wst * xy
            z2 += wst * yy
            gs = wst * inv2
            k0 += gs * q0
            k1 += gs * q1
            k2 += gs * q2
            k3 += gs * q3
            k4 += gs * q4
            slip = (ee > 0.0) & (mukn > 0.0) & (not stick)
            wsl = ((mukn if fstar >= 0.0 else -mukn) * r * inv) if slip else 0.0
            w0 += wsl * xx
            w1 += wsl * xy
            w2 += wsl * yy
            gl = -wsl * inv2
            p0 += gl * q0
            p1 += gl * q1
            p2 += gl * q2
            p3 += gl * q3
            p4 += gl * q4
    acc[_E2] = e2
    acc[_S], acc[_S + 1], acc[_S + 2] = s0, s1, s2
    acc[_TN], acc[_TN + 1], acc[_TN + 2], acc[_TN + 3], acc[_TN + 4] = n0, n1, n2, n3, n4
    acc[_FT2] = ft2
    acc[_DIS] = dis
    acc[_SR] = sr
    acc[_U], acc[_U + 1], acc[_U + 2] = u0, u1, u2
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
def evaluate_batch(F, X, Y, R, rho, kn, kt, mu, inv_area, min_stretch, tangent,
                   Fn, off_n, f_n, D_n, off, f, W, P, A, D, status):
    """Energy, stress, tangent and the new history at n points, from their committed history.

    Args:
        F: (n, 2, 2) deformation gradients.
        X, Y, R, rho: (M,) candidate arrays of :func:`kernel.candidate_pairs` (L = (X, Y)).
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
    acc = np.empty(N_ACC)
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
        for c in range(m):
            f[o + c] = f_n[off_n[q] + c]
        for c in range(m, n_visit):
            f[o + c] = 0.0  # not stored: not active at F_n
        G00, G01, G10, G11 = Fn[q, 0, 0], Fn[q, 0, 1], Fn[q, 1, 0], Fn[q, 1, 1]
        dth, th, alpha, beta = _rotation(F00, F01, F10, F11, G00, G01, G10, G11)
        _friction_sums(F00, F01, F10, F11, G00, G01, G10, G11, dth, X, Y, R, n_visit,
                       f[o:o + n_visit], kn, kt, mu, tangent, acc)
        D[q] = D_n[q] + (acc[_DIS] / kt * inv_area if kt > 0.0 else 0.0)
        _finish_point(q, F[q], acc, (th, alpha, beta), K, inv_area, kt, tangent, W, P, A)


@njit(cache=True, fastmath=_FASTMATH, error_model="numpy")
def contact_step(F, Fn, X, Y, R, n_visit, buf, kn, kt, mu, eps_out, stick_out):
    """Per-candidate step of one point (same arithmetic as the batch kernel), for diagnostics.

    ``buf`` (n_visit,) holds f_t,n on entry and f_t on exit; ``eps_out`` gets the overlaps and
    ``stick_out`` 1 for a sticking contact, 0 otherwise."""
    F00, F01, F10, F11 = F[0, 0], F[0, 1], F[1, 0], F[1, 1]
    G00, G01, G10, G11 = Fn[0, 0], Fn[0, 1], Fn[1, 0], Fn[1, 1]
    dth = _rotation(F00, F01, F10, F11, G00, G01, G10, G11)[0]
    cxx, cxy, cyy, dxx, dxy, dyy = _quadratic_forms(F00, F01, F10, F11, G00, G01, G10, G11)
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
        ds = r * (atan2(cxx * xx + cxy * xy + cyy * yy, dxx * xx + dxy * xy + dyy * yy) - dth)
        _, stick, ft = _contact_law(buf[c], ds, ee, kt, mu * kn)
        buf[c] = ft
        eps_out[c] = eps
        stick_out[c] = 1 if stick else 0
