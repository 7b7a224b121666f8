"""FIRE (Bitzek et al. 2006) on a relaxed cell: where Newton stalls far from the equilibrium
(a rearrangement), the disks relax towards it as damped particles, and Newton takes up again.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .cell import Cell
from .contact_state import ContactState, contact_state, energy, forces
from .errors import CameApart
from .settings import Settings

#: FIRE counts the cell as unjammed once its energy falls below this part of the start's
UNJAMMED = 1e-12
#: FIRE steps between two updates of the candidate list
FIRE_CHUNK = 200
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


def fire(cell: Cell, F: np.ndarray, w: np.ndarray, settings: Settings) -> tuple:
    """FIRE on the current positions x = F (X + w) (unit masses, the contact forces) until
    the largest net force is ``settings.fire_tol`` of the mean contact force, for at most
    ``settings.fire_steps`` steps: ``(w, steps, converged)``, w (N, 2) where it stopped.

    The steps run in Numba (:func:`fire_chunk`) in chunks of
    :data:`FIRE_CHUNK`; between chunks the candidate list is brought up to the disks' new
    positions (:meth:`Cell.visited`)."""
    Finv = np.linalg.inv(F)
    u = np.ascontiguousarray(w @ F.T)  # fluctuations in the current frame
    v = np.zeros_like(u)
    params = np.array([0.1 / np.sqrt(cell.K), 0.1, 0.0, 1.0 / np.sqrt(cell.K)])
    s = ContactState(cell, F, w)
    if not s.on.any():
        raise CameApart("the cell unjammed: relaxation opens its contacts", w, None)
    E0, steps = s.energy(cell, s.on), 0
    while steps < settings.fire_steps:
        m = cell.visited(F, u @ Finv.T)
        status, taken = fire_chunk(
            F, Finv, u, v, cell.pi, cell.pj, cell.X, cell.Y, cell.R, cell.K, m,
            cell.n_disks, params, min(FIRE_CHUNK, settings.fire_steps - steps),
            settings.fire_tol, E0, UNJAMMED,
        )  # fmt: skip
        steps += taken
        if status == FIRE_UNJAMMED:  # (the disks float where the motion left them)
            raise CameApart("the cell unjammed: relaxation opens its contacts", u @ Finv.T,
                            None)  # fmt: skip
        if status == FIRE_CONVERGED:
            return u @ Finv.T, steps, True
    return u @ Finv.T, steps, False
