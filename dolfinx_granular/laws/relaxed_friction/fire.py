"""The fallback of the frictional micro solver: FIRE (Bitzek et al. 2006), damped dynamics of
the disks (unit masses, a disk's moment of inertia r^2 / 2) under the forces and moments of the
same increment's return map, until they nearly balance; Newton then takes up again. DEM codes
relax their cells this way.
"""

from __future__ import annotations

import numpy as np

from ..relaxed.cell import Cell
from ..relaxed.errors import RelaxationError, RigidityLostError
from .cell_state import CellState, Increment, Springs
from .settings import Settings

#: steps between two checks of the residual (and updates of the candidate list)
CHECK_EVERY = 50


def fire(cell: Cell, springs: Springs, F, w, th, inc: Increment, settings: Settings) -> tuple:
    """FIRE from (w (N, 2), th (N,)) until the residual is ``settings.fire_tol``: ``(w, th,
    steps)``; RelaxationError after ``settings.fire_steps``."""
    Finv = np.linalg.inv(F)
    u = w @ F.T  # current-frame fluctuations
    th = np.array(th, dtype=np.float64)
    inertia = np.concatenate([np.ones((cell.n_disks, 2)), 0.5 * cell.radii[:, None] ** 2], 1)
    v = np.zeros((cell.n_disks, 3))
    dt_max = 0.1 * np.sqrt(1.0 / (springs.kn * springs.inv_area)) * 10.0
    dt, alpha, since = 0.1 * dt_max, 0.1, 0
    for step in range(settings.fire_steps):
        s = CellState(cell, springs, F, u @ Finv.T, th, inc, None)
        if s.count == 0:
            raise RigidityLostError("the cell unjammed: relaxation opens its contacts")
        if step % CHECK_EVERY == 0 and s.residual(cell)[0] <= settings.fire_tol:
            return u @ Finv.T, th, step
        a = np.concatenate([s.f, s.M[:, None]], 1) * springs.inv_area / inertia
        power = float((a * inertia * v).sum())
        if power > 0.0:
            an, vn = np.sqrt((a * a).sum()), np.sqrt((v * v).sum())
            v = (1.0 - alpha) * v + alpha * vn * a / max(an, 1e-300)
            since += 1
            if since > 5:
                dt, alpha = min(1.1 * dt, dt_max), 0.99 * alpha
        else:
            v[:] = 0.0
            dt, alpha, since = 0.5 * dt, 0.1, 0
        v += dt * a
        u = u + dt * v[:, :2]
        th = th + dt * v[:, 2]
    raise RelaxationError(f"FIRE did not relax the cell in {settings.fire_steps} steps")
