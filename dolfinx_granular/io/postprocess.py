"""Post-processing: von Mises stress, loss of ellipticity, MPI gathers, force networks and the
figure-7 style pyvista plot of the slope.

Functions that take a communicator gather to rank 0 what they need; pyvista is imported only by
:func:`plot_slope`, and only on rank 0.
"""

from __future__ import annotations

import textwrap
from typing import TYPE_CHECKING, Any

import numpy as np

from ..gathers import global_extremum, nearest_point  # noqa: F401 (their home before)
from ..laws.taylor import ContactSet

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence
    from os import PathLike

    from dolfinx.fem import Function, FunctionSpace
    from numpy.typing import ArrayLike

    from ..laws.friction import FrictionalRVE, FrictionContactSet, FrictionState
    from ..laws.levels import AdaptiveRVE, SmallStrainRVE
    from ..laws.taylor import TaylorRVE


def von_mises(sigma: ArrayLike) -> np.ndarray:
    """Von Mises stress (n,) in Pa of Cauchy stresses sigma (n, d, d), d = 2 or 3.

    ``sqrt(3/2 s:s)`` with the deviator ``s = sigma - tr(sigma)/d I``. In 2-D that is the
    in-plane deviator (the 2-D Taylor RVE's stress is a 2x2 tensor and has no out-of-plane
    component), i.e. ``sqrt(3/4 (s11 - s22)^2 + 3/4 (s12 + s21)^2)``.
    """
    sigma = np.asarray(sigma, dtype=float)
    if sigma.ndim != 3 or sigma.shape[1:] not in ((2, 2), (3, 3)):
        raise ValueError(f"sigma must have shape (n, 2, 2) or (n, 3, 3), got {sigma.shape}")
    d = sigma.shape[1]
    s = sigma - np.trace(sigma, axis1=1, axis2=2)[:, None, None] / d * np.eye(d)
    return np.sqrt(1.5 * np.einsum("qij,qij->q", s, s))


def min_acoustic_eigenvalue(A: ArrayLike, n_directions: int = 180) -> np.ndarray:
    """Smallest eigenvalue (n,) in Pa of the acoustic tensor ``Q_ik(N) = A_iJkL N_J N_L`` over
    ``n_directions`` unit vectors N equally spaced in [0, pi), at each point.

    A is dP/dF (n, 2, 2, 2, 2). With major symmetry (hyperelastic) Q is symmetric; a frictional
    law's A is not where contacts slide, and the eigenvalue is then that of Q's symmetric part
    (the least ``m . Q m`` over unit m). A negative value means the point has lost strong
    ellipticity: a band of localised deformation normal to that N can form, and the boundary
    value problem's solution depends on the mesh size there.
    """
    A = np.asarray(A, dtype=float)
    if A.ndim != 5 or A.shape[1:] != (2, 2, 2, 2):
        raise ValueError(f"A must have shape (n, 2, 2, 2, 2), got {A.shape}")
    if int(n_directions) < 1:
        raise ValueError(f"n_directions must be >= 1, got {n_directions!r}")
    lowest = np.full(A.shape[0], np.inf)
    for theta in np.pi * np.arange(int(n_directions)) / int(n_directions):
        N = np.array([np.cos(theta), np.sin(theta)])
        Q = np.einsum("qiJkL,J,L->qik", A, N, N)
        half_trace = 0.5 * (Q[:, 0, 0] + Q[:, 1, 1])
        radius = np.hypot(0.5 * (Q[:, 0, 0] - Q[:, 1, 1]), 0.5 * (Q[:, 0, 1] + Q[:, 1, 0]))
        np.minimum(lowest, half_trace - radius, out=lowest)
    return lowest


def cell_function(V0: FunctionSpace, owned_values: np.ndarray) -> Function:
    """Fill a DG0 Function on space ``V0`` from (n_owned_cells,) values; ghosts are scattered."""
    from dolfinx import fem

    from ..fem.compat import cell_dofs

    f = fem.Function(V0)
    n = owned_values.shape[0]
    dofs = cell_dofs(V0.dofmap).reshape(-1)[:n]
    f.x.array[dofs] = owned_values
    f.x.scatter_forward()
    return f


def gather_mesh(
    V: FunctionSpace, u: Function, cell_values: ArrayLike
) -> tuple[np.ndarray, ...] | None:
    """Collect the owned cells of a first-order vector space on rank 0.

    Returns on rank 0 ``(points (N, 3), cells (M, k), cell_types (M,), u (N, d), values (M,))``
    (reference coordinates; points on partition boundaries are duplicated), else ``None``.
    """
    from ..fem.compat import vtk_mesh

    msh = V.mesh
    n_owned = msh.topology.index_map(msh.topology.dim).size_local
    topology, cell_types, geometry = vtk_mesh(V)
    k = topology[0]
    cells = topology.reshape(-1, k + 1)[:n_owned, 1:]
    uu = u.x.array.reshape(-1, msh.geometry.dim)
    parts = msh.comm.gather(
        (geometry, cells, cell_types[:n_owned], uu, np.asarray(cell_values)), root=0
    )
    if msh.comm.rank != 0:
        return None
    offset = 0
    out = [[], [], [], [], []]
    for g, c, t, du, v in parts:
        out[0].append(g)
        out[1].append(c + offset)
        out[2].append(t)
        out[3].append(du)
        out[4].append(v)
        offset += g.shape[0]
    return tuple(np.concatenate(o) for o in out)


def contact_network(
    rve: TaylorRVE | SmallStrainRVE | AdaptiveRVE | FrictionalRVE,
    F: ArrayLike,
    state: FrictionState | None = None,
) -> tuple[ContactSet | FrictionContactSet, np.ndarray, np.ndarray]:
    """The active contacts of one RVE at F (2, 2): ``(contacts, normal_force (m,), sliding (m,)
    bool)``; ``state`` is the committed state of a law with history (frictional contacts: their
    sliding ones are flagged), None for an elastic law."""
    c = rve.contacts(F) if state is None else rve.contacts(F, state)
    if isinstance(c, ContactSet):  # an elastic law, or a relaxed RVE (sliding: frictional)
        sliding = np.zeros(len(c.force), dtype=bool) if c.sliding is None else c.sliding
        return c, c.force, np.asarray(sliding, dtype=bool)
    return c, c.normal_force, np.asarray(c.sliding, dtype=bool)


def force_network(
    rve: TaylorRVE | SmallStrainRVE | AdaptiveRVE | FrictionalRVE,
    F: ArrayLike,
    force_scale: float,
    state: FrictionState | None = None,
    network: tuple[ContactSet | FrictionContactSet, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Polygons of a deformed RVE's force network: one quad per contact, width ∝ normal force.

    Args:
        rve: the material-point law (a TaylorRVE, or a FrictionalRVE with ``state``).
        F: (2, 2) deformation gradient.
        force_scale: branch half-width per unit contact force (packing length per force unit).
        state: the committed state of one point, for a law with history.
        network: :func:`contact_network` of the same rve, F and state, if the caller has it
            (the contacts are not searched again).

    Returns:
        ``(quads (m, 4, 2), disks (N, 2) centres, radii (N,), sliding (m,) bool)`` in the
        deformed RVE, centred on the origin.
    """
    c, force, sliding = contact_network(rve, F, state) if network is None else network
    pk = rve.packing
    if state is not None and hasattr(rve, "positions"):  # disks off the affine positions
        centers = rve.positions(F, state)[0]
    else:
        centers = pk.centers @ np.asarray(F).T
    centers = centers - (np.asarray(F) @ (0.5 * pk.box))
    start = centers[c.pairs[:, 0]]
    end = start + c.branch
    length = np.linalg.norm(c.branch, axis=1)
    normal = np.stack([-c.branch[:, 1], c.branch[:, 0]], axis=1) / length[:, None]
    w = (force_scale * force)[:, None] * normal
    quads = np.stack([start - w, end - w, end + w, start + w], axis=1)
    return quads, centers, pk.radii, sliding


def plot_slope(
    path: str | PathLike[str],
    mesh_data: tuple[np.ndarray, ...],
    markers: Sequence[tuple[str, ArrayLike, str]],
    rves: Sequence[
        tuple[
            str,
            TaylorRVE | SmallStrainRVE | AdaptiveRVE | FrictionalRVE,
            ArrayLike,
            str,
            FrictionState | None,
        ]
    ],
    title: str = "",
    deformation_scale: float = 1.0,
    value_range: tuple[float, float] | None = None,
) -> tuple[float, float]:
    """Figure 7: von Mises contour on the deformed slope with min/max and four RVE force networks.

    Args:
        path: PNG file to write.
        mesh_data: output of :func:`gather_mesh` (rank 0).
        markers: list of ``(label, point (2,) reference coordinates, text)``; marked on the slope.
        rves: list of ``(label, rve, F (2, 2), text, state)`` for the insets (same force and
            length scale); ``state`` is None for an elastic law, else the committed state of
            the point (sliding contacts are drawn in blue).
        deformation_scale: factor on u for the deformed shape.
        value_range: ``(min, max)`` von Mises stress in Pa that the colour bar spans (default:
            the cell values'); pass the Gauss-point extremes that the markers name, so that the
            bar covers them.

    Returns:
        The colour bar's range ``(min, max)`` in MPa.
    """
    headless_vtk()
    import pyvista as pv

    pv.OFF_SCREEN = True
    plotter = pv.Plotter(
        off_screen=True,
        shape=(2, 4),
        groups=[(slice(0, 2), slice(0, 2))],
        window_size=(1800, 860),
        border=False,
    )
    plotter.subplot(0, 0)
    clim = _slope_panel(plotter, mesh_data, markers, deformation_scale, value_range)
    plotter.add_text(
        title + "\nbranch width proportional to normal contact force, same scale in "
        "A-D" + ("; blue: sliding contacts" if any(r[4] is not None for r in rves) else ""),
        font_size=11,
        position="upper_left",
    )
    # One force-width scale and one length scale for all insets, so that they compare.
    networks = [contact_network(rve, F, state) for _, rve, F, _, state in rves]
    fmax = max((f.max(initial=0.0) for _, f, _ in networks), default=0.0)
    mean_r = np.mean([rve.packing.radii.mean() for _, rve, *_ in rves]) if rves else 1.0
    scale = 0.3 * mean_r / fmax if fmax > 0 else 0.0
    corners = np.array([[0.5, 0.5], [0.5, -0.5]])
    extent = max(
        (np.abs((corners * rve.packing.box) @ np.asarray(F).T).max() for _, rve, F, *_ in rves),
        default=1.0,
    )
    for n, (inset, network) in enumerate(zip(rves, networks)):
        plotter.subplot(n // 2, 2 + n % 2)
        _inset(plotter, inset, network, scale, extent)
    plotter.screenshot(path)
    plotter.close()
    return clim


def _slope_panel(plotter, mesh_data, markers, deformation_scale, value_range):
    """The von Mises contour on the deformed slope, its colour bar and markers; the colour
    range (MPa)."""
    import pyvista as pv

    points, cells, cell_types, u, vm = mesh_data
    pts = points.copy()
    pts[:, :2] += deformation_scale * u
    vtk_cells = np.hstack([np.full((cells.shape[0], 1), cells.shape[1]), cells]).ravel()
    grid = pv.UnstructuredGrid(vtk_cells, cell_types, pts)
    grid.cell_data["von Mises [MPa]"] = vm / 1e6
    # Nodes on partition boundaries come from every rank, equal only to round-off: merge them.
    size = float(np.ptp(pts, axis=0).max()) or 1.0
    grid = grid.clean(tolerance=1e-9 * size).cell_data_to_point_data(pass_cell_data=True)
    lo, hi = value_range if value_range is not None else (vm.min(), vm.max())
    clim = (float(lo) / 1e6, float(hi) / 1e6)
    # VTK's scalar bar actor crashes in this VTK wheel (std::regex in its label formatter), so the
    # colour bar is drawn as a mesh of its own below the slope.
    plotter.add_mesh(
        grid, scalars="von Mises [MPa]", cmap="turbo", n_colors=16, clim=clim, show_scalar_bar=False
    )
    plotter.add_mesh(grid.extract_all_edges(), color="black", line_width=0.5, opacity=0.25)
    colorbar_mesh(
        plotter,
        grid.bounds,
        clim,
        "von Mises stress [MPa]: colours the cell means, the bar spans the Gauss points' range",
    )
    u_of = _displacement_lookup(points, u)
    mk = []
    for label, X, text in markers:
        x = np.array([X[0], X[1], 0.0])
        x[:2] += deformation_scale * u_of(X)
        mk.append((label, x, text))
    plotter.add_point_labels(
        np.array([m[1] for m in mk]),
        [f"{m[0]}: {m[2]}" for m in mk],
        point_size=14,
        font_size=14,
        point_color="black",
        text_color="black",
        shape_opacity=0.7,
        always_visible=True,
        render_points_as_spheres=True,
    )
    plotter.view_xy()
    plotter.camera.parallel_projection = True
    plotter.camera.zoom(1.25)
    return clim


def _inset(plotter, inset, network, scale, extent):
    """One RVE's force network: disks, cell, contacts (red; sliding ones blue)."""
    import pyvista as pv

    label, rve, F, text, state = inset
    c, force, sliding = network
    quads, centers, radii, _ = force_network(rve, F, scale, state, network)
    plotter.add_mesh(_circles(centers, radii), color="#9a9a9a", line_width=1)
    plotter.add_mesh(_cell_outline(F, rve.packing.box), color="black", line_width=1)
    for mask, colour in ((~sliding, "#b2182b"), (sliding, "#2166ac")):
        q = quads[mask]
        if len(q):
            faces = np.hstack([np.full((len(q), 1), 4), np.arange(4 * len(q)).reshape(-1, 4)])
            qpts = np.c_[q.reshape(-1, 2), np.zeros(4 * len(q))]
            plotter.add_mesh(pv.PolyData(qpts, faces.ravel()), color=colour)
    # the validity measure (validity.py): overlap over the smaller radius of the two disks
    smaller = np.minimum(radii[c.pairs[:, 0]], radii[c.pairs[:, 1]])
    overlap = float((c.overlap / smaller).max()) if len(smaller) else 0.0
    slide = f", {int(sliding.sum())} sliding" if state is not None else ""
    plotter.add_text(
        f"{label}: {text}\n{len(force)} contacts{slide}, largest overlap "
        f"{100 * overlap:.3g} % of the smaller radius",
        font_size=10,
        position="upper_left",
    )
    plotter.view_xy()
    plotter.camera.parallel_projection = True
    plotter.camera.focal_point = (0.0, 0.0, 0.0)
    plotter.camera.position = (0.0, 0.0, 10.0 * extent)
    plotter.camera.parallel_scale = 1.1 * extent


#: characters per line of a load-settlement figure's title (10 pt over its 6.4 in)
TITLE_WIDTH = 80


def plot_load_settlement(
    path: str | PathLike[str],
    curves: Sequence[tuple[str, ArrayLike, ArrayLike, Mapping[str, Any] | None]],
    title: str = "",
    load_label: str = "footing load (MN/m)",
    load_unit: float = 1e6,
) -> Any:
    """Load-settlement curves (matplotlib PNG); returns the matplotlib Figure. A title longer
    than :data:`TITLE_WIDTH` characters is wrapped onto more lines.

    Args:
        curves: list of ``(label, settlement (k,) in m (down positive), load (k,) in N/m, style)``
            with ``style`` a dict of matplotlib line options (or None).
        load_label, load_unit: the load axis's label and the load that is one unit on it (N/m;
            1 for a load factor).
    """
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 4.6))
    ax = fig.add_subplot()
    for label, settlement, load, style in curves:
        ax.plot(np.asarray(settlement), np.asarray(load) / load_unit, label=label, **(style or {}))
    ax.set_xlabel("settlement of the loaded footing edge (m)")
    ax.set_ylabel(load_label)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(textwrap.fill(title, TITLE_WIDTH), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return fig


def headless_vtk():
    """Render off screen through EGL where there is no display (call before importing
    pyvista): without one VTK tries X11 first and logs a warning."""
    import ctypes.util
    import os

    if not os.environ.get("DISPLAY") and ctypes.util.find_library("EGL"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def colorbar_mesh(plotter, bounds, clim, title, n_ticks=5, z=0.0):
    """A colour bar drawn as a mesh below ``bounds`` in the plane at ``z`` (the scalar bar
    actor crashes in this VTK wheel)."""
    import pyvista as pv

    x0, x1, y0, y1 = bounds[0], bounds[1], bounds[2], bounds[3]
    h = 0.04 * (y1 - y0 + x1 - x0)
    bar = pv.Plane(
        center=(0.5 * (x0 + x1), y0 - 2.2 * h, z),
        direction=(0, 0, 1),
        i_size=x1 - x0,
        j_size=h,
        i_resolution=128,
        j_resolution=1,
    )
    bar.point_data["c"] = clim[0] + (bar.points[:, 0] - x0) / (x1 - x0) * (clim[1] - clim[0])
    plotter.add_mesh(bar, scalars="c", cmap="turbo", n_colors=16, clim=clim, show_scalar_bar=False)
    ticks = np.linspace(clim[0], clim[1], n_ticks)
    pts = np.c_[np.linspace(x0, x1, n_ticks), np.full(n_ticks, y0 - 3.4 * h), np.full(n_ticks, z)]
    plotter.add_point_labels(
        pts,
        [f"{t:.2f}" for t in ticks],
        shape=None,
        show_points=False,
        font_size=14,
        text_color="black",
        justification_horizontal="center",
        always_visible=True,
    )
    plotter.add_text(title, position="lower_left", font_size=10)


def _displacement_lookup(points, u):
    def at(X):
        i = int(np.argmin(np.linalg.norm(points[:, :2] - np.asarray(X)[:2], axis=1)))
        return u[i]

    return at


def _circles(centers, radii, n=24):
    import pyvista as pv

    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    ring = np.stack([np.cos(t), np.sin(t)], axis=1)
    pts = (centers[:, None, :] + radii[:, None, None] * ring[None]).reshape(-1, 2)
    idx = np.arange(len(centers) * n).reshape(-1, n)
    lines = np.hstack([np.full((len(centers), 1), n + 1), idx, idx[:, :1]])
    return pv.PolyData(np.c_[pts, np.zeros(len(pts))], lines=lines.ravel())


def _cell_outline(F, box):
    import pyvista as pv

    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0, 0]], dtype=float) - 0.5
    pts = (corners * box) @ np.asarray(F).T
    return pv.PolyData(np.c_[pts, np.zeros(5)], lines=np.array([5, 0, 1, 2, 3, 4]))
