"""Slope stability benchmark of Meier, Steinmann & Kuhl (section 5, figure 6), reconstructed.

Figure 6 of the paper is not available; :class:`SlopeGeometry` holds the reconstruction (every
dimension in metres, plane strain, unit thickness) so it can be changed in one place. The mesh is a
structured Q1 mesh: one column of ``rows`` quadrilaterals per ``column_width``, rows spaced evenly
between the bottom and the ground surface. Each column is its own transfinite gmsh surface, so the
mapping is exactly bilinear and no node drifts off the evenly spaced rows.
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Iterator

    from dolfinx.mesh import Mesh
    from mpi4py.MPI import Comm
    from numpy.typing import ArrayLike
    from ufl.core.expr import Expr

#: physical group tags of the facets
BOTTOM, LEFT, RIGHT, FOOTING, SURFACE = 1, 2, 3, 4, 5
#: physical group tag of the cells
SOIL = 10


@dataclass(frozen=True)
class SlopeGeometry:
    """Dimensions (m) and loads of the slope benchmark.

    Ground at ``crest_height`` for x <= ``slope_start``, a straight slope down to ``toe_height``
    at ``slope_end``, then flat: by default a 45° slope (run over rise 1), and flatter or steeper
    ones from :meth:`with_slope_ratio`. The footing load is a linearly varying pressure over
    [footing_start, footing_end] whose resultant ``footing_load`` (N per metre, negative = down)
    acts ``eccentricity`` toward the slope (+x) from the footing centre.
    """

    width: float = 77.5
    crest_height: float = 58.125
    toe_height: float = 38.75
    slope_start: float = 38.75
    slope_end: float = 58.125
    column_width: float = 3.875
    rows: int = 19
    footing_start: float = 11.625
    footing_end: float = 34.875
    footing_load: float = -4.0e7
    eccentricity: float = 3.875
    density: float = 2.5e3
    gravity: float = 9.81

    def __post_init__(self):
        cols = self.width / self.column_width
        for name in ("slope_start", "slope_end", "footing_start", "footing_end"):
            k = getattr(self, name) / self.column_width
            if abs(k - round(k)) > 1e-9:
                raise ValueError(
                    f"{name}={getattr(self, name)} m is not on a column boundary (multiple of "
                    f"column_width={self.column_width} m); move it or change column_width"
                )
        if abs(cols - round(cols)) > 1e-9:
            raise ValueError(
                f"width={self.width} m is not a multiple of column_width={self.column_width} m"
            )
        if not (0 <= self.footing_start < self.footing_end <= self.width):
            raise ValueError("need 0 <= footing_start < footing_end <= width")
        if not (0 < self.slope_start <= self.slope_end <= self.width):
            raise ValueError("need 0 < slope_start <= slope_end <= width")
        if min(self.crest_height, self.toe_height) <= 0 or self.rows < 1:
            raise ValueError("heights must be > 0 and rows >= 1")
        if abs(self.eccentricity) > self.footing_width / 6 * (1 + 1e-12):
            raise ValueError(
                f"eccentricity {self.eccentricity} m exceeds B/6 = {self.footing_width / 6} m: the "
                "linear footing pressure would change sign (the footing would lift off)"
            )

    @classmethod
    def with_slope_ratio(cls, ratio: float, **overrides: Any) -> SlopeGeometry:
        """The slope with run : rise = ``ratio`` : 1 (1: 45°, the default geometry; 2: 26.6°).

        The crest with the footing, the rise (``crest_height - toe_height``) and the flat
        ground past the toe keep their lengths; the domain's width changes with the slope's
        run, ``ratio`` x rise. ``overrides`` set the other fields (``slope_end`` and ``width``
        follow from the ratio). The run must be a whole number of columns, so ``ratio`` is a
        multiple of column_width / rise (0.2 by default); other ratios raise ValueError
        naming the nearest ones, not rounded: a slope other than the one asked for would go
        unnoticed. ``refined(k)`` keeps the slope.
        """
        taken = {"slope_end", "width"} & set(overrides)
        if taken:
            names = ", ".join(sorted(taken))
            raise ValueError(f"slope_end and width follow from the slope ratio: drop {names}")
        defaults = {f.name: f.default for f in fields(cls)}
        values = {**defaults, **overrides}
        rise = values["crest_height"] - values["toe_height"]
        end = values["slope_start"] + slope_run(ratio, rise, values["column_width"])
        flat = defaults["width"] - defaults["slope_end"]  # the ground past the toe
        return cls(**{**values, "slope_end": end, "width": end + flat})

    @property
    def slope_ratio(self) -> float:
        """The slope's run over its rise, (slope_end - slope_start) / (crest_height -
        toe_height): 1 for 45°, 2 for 26.6° (inf for flat ground)."""
        rise = self.crest_height - self.toe_height
        return (self.slope_end - self.slope_start) / rise if rise else math.inf

    @property
    def slope_angle(self) -> float:
        """The slope's inclination to the horizontal in degrees (45 for ratio 1)."""
        run = self.slope_end - self.slope_start
        return math.degrees(math.atan2(self.crest_height - self.toe_height, run))

    @property
    def columns(self) -> int:
        return int(round(self.width / self.column_width))

    @property
    def footing_width(self) -> float:
        return self.footing_end - self.footing_start

    @property
    def n_cells(self) -> int:
        return self.columns * self.rows

    def refined(self, k: int) -> SlopeGeometry:
        """This slope on a mesh refined ``k`` times: column width / k, rows x k (k² x the
        cells)."""
        return replace(self, column_width=self.column_width / k, rows=self.rows * k)

    def surface_height(self, x: ArrayLike) -> np.ndarray | float:
        """Ground height y_s(x) (m) for x (array) in [0, width]."""
        return np.interp(
            x,
            [0.0, self.slope_start, self.slope_end, self.width],
            [self.crest_height, self.crest_height, self.toe_height, self.toe_height],
        )

    def footing_pressure_on_strip(self, x: float | np.ndarray | Expr) -> float | np.ndarray | Expr:
        """Footing pressure q(x) (Pa, signed like ``footing_load``, so negative = downward) for
        x on the footing; x may be a number, an array or a UFL expression.

        Linear in x with resultant ``footing_load`` and moment arm ``eccentricity``:
        q = P/B (1 + 12 e (x - x_c) / B²); for e = B/6 it is 0 at the heel and 2P/B at the edge.
        """
        B = self.footing_width
        xc = 0.5 * (self.footing_start + self.footing_end)
        return self.footing_load / B * (1.0 + 12.0 * self.eccentricity * (x - xc) / B**2)

    def footing_pressure(self, x: ArrayLike) -> np.ndarray:
        """Footing pressure q(x) (Pa) for x (array) anywhere on the surface (0 off the footing)."""
        x = np.asarray(x, dtype=float)
        q = self.footing_pressure_on_strip(x)
        return np.where((x >= self.footing_start) & (x <= self.footing_end), q, 0.0)

    @property
    def loaded_edge(self) -> float:
        """x (m) of the footing edge with the larger pressure (where settlement is reported)."""
        return self.footing_end if self.eccentricity >= 0 else self.footing_start


def slope_run(ratio: float, rise: float, column_width: float) -> float:
    """The horizontal length (m) of a slope of run : rise = ``ratio`` : 1 and ``rise`` m, a
    whole number of ``column_width`` columns; ValueError naming the nearest ratios that are."""
    if not (math.isfinite(ratio) and ratio > 0.0):
        raise ValueError(
            f"the slope ratio (run over rise) must be a finite number > 0, got {ratio!r}"
        )
    if not rise > 0.0:
        raise ValueError(f"a slope ratio needs the crest above the toe, got a rise of {rise!r} m")
    columns = ratio * rise / column_width
    whole = round(columns)
    if abs(columns - whole) > 1e-9 * max(1.0, columns) or whole < 1:
        step = column_width / rise
        near = sorted({max(1, math.floor(columns)), math.ceil(columns)})
        raise ValueError(
            f"slope ratio {ratio:g} makes the slope's run {ratio * rise:g} m, not a whole number "
            f"of {column_width:g} m columns: give a multiple of column_width / rise = {step:g}, "
            f"e.g. {' or '.join(f'{k * step:g}' for k in near)}"
        )
    return whole * column_width  # (exact on the columns, where ratio x rise may round)


def build_gmsh_model(geometry: SlopeGeometry = SlopeGeometry(), name: str = "slope") -> None:
    """Create the structured Q1 slope mesh in the current gmsh model (gmsh must be initialised).

    Physical groups: facets BOTTOM, LEFT, RIGHT, FOOTING, SURFACE (free surface, footing
    excluded); cells SOIL.
    """
    import gmsh

    gmsh.model.add(name)
    s = build_section(geometry)
    _group(1, s.bottom, BOTTOM, "bottom")
    _group(1, [s.vertical[0]], LEFT, "left")
    _group(1, [s.vertical[-1]], RIGHT, "right")
    _group(1, [c for c, f in zip(s.surface, s.on_footing) if f], FOOTING, "footing")
    _group(1, [c for c, f in zip(s.surface, s.on_footing) if not f], SURFACE, "surface")
    _group(2, s.faces, SOIL, "soil")
    gmsh.model.mesh.generate(2)


@dataclass(frozen=True)
class Section:
    """The gmsh entities of the slope's cross-section (one transfinite quadrilateral surface
    per column): curve tags ``bottom``, ``surface`` (one per column) and ``vertical`` (one per
    column boundary, left to right), surface tags ``faces``, and ``on_footing`` (bool per
    column)."""

    bottom: list
    surface: list
    vertical: list
    faces: list
    on_footing: np.ndarray


def build_section(geometry: SlopeGeometry) -> Section:
    """The cross-section in the current gmsh model (x to the right, y up, z = 0), its columns
    meshed as ``rows`` x 1 transfinite quadrilaterals (synchronised; not yet meshed)."""
    import gmsh

    g = geometry
    geo = gmsh.model.geo
    xs = np.linspace(0.0, g.width, g.columns + 1)
    ys = g.surface_height(xs)
    bot = [geo.addPoint(x, 0.0, 0.0) for x in xs]
    top = [geo.addPoint(x, y, 0.0) for x, y in zip(xs, ys)]
    vert = [geo.addLine(b, t) for b, t in zip(bot, top)]
    bottom = [geo.addLine(bot[i], bot[i + 1]) for i in range(g.columns)]
    surface = [geo.addLine(top[i], top[i + 1]) for i in range(g.columns)]
    faces = []
    for i in range(g.columns):
        loop = geo.addCurveLoop([bottom[i], vert[i + 1], -surface[i], -vert[i]])
        faces.append(geo.addPlaneSurface([loop]))
    # meshing constraints through the geo kernel: they survive later geo operations (an
    # extrusion, whose layers copy these quadrilaterals into hexahedra) and synchronisations
    mesh = geo.mesh
    for c in bottom + surface:
        mesh.setTransfiniteCurve(c, 2)
    for c in vert:
        mesh.setTransfiniteCurve(c, g.rows + 1)
    for f in faces:
        mesh.setTransfiniteSurface(f)
        mesh.setRecombine(2, f)
    geo.synchronize()
    mid = 0.5 * (xs[:-1] + xs[1:])
    on_footing = (mid > g.footing_start) & (mid < g.footing_end)
    return Section(bottom, surface, vert, faces, on_footing)


def _group(dim, entities, tag, name):
    import gmsh

    gmsh.model.addPhysicalGroup(dim, entities, tag)
    gmsh.model.setPhysicalName(dim, tag, name)


class MeshError(ValueError):
    """The mesh lacks what the slope model needs (physical groups)."""


REQUIRED_FACETS = {BOTTOM: "bottom", LEFT: "left", RIGHT: "right", FOOTING: "footing"}


def check_physical_groups(comm: Comm) -> None:
    """Check on rank 0 that the current gmsh model has a 2-D cell group and the facet groups of
    :data:`REQUIRED_FACETS`; raise :class:`MeshError` naming what is missing on every rank."""
    import gmsh

    problem = None
    if comm.rank == 0:
        groups = gmsh.model.getPhysicalGroups()
        cells = [tag for dim, tag in groups if dim == 2]
        facets = {tag for dim, tag in groups if dim == 1}
        missing = [f"{name} ({tag})" for tag, name in REQUIRED_FACETS.items() if tag not in facets]
        if not cells:
            missing.insert(0, "a 2-D cell group (soil)")
        if missing:
            problem = (
                f"the gmsh model lacks the physical groups {', '.join(missing)}; tag the "
                "boundary curves and the surfaces with gmsh.model.addPhysicalGroup as "
                "dolfinx_granular.slope.geometry.build_gmsh_model does"
            )
    problem = comm.bcast(problem, root=0)
    if problem:
        raise MeshError(problem)


def model_to_mesh(comm: Comm) -> tuple[Mesh, Any, Any]:
    """Distribute the current gmsh model (built on rank 0) over ``comm`` after
    :func:`check_physical_groups`: ``(mesh, cell_tags, facet_tags)``."""
    # the tags: dolfinx.mesh.MeshTagsMetaClass (0.5) / MeshTags (0.9+)
    import gmsh

    from ..fem.compat import gmsh_model_to_mesh

    check_physical_groups(comm)
    msh, cell_tags, facet_tags = gmsh_model_to_mesh(gmsh.model, comm, 0, gdim=2)
    msh.name = "slope"
    return msh, cell_tags, facet_tags


def create_mesh(comm: Comm, geometry: SlopeGeometry = SlopeGeometry()) -> tuple[Mesh, Any, Any]:
    """Build the slope mesh with gmsh on rank 0 and distribute it over ``comm``.

    Returns:
        ``(mesh, cell_tags, facet_tags)`` (DOLFINx objects); facet tags as in this module.
    """
    with gmsh_session(comm):
        if comm.rank == 0:
            build_gmsh_model(geometry)
        return model_to_mesh(comm)


@contextmanager
def gmsh_session(comm: Comm) -> Iterator[None]:
    """A gmsh session for building a model on rank 0: initialised here unless one is open
    (gmsh 4.8 has no isInitialized(): then none is assumed), quiet, and the model removed (and
    the session finalised, if opened here) on leaving."""
    import gmsh

    initialized = getattr(gmsh, "isInitialized", lambda: False)()
    if not initialized:
        gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    try:
        yield
    finally:
        if comm.rank == 0:
            gmsh.model.remove()
        if not initialized:
            gmsh.finalize()
