"""A packing confined: compressed isotropically to a pressure by the relaxed RVE, its disks in
static equilibrium there, as the prestressed reference packing of a boundary value problem.

A frictionless packing at zero pressure has no shear stiffness once relaxed: the first shear
strain opens half its contacts. A relaxed RVE therefore starts a boundary value problem from a
confined state: :func:`confined_packing` compresses the packing to sigma_11 = sigma_22 = -p
(the material-point driver on :class:`~dolfinx_granular.RelaxedRVE`, in geometric pressure
steps) and returns the relaxed disks in the compressed cell, a new packing whose reference state
F = I carries the stress P(I) ~ -p I (their overlaps) and is in equilibrium. The boundary value
problem holds that stress with the traction P(I) N on its free boundaries,
:func:`holding_traction` (the confinement of :class:`~dolfinx_granular.slope.SlopeOptions`).

:func:`ramp` and :func:`compress` are the stepping behind it, for studies of one point.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..laws.protocol import LawEvaluationError
from ..laws.relaxed import RelaxedRVE
from ..laws.tools import normal_stiffness as normal_stiffness_of
from ..packings.generation import MAX_PRESSURE
from ..packings.packing import Packing
from .material_point import ControlError, MaterialPoint, PointResult

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

#: pressure steps of :func:`compress`, geometric from 1 % of the pressure
RAMP = 6
#: halvings of one step of :func:`ramp` before it gives up
MAX_HALVINGS = 6


def ramp(
    point: MaterialPoint,
    values: Sequence[float],
    load: Callable[[float, np.ndarray], tuple[np.ndarray, dict]],
    max_increment: float,
    start: float = 0.0,
    partial: bool = False,
) -> Any:
    """Step ``point`` through the load parameters ``values``, committing each.

    ``load(v, F)`` gives the F guess (from the committed F) and the stress targets of parameter
    v. A step that fails (the contact network rearranges and the driver's Newton cycles, or the
    law raises) is halved, :data:`MAX_HALVINGS` times at most. Returns the committed
    :class:`~dolfinx_granular.drivers.material_point.PointResult` list; with ``partial``,
    ``(results, error)``: those up to a step that failed even so, and its error (None if none).
    """

    def advance(v):
        F, stress = load(v, point.F.copy())
        return point.step(F, stress, max_increment=max_increment)

    return _halving(values, advance, start, partial)


def _halving(values, advance, start, partial):
    """``advance(v)`` (commits, or raises and changes nothing) through ``values``, halving a
    step that fails: :func:`ramp`'s stepping. Each value gets :data:`MAX_HALVINGS` halvings in
    all, those whose midpoints were reached included (else a value that never converges, while
    every point short of it does, would be approached without end)."""
    targets, done, cuts, results = list(values), start, 0, []
    n_values = len(targets)
    while targets:
        try:
            results.append(advance(targets[0]))
        except (ControlError, LawEvaluationError) as err:
            if cuts == MAX_HALVINGS:
                if partial:
                    return results, err
                raise
            targets.insert(0, 0.5 * (done + targets[0]))
            cuts += 1
            continue
        done = targets.pop(0)
        if len(targets) < n_values:  # one of ``values`` reached: the next gets its halvings
            n_values, cuts = len(targets), 0
    return (results, None) if partial else results


def compress(
    point: MaterialPoint, pressure: float, max_increment: float, isotropic: bool = False
) -> PointResult:
    """Ramp sigma_11 = sigma_22 = -``pressure`` (Pa) in :data:`RAMP` geometric steps from 1 %
    of it; the unknowns are F11 and F22 (F12 = F21 = 0). ``max_increment`` caps the driver's
    strain steps: near jamming the relaxed tangent is nearly singular in shear. With
    ``isotropic``, F = lam I instead and the mean pressure -tr(sigma) / 2 is ramped
    (:meth:`MaterialPoint.compress`): the way to compress a packing near jamming, where mixed
    control takes the nearly free deviatoric steps. Returns the last result (committed)."""
    levels = np.geomspace(0.01, 1.0, RAMP) * pressure
    if isotropic:

        def advance(p):
            return point.compress(p, max_increment=max_increment)

        return _halving(levels, advance, 0.0, False)[-1]

    def load(p, F):
        return F, {(0, 0): -p, (1, 1): -p}

    return ramp(point, levels, load, max_increment)[-1]


def confined_packing(packing: Packing, normal_stiffness: float, pressure: float) -> Packing:
    """``packing`` compressed isotropically to ``pressure`` (p / k_n, dimensionless) and relaxed.

    Returns:
        A :class:`~dolfinx_granular.Packing` of the same disks in the compressed cell (its box
        F0 box, F0 = diag(F11, F22)), at the relaxed positions: in static equilibrium at F = I,
        with the Cauchy stress sigma_11 = sigma_22 = -p k_n (sigma_12 is what the relaxation
        leaves, a small fraction of p). Overlapping disks: give it to ``TaylorRVE`` with
        ``allow_overlaps=True``.

    Raises:
        ValueError: a pressure outside (0, 1e-2] (at larger p / k_n the overlaps pass 10 % of a
            radius: beyond the contact law's range).
        LawEvaluationError, ControlError: the packing cannot be compressed to it (e.g. it
            unjams at a pressure far below the one it was generated at); generate the packing
            at this pressure (``generate_packing(n, pressure=p)``).
    """
    kn = normal_stiffness_of(normal_stiffness)
    p = float(pressure)
    if not 0.0 < p <= MAX_PRESSURE:
        raise ValueError(f"pressure is p / k_n in (0, {MAX_PRESSURE:g}], got {pressure!r}")
    rve = RelaxedRVE(packing, kn)
    point = MaterialPoint(rve)
    result = compress(point, p * kn, max_increment=10.0 * p)
    F0 = result.F
    return Packing(rve.positions(F0, result.state)[0], packing.radii, np.diag(F0) * packing.box)


def holding_traction(material: Any) -> Any:
    """The traction t = P(I) N (Pa) that holds a material's reference stress on its boundary.

    A confined packing (:func:`confined_packing`) is in equilibrium at F = I with the stress
    P(I) ~ -p I; a free face of the body must carry t = P(I) N (N the outward unit normal of the
    reference configuration), else u = 0 is no equilibrium and the body expands. Subtract
    ``ufl.dot(t, v) * ds`` from the residual over the free faces; over the whole boundary
    (``ufl.ds``) is the same, since the rows of Dirichlet dofs are replaced by their conditions.

    Args:
        material: a :class:`~dolfinx_granular.GranularMaterial` (its
            ``reference_stress()``, P(I) (d, d) in Pa, and its mesh).

    Returns:
        The UFL vector (d,) ``P(I) N``, P(I) a :class:`dolfinx.fem.Constant`.
    """
    # (UFL and DOLFINx here only: the packings above are built without them)
    import ufl
    from dolfinx import fem

    P0 = fem.Constant(material.mesh, np.asarray(material.reference_stress(), dtype=float))
    return ufl.dot(P0, ufl.FacetNormal(material.mesh))
