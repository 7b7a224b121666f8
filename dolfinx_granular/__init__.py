"""dolfinx_granular: Taylor-RVE granular material for DOLFINx (Meier, Steinmann & Kuhl).

The microscale lives in :mod:`~dolfinx_granular.packing` (disk packings) and
:mod:`~dolfinx_granular.rve` (stress and tangents, Numba kernels in
:mod:`~dolfinx_granular.kernel`). DOLFINx is imported only by the modules that need it; with
the PyPI wheel of DOLFINx, importing the package loads the wheel's MPI library (below).
"""

import importlib.util as _importlib_util

# The PyPI wheel of DOLFINx (dolfinx-solver-real) loads its MPI library in `dolfinx_solver`;
# importing dolfinx or petsc4py before it fails (libmpi.so.12). Do it for the user.
if _importlib_util.find_spec("dolfinx_solver") is not None:
    import dolfinx_solver  # noqa: F401

from .contacts import ContactCandidates
from .fabric import anisotropy, contact_angles, density_deviation, fabric_tensor, normal_density
from .friction import FrictionalRVE, FrictionState
from .generation import NetworkStats, generate_packing, network_stats, relax_overlaps
from .gsd import SieveCurve, cen_standard_sand
from .law import HistoryLaw, HistoryState, LawEvaluationError, MaterialLaw, law_dimension
from .levels import AdaptiveRVE, SmallStrainRVE
from .packing import Packing, PackingFileError
from .rve import ContactSet, TaylorRVE, UnsupportedDeformationError
from .validity import OVERLAP_THRESHOLD, OverlapMonitor, OverlapSummary, ValidityWarning

__all__ = [
    "Packing",
    "PackingFileError",
    "TaylorRVE",
    "FrictionalRVE",
    "FrictionState",
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
    "normal_density",
    "fabric_tensor",
    "anisotropy",
    "density_deviation",
    "SmallStrainRVE",
    "AdaptiveRVE",
    "OVERLAP_THRESHOLD",
    "OverlapSummary",
    "OverlapMonitor",
    "ValidityWarning",
]
__version__ = "0.2.0"
#: the DOLFINx releases this version supports and tests (Debian bookworm, trixie, PyPI wheel)
SUPPORTED_DOLFINX = (">=0.5.2", "<0.12")

# DOLFINx-side names, imported on first use so that `import dolfinx_granular` stays DOLFINx-free.
_LAZY = {
    "GranularMaterial": "material",
    "NewtonSolver": "solver",
    "GranularProblem": "problem",
    "MaterialPoint": "material_point",
    "solve_point": "material_point",
    "PointResult": "material_point",
    "ControlError": "material_point",
    "ConvergenceTest": "convergence",
    "LoadPhase": "loading",
    "SNESArcLength": "snes_al",
    "SolveResult": "solver",
    "LoadStepper": "loading",
    "ArcLength": "arclength",
    "QuadratureMaterial": "quadrature",
    "RunWriter": "runwriter",
    "LinearElasticMaterial": "linear",
    "derivative": "quadrature",
    "von_mises": "postprocess",
    "vector_space": "_dolfinx",
    "probe": "probing",
    "point_values": "probing",
    "cauchy_field": "fields",
    "validity_summary": "validity",
}
__all__ += list(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
