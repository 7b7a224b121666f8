"""Model levels with the :class:`~dolfinx_granular.TaylorRVE` interface: pay only for what a
scene needs.

* :class:`SmallStrainRVE` -- the linear model of eq. 15: ``P = C : eps`` with
  ``eps = sym(F - I)`` and ``A = C``; no contact work per evaluation.
* :class:`AdaptiveRVE` -- per point, the linearisation at the reference where the deformation is
  small (``||F - I||_2 <= tol``) and the contact set provably equals the reference one, the full
  Taylor RVE elsewhere.

Both wrap a :class:`TaylorRVE` (its packing and candidate arrays are shared, not copied: no second
candidate search) and are :class:`~dolfinx_granular.MaterialLaw` s, so they drop into
:class:`~dolfinx_granular.GranularMaterial` unchanged.

**The sufficient contact test of AdaptiveRVE.** A candidate contact with reference branch vector
L and radius sum R is active at F when ``|F L| <= R``, and ``s_min(F) |L| <= |F L| <= s_max(F) |L|``
with ``s_min``, ``s_max`` the singular values of F. Hence

* every reference contact (``R - |L| >= 0``) stays closed if ``s_max(F) <= min_c R_c / |L_c|``;
* every reference gap (``R - |L| < 0``) stays open if ``s_min(F) > max_g R_g / |L_g|`` (then
  ``|F L_g| >= s_min(F) |L_g| > R_g`` for every gap g).

Both bounds are computed once per packing (``reference_stretch_bounds``) and tested with a
relative safety margin of 1e-12, far above the rounding of the kernel's ``R - |F L|``. For the
jammed packings of :func:`~dolfinx_granular.generate_packing` the reference contacts
touch (``R / |L| = 1 + O(1e-11)``) and the nearest gaps are ~1e-6 R wide, so the test passes only
for F within ~1e-6 of a rotation that does not stretch: a provable linear region is tiny for a
packing at jamming. ``contact_test=False`` drops the contact test (strain criterion only); this is
not provable and its error is measured, not bounded.

**Error bound where the linear branch is used.** The linear branch is the exact linearisation of
the Taylor law at F = I, ``P(I) + A(I) : (F - I)`` (``A(I)`` is the eq. 15 modulus C and ``P(I) =
0`` for a stress-free reference; with reference overlaps both include the prestress). Over an
unchanged contact set, contact c contributes ``-K R_c (N(F L_c) - N(L_c) - DN(L_c) H L_c) (x) L_c``
to ``P_lin - P_Taylor`` with ``N(b) = b / |b|``, ``H = F - I``, ``K = k_n / V``. The remainder of N
is at most ``(1/sqrt 3) t^2 / (1 - t)^2`` for ``t = |H L| / |L| <= ||H||_2 < 1`` (the constant is
sharp as t -> 0), so::

    |P_lin - P_Taylor|_F <= (1/sqrt 3) K sum_c R_c |L_c| * t^2 / (1 - t)^2,   t = ||F - I||_2

:meth:`AdaptiveRVE.error_bound` evaluates it; with ``t <= tol`` the error relative to the linear
stress scale ``K sum R |L| t`` is at most ``tol / (sqrt 3 (1 - tol)^2)``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..packings.packing import require_disks
from . import taylor_kernel
from .taylor import TaylorRVE, UnsupportedDeformationError
from .tools import (
    as_batch,
    isotropic_lame,
    output_buffers,
    push_forward,
    singular_values_2x2,
    symmetrise_modulus,
)

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from ..packings.packing import Packing
    from .taylor import ContactSet
    from .validity import OverlapStatistics

# relative safety margin of the singular-value contact test (see module docstring)
_MARGIN = 1e-12
_REMAINDER_CONSTANT = 1.0 / np.sqrt(3.0)

# isotropic_lame and singular_values_2x2 live in lawtools; importable from here as before
__all__ = ["AdaptiveRVE", "SmallStrainRVE", "isotropic_lame", "singular_values_2x2"]


def _full_model(rve):
    """The TaylorRVE behind ``rve`` (a level wraps the full model, never another level)."""
    if isinstance(rve, _Level):
        return rve.taylor
    if not isinstance(rve, TaylorRVE):
        raise TypeError(f"rve must be a dolfinx_granular.TaylorRVE, got {type(rve).__name__}")
    require_disks(rve.packing, "the model levels (SmallStrainRVE, AdaptiveRVE)")
    return rve


def _validate_finite(F):
    """Raise UnsupportedDeformationError for non-finite F (the linear model needs nothing else)."""
    bad = np.flatnonzero(~np.isfinite(F.reshape(F.shape[0], -1)).all(axis=1))
    if bad.size:
        status = np.zeros(F.shape[0], dtype=np.int8)
        status[bad] = taylor_kernel.NOT_FINITE
        q = int(bad[0])
        raise UnsupportedDeformationError(
            f"F at {bad.size} of {F.shape[0]} points is outside the model's range; the first, "
            f"point {q}, F = {F[q].tolist()}, has a NaN or inf entry",
            bad,
            status,
        )


class _Level:
    """Shared public interface of a level wrapping the TaylorRVE ``taylor``; subclasses implement
    ``_material(F, tangent, out)``."""

    def __init__(self, rve: TaylorRVE) -> None:
        self.taylor = _full_model(rve)

    @property
    def packing(self) -> Packing:
        """The wrapped RVE's packing."""
        return self.taylor.packing

    @property
    def normal_stiffness(self) -> float:
        return self.taylor.normal_stiffness

    @property
    def min_stretch(self) -> float:
        return self.taylor.min_stretch

    def small_strain_modulus(self) -> np.ndarray:
        """The wrapped RVE's eq. 15 modulus C (2, 2, 2, 2), in Pa."""
        return self.taylor.small_strain_modulus()

    def _material(self, F, tangent, out):  # pragma: no cover - abstract
        raise NotImplementedError

    def evaluate(
        self, F: ArrayLike, out: tuple | None = None
    ) -> tuple[np.ndarray | float, np.ndarray, np.ndarray]:
        """Energy W (n,), first Piola stress P (n, 2, 2), A = dP/dF (n, 2, 2, 2, 2), in Pa."""
        F, single = as_batch(F)
        W, P, A = self._material(F, True, out)
        return (W[0], P[0], A[0]) if single else (W, P, A)

    def stress(
        self, F: ArrayLike, out: tuple | None = None
    ) -> tuple[np.ndarray | float, np.ndarray]:
        """Energy and first Piola stress without the tangent: ``(W (n,), P (n, 2, 2))``."""
        F, single = as_batch(F)
        W, P, _ = self._material(F, False, out)
        return (W[0], P[0]) if single else (W, P)

    def energy(self, F: ArrayLike) -> np.ndarray | float:
        """Energy density W (n,) per reference area, in Pa."""
        return self.stress(F)[0]

    def cauchy(self, F: ArrayLike) -> np.ndarray:
        """Cauchy stress (n, 2, 2) in Pa."""
        F, single = as_batch(F)
        _, P, _ = self._material(F, False, None)
        sigma = self._spatial(F, P, None)[0]
        return sigma[0] if single else sigma

    def spatial_tangent(self, F: ArrayLike) -> np.ndarray:
        """Spatial tangent (n, 2, 2, 2, 2) in Pa."""
        F, single = as_batch(F)
        _, P, A = self._material(F, True, None)
        a = self._spatial(F, P, A)[1]
        return a[0] if single else a

    def _spatial(self, F, P, A):
        return push_forward(F, P, A)

    def contacts(self, F: ArrayLike) -> ContactSet:
        """Active contacts of the full Taylor RVE at one F (2, 2) (force networks for figures)."""
        return self.taylor.contacts(F)

    def overlap_statistics(self, F: ArrayLike) -> OverlapStatistics:
        """The wrapped Taylor RVE's validity measure at F (``TaylorRVE.overlap_statistics``):
        the overlaps the contacts would have at F, whatever this level's stress."""
        return self.taylor.overlap_statistics(F)


class SmallStrainRVE(_Level):
    """The small-strain model of eq. 15 as a material level: linear, no contact work.

    ``P = C : eps`` with ``eps = sym(F - I)``, ``W = eps : C : eps / 2``, ``A = dP/dF = C``, where
    C is :meth:`TaylorRVE.small_strain_modulus` of the wrapped RVE, symmetrised exactly (major and
    minor symmetry, in floating point too). Linear theory does not distinguish stress measures:
    :meth:`cauchy` returns ``C : eps`` as well and :meth:`spatial_tangent` returns C. Any finite F
    is accepted. The reference prestress of an RVE with overlapping reference contacts is not
    included (for generated, stress-free packings it is zero).

    Args:
        rve: the full Taylor RVE whose reference contacts define C.

    Attributes:
        C: (2, 2, 2, 2) modulus in Pa.
        taylor: the wrapped :class:`TaylorRVE`.
    """

    def __init__(self, rve: TaylorRVE) -> None:
        super().__init__(rve)
        self.C = symmetrise_modulus(self.taylor.small_strain_modulus())
        self._C44 = np.ascontiguousarray(self.C.reshape(4, 4))

    def strain(self, F: ArrayLike) -> np.ndarray:
        """Small strain eps = sym(F - I), (n, 2, 2)."""
        H = F - np.eye(2)
        return 0.5 * (H + np.swapaxes(H, 1, 2))

    def _material(self, F, tangent, out):
        _validate_finite(F)
        n = F.shape[0]
        W, P, A = output_buffers(n, tangent, out)
        eps = self.strain(F).reshape(n, 4)
        sig = eps @ self._C44.T  # C is major-symmetric; P_ab = C_abcd eps_cd
        P[...] = sig.reshape(n, 2, 2)
        W[...] = 0.5 * np.einsum("qi,qi->q", sig, eps)
        if tangent:
            A[...] = self.C
        return W, P, A

    def _spatial(self, F, P, A):
        return P, (None if A is None else A)


class AdaptiveRVE(_Level):
    """Per point: the reference linearisation where it is provably accurate, full Taylor elsewhere.

    A point takes the linear branch ``P(I) + A(I) : (F - I)`` (tangent ``A(I)``; ``A(I)`` is the
    eq. 15 modulus for a stress-free reference) when

    * ``||F - I||_2 <= tol`` (spectral norm, so rotations count), and
    * (``contact_test=True``) the singular-value test proves that the contact set is the reference
      one (module docstring).

    Every other point is evaluated by the wrapped Taylor RVE, bit for bit. Where the linear branch
    is taken the stress error against full Taylor is at most :meth:`error_bound`.

    Args:
        rve: the full Taylor RVE.
        tol: strain tolerance, 0 <= tol < 1.
        contact_test: require the provable contact test (default). ``False`` uses the strain
            criterion alone: cheaper choices, error not bounded.

    Attributes:
        counts: ``{"linear": n, "taylor": n}`` of the last evaluation.
        totals: the same, summed over all evaluations since construction (or ``reset_counts``).
        linear_mask: (n,) bool, the points of the last evaluation that took the linear branch.
        stretch_bounds: ``(s_max allowed, s_min required)`` of the contact test, margin included.
        error_constant: ``K sum_c R_c |L_c|`` over the reference contacts (Pa), the factor of
            :meth:`error_bound`.
    """

    def __init__(self, rve: TaylorRVE, tol: float, contact_test: bool = True) -> None:
        super().__init__(rve)
        tol = float(tol)
        if not (0.0 <= tol < 1.0):
            raise ValueError(f"tol must lie in [0, 1), got {tol!r}")
        self.tol = tol
        self.contact_test = bool(contact_test)
        self.W0, self.P0, self.A0 = self.taylor.evaluate(np.eye(2))
        self._A044 = np.ascontiguousarray(self.A0.reshape(4, 4))
        c = self.taylor.candidates
        R, L = c.radius_sum, c.branch
        d = np.sqrt(L[:, 0] * L[:, 0] + L[:, 1] * L[:, 1])  # as the kernel computes |F L| at F = I
        closed = R - d >= 0.0
        ratio = R / d  # the contact stays active while the stretch along L is <= R / |L|
        smax_ok = ratio[closed].min() if closed.any() else np.inf
        smin_req = ratio[~closed].max() if (~closed).any() else 0.0
        self.stretch_bounds = (smax_ok * (1.0 - _MARGIN), smin_req * (1.0 + _MARGIN))
        self.n_reference_contacts = int(closed.sum())
        K = self.taylor.normal_stiffness / self.taylor.packing.area  # k_n / V, as the kernel's
        self.error_constant = float(K * np.sum(R[closed] * d[closed]))
        self.counts = {"linear": 0, "taylor": 0}
        self.totals = {"linear": 0, "taylor": 0}
        self.linear_mask = np.zeros(0, dtype=bool)

    def reset_counts(self) -> None:
        self.totals = {"linear": 0, "taylor": 0}

    def strain_measure(self, F: ArrayLike) -> np.ndarray:
        """``||F - I||_2`` (n,), the largest singular value of F - I."""
        F, _ = as_batch(F)
        return singular_values_2x2(F - np.eye(2))[0]

    def linear_points(self, F: ArrayLike) -> np.ndarray:
        """(n,) bool: points where the linear branch is taken (both criteria of the class doc)."""
        F, _ = as_batch(F)
        with np.errstate(invalid="ignore"):
            ok = self.strain_measure(F) <= self.tol  # NaN -> False -> Taylor, which rejects it
            if self.contact_test:
                smax, smin = singular_values_2x2(F)
                ok &= (smax <= self.stretch_bounds[0]) & (smin > self.stretch_bounds[1])
        return ok

    def error_bound(self, F: ArrayLike) -> np.ndarray:
        """Upper bound (n,) of ``|P_linear - P_Taylor|_F`` (Pa) valid wherever the contact set is
        the reference one: ``(1/sqrt 3) error_constant t^2 / (1 - t)^2``, t = ||F - I||_2 < 1."""
        t = self.strain_measure(F)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(
                t < 1.0, _REMAINDER_CONSTANT * self.error_constant * t**2 / (1.0 - t) ** 2, np.inf
            )

    def _linear(self, F, tangent):
        """The linear branch at points F (m, 2, 2): W, P and (if ``tangent``) A."""
        H = (F - np.eye(2)).reshape(-1, 4)
        dP = H @ self._A044.T
        P = self.P0 + dP.reshape(-1, 2, 2)
        W = self.W0 + H @ self.P0.reshape(4) + 0.5 * np.einsum("qi,qi->q", dP, H)
        return W, P, (np.broadcast_to(self.A0, (F.shape[0], 2, 2, 2, 2)) if tangent else None)

    def _split(self, F):
        lin = self.linear_points(F)
        self.linear_mask = lin
        idx, full = np.flatnonzero(lin), np.flatnonzero(~lin)
        self.counts = {"linear": int(idx.size), "taylor": int(full.size)}
        for k, v in self.counts.items():
            self.totals[k] += v
        return idx, full

    def _taylor(self, method, F, full):
        """``self.taylor.<method>`` at the points ``full``; errors name the points of the batch."""
        try:
            return getattr(self.taylor, method)(F if full.size == F.shape[0] else F[full])
        except UnsupportedDeformationError:
            getattr(self.taylor, method)(F)  # re-raise with the batch's point numbers
            raise

    def _material(self, F, tangent, out):
        W, P, A = output_buffers(F.shape[0], tangent, out)
        idx, full = self._split(F)
        if full.size:
            if tangent:
                W[full], P[full], A[full] = self._taylor("evaluate", F, full)
            else:
                W[full], P[full] = self._taylor("stress", F, full)
        if idx.size:
            Wl, Pl, Al = self._linear(F[idx], tangent)
            W[idx], P[idx] = Wl, Pl
            if tangent:
                A[idx] = Al
        return W, P, A

    def cauchy(self, F: ArrayLike) -> np.ndarray:
        """Cauchy stress (n, 2, 2) in Pa: the kernel's (Taylor points) or the push-forward of the
        linear branch."""
        F, single = as_batch(F)
        sigma = np.empty((F.shape[0], 2, 2))
        idx, full = self._split(F)
        if full.size:
            sigma[full] = self._taylor("cauchy", F, full)
        if idx.size:
            sigma[idx] = push_forward(F[idx], self._linear(F[idx], False)[1], None)[0]
        return sigma[0] if single else sigma

    def spatial_tangent(self, F: ArrayLike) -> np.ndarray:
        """Spatial tangent (n, 2, 2, 2, 2) in Pa (kernel, or push-forward of the linear branch)."""
        F, single = as_batch(F)
        a = np.empty((F.shape[0], 2, 2, 2, 2))
        idx, full = self._split(F)
        if full.size:
            a[full] = self._taylor("spatial_tangent", F, full)
        if idx.size:
            _, Pl, Al = self._linear(F[idx], True)
            a[idx] = push_forward(F[idx], Pl, np.ascontiguousarray(Al))[1]
        return a[0] if single else a
