"""The problem the solver, loading and model-level tests share: a granular column."""

from collections import namedtuple

from dolfinx_granular._dolfinx import vector_space
from dolfinx_granular.material import GranularMaterial
from dolfinx_granular.solver import NewtonSolver

import numpy as np
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI

Column = namedtuple("Column", "solver material u p")


def granular_column(
    rve, prefix, n=4, pressure=0.0, material_class=GranularMaterial, stabilise=0.0, **solver_kwargs
):
    """A 10 m x 10 m column of n x n Q1 cells: fixed base, rollers on the sides, a top pressure
    ``p * (1 + 0.05 x)`` (p a Constant in Pa, positive = downward; the variation makes the
    solution non-homogeneous). Returns ``Column(solver, material, u, p)``."""
    msh = mesh.create_rectangle(
        MPI.COMM_WORLD, [[0, 0], [10, 10]], [n, n], mesh.CellType.quadrilateral
    )
    V = vector_space(msh)
    u, v, du = fem.Function(V), ufl.TestFunction(V), ufl.TrialFunction(V)
    material = material_class(rve, u, **({"stabilise": stabilise} if stabilise else {}))
    top = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 10))
    bottom = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 0))
    walls = mesh.locate_entities_boundary(
        msh, 1, lambda x: np.isclose(x[0], 0) | np.isclose(x[0], 10)
    )
    ds = ufl.Measure("ds", msh, subdomain_data=mesh.meshtags(msh, 1, top, np.full_like(top, 1)))
    x = ufl.SpatialCoordinate(msh)
    p = fem.Constant(msh, float(pressure))
    residual = material.residual_form(v) + p * (1 + 0.05 * x[0]) * v[1] * ds(1)
    bcs = [
        fem.dirichletbc(np.zeros(2), fem.locate_dofs_topological(V, 1, bottom), V),
        fem.dirichletbc(0.0, fem.locate_dofs_topological(V.sub(0), 1, walls), V.sub(0)),
    ]
    solver = NewtonSolver(
        residual, material.jacobian_form(du, v), u, bcs, material, prefix=prefix, **solver_kwargs
    )
    return Column(solver, material, u, p)
