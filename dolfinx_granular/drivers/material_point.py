"""A material-point driver: strain, stress or mixed control of one point of any law.

Every component F_ij of the deformation gradient is either prescribed or unknown; each unknown
F_ij is solved so that the matching stress component (Cauchy sigma_ij or first Piola P_ij) takes
a prescribed value. Newton's method uses the law's consistent tangent A = dP/dF (pushed forward
for the Cauchy stress); steps are capped, and with one unknown an iterate that leaves the bracket
of the root found so far is replaced by bisection (stick/slip switches make the stress only
piecewise smooth; where the last step did not halve the residual, too; where the stress jumps
across its target, ``accept_jump`` takes the nearer side; an iterate at which a relaxed cell
comes apart bounds a compressive target from the dilated side). Works for
:class:`~dolfinx_granular.MaterialLaw` (no history) and :class:`~dolfinx_granular.HistoryLaw`
(a committed 1-point state), in any dimension d.

    point = MaterialPoint(FrictionalRVE(packing, 2.8e7, friction=0.5))
    point.step(F=[[1, 0], [0, 1]], stress={(1, 1): -1e5})            # confine: sigma_22 = -p
    point.step(F=[[1, 0.01], [0, point.F[1, 1]]], stress={(1, 1): -1e5})  # shear under p

Serial, pure NumPy around the law's own ``evaluate``: a step costs a few law evaluations.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..laws.protocol import law_dimension
from ..laws.relaxed.errors import RelaxationError, RigidityLostError

#: default tolerance: |s_ij - target_ij| <= RTOL * stress scale at every stress-controlled ij
RTOL = 1e-10
MEASURES = ("cauchy", "piola")


class ControlError(RuntimeError):
    """The mixed-control iteration did not reach the stress targets; nothing was committed."""


@dataclass(frozen=True)
class PointResult:
    """A converged material-point step.

    Attributes:
        F: (d, d) deformation gradient.  W: stored energy density (Pa).
        P: (d, d) first Piola stress (Pa).  sigma: (d, d) Cauchy stress (Pa).
        state: the law's trial state at F from the committed one (None without history).
        iterations: Newton iterations (0: the guess was converged).
        residuals: per iterate, the stress residual of largest magnitude (signed, Pa).
        control_error: where the stress jumps across its target (``accept_jump``), how far it
            is from it (Pa, signed); 0 otherwise.
        floating: the law's cell came apart at F (``collapse``): P is round-off.
    """

    F: np.ndarray
    W: float
    P: np.ndarray
    sigma: np.ndarray
    state: Any
    iterations: int
    residuals: tuple
    control_error: float = 0.0
    floating: bool = False


def _evaluate(law, F, state):
    """(W, P (d, d), A (d, d, d, d), trial state) of one point."""
    if state is None:
        W, P, A = law.evaluate(F)[:3]
        new = None
    else:
        W, P, A, new = law.evaluate(F, state)
    d = F.shape[0]
    return float(np.ravel(W)[0]), np.reshape(P, (d, d)), np.reshape(A, (d, d, d, d)), new


def stress_tangent(F, P, A, measure="cauchy"):
    """d s_ij / d F_kl (d, d, d, d) of s = P (``"piola"``) or sigma = P F^T / J (``"cauchy"``):
    d sigma_ij / d F_kl = (A_imkl F_jm + P_il delta_jk) / J - sigma_ij (F^-1)_lk."""
    if measure == "piola":
        return A
    J = np.linalg.det(F)
    sigma, Finv = P @ F.T / J, np.linalg.inv(F)
    T = np.empty(A.shape)
    # entry by entry, in the operation order of the hand-written confined-shear driver the
    # friction study had: its published numbers stay bitwise the same
    for i, j, k, m in np.ndindex(*A.shape):
        push = A[i, :, k, m] @ F[j] + (P[i, m] if j == k else 0.0)
        T[i, j, k, m] = push / J - sigma[i, j] * Finv[m, k]
    return T


def _check(F, stress, measure, scale):
    """Validated (F (d, d), unknown indices [(i, j)], targets (k,), tolerance scale)."""
    F = np.array(F, dtype=float)
    if F.ndim != 2 or F.shape[0] != F.shape[1]:
        raise ValueError(f"F must be a (d, d) array, got shape {F.shape}")
    if measure not in MEASURES:
        raise ValueError(f"measure must be one of {MEASURES}, got {measure!r}")
    keys = [tuple(int(i) for i in k) for k in (stress or {})]
    if any(len(k) != 2 or not all(0 <= i < F.shape[0] for i in k) for k in keys):
        raise ValueError(f"stress keys must be index pairs (i, j) into F {F.shape}, got {keys}")
    targets = np.array([float(v) for v in (stress or {}).values()])
    if scale is None:
        scale = float(np.abs(targets).max()) if targets.size else 1.0
    if not scale > 0.0:
        raise ValueError("every stress target is 0: give stress_scale (Pa) for the tolerance")
    return F, keys, targets, scale


def solve_point(
    law,
    F,
    stress=None,
    state=None,
    measure="cauchy",
    rtol=RTOL,
    stress_scale=None,
    max_iter=50,
    max_increment=0.02,
    accept_jump=0.0,
    accept_unjammed=0.0,
    collapse=False,
):
    """Solve the unknown components of F so that the stress meets its targets, from ``state``.

    Args:
        law: a MaterialLaw (``state`` None) or a HistoryLaw (``state`` its committed 1-point
            state, never modified: every iterate starts from it).
        F: (d, d) prescribed components, and the initial guess of the unknown ones.
        stress: ``{(i, j): target}`` in Pa: F_ij is unknown and s_ij = target (None or {}:
            pure strain control, one evaluation).
        measure: ``"cauchy"`` (sigma = P F^T / J) or ``"piola"`` (P).
        rtol, stress_scale: converged when every |s_ij - target| <= rtol * stress_scale
            (default scale: the largest |target|).
        max_iter: Newton iterations allowed.  max_increment: largest change of an unknown F_ij
            per iteration.
        accept_jump: with one unknown, where the stress jumps across its target (the bracket
            of the root has shrunk to round-off: a relaxed RVE that rearranges, a law with no F
            between two branches), the bracket's end nearer the target is the answer if it
            misses by at most ``accept_jump`` times the stress scale (its miss in
            ``PointResult.control_error``); 0: never (a :class:`ControlError` names the jump).
            With one unknown held to a compressive target, an iterate at which the law's cell
            comes apart (:class:`~dolfinx_granular.laws.relaxed.errors.RigidityLostError`: a
            relaxed RVE dilated past jamming) counts as stress-free, the bracket's dilated
            end; so does one at which the micro solver finds no equilibrium
            (:class:`~dolfinx_granular.laws.relaxed.errors.RelaxationError`) on the dilated
            side of an iterate that held more than the target. Before an iterate held more
            than the target, the next one lies ``max_increment`` more compressed, twice as far
            after each further iterate that came apart, up to :data:`UNJAMMED_GROWTH` times (a
            loose frictional cell that collapsed may jam again only further in).
        accept_unjammed: where the bracket has shrunk between such an iterate and one that
            holds (a cell jammed on one side of a round-off, come apart on the other: no F
            between holds the target), the jammed end is the answer if it misses by at most
            this times the stress scale (0: only as ``accept_jump`` allows).
        collapse: there, where the jammed end misses by more than ``accept_jump`` and the law
            gave the state of its cell come apart
            (:class:`~dolfinx_granular.laws.relaxed.errors.CellFloats`), that end is the answer
            (``PointResult.floating``, its miss the whole target): committed, it lets the cell
            collapse, as a servo-controlled wall that retreats does, to jam again further in.

    Returns:
        :class:`PointResult`. Raises :class:`ControlError` (with the residual history) when not
        converged; nothing is committed then.
    """
    F0, keys, targets, scale = _check(F, stress, measure, stress_scale)
    idx = tuple(np.array(keys, dtype=int).T) if keys else None
    one = np.eye(F0.shape[0])[idx] if keys else None
    # the unknowns are the displacement gradient H_ij = F_ij - delta_ij: small numbers, and
    # F_ij = delta_ij + H_ij as the friction study's hand-written driver built it (bitwise)
    x = F0[idx] - one if keys else None
    bracket = _Bracket()
    residuals = []
    for it in range(max_iter + 1):
        F = F0.copy()
        if keys:
            F[idx] = one + x
        try:
            W, P, A, new = _evaluate(law, F, state)
        except RelaxationError as err:
            if not (isinstance(err, RigidityLostError) or _gave_way(bracket, x)):
                raise
            floated = _floated(F, err, it, residuals, targets)
            x = _unjammed_next(bracket, x, keys, targets, residuals, max_increment, floated)
            if x is None:
                raise
            if bracket.shrunk():  # (bisected onto the edge of jamming from the dilated side)
                return bracket.jump(accept_jump, scale, keys[0], accept_unjammed, collapse)
            continue
        sigma = P @ F.T / np.linalg.det(F)
        if idx is None:
            return PointResult(F, W, P, sigma, new, 0, ())
        r = (sigma if measure == "cauchy" else P)[idx] - targets
        residuals.append(float(r[np.argmax(np.abs(r))]))
        result = PointResult(F, W, P, sigma, new, it, tuple(residuals))
        if np.abs(r).max() <= rtol * scale:
            return result
        K = stress_tangent(F, P, A, measure)[idx][:, idx[0], idx[1]]  # (k, k)
        step = _newton_step(K, r, max_increment)
        if r.size > 1:
            x = x + step
            continue
        bracket.add(x[0], r[0], result)
        if bracket.shrunk():
            return bracket.jump(accept_jump, scale, keys[0], accept_unjammed, collapse)
        x = np.array([bracket.next(x[0], step[0], residuals, max_increment)])
    raise ControlError(
        f"material point: |s - target| = {abs(residuals[-1]):.3e} Pa > {rtol:.0e} x "
        f"{scale:.6g} Pa after {max_iter} iterations (residuals "
        f"{', '.join(f'{x:.2e}' for x in residuals[-5:])}); state not committed"
    )


def _floated(F, err, it, residuals, targets):
    """The :class:`PointResult` (``floating``) of iterate ``it`` at F, where the law's cell came
    apart and ``err`` carries the law's outputs there
    (:class:`~dolfinx_granular.laws.relaxed.errors.CellFloats`); else None."""
    outputs = getattr(err, "outputs", None)
    if outputs is None or targets.size != 1:
        return None
    W, P, _, new = outputs
    d = F.shape[0]
    P = np.reshape(P, (d, d))
    sigma = P @ F.T / np.linalg.det(F)
    return PointResult(F, float(np.ravel(W)[0]), P, sigma, new, it,
                       (*residuals, -float(targets[0])), floating=True)  # fmt: skip


def _gave_way(bracket, x) -> bool:
    """The iterate x (1,) at which the micro solver found no equilibrium lies on the dilated
    side of an iterate that held more than the target (the bracket's ``lo``; a bracket is kept
    for one unknown only, and :func:`_unjammed_next` refuses any but a diagonal one held to a
    compressive target): near jamming, where a cell that holds too much on one side gives way
    on the other (at p / k_n = 1e-3, a frictional cell of 70 disks that jammed at 1.4 p did
    not come to rest a thousandth of a strain further out), it counts as come apart."""
    return "lo" in bracket.ends and x[0] > bracket.lo


def _unjammed_next(bracket, x, keys, targets, residuals, max_increment, floated=None):
    """The next iterate where the iterate x (1,) of one diagonal unknown F_ij, held to a
    compressive target, lost its contact network (a relaxed cell dilated past jamming carries
    no stress: residual = -target): x bounds the root from the dilated side, and the next
    iterate bisects the bracket, or before an iterate held more than the target, lies
    ``max_increment`` more compressed, doubled for every iterate before it that came apart
    (at most :data:`UNJAMMED_GROWTH` times). None where x tells nothing (the caller
    re-raises). ``floated``: the iterate's result where the law gave its state (else None)."""
    if x is None or x.size != 1 or keys[0][0] != keys[0][1] or not targets[0] < 0.0:
        return None
    bracket.add(x[0], -float(targets[0]), floated, apart=True)
    residuals.append(-float(targets[0]))
    if bracket.found():
        return np.array([0.5 * (bracket.lo + bracket.hi)])
    bracket.apart += 1
    return x - max_increment * min(2.0 ** (bracket.apart - 1), UNJAMMED_GROWTH)


#: the largest factor on ``max_increment`` of the moves towards compression while iterates
#: come apart (doubled from 1: 1, 2, 4, ... 64): where a collapsed loose cell jams again only
#: further in, the search gets there in a few iterations, not in 50 moves of ``max_increment``
#: (p / k_n in the element tests)
UNJAMMED_GROWTH = 64.0

#: a bracket narrower than this (in F_ij, times max(1, |F_ij - delta_ij|)) has shrunk to
#: round-off: the stress jumps across its target there
JUMP_WIDTH = 1e-13


class _Bracket:
    """One unknown's root bracket: the nearest iterates with a residual < 0 (lo) and > 0 (hi),
    and their results. Newton's iterate is kept inside it; where it would leave it, or where
    the last step did not halve the residual (a piecewise smooth or jumping stress), the
    bracket is bisected instead; a slow Newton without a bracket doubles its moves."""

    def __init__(self):
        self.lo, self.hi = -np.inf, np.inf
        self.ends = {}  # "lo", "hi": (residual, result or None, the cell came apart there)
        self.move = 0.0
        self.apart = 0  # iterates that came apart before a bracket was found

    def add(self, x, r, result, apart=False):
        if r < 0.0:
            self.lo, self.ends["lo"] = x, (r, result, apart)
        else:
            self.hi, self.ends["hi"] = x, (r, result, apart)

    def found(self) -> bool:
        """Both ends exist: the root lies between them."""
        return bool(np.isfinite(self.lo) and np.isfinite(self.hi))

    def shrunk(self) -> bool:
        """Both ends exist and lie a round-off apart (:data:`JUMP_WIDTH`)."""
        width = JUMP_WIDTH * max(1.0, abs(self.lo), abs(self.hi))
        return self.found() and self.hi - self.lo <= width

    def next(self, x, step, residuals, max_increment) -> float:
        """The next iterate from x (its Newton step ``step``): where the last step did not
        halve the residual, the bracket's midpoint, or without a bracket yet twice the last
        move (at most ``max_increment``)."""
        slow = len(residuals) > 1 and abs(residuals[-1]) > 0.5 * abs(residuals[-2])
        if slow and self.found():
            return 0.5 * (self.lo + self.hi)
        if slow and abs(step) < 2.0 * abs(self.move):
            step = np.sign(step) * min(2.0 * abs(self.move), max_increment)
        if not self.lo < x + step < self.hi:
            # a step always heads for the root's side of x, so only the far bound can be
            # crossed, and that one is finite: bisect the bracket
            return 0.5 * (self.lo + self.hi)
        self.move = step
        return x + step

    def jump(self, accept, scale, key, accept_unjammed=0.0, collapse=False):
        """The result at the end nearer the target, where it misses by at most ``accept`` x
        ``scale``; where the other end came apart, the jammed end, where it misses by at most
        ``accept`` x ``scale``, else (``collapse``) the end come apart where it has a result,
        else the jammed end where it misses by at most ``accept_unjammed`` x ``scale``; else
        ControlError."""
        (r_lo, lo, lo_apart), (r_hi, hi, hi_apart) = self.ends["lo"], self.ends["hi"]
        r, result = (r_lo, lo) if -r_lo <= r_hi else (r_hi, hi)
        limit = accept
        if lo_apart or hi_apart:
            (r, result), (r_apart, apart) = (
                ((r_hi, hi), (r_lo, lo)) if lo_apart else ((r_lo, lo), (r_hi, hi))
            )
            if collapse and apart is not None and not abs(r) <= accept * scale:
                return replace(apart, control_error=float(r_apart))
            limit = max(accept, accept_unjammed)
        if result is not None and abs(r) <= limit * scale:
            return replace(result, control_error=float(r))
        raise ControlError(
            f"material point: the stress {key} jumps from {r_lo:+.3e} to {r_hi:+.3e} Pa about its "
            f"target at F{key[0] + 1}{key[1] + 1} = {1.0 * (key[0] == key[1]) + self.lo:.15g}: "
            f"no F meets it (accept_jump = {accept:g}, accept_unjammed = {accept_unjammed:g} of "
            f"{scale:.6g} Pa take the nearer or the jammed side); "
            "state not committed"
        )


def solve_pressure(
    law, pressure, state=None, lam=1.0, rtol=1e-8, max_iter=50, max_increment=0.02, dim=None
):
    """Solve F = lam I (an isotropic strain path) for the mean pressure -tr(sigma) / d =
    ``pressure`` (Pa), from ``state`` and the guess ``lam``.

    Near jamming a frictionless packing has almost no shear stiffness, so mixed control of
    sigma_11 = sigma_22 (:func:`solve_point`) takes large deviatoric steps; along F = lam I the
    only unknown is the volume, and the deviatoric stress is what the packing gives. Newton on
    h = lam - 1, kept inside the bracket of the root found so far, as :func:`solve_point` does
    for one unknown; ``residuals`` are the mean stress minus its target -``pressure``.
    ``rtol``: the pressure is good to eps R / e of itself (R a radius, e an overlap), ~1e-9 at
    1e-7 of the radii. ``dim``: d (default :func:`~dolfinx_granular.law_dimension`).

    Returns:
        :class:`PointResult`; :class:`ControlError` when not converged (nothing committed).
    """
    if not pressure > 0.0:
        raise ValueError(f"pressure must be > 0 Pa, got {pressure!r}")
    d = law_dimension(law) if dim is None else int(dim)
    x, lo, hi, residuals = np.array([float(lam) - 1.0]), -np.inf, np.inf, []
    for it in range(max_iter + 1):
        F = (1.0 + x[0]) * np.eye(d)
        W, P, A, new = _evaluate(law, F, state)
        sigma = P @ F.T / np.linalg.det(F)
        r = np.array([np.trace(sigma) / d + pressure])  # mean stress - its target -pressure
        residuals.append(float(r[0]))
        if abs(r[0]) <= rtol * pressure:
            return PointResult(F, W, P, sigma, new, it, tuple(residuals))
        K = np.einsum("iikk->", stress_tangent(F, P, A)) / d  # d(tr sigma / d) / dh, dF = dh I
        lo, hi = (x[0], hi) if r[0] < 0.0 else (lo, x[0])
        x = x + _newton_step(np.array([[K]]), r, max_increment)
        if not lo < x[0] < hi:
            x = np.array([0.5 * (lo + hi)])  # (only the finite far bound can be crossed)
    raise ControlError(
        f"material point: mean pressure off by {abs(residuals[-1]):.3e} Pa > {rtol:.0e} x "
        f"{pressure:.6g} Pa after {max_iter} iterations along F = lam I; state not committed"
    )


def _newton_step(K, r, max_increment):
    """Newton's increment -K^-1 r scaled to |dx|_max <= max_increment; without stiffness (no
    contact yet, or a singular K) a step of max_increment against the residual's sign."""
    if r.size == 1:
        step = -r / K[0, 0] if K[0, 0] > 0.0 else -np.sign(r) * max_increment
        return np.clip(step, -max_increment, max_increment)
    try:
        step = np.linalg.solve(K, -r)
    except np.linalg.LinAlgError:
        step = -np.sign(r) * max_increment
    big = np.abs(step).max()
    return step * (max_increment / big) if big > max_increment else step


class MaterialPoint:
    """One material point of ``law`` with its committed state and deformation.

    Attributes:
        law: the law.  state: committed state (``law.initial_state(1)`` for a HistoryLaw, None
            for a MaterialLaw).  F: (d, d) committed deformation gradient (the identity at first).
        last: the last committed :class:`PointResult` (None before the first step).
    """

    def __init__(self, law, state=None, dim=2):
        self.law = law
        if state is None and hasattr(law, "initial_state"):
            state = law.initial_state(1)
        self.state = state
        self.F = np.eye(dim)
        self.last = None

    def trial(self, F, stress=None, **options) -> PointResult:
        """:func:`solve_point` from the committed state; commits nothing."""
        return solve_point(self.law, F, stress, self.state, **options)

    def commit(self, result: PointResult) -> None:
        """Make ``result`` (a converged step from the committed state) the committed one."""
        self.state, self.F, self.last = result.state, result.F, result

    def step(self, F, stress=None, **options) -> PointResult:
        """Solve (:func:`solve_point`) and commit; on :class:`ControlError` nothing changes."""
        result = self.trial(F, stress, **options)
        self.commit(result)
        return result

    def compress(self, pressure, **options) -> PointResult:
        """Solve F = lam I for the mean pressure (:func:`solve_pressure`, from the committed
        F's lam) and commit; on :class:`ControlError` nothing changes."""
        lam = float(np.trace(self.F)) / self.F.shape[0]
        result = solve_pressure(self.law, pressure, self.state, lam, dim=self.F.shape[0], **options)
        self.commit(result)
        return result

    def path(self, Fs, stress=None, **options) -> list:
        """Follow the (m, d, d) prescribed F (the unknown components of each start from the
        last converged F) under the same stress targets, committing every step; a ``stress``
        of callables ``{(i, j): f(k)}`` gives the target at step k. Returns the m results."""
        out = []
        for k, F in enumerate(np.asarray(Fs, dtype=float)):
            F = F.copy()
            targets = {key: (v(k) if callable(v) else v) for key, v in (stress or {}).items()}
            for i, j in targets:
                F[i, j] = self.F[i, j]
            out.append(self.step(F, targets, **options))
        return out
