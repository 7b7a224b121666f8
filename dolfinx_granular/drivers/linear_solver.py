"""The linear solver inside Newton: a direct factorisation, or a Krylov method preconditioned by
algebraic multigrid with the rigid-body modes.

``"direct"``: LU with MUMPS (PETSc's own LU where MUMPS is missing; it is serial only).

``"iterative"``: GMRES with PETSc's GAMG (smoothed aggregation; the one AMG in every supported
PETSc: the DOLFINx 0.11 wheel has no hypre). GAMG is given the rigid-body modes of the
displacement space as the matrix's near-nullspace (2 translations and 1 rotation in 2-D, 3 and
3 in 3-D), which it needs for elasticity-like operators: without them it takes 3x as many
iterations. The Krylov tolerance is tied to the Newton residual (:func:`forcing`): the first
Newton step is solved to 1e-3, the later ones to 1e-3 |R_k| / |R_0|, so Newton keeps its
quadratic convergence and, measured on the 3-D footing and the README column, the very
iterations of the direct solver (1e-2 costs the column one Newton step more in one load step
of three; Eisenstat and Walker's forcing terms, PETSc's ``snes_ksp_ew``, cost the footing one
more per load step). GMRES rather than CG: a frictional RVE's tangent is not symmetric.

GAMG reads its smoother options when the preconditioner is first set up (the first solve), so
the options of an iterative solver stay in PETSc's options database while the solver lives
(:func:`release` removes them).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # (PETSc loads on use: the slope's options check a name without it)
    from collections.abc import Mapping

    from dolfinx import fem
    from petsc4py import PETSc

LINEAR_SOLVERS = ("direct", "iterative")

ITERATIVE = {
    "ksp_type": "gmres",
    "ksp_gmres_restart": 100,
    "ksp_max_it": 500,
    "pc_type": "gamg",
    "pc_gamg_type": "agg",
    # plain aggregation: measured on the 3-D footing, 0.8x the linear solve time of smoothed
    # aggregation
    "pc_gamg_agg_nsmooths": 0,
    "pc_gamg_coarse_eq_limit": 1000,
    "mg_levels_ksp_type": "chebyshev",
    "mg_levels_pc_type": "jacobi",
    "ksp_rtol": 1e-3,
}

#: the Krylov tolerance of :func:`forcing`: at most this, and this times |R_k| / |R_0|
FORCING = 1e-3
#: the smallest Krylov tolerance :func:`forcing` asks for (round-off)
MIN_RTOL = 1e-12


def check(kind: str) -> str:
    """``kind`` if it names a linear solver, else a ValueError naming the choices."""
    if kind not in LINEAR_SOLVERS:
        raise ValueError(f"linear_solver must be one of {LINEAR_SOLVERS}, got {kind!r}")
    return kind


def options(kind: str) -> dict[str, Any]:
    """The PETSc options (without prefix) of a linear solver ``kind``."""
    from petsc4py import PETSc

    if check(kind) == "iterative":
        return dict(ITERATIVE)
    opts = {"ksp_type": "preonly", "pc_type": "lu"}
    if PETSc.Sys.hasExternalPackage("mumps"):
        opts["pc_factor_mat_solver_type"] = "mumps"  # PETSc's own LU is serial only
    return opts


def forcing(fnorm: float, fnorm0: float) -> float:
    """Krylov relative tolerance of a Newton step from an iterate with residual norm ``fnorm``,
    the solve having started at ``fnorm0``: ``FORCING * min(1, fnorm / fnorm0)`` (at least
    ``MIN_RTOL``). A forcing term O(|R_k|) keeps Newton quadratic (Dembo, Eisenstat and
    Steihaug 1982)."""
    ratio = fnorm / fnorm0 if fnorm0 > 0.0 else 1.0
    return max(FORCING * min(1.0, ratio), MIN_RTOL)


def rigid_body_modes(V: fem.FunctionSpace, A: PETSc.Mat) -> PETSc.NullSpace:
    """The rigid-body modes of a vector Lagrange space V (one component per dimension) as an
    orthonormal PETSc NullSpace of vectors laid out like A's rows (2-D: 3 modes, 3-D: 6)."""
    from petsc4py import PETSc

    gdim = V.mesh.geometry.dim
    n, bs = V.dofmap.index_map.size_local, V.dofmap.index_map_bs
    if bs != gdim:
        raise ValueError(
            f"rigid-body modes need a vector space with {gdim} components per node, got {bs}"
        )
    x = V.tabulate_dof_coordinates()[:n, :gdim]  # owned nodes; dof = bs * node + component
    modes = np.zeros((3 if gdim == 2 else 6, n, bs))
    for i in range(gdim):
        modes[i][:, i] = 1.0  # translations
    rotations = [(2, 0, 1)] if gdim == 2 else [(3, 0, 1), (4, 2, 0), (5, 1, 2)]
    for k, a, b in rotations:  # rotation in the (a, b) plane: u_a = -x_b, u_b = x_a
        modes[k][:, a], modes[k][:, b] = -x[:, b], x[:, a]
    vecs = [A.createVecLeft() for _ in modes]
    for v, mode in zip(vecs, modes):
        # setArray, not writes into getArray(): newer PETSc caches norms, and a raw write
        # leaves the cached norm of the zero vector (normalize() would then do nothing)
        v.setArray(mode.ravel())
    for i, v in enumerate(vecs):  # modified Gram-Schmidt (collective dots)
        for w in vecs[:i]:
            v.axpy(-v.dot(w), w)
        v.normalize()
    return PETSc.NullSpace().create(vectors=vecs, comm=V.mesh.comm)


def prepare(kind: str, A: PETSc.Mat, V: fem.FunctionSpace) -> None:
    """Give the Jacobian matrix A what linear solver ``kind`` needs (the iterative one: the
    near-nullspace; it stays through reassembly)."""
    if check(kind) == "iterative":
        A.setNearNullSpace(rigid_body_modes(V, A))


def release(prefix: str, opts: Mapping[str, Any]) -> None:
    """Remove the options ``opts`` set under ``prefix`` from PETSc's options database."""
    from petsc4py import PETSc

    db = PETSc.Options()
    for key in opts:
        db.delValue(prefix + key)
