"""The Taylor RVE material: energy, stresses and tangents of a disk packing under a macroscopic F.

Equation numbers refer to Meier, Steinmann & Kuhl, *Towards multiscale computation of confined
granular media: contact forces, stresses and tangent operators*. Every particle
follows the macroscopic deformation gradient (x = F X, eq. 1); disks in contact (overlap eps >= 0,
eq. 3) interact through linear normal springs (eq. 4). Each physical contact is counted once, which
equals the paper's double sum over i != j with its factor 1/2.

The same class serves disks in 2-D and spheres in 3-D: the packing's dimension d decides, and
every formula holds with its indices running over d (the 3-D kernel is
:mod:`~dolfinx_granular.laws.taylor_kernel_3d`).

Units: ``normal_stiffness`` k_n in N/m² in 2-D (force per unit overlap per unit thickness) and in
N/m in 3-D (force per unit overlap); the packing's lengths in mm
(:data:`~dolfinx_granular.packings.packing.LENGTH_UNIT`); energy density W and all stresses and
tangents in Pa. The 2-D Taylor stress does not depend on the packing's absolute size; the 3-D
one scales with 1 / size (k_n / V times length²: a packing of 1 mm spheres at k_n = 1e5 N/m
has moduli of the order of 1e8 Pa).
"""

from __future__ import annotations

import os
import sys
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..packings.packing import LENGTH_UNIT, Packing
from . import taylor_kernel, taylor_kernel_3d, tools, validity
from .contacts import ContactCandidates
from .tools import UnsupportedDeformationError, as_batch, to_float, unsupported_deformation

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

__all__ = [
    "MAX_REFERENCE_OVERLAP",
    "PRESTRESS_WARNING",
    "ContactSet",
    "PrestressWarning",
    "TaylorRVE",
    "UnsupportedDeformationError",  # defined in lawtools, the laws' shared helpers
]


#: |P(I)| / |C| above which the reference state counts as prestressed (a warning); a generated,
#: stress-free packing has ~1e-11 (its contacts overlap by 1e-11 of the mean diameter)
PRESTRESS_WARNING = 1e-6
#: largest reference overlap / (r_i + r_j) accepted without ``allow_overlaps``: beyond it the
#: packing is not a contact configuration but overlapping disks (linear springs far out of range)
MAX_REFERENCE_OVERLAP = 0.05


class PrestressWarning(UserWarning):
    """The packing's reference state (F = I) carries stress: its disks overlap."""


@dataclass(frozen=True)
class ContactSet:
    """Active contacts of one RVE at one F (for force networks and diagnostics).

    Attributes:
        pairs: (m, 2) particle indices i, j.
        shift: (m, d) periodic image offset of j, in cells.
        branch: (m, d) current branch vectors l = F L (length).
        overlap: (m,) eps >= 0 (length).
        force: (m,) normal force magnitude k_n * eps (N per unit thickness in 2-D, N in 3-D).
        tangential: (m,) for a frictional relaxed RVE, the tangential force on j along
            t = (-n_y, n_x), n the unit branch vector from i to j (N per unit thickness);
            None for the other laws.
        sliding: (m,) bool, True where the contact slips; None for the other laws.
        rolling: (m,) for a frictional relaxed RVE, the rolling moment (couple) on j,
            counter-clockwise positive (N m per unit thickness; i feels the opposite; zero
            without rolling resistance); None for the other laws.
    """

    pairs: np.ndarray
    shift: np.ndarray
    branch: np.ndarray
    overlap: np.ndarray
    force: np.ndarray
    tangential: np.ndarray | None = None
    sliding: np.ndarray | None = None
    rolling: np.ndarray | None = None


def _user_stacklevel() -> int:
    """``stacklevel`` for a ``warnings.warn`` in the caller of this function that names the first
    line outside this package: the user's, however many of the package's own calls lie between
    (a FrictionalRVE builds its TaylorRVE; as pandas' find_stack_level)."""
    package = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep
    frame, level = sys._getframe(1), 1  # the caller of this function is stacklevel 1
    while frame is not None and os.path.abspath(frame.f_code.co_filename).startswith(package):
        frame, level = frame.f_back, level + 1
    return level


class TaylorRVE:
    """Taylor-assumption RVE of a periodic packing of disks (2-D) or spheres (3-D) with linear
    normal contact springs.

    Args:
        packing: the reference microstructure; its ``dim`` is the RVE's.
        normal_stiffness: k_n > 0, in N/m² in 2-D and N/m in 3-D.
        min_stretch: smallest singular value of F that is supported, 0 < min_stretch <= 1.
            Candidate contacts are all pairs that can touch at such an F; a smaller bound costs
            more memory and set-up time but not evaluation time at moderate strain.
        allow_overlaps: accept a packing whose disks overlap by more than
            ``MAX_REFERENCE_OVERLAP`` of their radius sum at F = I (otherwise a ValueError).

    The reference state is explicit: :attr:`prestress` is P(I). A packing whose P(I) exceeds
    ``PRESTRESS_WARNING`` of its modulus (overlapping disks) gives a :class:`PrestressWarning`;
    :func:`~dolfinx_granular.relax_overlaps` makes it stress-free.

    Every ``F`` argument is an array of shape (n, d, d) (or (d, d) for a single point); an F that
    is non-finite, has det F <= 0 or a singular value below ``min_stretch`` raises
    :class:`UnsupportedDeformationError` naming the points.

    Attributes:
        candidates: the packing's :class:`~dolfinx_granular.ContactCandidates` at
            ``min_stretch`` (shared, read-only: the other laws and levels build on it).
    """

    def __init__(
        self,
        packing: Packing,
        normal_stiffness: float,
        min_stretch: float = 0.5,
        allow_overlaps: bool = False,
    ) -> None:
        if not isinstance(packing, Packing):
            raise TypeError(
                f"packing must be a dolfinx_granular.Packing, got {type(packing).__name__}"
            )
        k = tools.normal_stiffness(normal_stiffness)
        s = to_float(min_stretch, "min_stretch")
        if not (0.0 < s <= 1.0):
            raise ValueError(f"min_stretch must lie in (0, 1], got {min_stretch!r}")
        self.packing = packing
        self.normal_stiffness = k
        self.min_stretch = s
        self.dim = packing.dim
        self.candidates = ContactCandidates.from_packing(packing, s)
        # k_n / V in N/m² / length² (2-D) and N/m / m / length² (3-D: V in m³, lengths in mm)
        self._K = k / (packing.volume * LENGTH_UNIT ** (packing.dim - 2))
        self._check_reference(bool(allow_overlaps))

    def _check_reference(self, allow_overlaps):
        """Refuse far-overlapping particles, report the prestress P(I) of overlapping ones."""
        _, eps = self.candidates.overlaps(np.eye(self.dim))
        worst = float((eps / self.candidates.radius_sum).max()) if eps.size else 0.0
        self.max_reference_overlap = max(worst, 0.0)
        # relax_overlaps is for disks; a sphere packing is made stress-free by generating it
        fix = (
            "dolfinx_granular.relax_overlaps(packing) (command line: python -m "
            "dolfinx_granular relax IN.npz -o OUT.npz)"
            if self.dim == 2
            else "generate_packing(n, dim=3), whose spheres touch without stress,"
        )
        kind = "disks" if self.dim == 2 else "spheres"
        if worst > MAX_REFERENCE_OVERLAP and not allow_overlaps:
            raise ValueError(
                f"the packing's {kind} overlap by up to {100 * worst:.3g} % of their radius sums "
                f"at F = I (more than {100 * MAX_REFERENCE_OVERLAP:g} %): that is no contact "
                f"network but overlapping {kind}. Make it stress-free first ({fix} makes one), "
                "or use it as it is with allow_overlaps=True (the slope: --allow-overlaps)"
            )
        self.prestress = self.stress(np.eye(self.dim))[1]
        if self.prestress_ratio > PRESTRESS_WARNING:
            warnings.warn(
                f"the reference state is prestressed: P(I) = {self.prestress.round(1).tolist()} Pa "
                f"({self.prestress_ratio:.2g} of the modulus), from {kind} overlapping by up to "
                f"{100 * self.max_reference_overlap:.3g} % at F = I; {fix} makes it stress-free",
                PrestressWarning,
                stacklevel=_user_stacklevel(),
            )

    @property
    def prestress_ratio(self) -> float:
        """|P(I)| / |C| (Frobenius norms; C the eq. 15 modulus): the strain that would carry the
        reference stress. ~1e-11 for a generated packing."""
        C = np.linalg.norm(self.small_strain_modulus())
        return float(np.linalg.norm(self.prestress) / C) if C > 0 else 0.0

    @property
    def n_candidates(self) -> int:
        """Number of candidate contacts (pairs that can touch at a supported F)."""
        return len(self.candidates)

    # -- batch evaluation -------------------------------------------------------------------------

    def _run(self, F, spatial, tangent, out=None):
        F, single = as_batch(F, self.dim)
        n = F.shape[0]
        W, P, A = tools.output_buffers(n, tangent, out, self.dim)
        if A is None:
            A = np.empty((0,) + (self.dim,) * 4)
        status = np.empty(n, dtype=np.int8)
        c = self.candidates
        args = (c.radius_sum, c.ratio, self._K, self.min_stretch, spatial, tangent, W, P, A)
        if self.dim == 2:
            taylor_kernel.evaluate_batch(F, *c.components, *args, status)
        else:
            taylor_kernel_3d.evaluate_batch(F, *c.components, *args, status)
        if status.any():
            raise unsupported_deformation(F, status, self.min_stretch)
        if single:
            return W[0], P[0], (A[0] if tangent else None)
        return W, P, (A if tangent else None)

    def evaluate(
        self, F: ArrayLike, out: tuple | None = None
    ) -> tuple[np.ndarray | float, np.ndarray, np.ndarray]:
        """Energy, first Piola stress and its tangent.

        Args:
            F: (n, d, d) deformation gradients.
            out: optional ``(W, P, A)`` C-contiguous arrays of shapes (n,), (n, d, d),
                (n, d, d, d, d) to write into (e.g. views of DOLFINx quadrature data).

        Returns:
            ``(W, P, A)``: W (n,) energy density (eq. 7), P (n, d, d) first Piola stress (eq. 10),
            A (n, d, d, d, d) with ``A[q, a, b, c, d] = dP_ab / dF_cd`` (eqs. 12-13), in Pa.
        """
        return self._run(F, spatial=False, tangent=True, out=out)

    def stress(
        self, F: ArrayLike, out: tuple | None = None
    ) -> tuple[np.ndarray | float, np.ndarray]:
        """Energy and first Piola stress, no tangent (cheaper): ``(W (n,), P (n, d, d))``."""
        W, P, _ = self._run(F, spatial=False, tangent=False, out=out)
        return W, P

    def energy(self, F: ArrayLike) -> np.ndarray | float:
        """Energy density W (n,) per reference area (2-D) or volume (3-D) (eq. 7), in Pa."""
        return self.stress(F)[0]

    def cauchy(self, F: ArrayLike) -> np.ndarray:
        """Cauchy stress sigma (n, d, d) (eq. 11), in Pa; symmetric by construction."""
        return self._run(F, spatial=True, tangent=False)[1]

    def spatial_tangent(self, F: ArrayLike) -> np.ndarray:
        """Spatial tangent a (n, d, d, d, d) of eq. 14, in Pa: (1/J) F_bB F_dD A_aBcD."""
        return self._run(F, spatial=True, tangent=True)[2]

    def small_strain_modulus(self) -> np.ndarray:
        """Linear modulus C (d, d, d, d) of eq. 15 over the contacts active at F = I, in Pa.

        C_abcd = (k_n / V) sum_c |L|² n_a n_b n_c n_d. It equals A(I) when the reference contacts
        are exactly touching (no prestress).
        """
        L = self.candidates.branch[self.candidates.overlaps(np.eye(self.dim))[1] >= 0.0]
        w = self._K / np.einsum("ci,ci->c", L, L)
        return np.einsum("m,ma,mb,mc,md->abcd", w, L, L, L, L)

    def contacts(self, F: ArrayLike) -> ContactSet:
        """Active contacts at a single F (d, d): pairs, current branch vectors, overlaps,
        forces."""
        F = np.asarray(F, dtype=np.float64)
        d = self.dim
        if F.shape != (d, d):
            raise ValueError(f"contacts() takes one F of shape ({d}, {d}), got {F.shape}")
        self.stress(F)  # validates F with the kernel's own rule
        l, eps = self.candidates.overlaps(F)
        on = eps >= 0.0
        return ContactSet(
            pairs=self.candidates.pairs[on],
            shift=self.candidates.shift[on],
            branch=l[on],
            overlap=eps[on],
            force=self.normal_stiffness * eps[on],
        )

    def overlap_statistics(self, F: ArrayLike) -> validity.OverlapStatistics:
        """The validity measure at F (n, d, d) (or (d, d): scalars): ``(max_ratio (n,),
        contacts (n,))``, the largest overlap of an active contact over the smaller radius of its
        two disks, and the number of active contacts (:mod:`~dolfinx_granular.laws.validity`)."""
        return validity.overlap_statistics(self, F)
