"""dolfinx_granular: Taylor-RVE granular material for DOLFINx (Meier, Steinmann & Kuhl).

The microscale lives in :mod:`~dolfinx_granular.packings.packing` (disk packings) and
:mod:`~dolfinx_granular.laws.taylor` (stress and tangents, Numba kernels in
:mod:`~dolfinx_granular.laws.taylor_kernel`). The subpackages hold the layers: ``packings``,
``laws``, ``fem`` (the DOLFINx glue), ``drivers``, ``io`` and ``slope``; every public name is
imported from the package itself. DOLFINx is imported only by the modules that need it; with the
PyPI wheel of DOLFINx, importing the package loads the wheel's MPI library (below).
"""

import importlib.util as _importlib_util

# The PyPI wheel of DOLFINx (dolfinx-solver-real) loads its MPI library in `dolfinx_solver`;
# importing dolfinx or petsc4py before it fails (libmpi.so.12). Do it for the user.
if _importlib_util.find_spec("dolfinx_solver") is not None:
    import dolfinx_solver  # noqa: F401

from .drivers.protocol import LoadPathWarning, SolveFailedWarning
from .laws.contacts import ContactCandidates
from .laws.friction import FrictionalRVE, FrictionState
from .laws.levels import AdaptiveRVE, SmallStrainRVE
from .laws.protocol import HistoryLaw, HistoryState, LawEvaluationError, MaterialLaw, law_dimension
from .laws.relaxed import RelaxationError, RelaxedRVE, RelaxedState, RigidityLostError
from .laws.relaxed_friction import FrictionalRelaxedRVE, FrictionalRelaxedState
from .laws.taylor import ContactSet, TaylorRVE, UnsupportedDeformationError
from .laws.validity import OVERLAP_THRESHOLD, OverlapMonitor, OverlapSummary, ValidityWarning
from .packings.fabric import (
    anisotropy,
    anisotropy_3d,
    contact_angles,
    contact_normals,
    density_deviation,
    fabric_tensor,
    normal_density,
    normal_density_sphere,
)
from .packings.generation import NetworkStats, generate_packing, network_stats, relax_overlaps
from .packings.gsd import SieveCurve, cen_standard_sand
from .packings.packing import Packing, PackingFileError
from .packings.reference_packing import reference_packing

__all__ = [
    "Packing",
    "PackingFileError",
    "reference_packing",
    "TaylorRVE",
    "FrictionalRVE",
    "FrictionalRelaxedRVE",
    "FrictionalRelaxedState",
    "FrictionState",
    "RelaxedRVE",
    "RelaxedState",
    "RelaxationError",
    "RigidityLostError",
    "ContactSet",
    "ContactCandidates",
    "UnsupportedDeformationError",
    "LawEvaluationError",
    "MaterialLaw",
    "HistoryLaw",
    "HistoryState",
    "law_dimension",
    "SieveCurve",
    "cen_standard_sand",
    "generate_packing",
    "network_stats",
    "NetworkStats",
    "relax_overlaps",
    "contact_angles",
    "contact_normals",
    "normal_density",
    "normal_density_sphere",
    "anisotropy_3d",
    "fabric_tensor",
    "anisotropy",
    "density_deviation",
    "SmallStrainRVE",
    "AdaptiveRVE",
    "OVERLAP_THRESHOLD",
    "OverlapSummary",
    "OverlapMonitor",
    "ValidityWarning",
    "SolveFailedWarning",
    "LoadPathWarning",
]
__version__ = "0.5.0"
#: the DOLFINx releases this version supports and tests (Debian bookworm, trixie, PyPI wheel)
SUPPORTED_DOLFINX = (">=0.5.2", "<0.12")

# DOLFINx-side names, imported on first use so that `import dolfinx_granular` stays DOLFINx-free.
_LAZY = {
    "GranularMaterial": "fem.material",
    "NewtonSolver": "drivers.newton",
    "GranularProblem": "drivers.problem",
    "MaterialPoint": "drivers.material_point",
    "solve_point": "drivers.material_point",
    "PointResult": "drivers.material_point",
    "ControlError": "drivers.material_point",
    "ConvergenceTest": "drivers.convergence",
    "confined_packing": "drivers.confinement",
    "holding_traction": "drivers.confinement",
    "LoadPhase": "drivers.loading",
    "SNESArcLength": "drivers.snes_al",
    "SolveResult": "drivers.newton",
    "LoadStepper": "drivers.loading",
    "ArcLength": "drivers.arclength",
    "QuadratureMaterial": "fem.quadrature",
    "RunWriter": "io.runwriter",
    "LinearElasticMaterial": "fem.linear",
    "derivative": "fem.quadrature",
    "von_mises": "io.postprocess",
    "vector_space": "fem.compat",
    "probe": "fem.probing",
    "point_values": "fem.probing",
    "cauchy_field": "fem.fields",
    "validity_summary": "laws.validity",
    "strength_curve": "drivers.strength",
    "friction_angle": "drivers.strength",
}
__all__ += list(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
