"""The failure mechanism of a factor-of-safety run: the displacement increment at the limit.

:func:`limit_increment` reads a trial's ``restart.npz`` (every converged state's nodal
displacements): the increment Du from the last state but one to the last, where the trial's
path following reached its limit point or passed it (the whole displacement where only one state
converged). :func:`draw_mechanism` draws |Du| over the slope, its directions, and the critical
circles of Bishop's method over it (matplotlib without pyplot: headless).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np
from matplotlib.figure import Figure
from matplotlib.tri import Triangulation

from ..io.runwriter import read_npz

if TYPE_CHECKING:
    from collections.abc import Sequence

    from .geometry import SlopeGeometry
    from .limit_equilibrium import SlipCircle

#: the most arrows drawn (every k-th node beyond)
ARROWS = 500


def limit_increment(folder: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray, int] | None:
    """``(X (n, 2) m, Du (n, 2) m, states)`` of the run in ``folder``: the nodes, the increment
    of its last converged state and how many states it stored; None without a restart file (no
    state converged)."""
    from .run import RESTART_FORMAT

    path = os.path.join(folder, "restart.npz")
    if not os.path.exists(path):
        return None
    f = read_npz(path, RESTART_FORMAT)
    u = np.asarray(f["u_history"], dtype=float)
    du = u[-1] - u[-2] if len(u) > 1 else u[-1]
    return np.asarray(f["nodes"], dtype=float), du, len(u)


def draw_mechanism(
    path: str | os.PathLike[str],
    geometry: SlopeGeometry,
    X: np.ndarray,
    du: np.ndarray,
    circles: Sequence[tuple[str, SlipCircle, str]],
    title: str,
    footing_scale: float = 0.0,
) -> None:
    """Save the figure of |Du| (colour, relative to its largest) and its directions (arrows)
    at the nodes ``X`` (n, 2) m over the slope of ``geometry``, with ``circles``: (label,
    :class:`~.limit_equilibrium.SlipCircle`, line style; two at most) drawn between their entry
    and exit;
    the footing (thick) where ``footing_scale`` > 0."""
    magnitude = np.linalg.norm(du, axis=1)
    largest = magnitude.max() if magnitude.size and magnitude.max() > 0 else 1.0
    top = 1.08 * geometry.crest_height
    # the slope at equal scales, 4 inches high, beside its colour bar
    fig = Figure(figsize=(4.0 * geometry.width / top + 1.8, 4.8), layout="constrained")
    ax = fig.add_subplot()
    tri = Triangulation(X[:, 0], X[:, 1])
    centre = X[tri.triangles].mean(axis=1)
    # Delaunay fills the convex hull: drop the triangles above the ground (over the slope)
    tri.set_mask(centre[:, 1] > geometry.surface_height(centre[:, 0]) + 1e-6 * geometry.width)
    shade = ax.tripcolor(
        tri, magnitude / largest, shading="gouraud", cmap="viridis", vmin=0.0, vmax=1.0
    )
    fig.colorbar(shade, ax=ax, shrink=0.8, label=f"|Du| / {largest:.3g} m")
    every = max(1, len(X) // ARROWS)
    ax.quiver(
        X[::every, 0],
        X[::every, 1],
        du[::every, 0],
        du[::every, 1],
        color="white",
        angles="xy",
        scale_units="xy",
        scale=largest / (0.6 * geometry.column_width),
        width=0.002,
    )
    _ground(ax, geometry, footing_scale)
    for (label, circle, style), colour in zip(circles, ("tab:red", "tab:orange")):
        _arc(ax, circle, label, style, colour)
    ax.set(aspect="equal", xlabel="x (m)", ylabel="y (m)", title=title)
    ax.set_xlim(0.0, geometry.width)
    ax.set_ylim(0.0, top)
    if circles:
        ax.legend(loc="lower left", fontsize=8)
    fig.savefig(path, dpi=130)


def _ground(ax, g, footing_scale):
    xs = np.array([0.0, g.slope_start, g.slope_end, g.width])
    ax.plot(xs, g.surface_height(xs), color="black", lw=1.0)
    if footing_scale > 0.0:
        xf = np.array([g.footing_start, g.footing_end])
        ax.plot(
            xf,
            g.surface_height(xf) + 0.4,
            color="tab:red",
            lw=4.0,
            label=f"footing x{footing_scale:g}",
        )


def _arc(ax, c, label, style, colour):
    """The lower arc of the circle between its entry and exit (nothing for no circle)."""
    if not np.isfinite(c.radius):
        return
    x = np.linspace(c.entry_x, c.exit_x, 200)
    y = c.centre_y - np.sqrt(np.clip(c.radius**2 - (x - c.centre_x) ** 2, 0.0, None))
    ax.plot(x, y, style, color=colour, lw=2.0, label=f"{label}: FS {c.factor_of_safety:.3f}")
