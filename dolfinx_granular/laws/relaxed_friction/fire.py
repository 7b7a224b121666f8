"""The fallback of the frictional micro solver: FIRE (Bitzek et al. 2006), damped dynamics of
the disks (unit masses, a disk's moment of inertia r^2 / 2) under the forces and moments of the
same increment's return map, until they nearly balance; Newton then takes up again. DEM codes
relax their cells this way. The steps run in Numba, in chunks between which the candidate list
is brought up to the disks' positions.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..relaxed.cell import Cell
from ..relaxed.errors import RigidityLostError
from .cell_state import CellState, Increment, Springs
from .contact_law import return_map
from .settings import Settings
from .system import balance

#: steps between two updates of the candidate list
CHUNK = 500
#: what :func:`fire_chunk` stopped at
RUNNING, CONVERGED, UNJAMMED = 0, 1, 2


@njit(cache=True)
def fire_chunk(F, Finv, u, th, v, inc_arrays, geo, law, m, params, n_steps, tol):
    """Up to ``n_steps`` FIRE steps on the current-frame fluctuations u (N, 2) and rotations th
    (N,) with velocities v (N, 3), all updated in place, over the first m candidates.

    ``params`` (4,) = (dt, alpha, steps since the power was last negative, dt_max), updated in
    place. Stops where every net force is at most ``tol`` of the mean normal force and every
    moment ``tol`` of it times the mean radius (CONVERGED), or where no two disks touch
    (UNJAMMED). Returns ``(status, steps taken)``."""
    F0, w0, th0, ft0, mr0 = inc_arrays
    pi, pj, X, Y, R, radii = geo
    kn, kt, mu, kr, mu_r = law
    N = radii.shape[0]
    mean_r = radii.mean()
    inertia = 0.5 * radii * radii
    w = np.empty_like(u)
    dt, alpha, since, dt_max = params[0], params[1], params[2], params[3]
    a = np.empty((N, 3))
    for step in range(n_steps):
        for i in range(N):
            w[i, 0] = Finv[0, 0] * u[i, 0] + Finv[0, 1] * u[i, 1]
            w[i, 1] = Finv[1, 0] * u[i, 0] + Finv[1, 1] * u[i, 1]
        _, _, lx, ly, d, e, ft, _, _, mr, _, _ = return_map(
            F, w, th, F0, w0, th0, ft0, mr0, pi, pj, X, Y, R, radii, m, kn, kt, mu, kr, mu_r
        )
        f, M, mean_force, count = balance(pi, pj, lx, ly, d, e, ft, mr, R, radii, kn, N)
        if count == 0:
            params[0], params[1], params[2] = dt, alpha, since
            return UNJAMMED, step
        big_f, big_M = 0.0, 0.0
        for i in range(N):
            big_f = max(big_f, np.sqrt(f[i, 0] ** 2 + f[i, 1] ** 2))
            big_M = max(big_M, abs(M[i]))
        if big_f <= tol * mean_force and big_M <= tol * mean_force * mean_r:
            params[0], params[1], params[2] = dt, alpha, since
            return CONVERGED, step
        power = 0.0
        for i in range(N):
            a[i, 0], a[i, 1], a[i, 2] = f[i, 0], f[i, 1], M[i] / inertia[i]
            power += f[i, 0] * v[i, 0] + f[i, 1] * v[i, 1] + M[i] * v[i, 2]
        if power > 0.0:
            an = np.sqrt((a * a).sum())
            vn = np.sqrt((v * v).sum())
            for i in range(N):
                for k in range(3):
                    v[i, k] = (1.0 - alpha) * v[i, k] + alpha * vn * a[i, k] / max(an, 1e-300)
            since += 1.0
            if since > 5.0:
                dt = min(1.1 * dt, dt_max)
                alpha *= 0.99
        else:
            v[:] = 0.0
            dt, alpha, since = 0.5 * dt, 0.1, 0.0
        for i in range(N):
            for k in range(3):
                v[i, k] += dt * a[i, k]
            u[i, 0] += dt * v[i, 0]
            u[i, 1] += dt * v[i, 1]
            th[i] += dt * v[i, 2]
    params[0], params[1], params[2] = dt, alpha, since
    return RUNNING, n_steps


def fire(cell: Cell, springs: Springs, F, w, th, inc: Increment, settings: Settings) -> tuple:
    """FIRE from (w (N, 2), th (N,)) until the residual is ``settings.fire_tol``: ``(w, th,
    steps, converged)``. After ``settings.fire_steps`` (where a disk keeps sliding in its cage
    or bouncing about it) the positions of the smallest residual seen at the end of a chunk,
    converged False, for Newton to try from."""
    Finv = np.linalg.inv(F)
    u = np.ascontiguousarray(w @ F.T)
    th = np.array(th, dtype=np.float64)
    v = np.zeros((cell.n_disks, 3))
    # forces are in N (k_n times length): the time unit is 1 / sqrt(k_n) for unit masses; a
    # disk's stiffness reaches ~ z (k_n + k_t), so explicit steps stay below ~2 / sqrt(that)
    dt_max = 0.5 / np.sqrt(springs.kn + springs.kt)
    params = np.array([0.1 * dt_max, 0.1, 0.0, dt_max])
    law = (springs.kn, springs.kt, springs.mu, springs.kr, springs.mu_r)
    steps, best = 0, (np.inf, w, th)
    while steps < settings.fire_steps:
        m = cell.visited(F, u @ Finv.T)
        inc_arrays = inc.arrays(cell.pi.shape[0])
        geo = (cell.pi, cell.pj, cell.X, cell.Y, cell.R, cell.radii)
        status, taken = fire_chunk(
            F, Finv, u, th, v, inc_arrays, geo, law, m, params,
            min(CHUNK, settings.fire_steps - steps), settings.fire_tol,
        )  # fmt: skip
        steps += taken
        if status == UNJAMMED:
            raise RigidityLostError("the cell unjammed: relaxation opens its contacts")
        w = u @ Finv.T
        if status == CONVERGED and cell.visited(F, w) == m:  # (no contact unseen)
            return w, th, steps, True
        residual = CellState(cell, springs, F, w, th, inc).residual(cell)[0]
        if residual < best[0]:
            best = (residual, w, th.copy())
    return best[1], best[2], steps, False
