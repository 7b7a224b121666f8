"""dolfinx_granular: Taylor-RVE granular material for DOLFINx (Meier, Steinmann & Kuhl).

The microscale lives in :mod:`~dolfinx_granular.packing` (disk packings) and
:mod:`~dolfinx_granular.rve` (stress and tangents, Numba kernels in
:mod:`~dolfinx_granular.kernel`). DOLFINx is imported only by the modules that need it.
"""

from .packing import Packing, PackingFileError
from .rve import ContactSet, TaylorRVE, UnsupportedDeformationError

__all__ = ["Packing", "PackingFileError", "TaylorRVE", "ContactSet", "UnsupportedDeformationError"]
__version__ = "0.1.0"
