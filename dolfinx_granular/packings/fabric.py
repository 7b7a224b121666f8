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

In 3-D (sphere packings) the normals n_c are unit vectors, A = (1 / N_c) sum_c n_c ⊗ n_c is (3, 3)
with trace 1, and the density on the unit sphere is approximated to second order as
rho(n) = (1 / 4 pi) (1 + a_ij n_i n_j) with a_ij symmetric and traceless (Ouadfel & Rothenburg,
Mech. Mater. 33, 2001). Averaging n ⊗ n over that rho gives A = I / 3 + (2 / 15) a, so
a_ij = (15 / 2) (A_ij - delta_ij / 3); the scalar anisotropy is a = sqrt(3/2 a_ij a_ij), which is
a_1 - a_3 = (15 / 2) (A_1 - A_3) for an axisymmetric fabric. The sphere density with a cone of
influence of half-angle delta counts each contact at +n_c and -n_c with the cap kernel
1 / (2 pi (1 - cos delta)), so it integrates to 1 and is 1 / (4 pi) for an isotropic set.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .packing import Packing, require_disks

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


def _branch_vectors(packing: Packing, F) -> np.ndarray:
    """(m, d) current branch vectors of the active contacts at F (default I), kernel's rule."""
    from ..laws.taylor import TaylorRVE

    d = packing.dim
    F = np.eye(d) if F is None else np.asarray(F, dtype=float)
    if F.shape != (d, d):
        raise ValueError(f"F must have shape ({d}, {d}) for a {d}-D packing, got {F.shape}")
    smin = float(np.linalg.svd(F, compute_uv=False).min()) if np.all(np.isfinite(F)) else 1.0
    rve = TaylorRVE(packing, 1.0, min_stretch=min(1.0, max(smin, 1e-3)))
    return rve.contacts(F).branch


def contact_normals(packing: Packing, F: ArrayLike | None = None) -> np.ndarray:
    """Unit contact normals n_c = l_c / |l_c| (N_c, d) of the active contacts at ``F``.

    Args:
        packing: a 2-D (disks) or 3-D (spheres) packing, d = ``packing.dim``.
        F: (d, d) deformation gradient, dimensionless; default the identity.

    Returns:
        (N_c, d) unit vectors, one per active contact (eps >= 0, periodic images included, the
        kernel's own contact rule, as in :func:`contact_angles`); (0, d) when none is active.

    Raises:
        ValueError: F of the wrong shape, or one the kernel rejects.
    """
    b = _branch_vectors(packing, F)
    length = np.linalg.norm(b, axis=1)
    if np.any(length == 0.0):
        raise ValueError("a contact has a zero branch vector (coincident centres): no normal")
    return b / length[:, None]


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


def _as_unit_vectors_3d(vectors) -> np.ndarray:
    v = np.asarray(vectors, dtype=float)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"contact normals must have shape (N_c, 3), got {v.shape}")
    if v.shape[0] == 0:
        raise ValueError(
            "no contacts: the density and fabric of an empty contact set are undefined"
        )
    if not np.all(np.isfinite(v)):
        raise ValueError("contact normals contain NaN or inf")
    length = np.linalg.norm(v, axis=1)
    if np.any(length == 0.0):
        raise ValueError(
            f"contact normals must be nonzero vectors; row {int(np.argmin(length))} is zero"
        )
    return v / length[:, None]


def fabric_tensor(angles: ArrayLike) -> np.ndarray:
    """Fabric tensor A = (1/N_c) sum n ⊗ n, trace 1.

    Args:
        angles: (N_c,) contact angles in rad or (N_c, 2) vectors (2-D), or (N_c, 3) vectors
            (3-D); vectors are normalised, their length and sign do not matter.

    Returns:
        (2, 2) or (3, 3) symmetric tensor, dimensionless.
    """
    v = np.asarray(angles, dtype=float)
    if v.ndim == 2 and v.shape[1] == 3:
        n = _as_unit_vectors_3d(v)
        A = n.T @ n / n.shape[0]
        return 0.5 * (A + A.T)
    a = _as_angles(v)
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


def anisotropy_3d(fabric: ArrayLike) -> tuple[float, np.ndarray]:
    """``(a, axis)`` of a 3-D fabric tensor (3, 3) (module docstring: a_ij = (15/2) (A - I/3)).

    Returns:
        a = sqrt(3/2 a_ij a_ij) >= 0, dimensionless, and the (3,) unit major principal axis of A
        (sign fixed so that its first component with |n_k| > 1e-12 is positive; for a repeated
        major eigenvalue, e.g. an isotropic fabric, one of the equivalent axes).
    """
    A = np.asarray(fabric, dtype=float)
    if A.shape != (3, 3):
        raise ValueError(f"the fabric tensor must have shape (3, 3), got {A.shape}")
    if not np.all(np.isfinite(A)):
        raise ValueError("the fabric tensor contains NaN or inf")
    if abs(np.trace(A) - 1.0) > 1e-6:
        raise ValueError(
            f"a fabric tensor (1/N_c) sum n ⊗ n of unit normals has trace 1, got {np.trace(A)}"
        )
    A = 0.5 * (A + A.T)
    dev = 7.5 * (A - np.eye(3) / 3.0)
    a = float(np.sqrt(1.5 * np.sum(dev * dev)))
    _, v = np.linalg.eigh(A)
    axis = v[:, 2] / np.linalg.norm(v[:, 2])
    k = int(np.argmax(np.abs(axis) > 1e-12))
    if axis[k] < 0:
        axis = -axis
    return a, axis


def normal_density_sphere(
    normals: ArrayLike, delta: float, n_lat: int = 90, n_lon: int = 180
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Contact-normal density on the unit sphere with a cone of influence of half-angle ``delta``.

    Each contact counts at +n_c and -n_c with the kernel 1 / (2 pi (1 - cos delta)) inside the
    cap of half-angle delta around each, weight 1 / (2 N_c): rho integrates to 1 over the sphere
    and is 1 / (4 pi) for an isotropic set (and everywhere for delta = pi / 2).

    Args:
        normals: (N_c, 3) contact normals or branch vectors (normalised here).
        delta: cone half-angle in rad, 0 < delta <= pi / 2.
        n_lat, n_lon: grid size in latitude and longitude.

    Returns:
        ``(lat (n_lat,), lon (n_lon,), rho (n_lat, n_lon))``: cell centres in rad, latitude in
        (-pi/2, pi/2), longitude in [0, 2 pi); rho in 1/sr, point n = (cos lat cos lon,
        cos lat sin lon, sin lat). The integral is sum rho cos(lat) dlat dlon.
    """
    n = _as_unit_vectors_3d(normals)
    delta = float(delta)
    if not (0.0 < delta <= 0.5 * np.pi):
        raise ValueError(f"the cone half-angle delta must lie in (0, pi/2] rad, got {delta}")
    n_lat, n_lon = int(n_lat), int(n_lon)
    if n_lat < 1 or n_lon < 1:
        raise ValueError(f"the grid needs n_lat, n_lon >= 1, got ({n_lat}, {n_lon})")
    lat = -0.5 * np.pi + (np.arange(n_lat) + 0.5) * (np.pi / n_lat)
    lon = (np.arange(n_lon) + 0.5) * (2.0 * np.pi / n_lon)
    cl = np.cos(lat)[:, None]
    grid = np.stack(
        [
            cl * np.cos(lon)[None, :],
            cl * np.sin(lon)[None, :],
            np.broadcast_to(np.sin(lat)[:, None], (n_lat, n_lon)),
        ],
        axis=-1,
    ).reshape(-1, 3)
    # m lies in the cap of +n or of -n iff |m . n| >= cos delta; the caps are disjoint for
    # delta <= pi/2. Chunks of grid points keep the (points, N_c) products to ~2^22 entries.
    cos_d = np.cos(delta)
    count = np.empty(grid.shape[0])
    step = max(1, (1 << 22) // n.shape[0])
    for i in range(0, grid.shape[0], step):
        count[i : i + step] = np.count_nonzero(np.abs(grid[i : i + step] @ n.T) >= cos_d, axis=1)
    rho = count / (4.0 * np.pi * (1.0 - cos_d) * n.shape[0])
    return lat, lon, rho.reshape(n_lat, n_lon)


def density_deviation(angles: ArrayLike, delta: float, n_theta: int = 720) -> float:
    """Isotropy indicator max_theta |2 pi rho_delta(theta) - 1| (0 for a perfectly uniform set)."""
    _, rho = normal_density(angles, delta, n_theta=n_theta)
    return float(np.max(np.abs(2.0 * np.pi * rho - 1.0)))
