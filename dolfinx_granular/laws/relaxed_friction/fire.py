"""The fallback of the frictional micro solver: FIRE (Bitzek et al. 2006), damped dynamics of
the disks (unit masses, a disk's moment of inertia r^2 / 2) under the forces and moments of the
same increment's return map, until they nearly balance; Newton then takes up again. DEM codes
relax their cells this way. The steps run in Numba, in chunks between which the candidate list
is brought up to the disks' positions.

Where the increment has no equilibrium that Newton, the continuation and FIRE find (a disk
slides out of its cage: the cell rearranges), :func:`settle` lets it rearrange as a DEM cell
does: the same damped dynamics at the fixed F, but with the friction law applied step by step
(each step's forces and positions committed before the next, as DEM codes integrate their
tangential springs), so that every slip dissipates and the cell comes to rest in a new
equilibrium, the end of a dynamic event that no quasi-static path reaches.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..relaxed.cell import Cell
from ..relaxed.errors import CameApart, RelaxationError
from .cell_state import CellState, Increment, Springs
from .contact_law import return_map
from .settings import Settings
from .system import balance

#: steps between two updates of the candidate list
CHUNK = 500
#: what :func:`fire_chunk` stopped at
RUNNING, CONVERGED, UNJAMMED = 0, 1, 2


@njit(cache=True)
def fire_chunk(F, Finv, u, th, v, inc_arrays, geo, law, m, params, n_steps, tol, stepwise):
    """Up to ``n_steps`` FIRE steps on the current-frame fluctuations u (N, 2) and rotations th
    (N,) with velocities v (N, 3), all updated in place, over the first m candidates.
    ``stepwise``: each step commits its forces, moments and positions into ``inc_arrays`` (in
    place; F0 must be F): the friction law integrated step by step, as in DEM.

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
        if stepwise:  # (a candidate beyond m is open: its history is lost)
            w0[:] = w
            th0[:] = th
            ft0[:m], mr0[:m] = ft, mr
            ft0[m:], mr0[m:] = 0.0, 0.0
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


def fire(cell: Cell, springs: Springs, F, w, th, inc: Increment, settings: Settings,
         stepwise: bool = False, budget: int | None = None) -> tuple:  # fmt: skip
    """FIRE from (w (N, 2), th (N,)) until the residual is ``settings.fire_tol``: ``(w, th,
    steps, converged)``. After ``budget`` steps (default ``settings.fire_steps``; where a disk
    keeps sliding in its cage or bouncing about it) the positions of the smallest residual
    seen at the end of a chunk, converged False, for Newton to try from. ``stepwise``: the
    friction law step by step, ``inc`` updated in place (its F0 must be F; :func:`settle`).
    :class:`~dolfinx_granular.laws.relaxed.errors.CameApart` where no two disks touch, or
    where, at the end of a chunk of :data:`CHUNK` steps, no disk keeps two contacts."""
    Finv = np.linalg.inv(F)
    u = np.ascontiguousarray(w @ F.T)
    th = np.array(th, dtype=np.float64)
    v = np.zeros((cell.n_disks, 3))
    # forces are in N (k_n times length): the time unit is 1 / sqrt(k_n) for unit masses; a
    # disk's stiffness reaches ~ z (k_n + k_t), so explicit steps stay below ~2 / sqrt(that)
    dt_max = 0.5 / np.sqrt(springs.kn + springs.kt)
    params = np.array([0.1 * dt_max, 0.1, 0.0, dt_max])
    law = (springs.kn, springs.kt, springs.mu, springs.kr, springs.mu_r)
    budget = settings.fire_steps if budget is None else budget
    steps, best = 0, (np.inf, w, th)
    while steps < budget:
        m = cell.visited(F, u @ Finv.T)
        inc_arrays = inc.arrays(cell.pi.shape[0])
        geo = (cell.pi, cell.pj, cell.X, cell.Y, cell.R, cell.radii)
        status, taken = fire_chunk(
            F, Finv, u, th, v, inc_arrays, geo, law, m, params,
            min(CHUNK, budget - steps), settings.fire_tol, stepwise,
        )  # fmt: skip
        steps += taken
        if status == UNJAMMED:
            raise CameApart("the cell unjammed: relaxation opens its contacts", u @ Finv.T, th)
        w = u @ Finv.T
        if status == CONVERGED and cell.visited(F, w) == m:  # (no contact unseen)
            return w, th, steps, True
        s = CellState(cell, springs, F, w, th, inc)
        if s.apart:
            # (a collapsed loose cell: its disks fly about and only collide, with no network
            # to stop them, so damped motion does not come to rest)
            raise CameApart("the cell came apart: no disk keeps two contacts", w, th)
        if stepwise:
            continue
        residual = s.residual(cell)[0]
        if residual < best[0]:
            best = (residual, w, th.copy())
    if stepwise:
        return w, th, steps, False
    return best[1], best[2], steps, False


def settle(cell: Cell, springs: Springs, F, w, th, inc: Increment, settings: Settings) -> tuple:
    """The cell at F (2, 2) rearranged from (w (N, 2), th (N,)), where the increment from
    ``inc`` has no equilibrium that the solvers find: FIRE with the friction law step by step
    (:func:`fire`, ``stepwise``; at most ``settings.settle_steps``), from the increment's
    forces at (w, th). Returns ``(base, available, steps)``: ``base`` the :class:`Increment`
    committed where the cell came to rest (its F0 = F; its net forces at most
    ``settings.fire_tol`` of the mean contact force, for Newton to finish from; chain None: the
    history no longer depends on F), ``available`` the energy at (w, th), stored and dissipated
    by the return map from ``inc`` (Pa): at the fixed F no work is done, so what the cell
    stores at its rest is that less what the rearrangement dissipated.
    RelaxationError where it does not come to rest."""
    n = cell.pi.shape[0]
    s = CellState(cell, springs, F, w, th, inc)
    ft0, mr0 = np.zeros(n), np.zeros(n)
    ft0[: s.m], mr0[: s.m] = s.ft, s.mr
    F = np.array(F, dtype=np.float64)
    base = Increment(F.copy(), np.array(w, dtype=np.float64), np.array(th, dtype=np.float64),
                     ft0, None, mr0)  # fmt: skip
    available = sum(s.energies(cell, springs))
    _, _, steps, rested = fire(cell, springs, F, base.w0.copy(), base.th0.copy(), base, settings,
                               stepwise=True, budget=settings.settle_steps)  # fmt: skip
    if not rested:
        raise RelaxationError(
            f"no equilibrium: the cell did not come to rest after {steps} steps of damped "
            "dynamics with the friction law step by step (it keeps rearranging)"
        )
    return base, available, steps
