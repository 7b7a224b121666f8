"""The slope stability benchmark of Meier, Steinmann & Kuhl (section 5) as library code.

* :mod:`~dolfinx_granular.slope.geometry`: the reconstructed slope (:class:`SlopeGeometry`) and
  its gmsh mesh;
* :mod:`~dolfinx_granular.slope.model`: the DOLFINx model (:class:`SlopeModel`), with the material
  and the solver from factories;
* :mod:`~dolfinx_granular.slope.run`: the load path, its records and files (:class:`SlopeRun`,
  :func:`run_slope`, restarts);
* :mod:`~dolfinx_granular.slope.summary`: ``summary.json`` and the figure-7 view;
* :mod:`~dolfinx_granular.slope.limit_equilibrium`: Bishop's method and the infinite slope;
* :mod:`~dolfinx_granular.slope.safety_run`: the factor of safety by strength reduction of the
  contact friction (:class:`SafetyRun`; the search in :mod:`~dolfinx_granular.slope.safety`);
* :mod:`~dolfinx_granular.slope.interrupt`: SIGINT/SIGTERM stop a run after a load step;
* :mod:`~dolfinx_granular.slope.cli`: the command line (``python -m dolfinx_granular.slope``).
"""

from .geometry import SlopeGeometry, create_mesh
from .limit_equilibrium import SlipCircle, bishop_factor_of_safety, infinite_slope_factor_of_safety
from .model import SlopeModel, granular_material, newton_solver
from .run import SlopeOptions, SlopeRun, load_restart, run_slope
from .safety_run import SafetyRun

__all__ = [
    "SlopeGeometry",
    "create_mesh",
    "SlipCircle",
    "bishop_factor_of_safety",
    "infinite_slope_factor_of_safety",
    "SlopeModel",
    "granular_material",
    "newton_solver",
    "SlopeOptions",
    "SlopeRun",
    "load_restart",
    "run_slope",
    "SafetyRun",
]
