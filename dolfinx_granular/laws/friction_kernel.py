"""Numba kernels of the frictional Taylor RVE (model: ``shared/notes/friction-taylor.md``).

Notation as in :mod:`dolfinx_granular.laws.taylor_kernel`: candidate c has reference branch
vector L = (x, y), radius sum R (the note's rho), l = F L, d = |l|, n = l / d, t = J n with
J = [[0, -1], [1, 0]], overlap eps = R - d. History per point: the committed F_n and the
tangential forces f_t,n of a prefix of the candidates (zero where a contact was not active at
F_n).

Per contact with eps > 0 the step from F_n to F is (closed form, no local iteration)

    ds = R wrap(dphi - dtheta) = R atan2(cross(G L, F L), dot(G L, F L)),   G = Q F_n,
    f* = f_t,n + k_t ds;  stick if |f*| <= lim = mu k_n eps and lim > 0, else f_t = sign(f*) lim,

with Q the rotation by the particle spin increment theta(F) - theta(F_n): the branch's turn is
measured against the committed branch carried along with the particles, so the angle is wrapped
once and ds is objective for any rotation increment (the note wraps dphi and dtheta separately,
which is not: see :mod:`dolfinx_granular.laws.friction`). Same derivatives as the note's formula.

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

Speed: one pass over the contacts, as in the frictionless kernel. The pass is bound by its
multiplications (time ~ vector products per contact), so the per-point constants k_n, k_t, mu k_n
are taken out of the sums and the TA and TB weights reuse those of Z1 and Z2. The loop has no
branch (selects; a polynomial or a rational atan) and calls only helpers that LLVM inlines, so it
vectorises. The helpers that decide the forces and the active set (:func:`_kinematics`,
:func:`_inverse_and_turn` or :func:`_inverse_and_angle`, :func:`_contact_law`) are compiled
without fast-math: they round the same with or without the tangent sums, and d as in
:func:`kernel.moment_sums`; only the sums use fast-math. Every point is computed independently
by the same code path: results do not depend on how the points are batched.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .taylor_kernel import FASTMATH, OK, check_F

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
# Largest |F G^-1 - I| (Frobenius; G = Q F_n, the spun history) for the polynomial: every branch
# then turns by |tan dphi| <= e / (1 - e) <= 0.0472 relative to G L, inside its |z| <= 0.05.
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
def _atan_poly(z):
    """atan(z) for |z| <= 0.05 (five multiply-adds)."""
    zz = z * z
    return z + z * (zz * (_C1 + zz * (_C2 + zz * (_C3 + zz * (_C4 + zz * _C5)))))


@njit(cache=True)
def _atan_small(y, x):
    """atan(y / x) for x > 0 and |y / x| <= 0.05."""
    return _atan_poly(y / x)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
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
        code, limit = check_F(F[q, 0, 0], F[q, 0, 1], F[q, 1, 0], F[q, 1, 1], min_stretch)
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
    """True if |F G^-1 - I| <= _SMALL_INCREMENT: every branch turns by |tan dphi| <= 0.05
    relative to G L. With G = Q F_n this is the increment without its spin."""
    jg = G00 * G11 - G01 * G10
    e00 = (F00 * G11 - F01 * G10) / jg - 1.0
    e01 = (F01 * G00 - F00 * G01) / jg
    e10 = (F10 * G11 - F11 * G10) / jg
    e11 = (F11 * G00 - F10 * G01) / jg - 1.0
    return e00 * e00 + e01 * e01 + e10 * e10 + e11 * e11 <= _SMALL_INCREMENT**2


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
def _contact_law(ftn, r, dphi, ee, kt, mukn):
    """Trial force f*, new tangential force f_t and the stick flag of one contact with
    ds = r dphi."""
    fstar = ftn + kt * (r * dphi)
    lim = mukn * ee
    ft = fstar if abs(fstar) <= lim else (lim if fstar >= 0.0 else -lim)
    return fstar, ft, (abs(fstar) <= lim) & (lim > 0.0)  # mu = 0: never sticks


@njit(cache=True)
def _kinematics(F00, F01, F10, F11, cq, x, y, r):
    """eps = R - |F L| (as kernel.moment_sums: same active set), xx, xy, yy and the scaled
    cross and dot of (G L, F L) of one candidate, and d = |F L|."""
    lx = F00 * x + F01 * y
    ly = F10 * x + F11 * y
    d = np.sqrt(lx * lx + ly * ly)
    xx = x * x
    xy = x * y
    yy = y * y
    cr = cq[0] * xx + cq[1] * xy + cq[2] * yy
    dt = cq[3] * xx + cq[4] * xy + cq[5] * yy
    return r - d, d, xx, xy, yy, cr, dt


@njit(cache=True)
def _inverse_and_turn(eps, d, cr, dt):
    """1/d (0 if open, eps < 0) and the turn dphi = atan(cr / dt) for a small increment
    (dt > 0, |cr / dt| <= 0.05: polynomial). (One shared division, 1/(d dt), was no faster.)"""
    return (1.0 / d if eps >= 0.0 else 0.0), _atan_small(cr, dt)


@njit(cache=True)
def _inverse_and_angle(eps, d, cr, dt):
    """1/d (0 if open) and dphi = atan2(cr, dt) for any angle."""
    return (1.0 / d if eps >= 0.0 else 0.0), _atan2_unit(cr, dt)


# The sums decide nothing (the forces and the active set come from the helpers above), so they
# may use fused multiply-adds.
_FASTMATH_SUMS = FASTMATH | {"contract"}


@njit(cache=True, fastmath=_FASTMATH_SUMS, error_model="numpy")
def _contact_pass(
    F00, F01, F10, F11, cq, X, Y, R, n_visit, kn, kt, mu, general, tangent, work, ft_out, acc
):
    """Contact law and every moment sum of one point into ``acc`` (layout: N_ACC), one pass.

    ``work`` (>= n_visit,) holds f_t,n on entry and each contact's dissipation |f_t| |f* - f_t|
    on exit (0 when open; -1, a marker, in stick, where it is 0), which :func:`_history_sums`
    sums in one fixed order, so that the state does not depend on ``tangent``; ``ft_out``
    (n_visit,) gets the new f_t. The sums of f_t², f_t R and the sticking R² are left to that pass
    too: they need nothing that is not stored anyway, and with them (27 sums) the 2-fold
    interleaved vector loop spilled most of its accumulators to the stack. ``work`` is a reused
    scratch array (it stays in cache) and the new state is written once, in the loop, where its
    memory traffic overlaps the arithmetic. Only these two arrays are written (with
    more, LLVM 14 needs more runtime alias checks than it allows and leaves the loop scalar); for
    the same reason the flags are compile-time: ``general`` None (small increment) or True (any
    angle), ``tangent`` None (stress sums only) or True (also TA, TB, Z1, Z2).
    Per contact, with p = R/d: Z1 = k_t sum p² LL, Z2 = mu k_n sum +-p LL,
    TA weight (k_n p - k_t p²) / d², TB weight -(2 f_t R/d² + mu k_n (+-p)) / d².
    """
    mukn = mu * kn
    e2 = s0 = s1 = s2 = u0 = u1 = u2 = 0.0
    a0 = a1 = a2 = a3 = a4 = b0 = b1 = b2 = b3 = b4 = 0.0
    z0 = z1 = z2 = w0 = w1 = w2 = 0.0
    for c in range(n_visit):
        r = R[c]
        # the forces and the active set: helpers without fast-math (module docstring)
        eps, d, xx, xy, yy, cr, dt = _kinematics(F00, F01, F10, F11, cq, X[c], Y[c], r)
        if general is None:
            inv, dphi = _inverse_and_turn(eps, d, cr, dt)
        else:
            inv, dphi = _inverse_and_angle(eps, d, cr, dt)
        ee = eps if eps >= 0.0 else 0.0  # noqa: FURB136 (a select, as in kernel.py)
        fstar, ft, stick = _contact_law(work[c], r, dphi, ee, kt, mukn)
        ft_out[c] = ft
        # -1 marks a sticking contact for _history_sums (its dissipation is 0); not -0.0,
        # which fast-math ('nsz') may turn into +0.0
        work[c] = -1.0 if stick else abs(ft) * abs(fstar - ft)
        b = ee * inv
        e2 += ee * ee
        s0 += b * xx
        s1 += b * xy
        s2 += b * yy
        inv2 = inv * inv
        u = ft * r * inv2
        u0 += u * xx
        u1 += u * xy
        u2 += u * yy
        if tangent is not None:
            p = r * inv
            zeta = p * p if stick else 0.0  # k_t zeta: stick weight of Z1
            omega = p if ft > 0.0 else -p  # mu k_n omega: slip weight of Z2 (f_t = 0: none)
            omega = omega if (not stick) & (ft != 0.0) else 0.0
            g = inv2 * (kn * p - kt * zeta)
            h = -inv2 * (u + u + mukn * omega)
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
            z0 += zeta * xx
            z1 += zeta * xy
            z2 += zeta * yy
            w0 += omega * xx
            w1 += omega * xy
            w2 += omega * yy
    acc[_E2], acc[_S], acc[_S + 1], acc[_S + 2] = e2, s0, s1, s2
    acc[_U], acc[_U + 1], acc[_U + 2] = u0, u1, u2
    if tangent is not None:
        acc[_TA], acc[_TA + 1], acc[_TA + 2], acc[_TA + 3], acc[_TA + 4] = a0, a1, a2, a3, a4
        acc[_TB], acc[_TB + 1], acc[_TB + 2], acc[_TB + 3], acc[_TB + 4] = b0, b1, b2, b3, b4
        acc[_Z1], acc[_Z1 + 1], acc[_Z1 + 2] = kt * z0, kt * z1, kt * z2
        acc[_Z2], acc[_Z2 + 1], acc[_Z2 + 2] = mukn * w0, mukn * w1, mukn * w2


@njit(cache=True, fastmath=_FASTMATH_SUMS, error_model="numpy")
def _history_sums(work, ft, R, n, kt, acc):
    """Dissipation sum |f_t| |f* - f_t|, sum f_t², sum f_t R and k_t sum R² over the sticking
    contacts (``work`` < 0) into ``acc``: a second, cheap pass over the arrays that
    :func:`_contact_pass` wrote (still in cache), which keeps three sums out of its
    register-bound loop. One call site for stress and tangent, so one summation order: the same
    state."""
    dis = ft2 = sr = skr = 0.0
    for c in range(n):
        w = work[c]
        f = ft[c]
        r = R[c]
        dis += max(w, 0.0)
        ft2 += f * f
        sr += f * r
        skr += r * r if w < 0.0 else 0.0
    acc[_DIS], acc[_FT2], acc[_SR], acc[_SKR] = dis, ft2, sr, kt * skr


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
                    v += I2[a, c] * (acc[_Z1 + bd] - kn * acc[_S + bd]) - J2[a, c] * (
                        acc[_U + bd] + acc[_Z2 + bd]
                    )
                    H = alpha * (J2[a, b] * J2[c, d] - I2[a, b] * I2[c, d]) + beta * (
                        J2[a, b] * I2[c, d] + I2[a, b] * J2[c, d]
                    )
                    v += (
                        -sr * H
                        - Z1[a, b] * Th[c, d]
                        - Th[a, b] * Z1[c, d]
                        + skr * Th[a, b] * Th[c, d]
                        + Th[a, b] * Z2[c, d]
                    )
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
def evaluate_batch(
    F,
    X,
    Y,
    R,
    rho,
    lmax2,
    kn,
    kt,
    mu,
    inv_area,
    min_stretch,
    tangent,
    Fn,
    off_n,
    f_n,
    D_n,
    off,
    f,
    W,
    P,
    A,
    D,
    status,
):
    """Energy, stress, tangent and the new history at n points, from their committed history.

    Args:
        F: (n, 2, 2) deformation gradients.
        X, Y, R, rho: (M,) candidate arrays of :func:`neighbours.candidate_pairs` (L = (X, Y)).
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
    work = np.empty(R.shape[0])
    M = np.empty((6, 2, 2))
    for q in range(F.shape[0]):
        F00, F01, F10, F11 = F[q, 0, 0], F[q, 0, 1], F[q, 1, 0], F[q, 1, 1]
        code, _ = check_F(F00, F01, F10, F11, min_stretch)
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
        ft = f[o : o + n_visit]  # the new forces
        _copy_history(f_n[off_n[q] : off_n[q + 1]], work[:n_visit])  # f_t,n, zero-padded
        G = _spun_history(F00, F01, F10, F11, Fn[q, 0, 0], Fn[q, 0, 1], Fn[q, 1, 0], Fn[q, 1, 1])
        cq = _quadratic_forms(F00, F01, F10, F11, G[0], G[1], G[2], G[3], lmax2)
        small = _small_increment(F00, F01, F10, F11, G[0], G[1], G[2], G[3])
        # one specialisation per (angle path, tangent): the flags must be compile-time
        if tangent and small:
            _contact_pass(
                F00, F01, F10, F11, cq, X, Y, R, n_visit, kn, kt, mu, None, True, work, ft, acc
            )
        elif tangent:
            _contact_pass(
                F00, F01, F10, F11, cq, X, Y, R, n_visit, kn, kt, mu, True, True, work, ft, acc
            )
        elif small:
            _contact_pass(
                F00, F01, F10, F11, cq, X, Y, R, n_visit, kn, kt, mu, None, None, work, ft, acc
            )
        else:
            _contact_pass(
                F00, F01, F10, F11, cq, X, Y, R, n_visit, kn, kt, mu, True, None, work, ft, acc
            )
        _history_sums(work, ft, R, n_visit, kt, acc)
        D[q] = D_n[q] + (inv_area * acc[_DIS] / kt if kt > 0.0 else 0.0)
        th, alpha, beta = _rotation(F00, F01, F10, F11)
        _finish_point(q, F[q], acc, (th, alpha, beta), kn, inv_area, kt, tangent, W, P, A, M)


@njit(cache=True)
def contact_step(F, Fn, X, Y, R, n_visit, lmax2, buf, kn, kt, mu, eps_out, stick_out):
    """Per-candidate step of one point, for diagnostics: the helpers of :func:`_contact_pass`.

    ``buf`` (n_visit,) holds f_t,n on entry and f_t on exit; ``eps_out`` gets the overlaps and
    ``stick_out`` 1 for a sticking contact, 0 otherwise."""
    F00, F01, F10, F11 = F[0, 0], F[0, 1], F[1, 0], F[1, 1]
    G = _spun_history(F00, F01, F10, F11, Fn[0, 0], Fn[0, 1], Fn[1, 0], Fn[1, 1])
    cq = _quadratic_forms(F00, F01, F10, F11, G[0], G[1], G[2], G[3], lmax2)
    small = _small_increment(F00, F01, F10, F11, G[0], G[1], G[2], G[3])
    for c in range(n_visit):
        eps, d, _, _, _, cr, dt = _kinematics(F00, F01, F10, F11, cq, X[c], Y[c], R[c])
        dphi = _atan_small(cr, dt) if small else _atan2_unit(cr, dt)
        ee = eps if eps >= 0.0 else 0.0  # noqa: FURB136 (a select, as in kernel.py)
        _, ft, stick = _contact_law(buf[c], R[c], dphi, ee, kt, mu * kn)
        buf[c] = ft
        eps_out[c] = eps
        stick_out[c] = 1 if stick else 0
