"""Cell fields for XDMF output: quadrature-point values as volume-weighted cell means (DG0).

A cell's value is the L2 projection of the quadrature data onto constants on that cell, with the
quadrature of the material's measure: ``sum_q w_q |J_q| v_q / sum_q w_q |J_q|`` (w_q the reference
weights, J_q the Jacobian determinant at point q). The integral of the DG0 field over any union of
cells therefore equals the quadrature integral of the point values, ``∫ v dx`` with
``material.dx``. :func:`cauchy_field` gives the Cauchy stress as a DG0 (d, d) tensor Function that
``XDMFFile.write_function`` writes as cell data (ParaView and pyvista show its components).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import ufl
from dolfinx import fem

from . import compat as dfx

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from .quadrature import QuadratureMaterial


def point_weights(material: QuadratureMaterial) -> np.ndarray:
    """(n_points,) the integration weights ``w_q |J_q|`` (m² in 2-D, m³ in 3-D) of the
    material's points on this rank, ordered like ``material.points``: ``∫ v dx = sum weights *
    v`` over the points."""
    w = dfx.quadrature_weights(material.mesh, material.quadrature_degree)
    detJ = dfx.expression(abs(ufl.JacobianDeterminant(material.mesh)), material.reference_points)
    J = dfx.evaluate(detJ, material.mesh, material.cells).reshape(
        material.cells.size, material.n_qp
    )
    return (J * w).reshape(-1)


def cell_means(material: QuadratureMaterial, values: ArrayLike) -> np.ndarray:
    """Volume-weighted mean over each cell of per-point ``values`` (n_points, ...) ->
    (n_cells, ...), cells as ``material.cells``."""
    values = np.asarray(values, dtype=float)
    if values.shape[:1] != (material.n_points,):
        raise ValueError(
            f"values must have one row per point of the material on this rank "
            f"({material.n_points}), got shape {values.shape}"
        )
    shape = values.shape[1:]
    w = point_weights(material).reshape(material.cells.size, material.n_qp)
    v = values.reshape(material.cells.size, material.n_qp, int(np.prod(shape)))
    means = np.einsum("cq,cqk->ck", w, v) / w.sum(axis=1)[:, None]
    return means.reshape(material.cells.size, *shape)


def cell_tensor_function(
    material: QuadratureMaterial, values: ArrayLike, name: str
) -> fem.Function:
    """A DG0 (d, d) Function named ``name`` holding the cell means of per-point tensors
    ``values`` (n_points, d, d) on the material's cells, zero on the others (ghosts updated);
    d is the mesh's dimension."""
    d = material.mesh.geometry.dim
    means = cell_means(material, values)
    if means.shape[1:] != (d, d):
        raise ValueError(f"values must have shape (n_points, {d}, {d}), got {np.shape(values)}")
    V0 = dfx.tensor_space(material.mesh, "DG", 0, (d, d))
    f = fem.Function(V0, name=name)
    dofs = dfx.cell_dofs(V0.dofmap)[material.cells, 0]
    f.x.array.reshape(-1, d * d)[dofs] = means.reshape(-1, d * d)
    f.x.scatter_forward()
    return f


def cauchy_field(material: QuadratureMaterial, name: str = "cauchy") -> fem.Function:
    """The Cauchy stress (Pa) of a GranularMaterial at its last update as a DG0 (d, d) tensor
    Function of volume-weighted cell means (``material.cauchy()``: the stabiliser's fictitious
    stress left out), for ``XDMFFile.write_function``. Collective: call it on every rank."""
    return cell_tensor_function(material, material.cauchy(), name)


def cauchy_output(material: QuadratureMaterial, name: str = "cauchy") -> fem.Function:
    """:func:`cauchy_field` as ``XDMFFile.write_function`` must get it for ParaView and pyvista
    to show its components right (``_dolfinx.xdmf_cell_tensor``: the same Function on DOLFINx
    0.5, a DG0 (3, 3) copy with zero third row and column on 0.7 and later). Collective."""
    return dfx.xdmf_cell_tensor(cauchy_field(material, name))
