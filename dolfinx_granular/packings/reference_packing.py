"""The slope's default RVE, shipped as package data: 700 disks of CEN standard sand, seed 0.

The file was written by the earlier generator (version 0.3.0), whose sizes, cell and jamming
search took numpy's ``pow``, ``log`` and ``exp``: those round differently by CPU (numpy's own
AVX-512 loops or the C library's) and by numpy release, and the jamming amplified that (the
packing of seed 0 differed by 5e-4 mm in the centres between an AVX-512 CPU and an AVX2 EPYC,
8e-4 of the mean radius between numpy 1.24 and 2.5). It is the packing that generator gave with
Debian bookworm's numpy 1.24 on a CPU with AVX-512 (:data:`MADE_WITH`).

Today's ``generate_packing(700, seed=0)`` gives the same bits on every CPU and numpy release,
but not these: the same contact network and rattlers, centres 2.5e-4 of the mean radius
(1e-4 mm) apart. The file is kept as it is, since the slope's documented numbers come from it;
from it the slope gives the same settlement to round-off (15 digits) on DOLFINx 0.5.2, 0.9 and
0.11.
"""

from __future__ import annotations

from importlib import resources

from .packing import Packing

#: what the shipped file holds: 700 particles of CEN standard sand, seed 0
PARTICLES = 700
SEED = 0
#: what wrote it: the earlier generator, on Debian bookworm's stack, numpy using AVX-512
MADE_WITH = {"generator": "0.3.0", "numpy": "1.24.2", "numba": "0.56.4", "avx512f": True}
_FILE = "data/sand700_seed0.npz"


def reference_packing() -> Packing:
    """The shipped packing: 700 disks of CEN standard sand, jammed and stress-free (seed 0)."""
    with resources.as_file(resources.files("dolfinx_granular").joinpath(_FILE)) as path:
        return Packing.load(path)
