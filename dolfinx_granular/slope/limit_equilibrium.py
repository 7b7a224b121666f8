"""Limit equilibrium of the slope benchmark: the infinite slope and Bishop's simplified method.

Dry soil (no pore pressure) of unit weight γ = density x gravity, friction angle φ and
cohesion c (0 by default: cohesionless), plane strain, per metre of width, on the ground of a
:class:`~.geometry.SlopeGeometry`. Pure numpy: nothing here needs DOLFINx. A uniform
confining pressure p held on the ground's boundary (the finite-element slope's
``confinement``) adds p to the normal stress on every slip surface and nothing to the driving
moment (an isotropic stress is in equilibrium by itself): it acts as a cohesion c = p tan φ.

* :func:`infinite_slope_factor_of_safety`: FS = tan φ / tan β;
* :func:`circle_factor_of_safety`: Bishop's simplified FS on one given circle;
* :func:`bishop_factor_of_safety`: the critical circle from a grid search refined around the
  best, as a :class:`SlipCircle`.

A circle is described by its entry and exit points on the ground, x_a < x_b in [0, width], and
u in (0, 1]: the arc subtends 2θ with θ = u (90° - |ψ|), ψ the chord's inclination, so the arc
is a function of x below its centre (u = 1: it meets the ground vertically at one end). The
slip mass is the ground between the arc and the surface. Admissible circles lie below the
ground between entry and exit (one slip mass), stay above the base y = 0 (no clipping: deeper
circles are rejected, the base is rigid as in the finite-element model), reach a depth (largest
vertical thickness of the slip mass) of at least ``min_depth``, and have m_α >= 0.2 on every
slice (Whitman & Bailey 1967: below, Bishop's normal forces are unreliable). A slip mass
whose weight turns it towards -x (away from the slope) is taken in that direction. The footing
is a vertical surcharge, footing_scale x the finite-element model's pressure, on the slices
beneath it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .geometry import SlopeGeometry

#: the least m_α = cos α + sin α tan φ / FS on any slice of an admissible circle
M_ALPHA_MIN = 0.2
#: the coarse grid's values of u (the arc's half-angle over its largest), shallow arcs densest
U_GRID = np.geomspace(0.01, 1.0, 33)
#: how many of the coarse grid's best circles the search refines
STARTS = 3
REACH = 2


@dataclass(frozen=True)
class SlipCircle:
    """The critical circle of :func:`bishop_factor_of_safety`.

    ``factor_of_safety`` (inf where no admissible circle drives a slip, the circle then nan);
    the circle's centre ``centre_x``, ``centre_y`` and ``radius`` (m); where it enters and
    leaves the ground, ``entry_x`` < ``exit_x`` (m); ``depth`` (m), the slip mass's largest
    vertical thickness. ``circle`` is (centre_x, centre_y, radius).
    """

    factor_of_safety: float
    centre_x: float
    centre_y: float
    radius: float
    entry_x: float
    exit_x: float
    depth: float

    @property
    def circle(self) -> tuple[float, float, float]:
        return (self.centre_x, self.centre_y, self.radius)


def infinite_slope_factor_of_safety(geometry: SlopeGeometry, phi_degrees: float) -> float:
    """FS = tan φ / tan β of a dry cohesionless infinite slope of the geometry's inclination β
    (inf for flat ground); ``phi_degrees`` the friction angle in degrees, in (0, 90)."""
    _check_phi(phi_degrees)
    beta = math.radians(geometry.slope_angle)
    return math.tan(math.radians(phi_degrees)) / math.tan(beta) if beta > 0 else math.inf


def circle_factor_of_safety(
    geometry: SlopeGeometry,
    phi_degrees: float,
    centre: tuple[float, float],
    radius: float,
    footing_scale: float = 0.0,
    n_slices: int = 100,
    cohesion: float = 0.0,
) -> float:
    """Bishop's simplified FS of the slip mass above the circle of ``centre`` (x, y) (m) and
    ``radius`` (m), with ``footing_scale`` x the footing load on it and ``cohesion`` c (Pa);
    ``n_slices`` slices of equal width. ValueError if the circle's lower arc does not cut the
    ground exactly twice within [0, width] or dips below the base y = 0. The m_α and depth
    checks of the search are not applied; inf if the slip mass drives no slip."""
    _check(geometry, phi_degrees, footing_scale, n_slices, cohesion)
    xc, yc = (float(v) for v in centre)
    if not (_number(radius) and radius > 0 and math.isfinite(xc) and math.isfinite(yc)):
        raise ValueError(
            f"need a finite centre (x, y) and a radius > 0 m, got {centre!r} and {radius!r}"
        )
    xa, xb = _crossings(geometry, xc, yc, float(radius))
    if xa <= xc <= xb and yc - radius < 0.0:
        raise ValueError(
            f"the circle dips {radius - yc:.3g} m below the base y = 0: give a smaller radius "
            "or a higher centre"
        )
    W, sin_a, cos_a, _ = _slices(
        geometry, footing_scale, *(np.array([v]) for v in (xa, xb, xc, yc, radius)), n_slices
    )
    cb = np.array([cohesion * (xb - xa) / n_slices])
    fs, _ = _bishop(W, sin_a, cos_a, math.tan(math.radians(phi_degrees)), cb)
    return float(fs[0])


def bishop_factor_of_safety(
    geometry: SlopeGeometry,
    phi_degrees: float,
    footing_scale: float = 0.0,
    *,
    min_depth: float | None = None,
    n_slices: int = 100,
    n_grid: int = 31,
    tolerance: float = 0.01,
    cohesion: float = 0.0,
) -> SlipCircle:
    """The critical circle and its FS by Bishop's simplified method (module docstring).

    ``phi_degrees``: friction angle in (0, 90) degrees; ``cohesion``: c >= 0 (Pa; p tan φ
    stands for a confining pressure p); ``footing_scale`` >= 0: the share of
    ``geometry.footing_load`` on the footing, with the finite-element model's linear pressure
    (:meth:`~.geometry.SlopeGeometry.footing_pressure`) as a surcharge on the slices beneath;
    ``min_depth`` (m): the shallowest admissible slip mass, by default 5 % of the slope's
    height (crest - toe; of crest_height on flat ground), which keeps away the degenerate
    vanishing circles whose FS tends to tan φ / tan β; ``n_slices`` slices per circle.

    Search: entry and exit on ``n_grid`` points each over [0, width], u on :data:`U_GRID`,
    with at most 40 slices; then from each of the :data:`STARTS` best, a 5 x 5 x 5 pattern
    in (entry, exit, ln u), moved with the best and halved once the best is inside, until
    its steps are below ``tolerance`` m in entry and exit and ``tolerance`` / width in ln u.
    Deterministic; on the benchmark's slopes (ratios 1 to 4, φ 25° to 35°, with and without
    the footing) the FS agrees with an 81-point grid's to 0.1 %, and with 300 slices' to
    0.3 % (the footing's circles, which end on the m_α limit).
    """
    _check(geometry, phi_degrees, footing_scale, n_slices, cohesion)
    depth = _min_depth(geometry, min_depth)
    if not (_integer(n_grid) and n_grid >= 3):
        raise ValueError(f"n_grid must be an integer >= 3 (31 by default), got {n_grid!r}")
    if not (_number(tolerance) and tolerance > 0):
        raise ValueError(f"tolerance must be a length > 0 m (0.01 by default), got {tolerance!r}")
    coarse = _evaluator(geometry, phi_degrees, footing_scale, depth, min(n_slices, 40), cohesion)
    xs = np.linspace(0.0, geometry.width, n_grid)
    xa, xb, u = (a.ravel() for a in np.meshgrid(xs, xs, np.log(U_GRID), indexing="ij"))
    p = np.stack([xa, xb, u], axis=1)[xa < xb]
    fs, _ = coarse(p)
    starts = np.argsort(fs, kind="stable")[:STARTS]
    if not np.isfinite(fs[starts[0]]):
        return SlipCircle(math.inf, *[math.nan] * 6)
    evaluate = _evaluator(geometry, phi_degrees, footing_scale, depth, n_slices, cohesion)
    step = np.array([xs[1], xs[1], np.log(U_GRID[1] / U_GRID[0])])
    tolerance = tolerance / np.array([1.0, 1.0, geometry.width])
    found = [_refine(evaluate, p[k], step, tolerance) for k in starts if np.isfinite(fs[k])]
    return min(found, key=lambda c: c.factor_of_safety)


def _refine(evaluate, p, step, tolerance) -> SlipCircle:
    """Pattern search from the parameters ``p`` (3,) with ``step`` (3,): a 5 x 5 x 5 grid
    around the best, moved while the best is on its edge, else halved, until ``step`` <
    ``tolerance`` (3,)."""
    fs = evaluate(p[None, :])[0][0]
    offsets = np.stack(np.meshgrid(*[np.arange(-REACH, REACH + 1)] * 3, indexing="ij"), -1)
    offsets = offsets.reshape(-1, 3)
    for _ in range(500):
        trial = p + offsets * step
        values, _ = evaluate(trial)
        k = int(np.argmin(values))
        moved = values[k] < fs
        if moved:
            p, fs = trial[k], values[k]
        if not (moved and np.any(np.abs(offsets[k]) == REACH)):
            if np.all(step < tolerance):
                break
            step = step / 2
    _, circle = evaluate(p[None, :])
    xc, yc, R, depth = (float(v[0]) for v in circle)
    return SlipCircle(float(fs), xc, yc, R, float(p[0]), float(p[1]), depth)


def _evaluator(geometry, phi_degrees, footing_scale, min_depth, n_slices, cohesion=0.0):
    """``evaluate(p)``: FS (m,) of the circles of parameters p (m, 3) (x_a, x_b, ln u), inf
    where inadmissible, and their centre x, centre y, radius and depth (4, m)."""
    tan_phi = math.tan(math.radians(phi_degrees))

    def evaluate(p):
        xa, xb, log_u = p.T
        ok = (xa >= 0.0) & (xb <= geometry.width) & (xa < xb) & (log_u <= 0.0)
        xa, xb, u = xa[ok], xb[ok], np.exp(log_u[ok])
        xc, yc, R = _circle(geometry, xa, xb, u)
        W, sin_a, cos_a, depth = _slices(geometry, footing_scale, xa, xb, xc, yc, R, n_slices)
        fs, m_min = _bishop(W, sin_a, cos_a, tan_phi, cohesion * (xb - xa) / n_slices)
        floor = np.where((xa <= xc) & (xc <= xb), yc - R, 0.0)
        admissible = (depth >= min_depth) & (floor >= 0.0) & (m_min >= M_ALPHA_MIN) & (fs > 0)
        out = np.full(len(p), np.inf)
        out[ok] = np.where(admissible, fs, np.inf)
        circle = np.full((4, len(p)), np.nan)
        circle[:, ok] = xc, yc, R, depth
        return out, circle

    return evaluate


def _circle(geometry, xa, xb, u):
    """Centre x, y and radius (m), each (m,), of the arcs from the ground at ``xa`` to ``xb``
    with half-angle u (90° - |ψ|)."""
    ya, yb = geometry.surface_height(xa), geometry.surface_height(xb)
    dx, dy = xb - xa, yb - ya
    chord = np.hypot(dx, dy)
    theta = u * (0.5 * np.pi - np.abs(np.arctan2(dy, dx)))
    R = chord / (2.0 * np.sin(theta))
    lift = R * np.cos(theta) / chord  # the centre above the chord's midpoint, along its normal
    return 0.5 * (xa + xb) - lift * dy, 0.5 * (ya + yb) + lift * dx, R


def _slices(geometry, footing_scale, xa, xb, xc, yc, R, n):
    """Slices of the circles (each argument (m,)): the weight with the footing's surcharge,
    W (m, n) (N/m, > 0 down), sin α and cos α (m, n) of the base (α > 0 where the base
    descends towards +x), and the depth (m,) (m): the slip mass's largest thickness, -inf
    where the arc rises above the ground between entry and exit."""
    b = (xb - xa) / n
    x = xa[:, None] + (np.arange(n) + 0.5) * b[:, None]
    sin_a = (xc[:, None] - x) / R[:, None]
    cos_a = np.sqrt(np.clip(1.0 - sin_a**2, 0.0, None))
    h = geometry.surface_height(x) - (yc[:, None] - R[:, None] * cos_a)
    depth = np.where(np.all(h >= -1e-9 * geometry.width, axis=1), h.max(axis=1), -np.inf)
    W = geometry.density * geometry.gravity * b[:, None] * np.maximum(h, 0.0)
    if footing_scale:
        lo = np.maximum(x - 0.5 * b[:, None], geometry.footing_start)
        hi = np.minimum(x + 0.5 * b[:, None], geometry.footing_end)
        q = geometry.footing_pressure_on_strip(0.5 * (lo + hi))  # linear: exact over [lo, hi]
        W = W - footing_scale * q * np.maximum(hi - lo, 0.0)
    return W, sin_a, cos_a, depth


def _bishop(W, sin_a, cos_a, tan_phi, cb=0.0, rtol=1e-11, max_iter=500):
    """Bishop's simplified FS (m,) of slices W, sin α, cos α (m, n) with cohesion times slice
    width ``cb`` (m,) (N/m; 0: cohesionless), from Fellenius's by fixed-point iteration to
    ``rtol``, and the least m_α (m,) on a loaded slice. A slip mass whose weight turns it
    towards -x is mirrored (α -> -α); inf where it drives no slip or the iteration fails (FS <=
    0 or no convergence)."""
    driving = np.sum(W * sin_a, axis=1)
    sin_a = sin_a * np.where(driving < 0.0, -1.0, 1.0)[:, None]
    driving = np.abs(driving)
    cb = np.broadcast_to(np.asarray(cb, dtype=float), (len(W),))[:, None]
    fs = np.full(len(W), np.inf)
    live = np.flatnonzero(driving > 1e-12 * np.sum(W, axis=1))  # not a symmetric mass
    with np.errstate(divide="ignore", invalid="ignore"):
        # (Fellenius: c over the base's length b / cos α)
        base = cb[live] / cos_a[live] + tan_phi * W[live] * cos_a[live]
        fs[live] = np.sum(base, axis=1) / driving[live]
        for _ in range(max_iter):
            m = cos_a[live] + sin_a[live] * (tan_phi / fs[live, None])
            new = np.sum((cb[live] + tan_phi * W[live]) / m, axis=1) / driving[live]
            done = np.abs(new - fs[live]) <= rtol * np.abs(new)
            fs[live] = np.where(np.isfinite(new) & (new > 0.0), new, np.inf)
            live = live[~done & np.isfinite(fs[live])]
            if not len(live):
                break
        fs[live] = np.inf
        m = cos_a + sin_a * (tan_phi / fs[:, None])
    return fs, np.where(W > 0.0, m, np.inf).min(axis=1)


def _crossings(geometry, xc, yc, R):
    """Entry and exit x (m) of the circle's lower arc on the ground; ValueError unless it cuts
    the ground exactly twice within [0, width]."""
    X = np.array([0.0, geometry.slope_start, geometry.slope_end, geometry.width])
    Y = geometry.surface_height(X)
    dx, dy, fx, fy = np.diff(X), np.diff(Y), X[:-1] - xc, Y[:-1] - yc
    a, b, c = dx**2 + dy**2, 2.0 * (fx * dx + fy * dy), fx**2 + fy**2 - R**2
    disc = np.sqrt(np.clip(b**2 - 4.0 * a * c, 0.0, None))[None, :] * np.array([[-1.0], [1.0]])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-b + disc) / (2.0 * a)
    hit = (b**2 - 4.0 * a * c >= 0.0) & (t >= 0.0) & (t <= 1.0) & (Y[:-1] + t * dy <= yc)
    xs = np.unique(np.round((X[:-1] + t * dx)[hit], 9))
    if len(xs) != 2:
        raise ValueError(
            f"the circle (centre ({xc:g}, {yc:g}) m, radius {R:g} m) cuts the ground {len(xs)} "
            "times below its centre within [0, width], not twice: give a circle whose lower "
            "arc enters and leaves the ground once, inside the domain"
        )
    return float(xs[0]), float(xs[1])


def _number(x) -> bool:
    """Whether ``x`` is a finite real number (not a bool)."""
    return (
        isinstance(x, (int, float, np.integer, np.floating))
        and not isinstance(x, bool)
        and math.isfinite(x)
    )


def _integer(x) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


def _check_phi(phi_degrees):
    if not (_number(phi_degrees) and 0.0 < phi_degrees < 90.0):
        raise ValueError(
            f"phi_degrees must be a friction angle in degrees in (0, 90), got {phi_degrees!r}: "
            "give e.g. 30 (degrees, not radians or tan φ)"
        )


def _check(geometry, phi_degrees, footing_scale, n_slices, cohesion=0.0):
    """ValueError naming the bad argument and the fix."""
    _check_phi(phi_degrees)
    if not (_number(cohesion) and cohesion >= 0.0):
        raise ValueError(f"cohesion must be a finite stress >= 0 in Pa, got {cohesion!r}")
    if not (_number(footing_scale) and footing_scale >= 0.0):
        raise ValueError(
            "footing_scale must be a finite number >= 0 (the share of footing_load applied: "
            f"0 none, 1 all), got {footing_scale!r}"
        )
    if not (_integer(n_slices) and n_slices >= 2):
        raise ValueError(f"n_slices must be an integer >= 2 (100 by default), got {n_slices!r}")
    if not geometry.density * geometry.gravity > 0.0:
        raise ValueError(
            "the unit weight density x gravity must be > 0, got "
            f"{geometry.density!r} x {geometry.gravity!r}: give both positive"
        )


def _min_depth(geometry, min_depth):
    """``min_depth`` (m) checked, or its default: 5 % of the slope's height."""
    if min_depth is None:
        rise = geometry.crest_height - geometry.toe_height
        return 0.05 * (rise if rise > 0.0 else geometry.crest_height)
    if not (_number(min_depth) and 0.0 <= min_depth < geometry.crest_height):
        raise ValueError(
            f"min_depth must be a depth in [0, crest_height = {geometry.crest_height}) m or "
            f"None (5 % of the slope's height), got {min_depth!r}"
        )
    return float(min_depth)
