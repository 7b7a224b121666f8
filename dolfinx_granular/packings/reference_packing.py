"""The slope's default RVE, shipped as package data so that every stack starts from one packing.

``generate_packing(700, seed=0)`` is deterministic on one stack, but not bit-identical across
them: numpy's ``pow`` and ``log`` differ in the last bit between numpy releases (the sampled
diameters of seed 0 differ by 4e-16 mm between numpy 1.24 and 2.x) and the jamming dynamics
amplify that (seed 0: centres 8e-4 of the mean radius apart between numpy 1.24 and 2.5, the
settlement in the 7th digit). The shipped file is that packing as Debian bookworm's stack
(numpy 1.24, numba 0.56) generates it on a CPU with AVX-512, where numpy 1.24 takes its own
AVX-512 float64 ``exp`` and ``log``; on a CPU without it numpy calls the C library's, and the
packing differs again (centres up to 5e-4 mm apart on an AVX2 EPYC). From the file the slope
gives the same settlement to the last digit on DOLFINx 0.5.2, 0.9 and 0.11.
"""

from __future__ import annotations

from importlib import resources

from .packing import Packing

#: what the shipped file holds: ``generate_packing(PARTICLES, seed=SEED)`` (CEN standard sand)
PARTICLES = 700
SEED = 0
#: the stack that wrote it (Debian bookworm, numpy using AVX-512), where ``generate_packing``
#: reproduces it exactly
MADE_WITH = {"numpy": "1.24.2", "numba": "0.56.4", "avx512f": True}
_FILE = "data/sand700_seed0.npz"


def reference_packing() -> Packing:
    """The shipped packing: 700 disks of CEN standard sand, jammed and stress-free (seed 0)."""
    with resources.as_file(resources.files("dolfinx_granular").joinpath(_FILE)) as path:
        return Packing.load(path)
