"""Why a Newton solve on quadrature materials cannot work: wiring mistakes and singular Jacobians.

:func:`check_wiring` runs when a :class:`~dolfinx_granular.NewtonSolver` is built and
refuses, with the fix in the message, what is wrong in the forms and the materials' cells:

* a material whose stress data P the residual reads but that is not in the solver's list (it
  would never be evaluated, and the consistent Jacobian would lack its tangent);
* a Jacobian without the tangent data A of a listed material whose P the residual reads (e.g.
  ``ufl.derivative(residual, u)``: P is data, so its derivative is zero);
* two materials on the same cell (their stresses and stiffnesses add up there);
* cells with no material when no other term of the residual depends on u (their nodes have no
  stiffness).

:func:`singular_jacobian` explains a failed factorisation after the fact: cells with no material,
and RVE points that have lost every contact (tension: P = 0 and a zero tangent).

Every check is collective (counts are summed over the ranks) and costs a pass over the forms'
coefficients or the materials' cell lists, nothing per Newton step.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from ufl.algorithms import extract_coefficients

from .quadrature import data_owner

if TYPE_CHECKING:
    from collections.abc import Sequence

    import ufl
    from dolfinx import fem

    from .quadrature import QuadratureMaterial


def _name(materials: Sequence[QuadratureMaterial], m: QuadratureMaterial) -> str:
    """``materials[i] (GranularMaterial)`` or the class name of a material not in the list."""
    for i, other in enumerate(materials):
        if other is m:
            return f"materials[{i}] ({type(m).__name__})"
    return f"a {type(m).__name__} on {m.mesh.comm.allreduce(m.cells.size)} cells"


def check_wiring(
    residual: ufl.Form,
    jacobian: ufl.Form | None,
    u: fem.Function,
    materials: Sequence[QuadratureMaterial],
) -> None:
    """Raise ValueError naming the mistake and its fix (collective; see the module docstring).

    Args:
        residual: the solver's residual form.
        jacobian: the user's Jacobian form, or None (the solver builds the consistent one).
        u: the displacement Function.
        materials: the materials handed to the solver.
    """
    read = set(map(id, extract_coefficients(residual)))
    _check_listed(residual, materials)
    if jacobian is not None:
        _check_tangents(read, jacobian, materials)
    if materials:
        _check_shared_cells(materials)
        _check_coverage(residual, u, materials)


def _check_listed(residual, materials):
    for f in extract_coefficients(residual):
        owner = data_owner(f)
        if owner is not None and not any(owner is m for m in materials):
            raise ValueError(
                f"the residual reads the stress of {_name(materials, owner)} that is not in the "
                "solver's materials: it would never be evaluated; pass every material whose "
                "residual_form is in the residual, NewtonSolver(..., materials=[m1, m2, ...])"
            )


def _check_tangents(read, jacobian, materials):
    has = set(map(id, extract_coefficients(jacobian)))
    for m in materials:
        if m.data and id(m.data[0]) in read and id(m.data[1]) not in has:
            raise ValueError(
                f"the Jacobian does not contain the tangent A of {_name(materials, m)}, whose "
                "stress P the residual reads: ufl.derivative(residual, u) sees P as data and "
                "gives zero for it. Pass jacobian=None (the solver builds derivative(residual, u, "
                "du, materials)) or material.jacobian_form(du, v)"
            )


def _check_shared_cells(materials):
    comm = materials[0].mesh.comm
    for i, a in enumerate(materials):
        for j in range(i + 1, len(materials)):
            b = materials[j]
            shared = comm.allreduce(np.intersect1d(a.cells, b.cells, assume_unique=True).size)
            if shared:
                raise ValueError(
                    f"materials[{i}] ({type(a).__name__}) and materials[{j}] "
                    f"({type(b).__name__}) share {shared} cells: their stresses and stiffnesses "
                    "would add up there. Give each cell one material (disjoint cells=)"
                )


def uncovered_cells(materials: Sequence[QuadratureMaterial]) -> int:
    """Number of owned cells (all ranks) that no material occupies (collective)."""
    msh = materials[0].mesh
    n_owned = msh.topology.index_map(msh.topology.dim).size_local
    covered = np.unique(np.concatenate([m.cells for m in materials]))
    return msh.comm.allreduce(int(n_owned - covered.size))


def _check_coverage(residual, u, materials):
    """Refuse cells with no material unless another u-dependent term may give them stiffness."""
    missing = uncovered_cells(materials)
    if not missing or _other_u_terms(residual, u, materials):
        return
    raise ValueError(
        f"{missing} cells of the mesh belong to no material and nothing else in the residual "
        "depends on u there: their nodes have no stiffness (a singular Jacobian). Give every "
        "cell a material (the materials' cells= must cover the mesh)"
    )


def _other_u_terms(residual, u, materials):
    """True if an integral of the residual depends on u and is not a material's residual_form."""
    v = residual.arguments()[0]
    own = {i.integrand() for m in materials for i in m.residual_form(v).integrals()}
    return any(
        i.integrand() not in own and any(c is u for c in extract_coefficients(i.integrand()))
        for i in residual.integrals()
    )


def singular_jacobian(materials: Sequence[QuadratureMaterial]) -> str:
    """What makes the Jacobian at the materials' last update singular, as advice; '' if nothing
    is found (collective)."""
    if not materials:
        return ""
    comm = materials[0].mesh.comm
    notes = []
    missing = uncovered_cells(materials)
    if missing:
        notes.append(
            f"{missing} cells belong to no material (no stiffness there, unless a term of your "
            "own gives them some): give every cell a material (the materials' cells= must "
            "cover the mesh)"
        )
    # (a stabilised material carries its open points itself)
    granular = [m for m in materials if hasattr(m, "n_open") and not getattr(m, "stabilise", 0)]
    n_open = comm.allreduce(sum(m.n_open for m in granular))
    if n_open:
        n_points = comm.allreduce(sum(m.n_points for m in granular))
        notes.append(
            f"{n_open} of {n_points} RVE points have lost every contact (tension: P = 0, a zero "
            "tangent); confine the model (a confining load) or stabilise those points: "
            "GranularMaterial(..., stabilise=1e-3), --stabilise 1e-3 in the slope demo"
        )
    return "; ".join(notes)
