"""The tangent through the quasi-static path: the derivative of the algorithmic P(F) when the
increment to F takes several substeps, each committing its tangential forces and positions.

A substep k solves r(q_k; U_k, h_k-1) = 0, h_k-1 the history it starts from (the last
substep's positions w, rotations theta and tangential forces f_t, and its U_k-1), and U_k
depends on the final F (the substeps are spaced evenly in the right stretch). So, with every
derivative a (., 4) matrix over F's four components,

    dq_k = -K_qq^-1 (K_qF dU_k + K_qh dh_k-1),   dP = K_FF dU_m + K_Fq dq_m + K_Fh dh_m-1,

and the history enters the equations only through the trial force of a sticking contact,
f* = f_t0 + k_t ds, ds = r_i psi_i + r_j psi_j (:mod:`.contact_law`), and the trial moment of
a sticking rolling spring, m* = m_0 + k_r rho (:mod:`.rolling`): d f*/d f_t0 = 1,
d ds/d theta0_k = r_k and d ds/d l0 = -(R / d0) t0 for the committed branch l0 = F0 (L + w0_j -
w0_i). A sticking contact's force moves r and P as d r/d f_t = s_u and dP/d f_t = s_F (the
gradients of ds). The next substep's history follows from the new forces: k_t (s . dq + s_F .
dU) + d f*_h in stick, sign(f_t) mu k_n de in slip; and the rolling moments', d m*/d m_0 = 1,
d m*/d theta0_i = -k_r = -d m*/d theta0_j, moving the rotations' rows by +-1 (no stress). With
one substep (m = 1) this is the tangent at fixed history.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from .contact_law import SLIP, STICK, local, scratch
from .rolling import radius, stiffness


@dataclass
class Chain:
    """The committed side of a substep, differentiated with respect to the final F (flattened
    row-major): Dw (N, 2, 4), Dth (N, 4), Dft (M, 4) and Dmr (M, 4) per candidate (tangential
    forces, rolling moments; they grow with the list), DF0 (4, 4) of the committed F0. An
    increment from the macro-committed state has none (nothing there depends on F)."""

    Dw: np.ndarray
    Dth: np.ndarray
    Dft: np.ndarray
    DF0: np.ndarray
    Dmr: np.ndarray

    def forces(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(Dft, Dmr) for a list of n candidates (new pairs: zero)."""
        if self.Dft.shape[0] < n:
            self.Dft = np.concatenate([self.Dft, np.zeros((n - self.Dft.shape[0], 4))])
        if self.Dmr.shape[0] < n:
            self.Dmr = np.concatenate([self.Dmr, np.zeros((n - self.Dmr.shape[0], 4))])
        return self.Dft, self.Dmr


@njit(cache=True)
def stretch_derivative(F: np.ndarray) -> np.ndarray:
    """dU/dF (4, 4) of the right stretch U = (C + s I) / t (:func:`~dolfinx_granular.laws.
    relaxed.path.stretch`; C = F^T F, s = det F > 0, t = (tr C + 2 s)^(1/2)), both flattened
    row-major."""
    C = F.T @ F
    s = F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]
    t = np.sqrt(C[0, 0] + C[1, 1] + 2.0 * s)
    U = (C + s * np.eye(2)) / t
    # (d det F = s tr(F^-1 dF) = cof(F) : dF)
    cof = np.array([[F[1, 1], -F[1, 0]], [-F[0, 1], F[0, 0]]])
    out = np.empty((4, 4))
    for p in range(4):
        dF = np.zeros((2, 2))
        dF[p // 2, p % 2] = 1.0
        dC = dF.T @ F + F.T @ dF
        ds = cof[p // 2, p % 2]
        dt = (dC[0, 0] + dC[1, 1] + 2.0 * ds) / (2.0 * t)
        out[:, p] = ((dC + ds * np.eye(2)) / t - U * dt / t).ravel()
    return out


@njit(cache=True)
def history_terms(G, qx, qy, lx, ly, d, e, ft, fstar, status, rstatus, pi, pj, X, Y, R, radii,
                  F0, w0, kn, kt, mu, kr, inv_area, network, Dw0, Dth0, Dft0, DF0,
                  Dmr0):  # fmt: skip
    """``(Rh (3N, 4), Ph (4, 4), dfh (m, 4), dmh (m, 4))``: K_qh dh and K_Fh dh (per area)
    and each sticking contact's trial force (N) and rolling moment (N m) moved by the history,
    d f*_h and d m*_h."""
    N = radii.shape[0]
    m = e.shape[0]
    Rh = np.zeros((3 * N, 4))
    Ph = np.zeros((4, 4))
    dfh = np.zeros((m, 4))
    dmh = np.zeros((m, 4))
    out = scratch()
    for c in range(m):
        if not network[c]:
            continue
        i, j = pi[c], pj[c]
        if rstatus[c] == STICK:
            k = stiffness(radii[i], radii[j], kr)
            for p in range(4):
                dmh[c, p] = Dmr0[c, p] - k * (Dth0[i, p] - Dth0[j, p])
                Rh[3 * i + 2, p] += inv_area * dmh[c, p]
                Rh[3 * j + 2, p] -= inv_area * dmh[c, p]
        if status[c] != STICK:
            continue
        x0 = X[c] + w0[j, 0] - w0[i, 0]
        y0 = Y[c] + w0[j, 1] - w0[i, 1]
        a0 = F0[0, 0] * x0 + F0[0, 1] * y0
        b0 = F0[1, 0] * x0 + F0[1, 1] * y0
        d0 = np.sqrt(a0 * a0 + b0 * b0)
        t0x, t0y = -b0 / d0, a0 / d0
        local(G, qx[c], qy[c], lx[c], ly[c], d[c], e[c], ft[c], fstar[c], status[c], R[c],
              radii[i], radii[j], kn, kt, mu, 2, out)  # fmt: skip
        su, sF = out[8][0], out[8][1][:4]
        idx = (3 * i, 3 * i + 1, 3 * i + 2, 3 * j, 3 * j + 1, 3 * j + 2)
        for p in range(4):
            dx = Dw0[j, 0, p] - Dw0[i, 0, p]
            dy = Dw0[j, 1, p] - Dw0[i, 1, p]
            dlx = DF0[0, p] * x0 + DF0[1, p] * y0 + F0[0, 0] * dx + F0[0, 1] * dy
            dly = DF0[2, p] * x0 + DF0[3, p] * y0 + F0[1, 0] * dx + F0[1, 1] * dy
            ds = -R[c] / d0 * (t0x * dlx + t0y * dly)
            ds += radii[i] * Dth0[i, p] + radii[j] * Dth0[j, p]
            f = Dft0[c, p] + kt * ds
            dfh[c, p] = f
            for u in range(6):
                Rh[idx[u], p] += inv_area * su[u] * f
            for a in range(4):
                Ph[a, p] += inv_area * sF[a] * f
    return Rh, Ph, dfh, dmh


@njit(cache=True)
def force_derivatives(G, qx, qy, lx, ly, d, e, ft, fstar, status, mr, rstatus, pi, pj, R, radii,
                      kn, kt, mu, kr, mu_r, network, dq, DG, dfh, dmh):  # fmt: skip
    """``(Dft (m, 4), Dmr (m, 4))``: d f_t / dF and d m_r / dF of every contact of the network
    at the solution (d(w, theta) = dq (N, 3, 4), dU = DG (4, 4)): the next substep's d f_t0
    and d m_0."""
    m = e.shape[0]
    out = scratch()
    Dft = np.zeros((m, 4))
    Dmr = np.zeros((m, 4))
    for c in range(m):
        if network[c]:
            _rolling_derivative(c, G, qx, qy, lx, ly, d, mr, rstatus, pi, pj, radii, kn, kr,
                                mu_r, dq, DG, dmh, Dmr)  # fmt: skip
        if not network[c] or (status[c] != STICK and status[c] != SLIP):
            continue
        i, j = pi[c], pj[c]
        local(G, qx[c], qy[c], lx[c], ly[c], d[c], e[c], ft[c], fstar[c], status[c], R[c],
              radii[i], radii[j], kn, kt, mu, 2, out)  # fmt: skip
        su, sF, de, deF = out[8][0], out[8][1][:4], out[8][2], out[8][3][:4]
        k = mu * kn if ft[c] >= 0.0 else -mu * kn
        for p in range(4):
            dqc = (dq[i, 0, p], dq[i, 1, p], dq[i, 2, p], dq[j, 0, p], dq[j, 1, p], dq[j, 2, p])
            a = 0.0
            b = 0.0
            for u in range(6):
                a += su[u] * dqc[u]
                b += de[u] * dqc[u]
            for q in range(4):
                a += sF[q] * DG[q, p]
                b += deF[q] * DG[q, p]
            Dft[c, p] = kt * a + dfh[c, p] if status[c] == STICK else k * b
    return Dft, Dmr


@njit(cache=True)
def _rolling_derivative(c, G, qx, qy, lx, ly, d, mr, rstatus, pi, pj, radii, kn, kr, mu_r, dq,
                        DG, dmh, Dmr):  # fmt: skip
    """Contact c's row of Dmr: k_r (d theta_i - d theta_j) + d m*_h in stick, sign(m) mu_r
    r_eff k_n de in slip."""
    i, j = pi[c], pj[c]
    if rstatus[c] == STICK:
        k = stiffness(radii[i], radii[j], kr)
        for p in range(4):
            Dmr[c, p] = k * (dq[i, 2, p] - dq[j, 2, p]) + dmh[c, p]
    elif rstatus[c] == SLIP:
        # de/du, de/dF (the overlap's gradients, as contact_law.local's)
        nx, ny = lx[c] / d[c], ly[c] / d[c]
        k = mu_r * radius(radii[i], radii[j]) * kn
        k = k if mr[c] >= 0.0 else -k
        for p in range(4):
            dx = dq[j, 0, p] - dq[i, 0, p]
            dy = dq[j, 1, p] - dq[i, 1, p]
            dlx = G[0, 0] * dx + G[0, 1] * dy + DG[0, p] * qx[c] + DG[1, p] * qy[c]
            dly = G[1, 0] * dx + G[1, 1] * dy + DG[2, p] * qx[c] + DG[3, p] * qy[c]
            Dmr[c, p] = -k * (nx * dlx + ny * dly)
