"""Pseudo-transient continuation, the frictional micro solver's first fallback: implicit Euler
steps of the disks' overdamped motion under the forces and moments of the same increment's
return map,

    (sigma D + J) dq = -r,    D = k_n / V per translation, k_n r_k^2 / V per rotation,

with J the Jacobian Newton takes and sigma the inverse pseudo-time step (dimensionless).

A step is taken where it lowers the increment's potential with the Coulomb caps frozen at the
current iterate (by a part of its first-order decrease),

    Pi(q) = sum over contacts of  k_n e^2 / 2 + H_c(f*) / k_t,   c = mu k_n e(current),

H_c the Huber function (x^2 / 2 inside the cap, c |x| - c^2 / 2 beyond; the rolling springs'
H(m*) / k_r likewise, :mod:`.rolling`): r is its gradient at
the current iterate, so a short enough step always lowers it, and it keeps falling where a disk
must move to a new equilibrium (the residual rising while it moves), where a line search on
the residual stops. A step that lowers the squared residual is taken too (near the equilibrium
Pi changes by round-off). Each taken step divides sigma by :data:`SHORTER`, each
refused one multiplies it by :data:`LONGER`, so the steps end as Newton's, quadratically. Each
step is one factorisation on the block LU, and no disk moves more than
:data:`~dolfinx_granular.laws.relaxed_friction.newton_kernel.MAX_STEP` of the smallest radius
sum in one. Where sigma grows past :data:`SIGMA_MAX` or the steps run out, Newton takes over
from the last iterate (a stall at a contact on the cone's edge, which Newton's retry handles).
The equilibrium is the increment's, as Newton's: only the way to it differs.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..relaxed.newton import visited
from .newton_kernel import (
    BEYOND_PATTERN,
    CONVERGED,
    GROW_LIST,
    HAND_BACK,
    MAX_STEP,
    RIGIDITY_LOST,
    SINGULAR_PIVOT,
    cell_state,
    direction,
    factorise,
    merit,
    newton,
    residual,
    step_limit,
)
from .system import potential_change, rolling_springs

#: sigma of the first step: a shift of one contact's normal stiffness per unknown
SIGMA_START = 1.0
#: below this sigma the steps are Newton's to round-off; above :data:`SIGMA_MAX` the
#: continuation has failed (the steps no longer move the disks)
SIGMA_MIN, SIGMA_MAX = 1e-12, 1e10
#: sigma after a taken step is divided by SHORTER, after a refused one multiplied by LONGER
SHORTER, LONGER = 3.0, 10.0
#: a step is taken where it lowers the potential by ARMIJO times its first-order decrease, or
#: the squared residual by twice that part
ARMIJO = 1e-4


@njit(cache=True)
def potential_falls(s, trial, dq, cell, springs, armijo):
    """The step dq (N, 3) from the :func:`~dolfinx_granular.laws.relaxed_friction.
    newton_kernel.cell_state` s to ``trial`` lowers the increment's
    potential with the Coulomb caps frozen at s (:func:`~dolfinx_granular.laws.
    relaxed_friction.system.potential`) by at least ``armijo`` times its first-order
    decrease."""
    kn, kt, mu, inv_area, kr, mu_r = springs
    slope = (s[14] * dq).sum() / inv_area  # (d Pi along the step)
    if not slope < 0.0:
        return False
    caps = mu * kn * np.maximum(s[5], 0.0)
    rcaps, krs = rolling_springs(cell[0], cell[1], cell[5], s[5], kn, kr, mu_r)
    change = potential_change(s[5], s[7], trial[5], trial[7], caps, kn, kt, s[16], trial[16],
                              rcaps, krs)  # fmt: skip
    return change <= armijo * slope


@njit(cache=True)
def transient_entry(F, F_smin, w, th, inc0, inc1, cell0, cell1, springs, geo0, geo1, geo2,
                    verlet, pat0, pat1, pat2, pat3, lu, force_tol, max_steps, history, counts,
                    sigma):  # fmt: skip
    """:func:`transient` from Python, its long tuples in chunks as
    :func:`~dolfinx_granular.laws.relaxed_friction.newton_kernel.newton_entry` takes them."""
    return transient(F, F_smin, w, th, inc0 + inc1, cell0 + cell1, springs, geo0 + geo1 + geo2,
                     verlet, pat0 + pat1 + pat2 + pat3, lu, force_tol, max_steps, history,
                     counts, sigma)  # fmt: skip


@njit(cache=True)
def transient(F, F_smin, w, th, inc, cell, springs, geo, verlet, pattern, lu, force_tol,
              max_steps, history, counts, sigma):  # fmt: skip
    """Pseudo-transient continuation from (w, th), with the arguments and outcome of
    :func:`~dolfinx_granular.laws.relaxed_friction.newton_kernel.newton`; ``sigma`` (1,) is
    read and updated in place (a hand-back resumes with it)."""
    pi, pj, X, Y, R, radii = cell
    mean_radius = radii.mean()
    m = visited(F_smin, w, geo, verlet)
    if m < 0:
        return HAND_BACK, GROW_LIST, w, th, w
    s = cell_state(F, w, th, inc, cell, springs, m)
    for _ in range(max_steps):
        if s[13] == 0:
            return RIGIDITY_LOST, 0, w, th, w
        res, floor = residual(s, R, radii)
        history[counts[3]] = res
        counts[3] += 1
        if res <= max(force_tol, floor):
            return CONVERGED, 0, w, th, w
        if sigma[0] > SIGMA_MAX:
            break
        why, held, _ = factorise(F, s, cell, springs, pattern, lu, 0.0, False, 1.0, sigma[0])
        if why == BEYOND_PATTERN:
            return HAND_BACK, why, w, th, w
        sigma[0] *= LONGER
        if why == SINGULAR_PIVOT:
            continue
        counts[1] += 1
        dq = direction(s, held, pattern, lu)
        if not np.isfinite(dq).all():
            continue
        alpha = step_limit(F, dq, radii, geo[9], MAX_STEP)
        wt, tt = w + alpha * dq[:, :2], th + alpha * dq[:, 2]
        mt = visited(F_smin, wt, geo, verlet)
        if mt < 0:
            sigma[0] /= LONGER
            return HAND_BACK, GROW_LIST, w, th, wt
        trial = cell_state(F, wt, tt, inc, cell, springs, mt)
        if trial[13] == 0:
            continue
        lower = merit(trial, held, mean_radius) <= (1.0 - 2.0 * ARMIJO) * merit(
            s, held, mean_radius
        ) or potential_falls(s, trial, alpha * dq, cell, springs, ARMIJO)
        if not lower:
            continue
        # (a step cut short by the step limit: the shift is too small for the softest mode)
        sigma[0] = max(sigma[0] / LONGER * (SHORTER if alpha < 1.0 else 1.0 / SHORTER), SIGMA_MIN)
        w, th, s = wt, tt, trial
        counts[0] += 1
    # (stalled at a kink of the return map, a contact at the cone's edge: Newton's retry there)
    return newton(F, F_smin, w, th, inc, cell, springs, geo, verlet, pattern, lu, force_tol,
                  max_steps, history, counts)  # fmt: skip
