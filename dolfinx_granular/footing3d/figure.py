"""The 3-D scene's figure (pyvista, off screen): von Mises stress on the deformed solid, cut open
through the footing's middle, and the force networks of two RVEs as tubes whose radius grows
with the contact force."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..gathers import nearest_point
from ..io.postprocess import colorbar_mesh, gather_mesh, headless_vtk

if TYPE_CHECKING:
    from .model import FootingModel


def rve_sites(model: FootingModel) -> list[tuple[str, np.ndarray, str]]:
    """Two reference points in the cut plane: below the footing's loaded edge, and in the
    slope (label, point (3,), text)."""
    sec = model.geometry.section
    z = model.edge[2]
    below = model.edge - np.array([0.5 * sec.column_width, 0.2 * sec.footing_width, 0.0])
    x = 0.5 * (sec.slope_start + sec.slope_end)
    slope = np.array([x, float(sec.surface_height(x)) - 0.15 * sec.crest_height, z])
    return [("A", below, "below the footing's edge"), ("B", slope, "in the slope")]


def plot_footing(model: FootingModel, path: str, deformation_scale: float | None = None) -> None:
    """Write the figure to ``path`` (PNG). Collective: every rank gathers, rank 0 draws."""
    comm = model.comm
    data = gather_mesh(model.V, model.u, model.von_mises())
    sites = []
    for label, target, text in rve_sites(model):
        rank, i, point = nearest_point(comm, model.material.points, target)
        F = comm.bcast(model.material.F[i] if comm.rank == rank else None, root=rank)
        sites.append((label, point, text, F))
    if comm.rank == 0:
        _draw(model, data, sites, path, deformation_scale)


def _draw(model, data, sites, path, deformation_scale):
    headless_vtk()
    import pyvista as pv

    points, cells, cell_types, u, vm = data
    width = model.geometry.section.width
    umax = float(np.abs(u).max()) or 1.0
    scale = deformation_scale or 0.04 * width / umax
    plotter = pv.Plotter(
        off_screen=True, shape=(2, 3), groups=[(np.s_[:], np.s_[:2])], window_size=(1800, 900)
    )
    plotter.subplot(0, 0)
    grid = pv.UnstructuredGrid(
        np.hstack([np.full((len(cells), 1), cells.shape[1]), cells]).ravel(), cell_types, points
    )
    grid.point_data["u"] = u
    grid.cell_data["vm"] = vm / 1e6
    size = float(np.ptp(points, axis=0).max())
    grid = grid.clean(tolerance=1e-9 * size)  # nodes on partition boundaries, from every rank
    solid = grid.warp_by_vector("u", factor=scale)
    cut = solid.clip(normal="z", origin=(0.0, 0.0, model.edge[2]), invert=True)  # z <= mid
    clim = (float(vm.min()) / 1e6, float(vm.max()) / 1e6)
    plotter.add_mesh(cut, scalars="vm", cmap="turbo", n_colors=16, clim=clim, show_scalar_bar=False)
    plotter.add_mesh(cut.extract_feature_edges(), color="black", line_width=1)
    marks = np.array([p for _, p, _, _ in sites]) + scale * _nearest_u(grid, sites)
    plotter.add_point_labels(
        marks, [f"{label}: {text}" for label, _, text, _ in sites], point_size=16,
        font_size=14, point_color="black", shape_opacity=0.7, always_visible=True,
        render_points_as_spheres=True,
    )  # fmt: skip
    z = model.edge[2]
    colorbar_mesh(plotter, cut.bounds, clim, "von Mises stress [MPa] (cell means)", z=z)
    plotter.add_text(
        f"footing on a 3-D slope, cut at its middle; displacements x {scale:.3g}\n"
        "insets: force networks, tube radius proportional to the normal contact force",
        font_size=11,
        position="upper_left",
    )
    # y is up; the camera looks at the cut face (z = mid, facing +z) from the slope's side
    centre = np.array(cut.center) - np.array([0.0, 0.22 * model.geometry.section.crest_height, 0])
    plotter.camera.focal_point = centre
    plotter.camera.position = centre + 2.0 * width * np.array([0.45, 0.35, 1.0])
    plotter.camera.up = (0.0, 1.0, 0.0)
    networks = [model.law.contacts(F) for *_, F in sites]
    fmax = max(float(c.force.max(initial=0.0)) for c in networks) or 1.0
    for row, ((label, _, text, F), c) in enumerate(zip(sites, networks)):
        plotter.subplot(row, 2)
        _network(plotter, model.law.packing, F, c, fmax)
        plotter.add_text(f"{label}: {text}, {len(c.force)} contacts", font_size=10)
    plotter.screenshot(path)
    plotter.close()


def _nearest_u(grid, sites):
    """Displacements (k, 3) of the grid nodes nearest to the sites' points."""
    ids = [grid.find_closest_point(p) for _, p, _, _ in sites]
    return np.asarray(grid.point_data["u"])[ids]


def _network(plotter, packing, F, contacts, fmax):
    """One RVE's contacts as tubes (radius proportional to the force; largest: 0.35 of the mean
    radius) between the deformed centres, and its deformed cell's edges."""
    import pyvista as pv

    centres = (packing.centers - 0.5 * packing.box) @ np.asarray(F).T
    start = centres[contacts.pairs[:, 0]]
    end = start + contacts.branch
    m = len(start)
    lines = pv.PolyData(np.vstack([start, end]))
    lines.lines = np.column_stack([np.full(m, 2), np.arange(m), np.arange(m) + m]).ravel()
    lines.point_data["force"] = np.concatenate([contacts.force, contacts.force]) / fmax
    r = 0.35 * float(packing.radii.mean())
    tubes = lines.tube(scalars="force", radius=0.05 * r, radius_factor=20.0, n_sides=8)
    plotter.add_mesh(tubes, color="#b2182b", smooth_shading=True)
    box = pv.Box(bounds=np.ravel([-0.5 * packing.box, 0.5 * packing.box], order="F"))
    plotter.add_mesh(box.transform(_affine(F), inplace=False).extract_all_edges(), color="black")
    plotter.camera_position = "iso"


def _affine(F):
    """The (4, 4) homogeneous matrix of x -> F x."""
    T = np.eye(4)
    T[:3, :3] = F
    return T
