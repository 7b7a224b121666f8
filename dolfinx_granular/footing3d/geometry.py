"""The 3-D scene's geometry: the slope benchmark's cross-section extruded in z, a rectangular
footing near the crest.

The cross-section is :class:`~dolfinx_granular.slope.geometry.SlopeGeometry` (x to the right,
y up, every dimension in m); gmsh extrudes its transfinite columns in z in ``layers`` layers of
hexahedra. The footing covers the 2-D footing's columns in x and ``footing_layers`` in z; its
pressure varies in x as in 2-D (:meth:`SlopeGeometry.footing_pressure_on_strip`, eccentric
toward the slope) and is uniform in z. The faces z = 0 and z = depth are planes of symmetry
(rollers), so the scene is one slice of a row of footings, or half of a footing twice as deep
when the footing touches z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from ..slope.geometry import SlopeGeometry, build_section, gmsh_session

if TYPE_CHECKING:
    from dolfinx.mesh import Mesh
    from mpi4py.MPI import Comm

#: physical group tags of the facets
BOTTOM, LEFT, RIGHT, FRONT, BACK, FOOTING, SURFACE = 1, 2, 3, 4, 5, 6, 7
#: physical group tag of the cells
SOIL = 10


@dataclass(frozen=True)
class FootingGeometry:
    """Dimensions (m) of the 3-D scene.

    Attributes:
        section: the cross-section and its loads (the 2-D benchmark's by default); the
            footing's x range and pressure q(x) (Pa) come from it.
        depth: extent in z (m).
        layers: hexahedra across the depth.
        footing_layers: (first, last + 1) layer the footing covers in z.
    """

    section: SlopeGeometry = field(default_factory=SlopeGeometry)
    depth: float = 46.5
    layers: int = 6
    footing_layers: tuple[int, int] = (2, 4)

    def __post_init__(self):
        a, b = self.footing_layers
        if not (self.depth > 0 and self.layers >= 1):
            raise ValueError(f"need depth > 0 and layers >= 1, got {self.depth}, {self.layers}")
        if not (0 <= a < b <= self.layers):
            raise ValueError(
                f"footing_layers={self.footing_layers} must be (first, last + 1) with "
                f"0 <= first < last + 1 <= layers={self.layers}"
            )

    @property
    def n_cells(self) -> int:
        """Number of hexahedra."""
        return self.section.n_cells * self.layers

    @property
    def footing_z(self) -> tuple[float, float]:
        """The footing's z range (m)."""
        h = self.depth / self.layers
        return self.footing_layers[0] * h, self.footing_layers[1] * h

    @property
    def middle_z(self) -> float:
        """The layer boundary nearest to the footing's middle in z (m): where the settlement
        is read and the figure cuts the solid (a plane of nodes)."""
        a, b = self.footing_layers
        return round(0.5 * (a + b) + 1e-9) * self.depth / self.layers

    @property
    def footing_area(self) -> float:
        """Footing area (m²)."""
        z0, z1 = self.footing_z
        return self.section.footing_width * (z1 - z0)

    @property
    def footing_load(self) -> float:
        """Resultant of the footing pressure (N, negative = down): the 2-D line load times the
        footing's length in z."""
        z0, z1 = self.footing_z
        return self.section.footing_load * (z1 - z0)

    def scaled(self, k: int) -> FootingGeometry:
        """The scene on a mesh refined k times in every direction (k³ x the cells)."""
        a, b = self.footing_layers
        return FootingGeometry(self.section.refined(k), self.depth, self.layers * k, (a * k, b * k))


def build_gmsh_model(geometry: FootingGeometry, name: str = "footing3d") -> None:
    """The hexahedral mesh of the scene in the current gmsh model (gmsh initialised), with
    physical groups BOTTOM (y = 0), LEFT (x = 0), RIGHT (x = width), FRONT (z = 0), BACK
    (z = depth), FOOTING, SURFACE (the ground, footing excluded) and the cells SOIL."""
    import gmsh

    g = geometry
    gmsh.model.add(name)
    s = build_section(g.section)
    geo = gmsh.model.geo
    h = g.depth / g.layers
    a, b = g.footing_layers
    front = [(2, f) for f in s.faces]
    base = front
    groups = {tag: [] for tag in (BOTTOM, LEFT, RIGHT, FOOTING, SURFACE)}
    volumes = []
    # three extrusions (before, under, after the footing) so that its edges lie on layers
    for first, last in ((0, a), (a, b), (b, g.layers)):
        if last == first:
            continue
        out = geo.extrude(base, 0.0, 0.0, (last - first) * h, [last - first], recombine=True)
        # per face: the far face, the volume, then the sides from its curve loop
        # (bottom, right vertical, ground surface, left vertical)
        per = [out[6 * k : 6 * k + 6] for k in range(len(base))]
        base = [p[0] for p in per]
        volumes += [p[1][1] for p in per]
        groups[BOTTOM] += [p[2][1] for p in per]
        groups[RIGHT].append(per[-1][3][1])
        groups[LEFT].append(per[0][5][1])
        loaded = first == a and last == b
        for p, under in zip(per, s.on_footing):
            groups[FOOTING if loaded and under else SURFACE].append(p[4][1])
    geo.synchronize()
    names = {BOTTOM: "bottom", LEFT: "left", RIGHT: "right", FOOTING: "footing"}
    names[SURFACE] = "surface"
    for tag, entities in groups.items():
        _group(2, entities, tag, names[tag])
    _group(2, [f for _, f in front], FRONT, "front")
    _group(2, [f for _, f in base], BACK, "back")
    _group(3, volumes, SOIL, "soil")
    gmsh.model.mesh.generate(3)


def _group(dim, entities, tag, name):
    import gmsh

    gmsh.model.addPhysicalGroup(dim, entities, tag)
    gmsh.model.setPhysicalName(dim, tag, name)


def create_mesh(comm: Comm, geometry: FootingGeometry) -> tuple[Mesh, Any, Any]:
    """Build the scene's mesh with gmsh on rank 0 and distribute it over ``comm``:
    ``(mesh, cell_tags, facet_tags)`` (tags as in this module)."""
    import gmsh

    from ..fem.compat import gmsh_model_to_mesh

    with gmsh_session(comm):
        if comm.rank == 0:
            build_gmsh_model(geometry)
        msh, cell_tags, facet_tags = gmsh_model_to_mesh(gmsh.model, comm, 0, gdim=3)
    msh.name = "footing3d"
    return msh, cell_tags, facet_tags


def facet_area(msh: Mesh, facets: Any, tag: int) -> float:
    """Area (m²) of the facets tagged ``tag``, summed over the ranks (a check of the tags)."""
    import ufl
    from dolfinx import fem

    ds = ufl.Measure("ds", domain=msh, subdomain_data=facets)
    one = fem.Constant(msh, 1.0)
    local = fem.assemble_scalar(fem.form(one * ds(tag)))
    return float(msh.comm.allreduce(local))
