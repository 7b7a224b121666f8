"""Numba kernels of the frictional Taylor RVE (model: ``shared/notes/friction-taylor.md``).

Notation as in :mod:`dolfinx_granular.kernel`: candidate c has reference branch vector L = (x, y),
radius sum R (the note's rho), l = F L, d = |l|, n = l / d, t = J n with J = [[0, -1], [1, 0]],
overlap eps = R - d. History per point: the committed F_n (= G below) and the tangential forces
f_t,n of a prefix of the candidates (zero where a contact was not active at F_n).

Per contact with eps > 0 the step from F_n to F is (closed form, no local iteration)

    ds = R (dphi - dtheta),  dphi = atan2(cross(G L, F L), dot(G L, F L)),  dtheta per point,
    f* = f_t,n + k_t ds;  stick if |f*| <= lim = mu k_n eps and lim > 0, else f_t = sign(f*) lim.

Every output is a contraction of moment sums over the contacts (weighted LL and LLLL products of
the reference branch vector, as in the frictionless kernel) with the per-point matrices F,
JF = J F, Theta = dtheta/dF and H = d²theta/dF². With w_st = k_t R² for sticking contacts and
w_sl = sign(f_t) mu k_n R for sliding ones (else 0):

    S  = sum eps/d LL                 U  = sum f_t R/d² LL           sR = sum f_t R
    TA = sum (k_n R/d³ - w_st/d⁴) LLLL    TB = sum (-2 f_t R/d⁴ - w_sl/d³) LLLL
    Z1 = sum w_st/d² LL               Z2 = sum w_sl/d LL             skr = sum w_st

    V P = -k_n F S + JF U - sR Theta
    V A = F F TA + F JF TB - k_n I S + I Z1 - J (U + Z2) - sR H
          - (JF Z1) x Theta - Theta x (JF Z1) + skr Theta x Theta + Theta x (F Z2)

where ``X Y T`` means X_ae Y_cf T_efBD and ``I S`` means delta_ac S_BD. Derivation: ds/dF =
R [t (x) L / d - Theta], d²phi/dF² = -(t n + n t) L L / d², stick adds k_t ds/dF (x) ds/dF, slip
adds -sign(f*) mu k_n ds/dF (x) (n (x) L). Per contact the 4th-order part is M_ac L_B L_D with
M = a n n + b n t + c t n + e t t; t t = I - n n and t n = n t + J give
M = (a - e) n n + (b + c) n t + e I + c J, hence two LLLL sums instead of four.

The contact loops have no branch (atan by selects and a rational or, for small rotation
increments, a polynomial) and call only small helpers that LLVM inlines, so LLVM vectorises them
like the frictionless loop. (The helpers are plain njit functions: numba's own inline="always"
made the first compilation ~8 times slower.) The helpers are compiled without fast-math, so the
angle and the contact law round the same wherever they are inlined. Every point is computed
independently by the same code path: results do not depend on how the points are batched.
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
_E2, _S, _FT2, _DIS, _SR, _U, _TA, _TB, _Z1, _Z2, _SKR = 0, 1, 4, 5, 6, 7, 10, 15, 20, 23, 26
N_ACC = 27

# Coefficients (-1)^k / (2k + 1) of atan(z) = z + z sum_k c_k z^2k; six terms are exact to
# < 0.1 ulp for |z| <= 0.05 (next term z^13 / 13).
_C1, _C2, _C3, _C4, _C5 = -1.0 / 3.0, 1.0 / 5.0, -1.0 / 7.0, 1.0 / 9.0, -1.0 / 11.0
# Largest |F F_n^-1 - I| (Frobenius) for the polynomial: |tan dphi| <= e / (1 - e) <= 0.0472.
_SMALL_INCREMENT = 0.045


@njit(cache=True)
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
    d10 = d8 * d2
    qq = ((((n2 + _Q0 * d2) * n2 + _Q1 * d4) * n2 + _Q2 * d6) * n2 + _Q3 * d8) * n2 + _Q4 * d10
    r = num * (qq + n2 * p) / (den * qq)
    r = r + (_PIO4 + 0.5 * _MOREBITS) if big else r
    r = (_PIO2 - r) + _MOREBITS if swap else r
    r = (_PI - r) + 2.0 * _MOREBITS if x < 0.0 else r
    return -r if y < 0.0 else r


@njit(cache=True)
def atan2(y, x):
    """atan2(y, x) in (-pi, pi] for any finite (x, y) != (0, 0), to ~1 ulp (tests: <= 4 ulp)."""
    m = max(abs(x), abs(y))
    return _atan2_unit(y / m, x / m)


@njit(cache=True)
def _atan_small(y, x):
    """atan(y / x) for x > 0 and |y / x| <= 0.05 (one division, five multiply-adds)."""
    z = y / x
    zz = z * z
    return z + z * (zz * (_C1 + zz * (_C2 + zz * (_C3 + zz * (_C4 + zz * _C5)))))


@njit(cache=True, fastmath=_FASTMATH, error_model="numpy")
def atan2_array(y, x, out, kind):
    """Elementwise (n,) :func:`atan2` (kind 0), :func:`_atan2_unit` (1) or :func:`_atan_small`
    (2), for tests."""
    for i in range(y.shape[0]):
        if kind == 0:
            out[i] = atan2(y[i], x[i])
        elif kind == 1:
            out[i] = _atan2_unit(y[i], x[i])
        else:
            out[i] = _atan_small(y[i], x[i])


@njit(cache=True)
def prefix_lengths(F, rho, min_stretch, status, lengths):
    """Status code (n,) and the visited candidate count (n,) of each F (0 for a rejected F).

    The count is the prefix rho <= 1/s_min(F) that :func:`evaluate_batch` visits, and the length
    of the point's force array in the new state."""
    for q in range(F.shape[0]):
        code, limit = _check_F(F[q, 0, 0], F[q, 0, 1], F[q, 1, 0], F[q, 1, 1], min_stretch)
        status[q] = code
        lengths[q] = np.searchsorted(rho, limit, side="right") if code == OK else 0


@njit(cache=True)
def _quadratic_forms(F00, F01, F10, F11, G00, G01, G10, G11, lmax2):
    """Coefficients of cross(G L, F L) and dot(G L, F L) as quadratic forms in (xx, xy, yy),
    scaled so that both are at most ~1 for |L|² <= lmax2 (their ratio, the angle, is kept)."""
    cxx = G00 * F10 - G10 * F00
    cxy = G00 * F11 + G01 * F10 - G10 * F01 - G11 * F00
    cyy = G01 * F11 - G11 * F01
    dxx = G00 * F00 + G10 * F10
    dxy = G00 * F01 + G01 * F00 + G10 * F11 + G11 * F10
    dyy = G01 * F01 + G11 * F11
    big = max(abs(cxx), abs(cxy), abs(cyy), abs(dxx), abs(dxy), abs(dyy))
    s = 1.0 / (big * lmax2)
    return cxx * s, cxy * s, cyy * s, dxx * s, dxy * s, dyy * s


@njit(cache=True)
def _small_increment(F00, F01, F10, F11, G00, G01, G10, G11):
    """True if |F G^-1 - I| <= _SMALL_INCREMENT: every branch turns by |tan dphi| <= 0.05."""
    jg = G00 * G11 - G01 * G10
    e00 = (F00 * G11 - F01 * G10) / jg - 1.0
    e01 = (F01 * G00 - F00 * G01) / jg
    e10 = (F10 * G11 - F11 * G10) / jg
    e11 = (F11 * G00 - F10 * G01) / jg - 1.0
    return e00 * e00 + e01 * e01 + e10 * e10 + e11 * e11 <= _SMALL_INCREMENT**2


@njit(cache=True)
def _contact_law(ftn, ds, ee, kt, mukn):
    """Trial force f*, new tangential force f_t and the stick flag of one contact."""
    fstar = ftn + kt * ds
    lim = mukn * ee
    ft = fstar if abs(fstar) <= lim else (lim if fstar >= 0.0 else -lim)
    return fstar, ft, (abs(fstar) <= lim) & (lim > 0.0)  # mu = 0: never sticks


@njit(cache=True, fastmath=_FASTMATH, error_model="numpy")
def _contact_pass(F00, F01, F10, F11, cq, X, Y, R, n_visit, kn, kt, mu, general, ft_io,
                  winv, acc):
    """Contact law and the stress sums e2, S, ft2, dis, sR, U of one point into ``acc``.

    ``ft_io`` (n_visit,) holds f_t,n on entry and the new f_t on exit; ``winv`` (>= n_visit,) gets
    1/d (0 if open), negated unless the contact sticks, for :func:`_tangent_pass`. Only these two
    arrays are written: with more LLVM needs more runtime alias checks than it allows and leaves
    the loop scalar; a branch on a flag inside the loop does the same, so ``general`` is None
    (small increment: polynomial atan, branch pruned at compile time) or True (any angle).
    """
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
        ee = eps if eps >= 0.0 else 0.0  # noqa: FURB136 (a select, as in kernel.py)
        inv = on / d
        xx = x * x
        xy = x * y
        yy = y * y
        b = ee * inv
        e2 += ee * ee
        s0 += b * xx
        s1 += b * xy
        s2 += b * yy
        # sliding since F_n: the branch's turn relative to the spun history Q F_n (wrapped once)
        cr = cxx * xx + cxy * xy + cyy * yy
        dt = dxx * xx + dxy * xy + dyy * yy
        if general is None:
            dphi = _atan_small(cr, dt)
        else:
            dphi = _atan2_unit(cr, dt)
        fstar, ft, stick = _contact_law(ft_io[c], r * dphi, ee, kt, mukn)
        ft_io[c] = ft
        winv[c] = inv if stick else -inv
        ft2 += ft * ft
        dis += abs(ft) * abs(fstar - ft)  # 0 in stick and for open contacts
        ftr = ft * r
        u = ftr * inv * inv
        sr += ftr
        u0 += u * xx
        u1 += u * xy
        u2 += u * yy
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
def _tangent_pass(X, Y, R, n_visit, fts, winv, kn, kt, mukn, acc):
    """The tangent sums TA, TB, Z1, Z2, skr of one point into ``acc``, from the new forces
    ``fts`` and the signed 1/d ``winv`` of :func:`_contact_pass`.

    Stick: winv > 0, w_st = k_t R². Slip: winv < 0 and f_t != 0, w_sl = sign(f_t) mu k_n R
    (f_t = 0 when open, at eps = 0 or for mu = 0: no slip weight)."""
    a0 = a1 = a2 = a3 = a4 = 0.0
    b0 = b1 = b2 = b3 = b4 = 0.0
    z0 = z1 = z2 = 0.0
    w0 = w1 = w2 = 0.0
    skr = 0.0
    for c in range(n_visit):
        x = X[c]
        y = Y[c]
        r = R[c]
        ft = fts[c]
        w = winv[c]
        inv = abs(w)
        wst = kt * r * r if w > 0.0 else 0.0
        wsl = mukn * r if ft > 0.0 else -mukn * r
        wsl = wsl if (w < 0.0) & (ft != 0.0) else 0.0
        xx = x * x
        xy = x * y
        yy = y * y
        inv2 = inv * inv
        inv3 = inv2 * inv
        g = kn * r * inv3 - wst * inv2 * inv2
        h = -2.0 * ft * r * inv2 * inv2 - wsl * inv3
        q = xx * xx
        a0 += g * q
        b0 += h * q
        q = xx * xy
        a1 += g * q
        b1 += h * q
        q = xx * yy
        a2 += g * q
        b2 += h * q
        q = xy * yy
        a3 += g * q
        b3 += h * q
        q = yy * yy
        a4 += g * q
        b4 += h * q
        g = wst * inv2
        z0 += g * xx
        z1 += g * xy
        z2 += g * yy
        g = wsl * inv
        w0 += g * xx
        w1 += g * xy
        w2 += g * yy
        skr += wst
    acc[_TA], acc[_TA + 1], acc[_TA + 2], acc[_TA + 3], acc[_TA + 4] = a0, a1, a2, a3, a4
    acc[_TB], acc[_TB + 1], acc[_TB + 2], acc[_TB + 3], acc[_TB + 4] = b0, b1, b2, b3, b4
    acc[_Z1], acc[_Z1 + 1], acc[_Z1 + 2] = z0, z1, z2
    acc[_Z2], acc[_Z2 + 1], acc[_Z2 + 2] = w0, w1, w2
    acc[_SKR] = skr


@njit(cache=True)
def _rotation(F00, F01, F10, F11):
    """Theta = dtheta/dF (4 entries, row major) of theta(F) = atan2(F10 - F01, F00 + F11) and the
    coefficients (alpha, beta) of its Hessian H = alpha (J x J - I x I) + beta (J x I + I x J)."""
    a = F10 - F01
    b = F00 + F11
    r = np.sqrt(a * a + b * b)  # = tr U >= 2 s_min: never small for a supported F
    ca = a / r
    cb = b / r
    ir = 1.0 / r
    # Theta = (cb J - ca I) / r,  H = -(2 / r²) [ca cb (JxJ - IxI) + (cb² - ca²)/2 (JxI + IxJ)]
    th = (-ca * ir, -cb * ir, cb * ir, -ca * ir)
    alpha = -2.0 * ca * cb * ir * ir
    beta = -(cb * cb - ca * ca) * ir * ir
    return th, alpha, beta


@njit(cache=True)
def _spun_history(F00, F01, F10, F11, G00, G01, G10, G11):
    """Q G with Q the rotation by the particle spin increment theta(F) - theta(G), i.e. the
    committed F_n = G carried along with the particles.

    cos and sin of the increment come from the complex product (b + i a)(b_n - i a_n), without
    trigonometry; at F = G they are exactly (1, 0) (sqrt(x²) = |x| in IEEE), so Q G = G."""
    a = F10 - F01
    b = F00 + F11
    an = G10 - G01
    bn = G00 + G11
    cq = b * bn + a * an
    sq = a * bn - b * an
    h = np.sqrt(cq * cq + sq * sq)  # = tr U(F) tr U(G) > 0
    c = cq / h
    s = sq / h
    return c * G00 - s * G10, c * G01 - s * G11, s * G00 + c * G10, s * G01 + c * G11


@njit(cache=True)
def _finish_point(q, Fq, acc, rot, kn, inv_area, kt, tangent, W, P, A, M):
    """W[q], P[q] and (if ``tangent``) A[q] from the sums of point q (module docstring);
    ``rot`` = (Theta (4,), alpha, beta) of :func:`_rotation`; ``M`` (6, 2, 2) scratch."""
    th, alpha, beta = rot
    JF, Th, Z1, Z2, I2, J2 = M[0], M[1], M[2], M[3], M[4], M[5]
    JF[0, 0] = -Fq[1, 0]
    JF[0, 1] = -Fq[1, 1]
    JF[1, 0] = Fq[0, 0]
    JF[1, 1] = Fq[0, 1]
    Th[0, 0], Th[0, 1], Th[1, 0], Th[1, 1] = th
    W[q] = inv_area * (0.5 * kn * acc[_E2] + (0.5 * acc[_FT2] / kt if kt > 0.0 else 0.0))
    sr = acc[_SR]
    for a in range(2):
        for b in range(2):
            fs = Fq[a, 0] * acc[_S + b] + Fq[a, 1] * acc[_S + 1 + b]
            fu = JF[a, 0] * acc[_U + b] + JF[a, 1] * acc[_U + 1 + b]
            P[q, a, b] = inv_area * (-kn * fs + fu - sr * Th[a, b])
    if not tangent:
        return
    for a in range(2):
        for b in range(2):
            Z1[a, b] = JF[a, 0] * acc[_Z1 + b] + JF[a, 1] * acc[_Z1 + 1 + b]  # JF Z1
            Z2[a, b] = Fq[a, 0] * acc[_Z2 + b] + Fq[a, 1] * acc[_Z2 + 1 + b]  # F Z2
            I2[a, b] = 1.0 if a == b else 0.0
    J2[0, 0], J2[0, 1], J2[1, 0], J2[1, 1] = 0.0, -1.0, 1.0, 0.0
    skr = acc[_SKR]
    for a in range(2):
        for b in range(2):
            for c in range(2):
                for d in range(2):
                    v = 0.0
                    for e in range(2):
                        for f in range(2):
                            i = e + f + b + d
                            v += Fq[a, e] * (Fq[c, f] * acc[_TA + i] + JF[c, f] * acc[_TB + i])
                    bd = b + d
                    v += (I2[a, c] * (acc[_Z1 + bd] - kn * acc[_S + bd])
                          - J2[a, c] * (acc[_U + bd] + acc[_Z2 + bd]))
                    H = (alpha * (J2[a, b] * J2[c, d] - I2[a, b] * I2[c, d])
                         + beta * (J2[a, b] * I2[c, d] + I2[a, b] * J2[c, d]))
                    v += (-sr * H - Z1[a, b] * Th[c, d] - Th[a, b] * Z1[c, d]
                          + skr * Th[a, b] * Th[c, d] + Th[a, b] * Z2[c, d])
                    A[q, a, b, c, d] = inv_area * v


@njit(cache=True)
def _copy_history(src, dst):
    """dst[:] = src, zero-padded or cut: committed forces past the stored prefix are zero."""
    m = min(src.shape[0], dst.shape[0])
    for c in range(m):
        dst[c] = src[c]
    for c in range(m, dst.shape[0]):
        dst[c] = 0.0


@njit(cache=True)
def evaluate_batch(F, X, Y, R, rho, lmax2, kn, kt, mu, inv_area, min_stretch, tangent,
                   Fn, off_n, f_n, D_n, off, f, W, P, A, D, status):
    """Energy, stress, tangent and the new history at n points, from their committed history.

    Args:
        F: (n, 2, 2) deformation gradients.
        X, Y, R, rho: (M,) candidate arrays of :func:`kernel.candidate_pairs` (L = (X, Y)).
        lmax2: max |L|² over the candidates (scales the angle computation).
        kn, kt, mu: normal and tangential stiffness (N/m²), friction coefficient.
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
    acc = np.zeros(N_ACC)
    winv = np.empty(R.shape[0])
    M = np.empty((6, 2, 2))
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
        ft = f[o:o + n_visit]  # the new forces, computed in place from the committed ones
        _copy_history(f_n[off_n[q]:off_n[q + 1]], ft)
        G00, G01, G10, G11 = Fn[q, 0, 0], Fn[q, 0, 1], Fn[q, 1, 0], Fn[q, 1, 1]
        th, alpha, beta = _rotation(F00, F01, F10, F11)
        G00, G01, G10, G11 = _spun_history(F00, F01, F10, F11, G00, G01, G10, G11)
        cq = _quadratic_forms(F00, F01, F10, F11, G00, G01, G10, G11, lmax2)
        if _small_increment(F00, F01, F10, F11, G00, G01, G10, G11):
            _contact_pass(F00, F01, F10, F11, cq, X, Y, R, n_visit, kn, kt, mu, None,
                          ft, winv, acc)
        else:
            _contact_pass(F00, F01, F10, F11, cq, X, Y, R, n_visit, kn, kt, mu, True,
                          ft, winv, acc)
        if tangent:
            _tangent_pass(X, Y, R, n_visit, ft, winv, kn, kt, mu * kn, acc)
        D[q] = D_n[q] + (inv_area * acc[_DIS] / kt if kt > 0.0 else 0.0)
        _finish_point(q, F[q], acc, (th, alpha, beta), kn, inv_area, kt, tangent, W, P, A, M)


@njit(cache=True, fastmath=_FASTMATH, error_model="numpy")
def contact_step(F, Fn, X, Y, R, n_visit, lmax2, buf, kn, kt, mu, eps_out, stick_out):
    """Per-candidate step of one point, for diagnostics: the arithmetic of :func:`_contact_pass`.

    ``buf`` (n_visit,) holds f_t,n on entry and f_t on exit; ``eps_out`` gets the overlaps and
    ``stick_out`` 1 for a sticking contact, 0 otherwise."""
    F00, F01, F10, F11 = F[0, 0], F[0, 1], F[1, 0], F[1, 1]
    G00, G01, G10, G11 = Fn[0, 0], Fn[0, 1], Fn[1, 0], Fn[1, 1]
    G00, G01, G10, G11 = _spun_history(F00, F01, F10, F11, G00, G01, G10, G11)
    cxx, cxy, cyy, dxx, dxy, dyy = _quadratic_forms(F00, F01, F10, F11, G00, G01, G10, G11,
                                                    lmax2)
    small = _small_increment(F00, F01, F10, F11, G00, G01, G10, G11)
    for c in range(n_visit):
        x = X[c]
        y = Y[c]
        r = R[c]
        lx = F00 * x + F01 * y
        ly = F10 * x + F11 * y
        eps = r - np.sqrt(lx * lx + ly * ly)
        ee = eps if eps >= 0.0 else 0.0  # noqa: FURB136 (a select, as in kernel.py)
        xx = x * x
        xy = x * y
        yy = y * y
        cr = cxx * xx + cxy * xy + cyy * yy
        dt = dxx * xx + dxy * xy + dyy * yy
        dphi = _atan_small(cr, dt) if small else _atan2_unit(cr, dt)
        _, ft, stick = _contact_law(buf[c], r * dphi, ee, kt, mu * kn)
        buf[c] = ft
        eps_out[c] = eps
        stick_out[c] = 1 if stick else 0
