"""Figures of the RVE study (paper figures 2-5) with matplotlib, headless.

Figures are built as :class:`matplotlib.figure.Figure` objects without pyplot, so no GUI backend
is ever touched; save them with ``fig.savefig(path, dpi=...)``.

Data layouts:

* stress curves (figs 4, 5): ``curves[n] = (x (s,), mean (s, 2, 2), std (s, 2, 2))``, the loading
  parameter (an F component) and the mean and standard deviation over realisations of the
  Cauchy stress in Pa, one entry per particle count n;
* speed against error: rows ``{"n": int, "cv_compression": float, "cv_shear": float,
  "time_per_point": float (s)}``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.collections import PatchCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Rectangle
from matplotlib.ticker import FormatStrFormatter, LogLocator

from ..packings.fabric import contact_angles, normal_density, normal_density_sphere
from ..packings.gsd import SieveCurve
from ..packings.packing import Packing

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from matplotlib.axes import Axes
    from numpy.typing import ArrayLike

#: Colours of the angles of influence 10°, 20°, 30° as in the paper's figure 3.
DELTA_COLORS = ("black", "tab:blue", "tab:red")
_N_COLORS = ("tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:cyan")


def plot_sieve_curve(
    curve: SieveCurve, packing: Packing | None = None, d_min: float | None = None
) -> Figure:
    """Figure 2: percent passing over the aperture (log scale) with a packing's grains overlaid.

    The packing's grading is its disk-area fraction passing, mapped onto the curve's scale above
    the cut ``d_min`` (mm): P(d_min) + (100 - P(d_min)) * area fraction below d.
    """
    fig = Figure(figsize=(6.0, 4.2))
    ax = fig.add_subplot()
    d = np.geomspace(curve.aperture[0], curve.aperture[-1], 200)
    ax.semilogx(d, curve.passing_at(d), "-", color="0.3", lw=1.2)
    ax.semilogx(curve.aperture, curve.passing, "o", color="black", label=curve.name)
    if d_min is not None:
        ax.axvline(d_min, color="0.5", ls=":", lw=1)
        ax.text(d_min, 96, f" cut d_min = {d_min:g} mm", color="0.3", fontsize=8, va="top")
    if packing is not None:
        diam = np.sort(2.0 * packing.radii)
        base = float(curve.passing_at(d_min)) if d_min is not None else 0.0
        # steps after each grain: the sample's own sieve curve
        pas = base + (1.0 - base / 100.0) * SieveCurve.area_passing(diam, diam)
        ax.step(
            diam,
            pas,
            where="post",
            color="tab:red",
            lw=1.2,
            label=f"generated packing, {packing.n_particles} grains",
        )
    ax.set_xlabel("mesh aperture d [mm]")
    ax.set_ylabel("passing [% of grain area]")
    ax.set_ylim(0, 102)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title("Grain size distribution (fig. 2)", fontsize=10)
    fig.tight_layout()
    return fig


def draw_packing(ax: Axes, packing: Packing, rattlers: ArrayLike | None = None) -> None:
    """Draw the disks of ``packing`` in its cell, periodic images clipped at the cell boundary.

    ``rattlers`` (indices) are drawn white, the load-bearing disks grey.
    """
    Lx, Ly = packing.box
    shaded = np.ones(packing.n_particles, bool)
    if rattlers is not None:
        shaded[np.asarray(rattlers, dtype=int)] = False
    patches, faces = [], []
    for (x, y), r, s in zip(packing.centers, packing.radii, shaded):
        for sx in (-1, 0, 1):
            for sy in (-1, 0, 1):
                cx, cy = x + sx * Lx, y + sy * Ly
                if -r < cx < Lx + r and -r < cy < Ly + r:
                    patches.append(Circle((cx, cy), r))
                    faces.append("0.65" if s else "white")
    coll = PatchCollection(patches, facecolors=faces, edgecolors="black", linewidths=0.3)
    frame = Rectangle((0, 0), Lx, Ly, fill=False, transform=ax.transData)
    ax.add_patch(frame)
    coll.set_clip_path(frame)
    ax.add_collection(coll)
    ax.set_xlim(0, Lx)
    ax.set_ylim(0, Ly)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])


def draw_density(
    ax: Axes, angles: ArrayLike, deltas_deg: Sequence[float] = (10.0, 20.0, 30.0)
) -> None:
    """Polar plot of 2 pi rho_delta(theta) for each angle of influence (unit circle = isotropic)."""
    theta = np.linspace(0.0, 2.0 * np.pi, 721)
    ax.plot(theta, np.ones_like(theta), ":", color="0.6", lw=0.8)
    for delta, color in zip(deltas_deg, DELTA_COLORS * 3):
        _, rho = normal_density(angles, np.radians(delta), theta=theta)
        ax.plot(theta, 2.0 * np.pi * rho, color=color, lw=0.9, label=f"δ = {delta:g}°")
    ax.set_ylim(0, 2.0)
    ax.set_yticks([1.0, 2.0])
    ax.set_yticklabels([])
    ax.set_xticks(np.radians([0, 90, 180, 270]))
    ax.set_xticklabels([])
    ax.grid(True, alpha=0.3)


def plot_packings_and_densities(
    sets: Mapping[int, Sequence[Packing]],
    deltas_deg: Sequence[float] = (10.0, 20.0, 30.0),
    rattlers: Mapping[int, Sequence[ArrayLike]] | None = None,
) -> Figure:
    """Figure 3: each packing as disks beside its polar contact-normal density.

    Args:
        sets: ``{n: [Packing, ...]}``, one row per particle count.
        deltas_deg: angles of influence in degrees (black, blue, red).
        rattlers: optional ``{n: [indices, ...]}`` drawn white.
    """
    rows = list(sets)
    cols = max(len(sets[n]) for n in rows)
    fig = Figure(figsize=(2.0 * 2 * cols, 2.1 * len(rows) + 0.5))
    for r, n in enumerate(rows):
        for c, packing in enumerate(sets[n]):
            ax = fig.add_subplot(len(rows), 2 * cols, r * 2 * cols + 2 * c + 1)
            draw_packing(ax, packing, None if rattlers is None else rattlers[n][c])
            if c == 0:
                ax.set_ylabel(f"{n} particles", fontsize=10)
            pax = fig.add_subplot(len(rows), 2 * cols, r * 2 * cols + 2 * c + 2, projection="polar")
            draw_density(pax, contact_angles(packing), deltas_deg)
    handles, labels = pax.get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(deltas_deg), fontsize=9, frameon=False)
    fig.suptitle(
        "RVEs and contact-normal densities 2π ρ_δ(θ) (fig. 3; dotted: isotropic)", fontsize=11
    )
    fig.tight_layout(rect=(0, 0.05, 1, 0.96))
    return fig


def plot_sphere_densities(
    panels: Sequence[tuple[str, ArrayLike]], delta_deg: float = 15.0, n_lat: int = 60
) -> Figure:
    """Contact-normal densities on the sphere as maps (Mollweide projection), one per panel.

    Args:
        panels: ``(title, normals (N_c, 3))`` each: unit contact normals (or branch vectors).
        delta_deg: half-angle of the cone of influence in degrees
            (:func:`~dolfinx_granular.packings.fabric.normal_density_sphere`).
        n_lat: latitude cells (longitude: twice as many).

    Drawn is 4 pi rho, 1 for an isotropic set, on one colour scale for all panels; longitude 0
    is the x axis, latitude +90° the z axis.
    """
    maps = []
    for title, normals in panels:
        *_, rho = normal_density_sphere(normals, np.radians(delta_deg), n_lat, 2 * n_lat)
        # longitudes [pi, 2 pi) are drawn at [-pi, 0): the x axis at the map's centre
        maps.append((title, np.roll(4.0 * np.pi * rho, n_lat, axis=1)))
    top = max(1.5, max(float(m.max()) for _, m in maps))
    lon_edges = np.linspace(-np.pi, np.pi, 2 * n_lat + 1)
    lat_edges = np.linspace(-0.5 * np.pi, 0.5 * np.pi, n_lat + 1)
    fig = Figure(figsize=(4.6 * len(maps), 3.0))
    for k, (title, m) in enumerate(maps):
        ax = fig.add_subplot(1, len(maps), k + 1, projection="mollweide")
        mesh = ax.pcolormesh(lon_edges, lat_edges, m, cmap="viridis", vmin=0.0, vmax=top)
        ax.set_title(title, fontsize=10, pad=12)
        ax.set_xticklabels([])
        ax.tick_params(labelsize=7)
        ax.grid(True, alpha=0.3)
    bar = fig.colorbar(mesh, ax=fig.axes, orientation="horizontal", shrink=0.5, pad=0.08)
    bar.set_label(f"4π ρ (1: isotropic), cone of influence δ = {delta_deg:g}°", fontsize=9)
    return fig


def plot_stress_curves(
    panels: Sequence[tuple[str, str, Mapping[int, tuple[np.ndarray, np.ndarray, np.ndarray]]]],
    title: str = "",
) -> Figure:
    """Figures 4 and 5: mean ± standard deviation of Cauchy stress against an F component.

    Args:
        panels: list of ``(panel_title, xlabel, curves)`` with ``curves`` as in the module
            docstring. Solid: sigma_11, dashed: sigma_22 (as in the paper), one colour per n.
    """
    fig = Figure(figsize=(5.2 * len(panels), 4.3))
    for k, (ptitle, xlabel, curves) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), k + 1)
        for color, (n, (x, mean, std)) in zip(_N_COLORS, curves.items()):
            for (a, b), ls, comp in (((0, 0), "-", "11"), ((1, 1), "--", "22")):
                ax.errorbar(
                    x,
                    mean[:, a, b] / 1e6,
                    yerr=std[:, a, b] / 1e6,
                    color=color,
                    ls=ls,
                    lw=1.1,
                    capsize=2,
                    elinewidth=0.8,
                    label=f"σ{comp}, {n} particles",
                )
        ax.set_xlabel(xlabel)
        ax.set_ylabel("Cauchy stress [MPa]")
        ax.set_title(ptitle, fontsize=10)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return fig


def plot_speed_error(rows: Sequence[Mapping[str, float]]) -> Figure:
    """Coefficient of variation over seeds against evaluation time per quadrature point."""
    fig = Figure(figsize=(5.6, 4.2))
    ax = fig.add_subplot()
    t = np.array([row["time_per_point"] for row in rows]) * 1e6
    for key, marker, label in (
        ("cv_compression", "o-", "σ11 at 5 % compression"),
        ("cv_shear", "s--", "σ12 at 5 % shear"),
    ):
        cv = np.array([row[key] for row in rows]) * 100.0
        ax.loglog(t, cv, marker, label=label)
        for row, ti, ci in zip(rows, t, cv):
            ax.annotate(
                f"{row['n']}", (ti, ci), textcoords="offset points", xytext=(4, 4), fontsize=8
            )
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_formatter(FormatStrFormatter("%g"))
        axis.set_minor_locator(LogLocator(subs=(2.0, 5.0)))
        axis.set_minor_formatter(FormatStrFormatter("%g"))
    ax.tick_params(which="minor", labelsize=7)
    ax.set_xlabel("evaluation time per quadrature point (stress + tangent) [µs]")
    ax.set_ylabel("coefficient of variation over seeds [%]")
    ax.set_title("RVE size: speed against error (labels: particles)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
