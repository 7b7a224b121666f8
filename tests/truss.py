"""The von Mises truss with a soft spring: a structure with an exact equilibrium path that has
two load limit points and a snap-back (the path-following tests trace it).

Two bars from the supports (-a, 0) and (a, 0) meet at the apex (0, h); a third bar, a soft
spring of length Ls, carries the load P (downward, P = lam) from the node (0, h + Ls) to the apex.
Bars are St Venant-Kirchhoff rods: energy ``EA L0 / 2 E^2`` with the Green strain
``E = (L^2 - L0^2) / (2 L0^2)``, written in UFL on a mesh of intervals in the plane (one element
per bar: the strain is uniform along a bar, so the finite element solution is exact). The apex
and the load point move vertically only (symmetry).

With w the apex and v the load point deflection (down), equilibrium gives exactly

    P(w) = EA z (h^2 - z^2) / L0^3,   z = h - w,  L0 = sqrt(a^2 + h^2),

limit points at z = +-h / sqrt(3) (P = +-2 EA h^3 / (3 sqrt(3) L0^3)), and the spring's
compression c = v - w from ``P = EA_s (Ls^2 - L^2) L / (2 Ls^3)``, ``L = Ls - c``. Past the first
limit point the truss softens faster than the spring (EA h^2 / L0^3 > EA_s / Ls): v turns back
(snap-back) while P keeps falling.
"""

from collections import namedtuple

from dolfinx_granular.drivers.newton import NewtonSolver
from dolfinx_granular.fem.compat import create_mesh, function_space, vector_space

import numpy as np
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI
from scipy.optimize import brentq

A_HALF, H, EA = 1.0, 0.2, 1.0
L_SPRING, EA_SPRING = 5.0, 0.15  # spring stiffness 0.03 < EA h^2 / L0^3 = 0.038: snap-back
L0 = np.hypot(A_HALF, H)
P_MAX = 2.0 * EA * H**3 / (3.0 * np.sqrt(3.0) * L0**3)

Truss = namedtuple("Truss", "solver u load external apex_dof top_dof")


def load_of_apex(w):
    """Exact load P (N) at apex deflection w (m, down)."""
    z = H - np.asarray(w, dtype=float)
    return EA * z * (H**2 - z**2) / L0**3


def spring_compression(P):
    """Exact shortening c (m) of the spring under the load P."""
    g = lambda L: EA_SPRING * (L_SPRING**2 - L**2) * L / (2.0 * L_SPRING**3) - P  # noqa: E731
    return L_SPRING - brentq(
        g,
        L_SPRING / np.sqrt(3.0) * (1 + 1e-12),
        2.0 * L_SPRING,
        xtol=1e-15,
        rtol=1e-15,
        maxiter=200,
    )


def truss(comm=MPI.COMM_WORLD, prefix="truss_"):
    """The truss model: a NewtonSolver of R(u) - lam f with lam = ``load`` (N, down)."""
    x = np.array([[-A_HALF, 0.0], [0.0, H], [A_HALF, 0.0], [0.0, H + L_SPRING]])
    msh = create_mesh(
        comm, np.array([[0, 1], [1, 2], [1, 3]]), x, "interval", 2, max_facet_to_cell_links=3
    )  # three bars meet at the apex
    V = vector_space(msh)
    u, v = fem.Function(V), ufl.TestFunction(V)
    cells = mesh.locate_entities(msh, 1, lambda p: np.isclose(p[0], 0.0))  # the spring
    stiffness = fem.Function(function_space(msh, "DG", 0))
    stiffness.x.array[:] = EA
    stiffness.x.array[cells] = EA_SPRING
    J = ufl.Jacobian(msh)
    t = ufl.as_vector([J[0, 0], J[1, 0]])  # reference tangent (not normalised), per element
    tt = t + ufl.dot(ufl.grad(u), t)
    E = (ufl.dot(tt, tt) / ufl.dot(t, t) - 1.0) / 2.0
    energy = stiffness / 2.0 * E**2 * ufl.dx  # EA / 2 E^2 per unit reference length
    top = mesh.locate_entities_boundary(msh, 0, lambda p: np.isclose(p[1], H + L_SPRING))
    ds = ufl.Measure("ds", msh, subdomain_data=mesh.meshtags(msh, 0, top, np.full_like(top, 1)))
    load = fem.Constant(msh, 0.0)
    external = -v[1] * ds(1)  # a unit downward point load at the top node (a vertex integral)
    residual = ufl.derivative(energy, u, v) - load * external
    supports = mesh.locate_entities_boundary(msh, 0, lambda p: np.isclose(p[1], 0.0))
    axis = mesh.locate_entities(msh, 0, lambda p: np.isclose(p[0], 0.0))
    bcs = [
        fem.dirichletbc(np.zeros(2), fem.locate_dofs_topological(V, 0, supports), V),
        fem.dirichletbc(0.0, fem.locate_dofs_topological(V.sub(0), 0, axis), V.sub(0)),
    ]
    solver = NewtonSolver(residual, None, u, bcs, prefix=prefix)
    n_owned = V.dofmap.index_map.size_local
    xs = V.tabulate_dof_coordinates()[:n_owned, :2]
    apex = np.flatnonzero(np.isclose(xs[:, 0], 0) & np.isclose(xs[:, 1], H))
    tip = np.flatnonzero(np.isclose(xs[:, 0], 0) & np.isclose(xs[:, 1], H + L_SPRING))
    dof = lambda found: 2 * int(found[0]) + 1 if found.size else -1  # noqa: E731 (y component)
    return Truss(solver, u, load, external, dof(apex), dof(tip))


def deflections(model):
    """(w, v): apex and load point deflections (m, down), the same on every rank."""
    comm = model.u.function_space.mesh.comm
    values = []
    for d in (model.apex_dof, model.top_dof):
        local = -float(model.u.x.array[d]) if d >= 0 else 0.0
        values.append(comm.allreduce(local))
    return tuple(values)
