"""Element tests of one material point: confined simple shear and the biaxial test.

Both start from the confined state F_c = lam I (compressed isotropically to the mean pressure
p = p / k_n times k_n, :func:`confine`) and prescribe one strain x in steps, while the
material-point driver (:class:`~dolfinx_granular.MaterialPoint`) solves one more, y, so that a
normal stress stays -p (:class:`Loading`: :data:`SHEAR`, :data:`BIAXIAL`). A step that fails is
halved; a step that fails after :data:`MAX_CUTS` halvings ends the test, which keeps the steps
it reached and the error (the known limit of the micro solver at large strain, where the cell
rearranges). :func:`load_test` runs one test, :func:`step_row` is a step's row and
:func:`measures` the test's scalars (peak and critical-state q/p = sin phi, dilatancy, ...).

Measures (2-D, compression positive): p = -(sigma_11 + sigma_22) / 2,
q = sqrt(((sigma_11 - sigma_22) / 2)^2 + sigma_12^2) = (sigma_1 - sigma_3) / 2, q / p = sin(phi
mobilised); e_v = ln(det F / det F_c) (dilation positive); the "critical state" is the mean
over the steps in the last quarter of the strain reached (of a test stopped early: where it got
to). Used by ``demos/relaxed_friction_study.py`` and :mod:`.strength`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from ..laws.friction import FrictionalRVE
from ..laws.protocol import LawEvaluationError
from ..laws.relaxed_friction import FrictionalRelaxedRVE
from .confinement import compress
from .element_progress import Progress
from .material_point import ControlError, MaterialPoint

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from ..packings.packing import Packing

K_N = 2.8e7  # normal contact stiffness, N/m² (table 1 of the paper)
K_T = K_N  # tangential stiffness, N/m² (a common DEM choice, as the friction study)
#: the laws by name: the frictional relaxed RVE and the frictional Taylor RVE
LAWS = {"relaxed": FrictionalRelaxedRVE, "taylor": FrictionalRVE}
MAX_CUTS = 3  # halvings of a failed step before its test stops
CRITICAL = 0.75  # the "critical state": the steps past this fraction of the strain reached
#: the stop message of a test stopped by its time budget ("stopped: " BUDGET_STOP ...)
BUDGET_STOP = "time budget"


def make_law(name: str, packing: Packing, mu: float, k_n: float = K_N, k_t: float = K_T,
             mu_r: float = 0.0):  # fmt: skip
    """The frictional relaxed (``"relaxed"``) or Taylor (``"taylor"``) RVE of ``packing`` with
    friction ``mu``, contact stiffnesses ``k_n``, ``k_t`` (N/m²) and, for the relaxed RVE,
    rolling friction ``mu_r``."""
    if name not in LAWS:
        raise ValueError(f"unknown law {name!r}: give one of {', '.join(LAWS)}")
    if mu_r == 0.0:
        return LAWS[name](packing, k_n, k_t, mu)
    if name != "relaxed":
        raise ValueError("rolling friction is a setting of the relaxed RVE: leave it out (0) "
                         f"with law {name!r}")  # fmt: skip
    return LAWS[name](packing, k_n, k_t, mu, rolling_friction=mu_r)


@dataclass(frozen=True)
class Loading:
    """A test's path from F_c = lam I: F[drive_ij] = lam (base + sign x), x (column ``drive``)
    prescribed; F[held_ij] = lam (1 + y), y (column ``free``) solved so that sigma[held_ij] =
    -p; F's other components stay F_c's. ``limits``: the configuration's keys of the largest x
    and of the number of steps to it."""

    test: str
    drive: str
    free: str
    drive_ij: tuple
    held_ij: tuple
    base: float
    sign: float
    limits: tuple
    label: str  # the axis label of x
    title: str

    def strains(self, F, lam):
        """(x, y) of F (+ 0.0: no -0.0 at x = 0)."""
        x = (F[self.drive_ij] / lam - self.base) / self.sign + 0.0
        return float(x), float(F[self.held_ij] / lam - 1.0)


SHEAR = Loading("shear", "gamma", "e22", (0, 1), (1, 1), 0.0, 1.0, ("max_shear", "shear_steps"),
                "shear strain γ [%]", "Confined simple shear (σ22 = −p, F11 held)")  # fmt: skip
BIAXIAL = Loading("biaxial", "eps1", "e11", (1, 1), (0, 0), 1.0, -1.0,
                  ("max_strain", "biaxial_steps"), "axial strain ε1 [%]",
                  "Biaxial compression (σ11 = −p, F12 = F21 = 0)")  # fmt: skip
LOADINGS = {loading.test: loading for loading in (SHEAR, BIAXIAL)}


def ratios(sigma):
    """(p in Pa, q / p, tau / p) of a Cauchy stress (2, 2)."""
    s11, s22, s12 = sigma[0, 0], sigma[1, 1], sigma[0, 1]
    p = -0.5 * (s11 + s22)
    return p, np.hypot(0.5 * (s11 - s22), s12) / p, s12 / p


def network(law, F, state, mu):
    """(contacts with overlap > 0, z over the disks with >= 2 of them, sliding share or NaN at
    mu = 0) of the 1-point ``state`` at F. The relaxed RVE's state is the one at F (its contacts
    are read, not solved again; sliding: slid in the increment to it); the Taylor RVE's is the
    committed state before the step to F (its ``contacts`` takes the step)."""
    c = law.contacts(F, state)
    on = c.overlap > 0.0
    pairs = c.pairs[on]
    n = law.packing.radii.shape[0]
    degree = np.bincount(pairs.ravel(), minlength=n)
    carried = degree >= 2
    between = carried[pairs[:, 0]] & carried[pairs[:, 1]]
    z = 2.0 * between.sum() / carried.sum() if carried.any() else 0.0
    sliding = np.asarray(c.sliding)[on]
    share = float(sliding.mean()) if mu > 0.0 and on.any() else float("nan")
    return int(on.sum()), float(z), share


def confine(law, pressure):
    """A :class:`MaterialPoint` of ``law`` compressed along F = lam I to the mean pressure
    ``pressure`` (p / k_n, times the law's k_n); its last result is the confined state. Raises
    what ``compress`` raises."""
    point = MaterialPoint(law)
    # (the driver's strain steps capped at ten times the strain the pressure asks for)
    compress(point, pressure * law.normal_stiffness, max_increment=10 * pressure, isotropic=True)
    return point


def step_row(loading, law, mu, Fc, Dc, r, before, seconds, collapses=0):
    """A step's row (the result ``r``); ``Dc``: the confined state's dissipation; ``before``: the
    committed state before the step (None: the confined state, no step: no sliding share);
    ``collapses``: the step's (:func:`hold_step`)."""
    lam = Fc[0, 0]
    x, y = loading.strains(r.F, lam)
    p, qp, taup = ratios(r.sigma)
    relaxed = isinstance(law, FrictionalRelaxedRVE)
    state = r.state if relaxed or before is None else before
    contacts, z, share = network(law, r.F, state, mu)
    return {
        loading.drive: x,
        loading.free: y,
        **{f"F{i + 1}{j + 1}": float(r.F[i, j]) for i in range(2) for j in range(2)},
        "sigma11_Pa": r.sigma[0, 0],
        "sigma12_Pa": r.sigma[0, 1],
        "sigma22_Pa": r.sigma[1, 1],
        "p_Pa": p,
        "q_over_p": qp,
        "tau_over_p": taup,
        "volumetric_strain": float(np.log(np.linalg.det(r.F) / np.linalg.det(Fc))),
        "contacts": contacts,
        "z": z,
        "sliding_share": share if before is not None else float("nan"),
        "dissipation_Pa": float(r.state.dissipation[0]) - Dc,
        "newton_iterations": r.iterations,
        "control_error_Pa": r.control_error,
        "collapses": collapses,
        "wall_s": seconds,
    }


#: where the held stress jumps across -p (a relaxed cell rearranging between two trial F a
#: round-off apart: no F holds it), a step takes the nearer side if it misses p by at most this
#: part (``control_error_Pa`` in its row); the next step holds it again. A rearrangement
#: moves the stress by the forces of a few contacts, each about 2 / (number of contacts) of p
#: (70 disks: ~1.5 %; measured misses of biaxial tests at p / k_n = 1e-2: 2.4-3.8 %), as a
#: servo-controlled wall of a DEM cell lags its target while the cell rearranges. A step
#: "holds p" where it misses by at most this part: :func:`measures` reads only those
ACCEPT_JUMP = 0.1
#: where the cell comes apart a round-off beyond a jammed trial F (a loose frictional packing
#: that collapses when dilated: measured at p / k_n = 1e-3 with 70 disks, the jammed side held
#: 1.32-1.54 p), the step takes the jammed side if it misses p by at most this part, as a
#: servo-controlled wall overshoots while a collapsing DEM cell re-jams; the next step holds p
#: again (where the law gives the state its cell came apart in, a miss beyond ACCEPT_JUMP
#: collapses the cell instead: :data:`MAX_COLLAPSES`)
ACCEPT_UNJAMMED = 1.0
#: steps in a row that may miss p by more than ACCEPT_JUMP: where a step's every halving meets
#: a jump beyond the limits above (near jamming a 70-disk cell gives way at once: at p / k_n =
#: 1e-3 from 1.5 p to 0.8 p, or from 2 p to a cell that came apart), the last halving takes the
#: jump's nearer (or jammed) side whatever it misses, as a servo-controlled wall overshoots
#: while its cell rearranges; the test stops where p is not held again within this many steps
MAX_OFF_TARGET = 5


def load_test(
    loading: Loading,
    law,
    pressure: float,
    targets: Sequence[float],
    budget: float | None = None,
    resume: Progress | None = None,
    keep: Callable[[Progress], None] | None = None,
) -> tuple[list[dict], str]:
    """One test (``loading``) of ``law`` (a :data:`LAWS` RVE, e.g. from :func:`make_law`)
    confined at ``pressure`` (p / k_n, times the law's k_n) to the strains ``targets`` (k,):
    ``(step rows, stop message or "")``. Row 0 is the confined state (x = 0); a test whose
    confinement failed has no rows. ``budget``: wall seconds, checked before every step (None:
    no limit). ``resume``: the :class:`~.element_progress.Progress` of this test after one of its
    steps (what ``keep`` was given): the test goes on from there, its rows first, its seconds
    counted in the budget. ``keep`` is called with the progress after the confinement and
    every step."""
    t0 = time.perf_counter() - (resume.seconds if resume is not None else 0.0)
    at = resume
    if at is None:
        try:
            point = confine(law, pressure)
        except (ControlError, LawEvaluationError) as err:
            return [], f"stopped: confinement failed: {err}"[:300]
        Fc, Dc = point.F.copy(), float(point.state.dissipation[0])
        rows = [step_row(loading, law, law.friction, Fc, Dc, point.last, None,
                         time.perf_counter() - t0)]  # fmt: skip
        # each target gets MAX_CUTS halvings in all (those whose midpoints were reached
        # included), as the driver's ramp
        at = Progress(rows, point.F, point.state, Fc, Dc, list(targets), 0.0, 0, len(targets), 0.0)
        _keep(keep, at, point, t0)
    point = MaterialPoint(law, at.state)
    point.F = np.array(at.F, dtype=float)
    stop = off_target(at.rows, pressure * law.normal_stiffness) if len(at.rows) > 1 else ""
    t_row = time.perf_counter()  # (a row's wall time: since the row before, halvings included)
    while at.targets and not stop:
        if budget is not None and time.perf_counter() - t0 > budget:
            stop = f"stopped: {BUDGET_STOP} of {budget:g} s reached"
            break
        n_rows = len(at.rows)
        stop = _next_step(loading, law, pressure, at, point, t_row)
        _keep(keep, at, point, t0)
        t_row = time.perf_counter() if len(at.rows) > n_rows else t_row
    return at.rows, stop


def _next_step(loading, law, pressure, at: Progress, point: MaterialPoint, t_row: float) -> str:
    """Try the step to ``at.targets[0]`` from ``point``: on success commit it and append its
    row (its wall time since ``t_row``), on failure halve it (:data:`MAX_CUTS` times a target);
    ``at`` updated. Returns the stop message (the failure after the last halving, or
    :func:`off_target`'s) or ""."""
    P, lam = pressure * law.normal_stiffness, at.Fc[0, 0]
    F = point.F.copy()
    F[loading.drive_ij] = lam * (loading.base + loading.sign * at.targets[0])
    if len(at.rows) > 1:
        F[loading.held_ij] = lam * (1.0 + held_guess(at.rows, loading, at.targets[0], P))
    before = point.state
    try:
        r, collapses = hold_step(point, F, loading.held_ij, P, pressure, at.cuts == MAX_CUTS)
    except (ControlError, LawEvaluationError) as err:
        if at.cuts == MAX_CUTS:
            return f"stopped: {err}"[:300]
        at.targets.insert(0, 0.5 * (at.done + at.targets[0]))
        at.cuts += 1
        return ""
    at.done = at.targets.pop(0)
    if len(at.targets) < at.left:  # one of the targets reached: the next gets its halvings
        at.left, at.cuts = len(at.targets), 0
    at.rows.append(step_row(loading, law, law.friction, at.Fc, at.dissipation_c, r, before,
                            time.perf_counter() - t_row, collapses))  # fmt: skip
    return off_target(at.rows, P)


def _keep(keep, at: Progress, point: MaterialPoint, t0: float) -> None:
    """``keep(at)`` with the point's committed F and state and the seconds since ``t0``."""
    at.F, at.state, at.seconds = point.F, point.state, time.perf_counter() - t0
    if keep is not None:
        keep(at)


def held_guess(rows, loading, target, P) -> float:
    """The held strain y's first guess for the step to x = ``target``: extrapolated along the
    last step where it and the one before held p (:func:`holds_p`; P in Pa) and it took no
    collapse, else the last step's y. A step that missed p, or whose cell collapsed and jammed
    again further in, does not tell the path's slope: at p / k_n = 1e-3 (mu = 0.1, 70 disks)
    the slope of a step that jammed 5 % further in took the next guess 27 p into compression,
    where Newton's moves of p / k_n did not get back to p within 50 iterations."""
    x, y = loading.drive, loading.free
    a, b = rows[-2], rows[-1]
    if b.get("collapses", 0) or not (holds_p(a, P) and holds_p(b, P)):
        return b[y]
    rate = (b[y] - a[y]) / (b[x] - a[x])
    return b[y] + rate * (target - b[x])


#: collapses a step may take: where the cell comes apart a round-off beyond a jammed trial F
#: that misses p by more than ACCEPT_JUMP and the law gives the state it came apart in (the
#: frictional relaxed RVE's loose cell), the step commits that state and holds p again from
#: it, at the same prescribed strain: a servo-controlled wall that retreats lets its cell
#: collapse, and the cell jams again further in
MAX_COLLAPSES = 3


#: Newton iterations of a step: a jump's bracket, found within a move of p / k_n, takes about
#: 33 bisections to shrink to round-off (:data:`~.material_point.JUMP_WIDTH`), and the moves
#: of p / k_n towards it come first (at p / k_n = 1e-3 a step of mu = 1 stopped after 50: 19
#: moves from a guess 3.8 p too compressed, then 31 bisections)
MAX_ITERATIONS = 80


def hold_step(point, F, held_ij, P, pressure, servo=False):
    """The step to F holding sigma[held_ij] = -P (Pa) with the jumps :data:`ACCEPT_JUMP` and
    :data:`ACCEPT_UNJAMMED` allow, through up to :data:`MAX_COLLAPSES` collapses; ``servo``: a
    larger jump too, at its nearer (or jammed) side whatever it misses
    (:data:`MAX_OFF_TARGET`): ``(result, collapses taken)``, the result's ``iterations``
    those of every solve. Where it fails, the point is as before it (a collapse it committed
    taken back)."""
    # (the limits decide only what a jump's end is taken: the iterates, and a step that
    # meets no jump beyond them, are the same under the servo's)
    accept = math.inf if servo else ACCEPT_JUMP

    def solve(F, collapse):
        # (Newton's steps on y capped at p / k_n: a trial F far off the path takes the
        # path-dependent micro solver there, and it fails more often; with 10 p / k_n,
        # 200 disks at p / k_n = 1e-2, mu = 0.5 stopped at gamma = 0.8 %, not 6.8 %)
        return point.step(F, {held_ij: -P}, max_increment=pressure, accept_jump=accept,
                          accept_unjammed=ACCEPT_UNJAMMED, collapse=collapse,
                          max_iter=MAX_ITERATIONS)  # fmt: skip

    before = (point.state, point.F, point.last)
    try:
        r, collapses, iterations = solve(F, True), 0, 0
        while r.floating:  # (committed where the cell came apart: p held again from there)
            collapses += 1
            iterations += r.iterations
            r = solve(point.F.copy(), collapses < MAX_COLLAPSES)
    except (ControlError, LawEvaluationError):
        point.state, point.F, point.last = before
        raise
    return replace(r, iterations=iterations + r.iterations), collapses


def holds_p(row, P) -> bool:
    """The step ``row`` held its stress to :data:`ACCEPT_JUMP` of the pressure P (Pa)."""
    return abs(row["control_error_Pa"]) <= ACCEPT_JUMP * P


def off_target(rows, P) -> str:
    """The stop message where the last :data:`MAX_OFF_TARGET` steps all missed P (Pa) by more
    than ACCEPT_JUMP, else ""."""
    last = rows[1:][-MAX_OFF_TARGET:]
    if len(last) < MAX_OFF_TARGET or any(holds_p(r, P) for r in last):
        return ""
    misses = ", ".join(f"{r['control_error_Pa'] / P:+.2f}" for r in last)
    return (
        f"stopped: {MAX_OFF_TARGET} steps in a row missed p by more than {ACCEPT_JUMP:g} of "
        f"it (misses {misses} of p): the cell does not return to its confinement"
    )


def measures(rows, stop, target, loading):
    """Scalars of one test: how far it got (x), peak, critical and final q/p (and final tau/p),
    peak and final dilatancy d e_v / d x, final e_v, critical and final z and sliding share,
    final dissipation, how many steps missed p (``off_target_steps``) and how many collapses
    the steps took (``collapses``; rows without the column: none). Critical: the mean
    over the steps with x >= CRITICAL x_reached. The peak and the critical means read only the
    steps that held p (:func:`holds_p`; p: the confined row 0's)."""
    x_name = loading.drive
    out = {f"{x_name}_reached": rows[-1][x_name] if rows else 0.0, "target": target,
           "stopped": bool(stop), "message": stop}  # fmt: skip
    if len(rows) < 2:
        return out
    g = np.array([r[x_name] for r in rows])
    qp = np.array([r["q_over_p"] for r in rows])
    ev = np.array([r["volumetric_strain"] for r in rows])
    held = np.array([holds_p(r, rows[0]["p_Pa"]) for r in rows])
    k = int(np.flatnonzero(held)[np.argmax(qp[held])])  # (row 0 holds p: it is confined to it)
    window = max(1, (len(rows) - 1) // 10)
    dil = (ev[window:] - ev[:-window]) / (g[window:] - g[:-window])
    tail = int(np.searchsorted(g, 0.8 * g[-1]))
    tail = min(tail, len(rows) - 2)
    # (a step at 3/4 of x_reached, round-off aside)
    critical = (g >= (CRITICAL - 1e-9) * g[-1]) & held

    def mean(key):  # over the critical steps (NaN where none has a value)
        v = np.array([r[key] for r in rows], dtype=float)[critical]
        return float(v[np.isfinite(v)].mean()) if np.isfinite(v).any() else float("nan")

    last = rows[-1]
    out.update({
        "qp_start": qp[0],
        "qp_peak": qp[k],
        f"{x_name}_peak": g[k],
        "critical_from": CRITICAL * g[-1],
        "qp_critical_last_quarter": mean("q_over_p"),
        "qp_final": qp[-1],
        "taup_final": last["tau_over_p"],
        "dilatancy_peak": float(dil.max()),
        "dilatancy_final": float((ev[-1] - ev[tail]) / (g[-1] - g[tail])),
        "ev_final": ev[-1],
        "z_critical_last_quarter": mean("z"),
        "z_final": last["z"],
        "sliding_critical_last_quarter": mean("sliding_share"),
        "sliding_final": last["sliding_share"],
        "dissipation_final_Pa": last["dissipation_Pa"],
        "off_target_steps": int((~held).sum()),
        "collapses": int(sum(r.get("collapses", 0) for r in rows)),
    })  # fmt: skip
    return out
