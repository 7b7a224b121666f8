"""The Taylor RVE as a DOLFINx user material: quadrature-space stress and tangent (any supported DOLFINx).

Every quadrature point of the owned cells carries the same :class:`~dolfinx_granular.rve.TaylorRVE`.
:meth:`GranularMaterial.update` evaluates F = I + grad u at those points, calls the Numba kernel and
writes the first Piola stress P and the tangent dP/dF into quadrature Functions, which the UFL forms
of :meth:`~GranularMaterial.residual_form` and :meth:`~GranularMaterial.jacobian_form` read. Ghost
cells are skipped: cell integrals never read their quadrature values, so no RVE is evaluated twice
across ranks.

Flattening convention (DOLFINx 0.5 cannot hold rank-4 quadrature tensors; one layout on every release): F, P and grad v are
flattened row-major, ``[F00, F01, F10, F11]``, and the tangent is the (4, 4) matrix
``A[2a+b, 2c+d] = dP_ab / dF_cd``.
"""

from __future__ import annotations

import time

import numpy as np
import ufl
from dolfinx import fem

from . import _dolfinx as dfx
from .rve import TaylorRVE, UnsupportedDeformationError


def flatten(T):
    """Row-major flattening of a 2x2 UFL tensor to a 4-vector ``[T00, T01, T10, T11]``."""
    return ufl.as_vector([T[0, 0], T[0, 1], T[1, 0], T[1, 1]])


class GranularMaterial:
    """Taylor-RVE material on the quadrature points of a DOLFINx mesh.

    Args:
        rve: the material point law.
        u: displacement Function on a 2-D vector Lagrange space (Q1/P1 or higher), in m.
        quadrature_degree: degree k of the "default" quadrature scheme (2: 2x2 Gauss points on
            quadrilaterals, 3 points on triangles).
        stabilise: alpha >= 0. Where an RVE has lost all its load-carrying contacts (W = 0: every
            contact open, P = 0 and a zero tangent, so the global matrix can become singular), add
            the linear stress ``alpha C : (F - I)`` and tangent ``alpha C``, C the packing's eq. 15
            modulus. Points with a contact under load are untouched; 0 (default) disables it. The
            stabilising stress is fictitious: W, :meth:`cauchy` and the von Mises output leave it
            out; :attr:`P_stab` holds it alone, so that its nodal forces can be measured.

    Attributes:
        P: quadrature Function (2, 2), first Piola stress in Pa (owned cells after ``update``).
        A: quadrature Function (4, 4), dP/dF on flattened F, in Pa.
        W: (n_points,) energy density in Pa at the owned quadrature points.
        F: (n_points, 2, 2) deformation gradient at the last ``update``.
        dx: the cell measure with matching quadrature metadata; use it for every form that reads
            P or A.
        points: (n_points, 2) reference coordinates x of the owned quadrature points (m), ordered
            like W and F (point ``cell * n_qp + q``).
        timings: seconds spent in ``"F"`` (evaluating grad u) and ``"rve"`` (the kernel).
        n_open: number of owned points at the last ``update`` whose RVE had no loaded contact.
        P_stab: quadrature Function with the stabilising stress of the last ``update`` (None
            without a stabiliser).
    """

    def __init__(self, rve: TaylorRVE, u: fem.Function, quadrature_degree: int = 2,
                 stabilise: float = 0.0):
        if not isinstance(rve, TaylorRVE):
            raise TypeError(f"rve must be a dolfinx_granular.TaylorRVE, got {type(rve).__name__}")
        V = u.function_space
        msh = V.mesh
        if msh.geometry.dim != 2 or u.ufl_shape != (2,):
            raise ValueError(
                f"GranularMaterial needs a 2-D mesh and a vector displacement with 2 components; got "
                f"geometric dimension {msh.geometry.dim} and value shape {u.ufl_shape}"
            )
        k = int(quadrature_degree)
        if k < 1:
            raise ValueError(f"quadrature_degree must be >= 1, got {quadrature_degree!r}")
        self.rve = rve
        self.u = u
        self.mesh = msh
        self.quadrature_degree = k
        self.P = fem.Function(dfx.quadrature_space(msh, k, (2, 2)), name="P")
        self.A = fem.Function(dfx.quadrature_space(msh, k, (4, 4)), name="A")
        self.dx = ufl.Measure(
            "dx", domain=msh, metadata={"quadrature_degree": k, "quadrature_scheme": "default"}
        )
        X = dfx.quadrature_points(msh, k)
        self.n_qp = X.shape[0]
        tdim = msh.topology.dim
        imap = msh.topology.index_map(tdim)
        self.cells = np.arange(imap.size_local, dtype=np.int32)
        n_all = imap.size_local + imap.num_ghosts
        n = self.cells.size * self.n_qp
        for f in (self.P, self.A):
            Q = f.function_space
            # Writing P and A by position needs dof = cell * n_qp + q with owned cells first.
            if (Q.dofmap.index_map.size_local != n
                    or not np.array_equal(dfx.cell_dofs(Q.dofmap).ravel(),
                                          np.arange(n_all * self.n_qp))):
                raise RuntimeError(
                    "the quadrature dofmap is not cell-major (dof = cell * n_qp + q); this DOLFINx "
                    "version lays out quadrature spaces differently and is not supported"
                )
        self._F_expr = dfx.expression(ufl.Identity(2) + ufl.grad(u), X)
        self._x_expr = dfx.expression(ufl.SpatialCoordinate(msh), X)
        self.W = np.zeros(n)
        self.F = np.tile(np.eye(2), (n, 1, 1))
        self._P_view = self.P.x.array[: 4 * n].reshape(n, 2, 2)
        self._A_view = self.A.x.array[: 16 * n].reshape(n, 2, 2, 2, 2)
        self.timings = {"F": 0.0, "rve": 0.0}
        self.n_updates = 0
        self.n_open = 0
        alpha = float(stabilise)
        if not (np.isfinite(alpha) and alpha >= 0.0):
            raise ValueError(f"stabilise must be a finite number >= 0, got {stabilise!r}")
        self.stabilise = alpha
        self._C_stab = alpha * rve.small_strain_modulus() if alpha > 0.0 else None
        self.P_stab = None  # the stabilising part of P alone, to measure its effect
        if alpha > 0.0:
            self.P_stab = fem.Function(self.P.function_space, name="P_stab")
            self._P_stab_view = self.P_stab.x.array[: 4 * n].reshape(n, 2, 2)

    @property
    def n_points(self) -> int:
        """Number of quadrature points (RVEs) on this rank's owned cells."""
        return self.W.shape[0]

    @property
    def points(self) -> np.ndarray:
        """(n_points, 2) reference coordinates of the owned quadrature points (m)."""
        if not hasattr(self, "_points"):
            self._points = dfx.evaluate(self._x_expr, self.mesh, self.cells).reshape(-1, 2)
        return self._points

    @property
    def tangent(self) -> np.ndarray:
        """(n_points, 2, 2, 2, 2) view of dP/dF in Pa at the last ``update(tangent=True)``,
        ``[q, a, b, c, d] = dP_ab / dF_cd`` (stabiliser included)."""
        return self._A_view

    def deformation_gradient(self) -> np.ndarray:
        """F = I + grad u (n_points, 2, 2) at the owned quadrature points for the current u."""
        t = time.perf_counter()
        F = dfx.evaluate(self._F_expr, self.mesh, self.cells).reshape(-1, 2, 2)
        self.timings["F"] += time.perf_counter() - t
        return F

    def update(self, tangent: bool = True) -> None:
        """Evaluate the RVEs at the current u and write P (and A if ``tangent``).

        Raises:
            UnsupportedDeformationError: F at some point is outside the RVE's range; the message
                names the cells and their coordinates.
        """
        F = self.deformation_gradient()
        t = time.perf_counter()
        try:
            if tangent:
                self.rve.evaluate(F, out=(self.W, self._P_view, self._A_view))
            else:
                self.rve.stress(F, out=(self.W, self._P_view, None))
        except UnsupportedDeformationError as err:
            cells = np.unique(err.points // self.n_qp)
            xy = self.points[err.points[0]]
            raise UnsupportedDeformationError(
                f"{err}. Affected cells (local) {cells[:10].tolist()}, first point at x = "
                f"{xy.tolist()} m. Reduce the load step or check the boundary conditions.",
                err.points, err.status,
            ) from None
        finally:
            self.timings["rve"] += time.perf_counter() - t
        opened = np.flatnonzero(self.W == 0.0)
        self.n_open = opened.size
        if self._C_stab is not None:
            self._P_stab_view[...] = 0.0
            if opened.size:
                E = F[opened] - np.eye(2)
                self._P_stab_view[opened] = np.einsum("abcd,qcd->qab", self._C_stab, E)
                self._P_view[opened] += self._P_stab_view[opened]
                if tangent:
                    self._A_view[opened] += self._C_stab
        self.F[...] = F
        self.n_updates += 1

    def residual_form(self, v):
        """Internal virtual work ``∫ P : grad v dx`` (UFL, N·m per unit thickness)."""
        return ufl.inner(self.P, ufl.grad(v)) * self.dx

    def jacobian_form(self, du, v):
        """Its linearisation ``∫ grad v : A : grad du dx`` (UFL bilinear form)."""
        return ufl.inner(ufl.dot(self.A, flatten(ufl.grad(du))), flatten(ufl.grad(v))) * self.dx

    def cauchy(self) -> np.ndarray:
        """Cauchy stress sigma (n_points, 2, 2) in Pa at the F of the last ``update``."""
        return self.rve.cauchy(self.F)

    def cell_average(self, values) -> np.ndarray:
        """Mean of a per-point array (n_points, ...) over each owned cell's quadrature points
        -> (n_owned_cells, ...) (unweighted: a display value, not an integral)."""
        values = np.asarray(values)
        return values.reshape(self.cells.size, self.n_qp, *values.shape[1:]).mean(axis=1)
