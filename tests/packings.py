"""Small packings with known properties, built in the tests (no generator involved)."""

from dolfinx_granular import Packing

import numpy as np


def random_packing(n=40, phi=0.85, seed=0):
    """Disks at random centres: many overlapping (prestressed) contacts in random directions."""
    rng = np.random.default_rng(seed)
    radii = rng.uniform(0.35, 0.65, n)
    side = np.sqrt(np.pi * np.sum(radii**2) / phi)
    return Packing(rng.uniform(0.0, side, (n, 2)), radii, (side, side))


def square_lattice(n=6):
    """n x n unit-spaced disks of radius 1/2: exactly touching, branch vectors exact in floats."""
    xs = np.arange(n) + 0.5
    centers = np.array([(x, y) for y in xs for x in xs])
    return Packing(centers, np.full(n * n, 0.5), (float(n), float(n)))


def hex_lattice(nx=6, ny=6, overlap=1e-9):
    """Triangular lattice of unit disks (6 contacts each, isotropic fabric), radii enlarged by a
    relative ``overlap`` so that every lattice contact is active despite rounding. ``ny`` even."""
    h = np.sqrt(3.0) / 2.0
    centers = np.array(
        [((ix + 0.5 * (iy % 2)) + 0.25, (iy + 0.5) * h) for iy in range(ny) for ix in range(nx)]
    )
    return Packing(centers, np.full(nx * ny, 0.5 * (1.0 + overlap)), (float(nx), ny * h))
