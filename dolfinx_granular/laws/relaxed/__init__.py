"""The relaxed RVE: every disk in static equilibrium in the periodic cell deformed by F.

The modules follow the data, each using only those before it:

1. :mod:`.errors`, :mod:`.settings`: what can go wrong, the micro solver's tolerances;
2. :mod:`.cell`: the candidate contacts (kept complete as the disks move) and the block
   patterns of the stiffness (:mod:`.block_ldlt`: the sparse L D L^T in d x d blocks);
3. :mod:`.contact_state`: overlaps, forces, energy, rattlers and the network at (F, w);
4. :mod:`.assembly`: the stiffness d2W/dw2 into a block pattern, the mixed d2W/dw dF;
5. :mod:`.newton`: the compiled Newton loop of one point; :mod:`.fire`, its fallback;
6. :mod:`.tangent`: the stress and the condensed tangent at an equilibrium;
7. :mod:`.equilibrium`: one point relaxed at one F; :mod:`.path`: its quasi-static path from
   the committed positions;
8. :mod:`.batch`: a rank's points along their paths in one compiled call (a point that needs
   more goes the Python way of 7);
9. :mod:`.law`: :class:`RelaxedRVE` and its :class:`RelaxedState`, the material.
"""

from .equilibrium import Equilibrium, at_rest, relax
from .errors import RelaxationError, RigidityLostError
from .law import RelaxedRVE, RelaxedState
from .settings import Settings

__all__ = [
    "Equilibrium",
    "RelaxationError",
    "RelaxedRVE",
    "RelaxedState",
    "RigidityLostError",
    "Settings",
    "at_rest",
    "relax",
]
