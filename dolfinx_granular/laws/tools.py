"""Helpers the material laws share: batches of F, output buffers, push-forward, rejected F.

Shapes: a batch holds n points; F (n, d, d), W (n,), P (n, d, d) and A (n, d, d, d, d) with
``A[q, a, b, c, d] = dP_ab / dF_cd``; stresses and tangents in Pa. The laws of the package are 2-D
(d = 2) today; the helpers take d where it matters.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from . import taylor_kernel
from .protocol import LawEvaluationError

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

#: why the kernels reject an F, by status code (:mod:`~dolfinx_granular.laws.taylor_kernel`)
REASONS = {
    taylor_kernel.NOT_FINITE: "has a NaN or inf entry (or entries so large that F^T F overflows)",
    taylor_kernel.NOT_ORIENTATION_PRESERVING: "has det F <= 0 (an inverted or collapsed element)",
    taylor_kernel.BELOW_MIN_STRETCH: "compresses below the supported smallest singular value",
}


class UnsupportedDeformationError(LawEvaluationError):
    """F is non-finite, has det F <= 0 or a singular value below ``min_stretch``.

    Attributes:
        points: indices of the rejected points in the batch.
        status: (n,) status code per point (see :mod:`dolfinx_granular.laws.taylor_kernel`).
    """

    def __init__(self, message: str, points: np.ndarray, status: np.ndarray) -> None:
        super().__init__(message, points)
        self.status = status


def unsupported_deformation(
    F: np.ndarray, status: np.ndarray, min_stretch: float
) -> UnsupportedDeformationError:
    """The error for a batch F (n, d, d) whose kernel ``status`` (n,) is not all OK: it names
    the rejected points, the first one's F and why (and the fix for a too small stretch)."""
    bad = np.flatnonzero(status)
    q = int(bad[0])
    reason = REASONS[int(status[q])]
    if status[q] == taylor_kernel.BELOW_MIN_STRETCH:
        smin = np.linalg.svd(F[q], compute_uv=False).min()
        reason += (
            f" ({smin:.4g} < min_stretch={min_stretch}; "
            "build the TaylorRVE with a smaller min_stretch)"
        )
    return UnsupportedDeformationError(
        f"F at {bad.size} of {F.shape[0]} points is outside the Taylor RVE's range; the first, "
        f"point {q}, F = {F[q].tolist()}, {reason}",
        bad,
        status,
    )


def to_float(value: object, name: str) -> float:
    """``value`` as a float; a ValueError that names the parameter otherwise."""
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None


def normal_stiffness(value: object) -> float:
    """A contact law's k_n as a finite float > 0 (N/m²); a ValueError that names it otherwise."""
    k = to_float(value, "normal_stiffness")
    if not (np.isfinite(k) and k > 0.0):
        raise ValueError(f"normal_stiffness must be a finite number > 0 (N/m²), got {value!r}")
    return k


def non_negative(value: object, name: str, unit: str = "") -> float:
    """``value`` as a finite float >= 0; a ValueError that names the parameter (and its
    ``unit``, e.g. " (N/m²)") otherwise."""
    v = to_float(value, name)
    if not (np.isfinite(v) and v >= 0.0):
        raise ValueError(f"{name} must be a finite number >= 0{unit}, got {value!r}")
    return v


def as_batch(F: ArrayLike, dim: int = 2) -> tuple[np.ndarray, bool]:
    """``(F (n, d, d) C-contiguous float64, single)``; one F (d, d) becomes a batch of 1 and
    ``single`` is True."""
    F = np.asarray(F, dtype=np.float64)
    if F.shape == (dim, dim):
        return np.ascontiguousarray(F[None]), True
    if F.ndim != 3 or F.shape[1:] != (dim, dim):
        raise ValueError(f"F must have shape (n, {dim}, {dim}) or ({dim}, {dim}), got {F.shape}")
    return np.ascontiguousarray(F), False


def output_buffers(n: int, tangent: bool, out: tuple | None = None, dim: int = 2) -> tuple:
    """``(W (n,), P (n, d, d), A (n, d, d, d, d) or None)``: the caller's ``out`` arrays, or new
    ones; A is None without ``tangent``."""
    if out is None:
        W, P = np.empty(n), np.empty((n, dim, dim))
        A = np.empty((n,) + (dim,) * 4) if tangent else None
    else:
        W, P, A = out
        if not tangent:
            A = None
    return W, P, A


def push_forward(
    F: np.ndarray, P: np.ndarray, A: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Cauchy stress sigma = P F^T / J (n, d, d) and spatial tangent a_abcd = F_bB F_dD A_aBcD / J
    (n, d, d, d, d) (eqs. 11, 14) from P and A = dP/dF (A may be None: a is None)."""
    if F.shape[1] == 2:
        J = F[:, 0, 0] * F[:, 1, 1] - F[:, 0, 1] * F[:, 1, 0]
    else:
        J = np.linalg.det(F)
    sigma = np.einsum("qaB,qbB->qab", P, F) / J[:, None, None]
    if A is None:
        return sigma, None
    a = np.einsum("qbB,qdD,qaBcD->qabcd", F, F, A) / J[:, None, None, None, None]
    return sigma, a


#: the most items of a tuple handed from Python to a compiled function (:func:`chunks`)
CHUNK = 4


def chunks(items: tuple) -> tuple:
    """``items`` in tuples of at most :data:`CHUNK` items, for a compiled entry that joins
    them again (``a + b`` of tuples compiles to nothing).

    Why: Numba before 0.57 (Debian 12's 0.56) caches the type of each argument under a
    fingerprint whose buffer is corrupted past 40 bytes, as a tuple of 5 arrays or more makes
    it. Such a tuple misses the cache and is typed in Python at every call (about 0.2 ms), and
    the cache grows by an entry each time."""
    return tuple(items[k : k + CHUNK] for k in range(0, len(items), CHUNK))


def singular_values_2x2(F: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Singular values ``(s_max, s_min)`` of (n, 2, 2) matrices, accurate to a few ulp absolute.

    Uses ``s = |q| +- |r|`` with ``q = ((F00 + F11) / 2, (F10 - F01) / 2)`` and
    ``r = ((F00 - F11) / 2, (F10 + F01) / 2)`` (no cancellation in a discriminant).
    """
    F = np.asarray(F, dtype=np.float64)
    q = np.hypot(0.5 * (F[:, 0, 0] + F[:, 1, 1]), 0.5 * (F[:, 1, 0] - F[:, 0, 1]))
    r = np.hypot(0.5 * (F[:, 0, 0] - F[:, 1, 1]), 0.5 * (F[:, 1, 0] + F[:, 0, 1]))
    return q + r, np.abs(q - r)


def symmetrise_modulus(C: ArrayLike) -> np.ndarray:
    """C (2, 2, 2, 2) averaged over the 8 major/minor index permutations, one value copied per
    orbit so that the symmetries hold exactly in floating point."""
    perms = ["abcd", "bacd", "abdc", "badc", "cdab", "dcab", "cdba", "dcba"]
    S = sum(np.einsum(f"{p}->abcd", C) for p in perms) / 8.0
    out = np.empty_like(S)
    for idx in np.ndindex(2, 2, 2, 2):
        a, b, c, d = idx
        orbit = [
            (a, b, c, d),
            (b, a, c, d),
            (a, b, d, c),
            (b, a, d, c),
            (c, d, a, b),
            (d, c, a, b),
            (c, d, b, a),
            (d, c, b, a),
        ]
        out[idx] = S[min(orbit)]
    return out


def isotropic_lame(C: ArrayLike) -> tuple[float, float]:
    """Lamé constants ``(lam, mu)`` of the isotropic part of a 2-D modulus C (2, 2, 2, 2).

    Orthogonal projection onto ``lam I (x) I + 2 mu I_sym``: it keeps the two isotropic invariants
    ``a = C_iikk = 4 lam + 4 mu`` and ``b = C_ikik = 2 lam + 6 mu``, so
    ``lam = (3a - 2b) / 8`` and ``mu = (2b - a) / 8``. For the central-force Taylor modulus of
    eq. 15, C is fully symmetric (Cauchy relation a = b) and ``lam = mu = C_iikk / 8``; the bulk
    modulus ``lam + mu = C_iikk / 4`` is exact for any fabric.
    """
    C = np.asarray(C, dtype=np.float64)
    a = np.einsum("iikk->", C)
    b = np.einsum("ikik->", C)
    return (3.0 * a - 2.0 * b) / 8.0, (2.0 * b - a) / 8.0
