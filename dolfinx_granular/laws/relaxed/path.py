"""A relaxed point's quasi-static path from its committed positions to a new F.

A relaxed cell has, near jamming, several equilibria at one F; which one a relaxation reaches
depends on where it starts. One big increment can land on another one than the path the cell
takes when F changes slowly, the quasi-static path that a load step stands for. The path is
therefore followed in substeps of the right stretch U = (F^T F)^(1/2), at most
:data:`MAX_SUBSTEP` apart (the response depends on C = F^T F only, so a rotation costs none),
and every relaxation starts from the last positions plus their first-order change
(:func:`predicted`, from the sensitivities dw/dF of the last equilibrium): it starts within
O(dF^2) of the equilibrium it follows.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import equilibrium

#: longest substep |U_k+1 - U_k| (Frobenius norm of the right stretch)
MAX_SUBSTEP = 1e-3


@njit(cache=True)
def predicted(w: np.ndarray, dw: np.ndarray, Fc: np.ndarray, F: np.ndarray) -> np.ndarray:
    """The fluctuations w (N, 2) relaxed at Fc (2, 2), carried to F (2, 2) to first order: w +
    dw : dF_C, dw (N, 2, 4) the sensitivities dw/dF at Fc (F flattened row-major) and dF_C =
    Fc^-T (C - C_c) / 2 the increment that changes C as F does (dF itself would be first-order
    only: a finite rotation, which changes nothing, would move the disks)."""
    dF = 0.5 * np.linalg.solve(np.ascontiguousarray(Fc.T), F.T @ F - Fc.T @ Fc)
    return w + (np.ascontiguousarray(dw).reshape(-1, 4) @ dF.ravel()).reshape(w.shape)


@njit(cache=True)
def stretch(F: np.ndarray) -> np.ndarray:
    """The right stretch U = (F^T F)^(1/2) (2, 2) of F (2, 2): for a 2 x 2 C = F^T F,
    U = (C + s I) / t with s = (det C)^(1/2) = |det F| and t = (tr C + 2 s)^(1/2)."""
    C = F.T @ F
    s = abs(F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0])
    return (C + s * np.eye(2)) / np.sqrt(C[0, 0] + C[1, 1] + 2.0 * s)


def substeps(Fc: np.ndarray, F: np.ndarray, longest: float = MAX_SUBSTEP) -> list:
    """The stretches (2, 2) between Fc and F (both excluded), evenly spaced in U and at most
    ``longest`` apart."""
    return list(stretches_between(Fc, F, longest))


@njit(cache=True)
def stretches_between(Fc, F, longest):
    """:func:`substeps` as an array (k, 2, 2)."""
    Uc, U = stretch(Fc), stretch(F)
    m = int(np.ceil(np.linalg.norm(U - Uc) / longest))
    out = np.empty((max(m - 1, 0), 2, 2))
    for k in range(1, m):
        out[k - 1] = Uc + (k / m) * (U - Uc)
    return out


def follow(cell, F, w, dw, Fc, tangent, settings) -> equilibrium.Equilibrium:
    """The :class:`~dolfinx_granular.laws.relaxed.equilibrium.Equilibrium` at F (2, 2) reached
    from the equilibrium (w (N, 2), sensitivities dw (N, 2, 4)) at Fc along the quasi-static
    path."""
    for Uk in substeps(Fc, F):
        eq = _step(cell, Uk, w, dw, Fc, True, settings)
        w, dw, Fc = eq.w, eq.sensitivity, Uk
    return _step(cell, F, w, dw, Fc, tangent, settings)


def _step(cell, F, w, dw, Fc, tangent, settings):
    """Relax at F from the predicted positions; where Newton stalls from there, from w as it
    is (carried affinely), and FIRE from that."""
    if not dw.any():
        return equilibrium.relax(cell, F, w, tangent, settings)
    start = predicted(w, dw, Fc, F)
    return equilibrium.relax(cell, F, start, tangent, settings, fallback=w)
