"""Contact-normal density and fabric tensor of a disk packing (paper section 4).

A contact has no orientation, so each contact normal n_c = l_c / |l_c| (l_c the branch vector,
periodic images included) is counted at its angle theta_c and at theta_c + pi. The density with
an *angle of influence* delta is a sliding window over angle, not a histogram with fixed bins:

    rho_delta(theta) = 1 / (2 N_c) sum_c sum_{s in {0, pi}} K_delta(wrap(theta - theta_c - s)),
    K_delta(phi) = 1 / (2 delta) for |phi| <= delta, else 0,

so that the integral of rho over the circle is 1 and rho = 1 / (2 pi) for an isotropic set; a
polar plot of 2 pi rho is the unit circle then. The fabric tensor (Satake 1982; Oda 1982) is
A = (1 / N_c) sum_c n_c ⊗ n_c (trace 1), its anisotropy a = 2 (A_1 - A_2) with principal values
A_1 >= A_2, as in rho(theta) ~ (1 / 2 pi) [1 + a cos 2 (theta - theta_a)] (Rothenburg &
Bathurst, Geotechnique 39, 1989).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .packing import Packing, require_disks

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


def contact_angles(packing: Packing, F: ArrayLike | None = None) -> np.ndarray:
    """Angles theta_c = atan2(l_y, l_x) in (-pi, pi] of the active contacts at ``F`` (default I).

    Uses the kernel's own contact rule (eps >= 0, periodic images included), so a generated
    packing's network at F = I is exactly what the stress sums see.
    """
    from ..laws.taylor import TaylorRVE

    require_disks(packing, "contact_angles")
    F = np.eye(2) if F is None else np.asarray(F, dtype=float)
    smin = float(np.linalg.svd(F, compute_uv=False).min()) if np.all(np.isfinite(F)) else 1.0
    rve = TaylorRVE(packing, 1.0, min_stretch=min(1.0, max(smin, 1e-3)))
    b = rve.contacts(F).branch
    return np.arctan2(b[:, 1], b[:, 0])


def _as_angles(angles) -> np.ndarray:
    a = np.asarray(angles, dtype=float)
    if a.ndim == 2 and a.shape[1] == 2:  # normal or branch vectors
        a = np.arctan2(a[:, 1], a[:, 0])
    if a.ndim != 1:
        raise ValueError(
            f"contact angles must be a 1-D array of angles in rad or (N_c, 2) vectors, got "
            f"shape {a.shape}"
        )
    if a.size == 0:
        raise ValueError(
            "no contacts: the density and fabric of an empty contact set are undefined"
        )
    if not np.all(np.isfinite(a)):
        raise ValueError("contact angles contain NaN or inf")
    return a


def normal_density(
    angles: ArrayLike, delta: float, theta: ArrayLike | None = None, n_theta: int = 720
) -> tuple[np.ndarray, np.ndarray]:
    """Contact-normal density with angle of influence ``delta``.

    Args:
        angles: (N_c,) contact angles in rad, or (N_c, 2) normal / branch vectors.
        delta: angle of influence in rad, 0 < delta <= pi / 2 (half-width of the window).
        theta: (M,) angles at which to evaluate, rad; default ``n_theta`` points on [0, 2 pi).
        n_theta: grid size when ``theta`` is None.

    Returns:
        ``(theta (M,), rho (M,))``; rho in 1/rad, integrates to 1 over the circle.
    """
    a = _as_angles(angles)
    delta = float(delta)
    if not (0.0 < delta <= 0.5 * np.pi):
        raise ValueError(f"the angle of influence delta must lie in (0, pi/2] rad, got {delta}")
    if theta is None:
        theta = np.arange(n_theta) * (2.0 * np.pi / n_theta)
    theta = np.asarray(theta, dtype=float)
    # Both orientations theta_c and theta_c + pi fold onto one axis of period pi: count the
    # contacts within delta of theta modulo pi (a window of half-width <= pi/2 never double-counts).
    a_mod = np.sort(np.mod(a, np.pi))
    t = np.mod(theta, np.pi)
    ext = np.concatenate([a_mod - np.pi, a_mod, a_mod + np.pi])
    count = np.searchsorted(ext, t + delta, side="right") - np.searchsorted(
        ext, t - delta, side="left"
    )
    # each counted contact adds 1 / (2 N_c) * K_delta = 1 / (4 N_c delta)
    rho = count / (4.0 * delta * a.size)
    return theta, rho


def fabric_tensor(angles: ArrayLike) -> np.ndarray:
    """Fabric tensor (1/N_c) sum n ⊗ n (2, 2) of contact angles (rad) or vectors (N_c, 2)."""
    a = _as_angles(angles)
    c, s = np.cos(a), np.sin(a)
    return np.array([[np.mean(c * c), np.mean(c * s)], [np.mean(c * s), np.mean(s * s)]])


def anisotropy(fabric: ArrayLike) -> tuple[float, float]:
    """``(a, theta_a)``: a = 2 (A_1 - A_2) >= 0 of a fabric tensor (2, 2) and the direction
    theta_a in [0, pi) rad of its major principal axis."""
    A = np.asarray(fabric, dtype=float)
    if A.shape != (2, 2):
        raise ValueError(f"the fabric tensor must have shape (2, 2), got {A.shape}")
    w, v = np.linalg.eigh(0.5 * (A + A.T))
    theta = float(np.mod(np.arctan2(v[1, 1], v[0, 1]), np.pi))
    return float(2.0 * (w[1] - w[0])), theta


def density_deviation(angles: ArrayLike, delta: float, n_theta: int = 720) -> float:
    """Isotropy indicator max_theta |2 pi rho_delta(theta) - 1| (0 for a perfectly uniform set)."""
    _, rho = normal_density(angles, delta, n_theta=n_theta)
    return float(np.max(np.abs(2.0 * np.pi * rho - 1.0)))
