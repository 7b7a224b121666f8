"""What defines a slope run: :class:`SlopeOptions` (stored in its restart file; importable from
:mod:`~dolfinx_granular.slope.run` too)."""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import TYPE_CHECKING, Any

from ..drivers.linear_solver import LINEAR_SOLVERS  # noqa: F401  (the CLI reads it here)
from ..drivers.linear_solver import check as check_linear_solver
from ..laws.taylor import PrestressWarning, TaylorRVE
from ..packings.generation import MAX_PRESSURE as MAX_CONFINEMENT
from .geometry import SlopeGeometry

if TYPE_CHECKING:
    from collections.abc import Mapping

    from ..laws.friction import FrictionalRVE
    from ..laws.relaxed import RelaxedRVE
    from ..laws.relaxed_friction import FrictionalRelaxedRVE
    from ..packings.packing import Packing

K_N = 2.8e7  # normal contact stiffness, N/m² (table 1 of the paper)
PHASES = ("gravity", "footing")
RVES = ("taylor", "relaxed")


@dataclasses.dataclass
class SlopeOptions:
    """What defines a slope run (stored in its restart file).

    Attributes:
        steps: nominal footing load steps after the gravity phase.
        gravity_steps: nominal steps of the gravity phase (1: the whole weight at once).
        load_factor: multiplies the footing load (2: doubled, -0.25: uplift).
        stabilise: stiffness where an RVE has no loaded contact, relative to its small-strain
            modulus (0: off).
        max_cutbacks: most halvings of one increment in a row.
        petsc_options: SNES/KSP options of the solver (e.g. the line search).
        normal_stiffness: k_n in N/m².
        geometry: the slope's dimensions and loads.
        friction: Coulomb coefficient mu of the contacts (0: frictionless, the paper's model).
        tangential_stiffness: k_t in N/m² (None: k_n where friction > 0).
        unload: after the footing phase, remove the footing load in as many steps.
        path_following: the phase taken by arc length (past a limit load), ``"footing"``
            (``True`` says the same) or ``"gravity"`` (the weight's factor is the load: the
            run ends with that phase); None (``False``): load control. The path stops once
            the load has fallen to ``unload_fraction`` of its peak, once the full load is
            carried, or after ``max_increments``; ``steps`` (``gravity_steps``) sets the
            first increment.
        allow_overlaps: accept a packing whose disks overlap far (``allow_overlaps`` of
            :class:`~dolfinx_granular.TaylorRVE`), prestressed as it is.
        rve: ``"taylor"`` (every disk follows F, the paper's model) or ``"relaxed"`` (the
            disks in static equilibrium, only with a ``confinement``):
            :class:`~dolfinx_granular.RelaxedRVE`, or with ``friction`` > 0
            :class:`~dolfinx_granular.FrictionalRelaxedRVE` (the disks also turn).
        linear_solver: ``"direct"`` (MUMPS) or ``"iterative"`` (GMRES + GAMG;
            :mod:`~dolfinx_granular.drivers.linear_solver`); path following needs the direct
            one.
        rolling_friction: rolling friction mu_r of the relaxed RVE's contacts (0: none): a
            rolling moment capped at mu_r r_eff f_n (``rolling_friction`` of
            :class:`~dolfinx_granular.FrictionalRelaxedRVE`).
        confinement: confining pressure in Pa (0: none). The packing is compressed to it and
            relaxed (:func:`~dolfinx_granular.drivers.confinement.confined_packing`), and the
            slope's boundaries other than the fixed base carry the traction P(I) n that holds
            this reference stress: the gravity and footing loads come on top of it.
        reduction: strength reduction by continuation (None: none): after the load phases,
            a ``"reduction"`` phase lowers the contact friction (and the rolling friction in
            proportion) at the whole load, geometrically from ``friction`` at t = 0 to this
            value at t = 1 (:meth:`reduced_friction`), each step an equilibrium of the slope
            from the last one; the phase fails where the slope can carry its load no more.
            Only with the frictional relaxed RVE, under load control.
        reduction_steps: nominal steps of the reduction phase (each lowers the friction by
            the same factor; cut-backs halve it).
        residual_tolerance: where Newton (or the path's corrector) no longer halves the
            residual, as it cycles while RVEs rearrange within an iterate, it accepts an
            iterate whose residual norm is at most this times the force scale (the larger of
            the internal and external force norms): an out-of-balance force tolerated, as
            geotechnical codes tolerate one, carried into the next step. 0 (default): never,
            every step ends at round-off or the energy norm.
    """

    steps: int = 20
    gravity_steps: int = 1
    load_factor: float = 1.0
    stabilise: float = 0.0
    max_cutbacks: int = 6
    petsc_options: dict = dataclasses.field(default_factory=dict)
    normal_stiffness: float = K_N
    geometry: SlopeGeometry = dataclasses.field(default_factory=SlopeGeometry)
    friction: float = 0.0
    tangential_stiffness: float | None = None
    unload: bool = False
    path_following: str | bool | None = None
    max_increments: int = 100
    unload_fraction: float = 0.9
    allow_overlaps: bool = False
    rve: str = "taylor"
    confinement: float = 0.0
    linear_solver: str = "direct"
    rolling_friction: float = 0.0
    reduction: float | None = None
    reduction_steps: int = 16
    residual_tolerance: float = 0.0

    def __post_init__(self):
        self._check_rve()
        self._check_path()
        self._check_reduction()
        check_linear_solver(self.linear_solver)
        if not (math.isfinite(self.residual_tolerance) and 0.0 <= self.residual_tolerance <= 1e-2):
            raise ValueError(
                "residual_tolerance is the out-of-balance force Newton accepts where it stalls, "
                "relative to the force scale, in [0, 0.01] (0, the default: none), got "
                f"{self.residual_tolerance!r}"
            )
        if self.path_following and self.linear_solver != "direct":
            raise ValueError(
                "path following reads the sign of det K from the LU factorisation: drop "
                "--linear-solver iterative, or --path-following"
            )
        if self.path_following and self.unload:
            raise ValueError(
                "path following ends past the limit load, where unloading has no "
                "meaning: choose --path-following or --unload"
            )

    def _check_path(self):
        # (a bool is how restart files before "gravity" stored the footing path)
        if self.path_following is True:
            self.path_following = "footing"
        elif self.path_following is False:
            self.path_following = None
        if self.path_following not in (None, *PHASES):
            raise ValueError(
                f"path_following is one of {PHASES} (the phase taken by arc length) or None, "
                f"got {self.path_following!r}"
            )

    def _check_reduction(self):
        if self.reduction is None:
            return
        if self.rve != "relaxed" or self.friction <= 0.0:
            raise ValueError(
                "strength reduction by continuation lowers the friction of the frictional "
                "relaxed RVE: give --rve relaxed --friction MU (> 0) with a --confinement"
            )
        if not 0.0 < self.reduction < self.friction:
            raise ValueError(
                f"reduction is the smallest friction of the reduction phase, in (0, friction "
                f"= {self.friction:g}), got {self.reduction!r}"
            )
        if self.path_following or self.unload:
            raise ValueError(
                "strength reduction by continuation follows the whole load under load control: "
                "drop --path-following and --unload"
            )
        if int(self.reduction_steps) != self.reduction_steps or self.reduction_steps < 1:
            raise ValueError(
                f"reduction_steps must be an integer >= 1, got {self.reduction_steps!r}"
            )

    def reduced_friction(self, t: float) -> tuple[float, float]:
        """(mu, mu_r) at t of the reduction phase: friction (reduction / friction)^t, the
        rolling friction lowered in proportion."""
        mu = self.friction * (self.reduction / self.friction) ** t
        return mu, self.rolling_friction / self.friction * mu

    def _check_rve(self):
        if self.rve not in RVES:
            raise ValueError(f"rve must be one of {RVES}, got {self.rve!r}")
        if not 0.0 <= self.confinement <= MAX_CONFINEMENT * self.normal_stiffness:
            raise ValueError(
                f"confinement is a pressure in [0, {MAX_CONFINEMENT:g} k_n] = [0, "
                f"{MAX_CONFINEMENT * self.normal_stiffness:g}] Pa, got {self.confinement!r}"
            )
        if not (math.isfinite(self.rolling_friction) and self.rolling_friction >= 0.0):
            raise ValueError(
                f"rolling_friction must be a finite number >= 0, got {self.rolling_friction!r}"
            )
        if self.rolling_friction > 0.0 and self.rve != "relaxed":
            raise ValueError(
                "rolling resistance is a setting of the relaxed RVE (the Taylor RVE's disks "
                "turn with F alike, so no rolling spring is loaded): give --rve relaxed (with "
                "--confinement), or drop --rolling-friction"
            )
        if self.rve == "relaxed" and self.confinement == 0.0:
            raise ValueError(
                "the relaxed RVE needs a confining pressure: a stress-free packing has no shear "
                "stiffness once its disks relax, with friction or without (its RVEs unjam in the "
                "first iterate of the gravity step): give --confinement P in Pa, e.g. 1e5"
            )

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)

    @property
    def path_full_load(self) -> float:
        """The load parameter lam at which the phase taken by arc length has its whole load:
        1 (the weight) for ``"gravity"``, ``load_factor`` for ``"footing"``."""
        return 1.0 if self.path_following == "gravity" else self.load_factor

    @property
    def phases(self) -> tuple:
        """The load phases: gravity, footing and (``unload``) unloading; gravity alone when
        it is taken by arc length; with a ``reduction``, gravity, the footing (unless
        ``load_factor`` is 0) and the reduction."""
        if self.path_following == "gravity":
            return PHASES[:1]
        if self.reduction is not None:  # (the weight alone: no footing phase)
            return (PHASES if self.load_factor else PHASES[:1]) + ("reduction",)
        return PHASES + (("unloading",) if self.unload else ())

    def law(
        self, packing: Packing
    ) -> TaylorRVE | FrictionalRVE | RelaxedRVE | FrictionalRelaxedRVE:
        """The material-point law: the Taylor or the relaxed RVE, with Coulomb friction if
        ``friction`` > 0; of the packing confined to ``confinement`` if > 0."""
        if self.confinement > 0.0:
            from ..drivers.confinement import confined_packing

            packing = confined_packing(
                packing, self.normal_stiffness, self.confinement / self.normal_stiffness
            )
        if self.rve == "relaxed":
            return self._relaxed_law(packing)
        with warnings.catch_warnings():
            if self.confinement > 0.0:  # (the prestress is the confinement asked for)
                warnings.simplefilter("ignore", PrestressWarning)
            return self._taylor_law(packing)

    @property
    def _kt(self) -> float:
        """The tangential stiffness k_t in N/m² of a frictional law (k_n unless given)."""
        if self.tangential_stiffness is None:
            return self.normal_stiffness
        return self.tangential_stiffness

    def _relaxed_law(self, packing: Packing) -> RelaxedRVE | FrictionalRelaxedRVE:
        if self.friction > 0.0 or self.rolling_friction > 0.0:
            from ..laws.relaxed_friction import FrictionalRelaxedRVE

            return FrictionalRelaxedRVE(
                packing, self.normal_stiffness, self._kt, self.friction,
                rolling_friction=self.rolling_friction,
            )  # fmt: skip
        from ..laws.relaxed import RelaxedRVE

        return RelaxedRVE(packing, self.normal_stiffness)

    def _taylor_law(self, packing: Packing) -> TaylorRVE | FrictionalRVE:
        overlaps = self.allow_overlaps or self.confinement > 0.0
        if self.friction > 0.0:
            from ..laws.friction import FrictionalRVE

            return FrictionalRVE(
                packing,
                normal_stiffness=self.normal_stiffness,
                tangential_stiffness=self._kt,
                friction=self.friction,
                allow_overlaps=overlaps,
            )
        return TaylorRVE(packing, self.normal_stiffness, allow_overlaps=overlaps)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> SlopeOptions:
        d = dict(d)
        d["geometry"] = SlopeGeometry(**d["geometry"])
        return cls(**d)
