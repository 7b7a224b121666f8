"""The frictional relaxed RVE: disks with contact friction and rotations in static equilibrium.

The modules follow the data, each using only those before it:

1. :mod:`.settings`: the micro solver's tolerances and the path's substep;
2. :mod:`.contact_law`: one contact's kinematics, return map and derivatives;
3. :mod:`.system`: the cell's equations (generalised forces, Jacobian, stress, mixed terms);
4. :mod:`.cell_state`: the cell at (F, w, theta) after an increment;
5. :mod:`.newton`: the micro solver; :mod:`.fire`, its fallback;
6. :mod:`.tangent`: the condensed tangent at an equilibrium;
7. :mod:`.point`: one point's increment and its quasi-static path;
8. :mod:`.state`, :mod:`.law`: :class:`FrictionalRelaxedState` and
   :class:`FrictionalRelaxedRVE`, the material.

The candidate contacts, the errors and the frictionless path's stretches come from
:mod:`~dolfinx_granular.laws.relaxed`.
"""

from .law import FrictionalRelaxedRVE
from .settings import Settings
from .state import FrictionalRelaxedState

__all__ = ["FrictionalRelaxedRVE", "FrictionalRelaxedState", "Settings"]
