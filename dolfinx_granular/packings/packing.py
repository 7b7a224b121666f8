"""Periodic packings of disks or spheres: the microstructure of a representative volume element.

A :class:`Packing` is a rectangular periodic cell ``[0, Lx) x [0, Ly)`` holding N disks (2-D), or
a box ``[0, Lx) x [0, Ly) x [0, Lz)`` holding N spheres (3-D); the dimension is the centres'
number of columns. It is plain data with validation and a versioned ``.npz`` file format; the
mechanics live in :mod:`dolfinx_granular.laws.taylor`.
"""

from __future__ import annotations

import os
import zipfile
from typing import TYPE_CHECKING

import numpy as np

from . import portable

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

#: metres per unit of a packing's lengths: centres, radii and box are in mm, as sieve curves
#: and the generator give them (the 2-D stress does not depend on it; the 3-D stress, k_n / V
#: times length², does)
LENGTH_UNIT = 1e-3

# the file-format tag, kept from when the module was dolfinx_granular.packing: old files load
FORMAT_NAME = "dolfinx_granular.packing"
FORMAT_VERSION = 1


class PackingFileError(ValueError):
    """A packing file is missing, truncated, not a packing or of an unknown version."""


class Packing:
    """Disks (2-D) or spheres (3-D) in a periodic rectangular cell.

    Args:
        centers: (N, d) centres in mm, d = 2 or 3; points outside the cell ``[0, box)`` are
            wrapped into it.
        radii: (N,) radii in mm, > 0.
        box: (d,) cell lengths (Lx, Ly) or (Lx, Ly, Lz) in mm, > 0.

    Attributes:
        centers: (N, d) float64, wrapped into the cell.
        radii: (N,) float64.
        box: (d,) float64.

    Raises:
        ValueError: naming the offending input (shape, count, non-finite value, non-positive radius
            or box length, or a particle wide enough to touch its own periodic image).
    """

    def __init__(self, centers: ArrayLike, radii: ArrayLike, box: ArrayLike) -> None:
        centers = _as_float_array(centers, "centers")
        radii = _as_float_array(radii, "radii")
        box = _as_float_array(box, "box")
        if centers.ndim != 2 or centers.shape[1] not in (2, 3):
            raise ValueError(
                f"centers must have shape (N, 2) (disks) or (N, 3) (spheres), got {centers.shape}; "
                "pass one (x, y) or (x, y, z) row per particle"
            )
        d = centers.shape[1]
        if radii.ndim != 1 or radii.shape[0] != centers.shape[0]:
            raise ValueError(
                f"radii must have shape (N,) = ({centers.shape[0]},) to match centers, "
                f"got {radii.shape}"
            )
        if box.shape != (d,):
            names = "(Lx, Ly)" if d == 2 else "(Lx, Ly, Lz)"
            raise ValueError(
                f"box must be {names} for centres with {d} columns, got shape {box.shape}"
            )
        n = centers.shape[0]
        if n < 2:
            raise ValueError(f"a packing needs at least 2 particles, got {n}")
        for name, arr in (("centers", centers), ("radii", radii), ("box", box)):
            bad = np.flatnonzero(~np.isfinite(arr.reshape(arr.shape[0], -1)).all(axis=1))
            if bad.size:
                raise ValueError(
                    f"{name} has non-finite values (NaN or inf) at index {bad[:5].tolist()}; "
                    "every value must be a finite number"
                )
        if np.any(box <= 0.0):
            raise ValueError(f"box lengths must be > 0, got {box.tolist()}")
        bad = np.flatnonzero(radii <= 0.0)
        if bad.size:
            raise ValueError(
                f"radii must be > 0; particle(s) {bad[:5].tolist()} have radius "
                f"{radii[bad[:5]].tolist()}"
            )
        too_big = np.flatnonzero(2.0 * radii >= box.min())
        if too_big.size:
            raise ValueError(
                f"particle(s) {too_big[:5].tolist()} with radius {radii[too_big[:5]].tolist()} "
                f"would touch their own periodic image in a cell of {box.tolist()}: every "
                "diameter must be smaller than the shortest box length; enlarge the box or shrink "
                "the particles"
            )
        self.centers = np.mod(centers, box)
        # np.mod can return exactly Lx for tiny negative inputs; keep the half-open interval.
        self.centers[self.centers >= box] -= box[np.nonzero(self.centers >= box)[1]]
        self.radii = radii
        self.box = box

    @property
    def n_particles(self) -> int:
        """Number of particles N."""
        return self.radii.shape[0]

    @property
    def dim(self) -> int:
        """Spatial dimension d: 2 (disks) or 3 (spheres)."""
        return self.box.shape[0]

    @property
    def volume(self) -> float:
        """Reference cell measure V_rve = prod(box): the area Lx Ly (length², per unit
        thickness) in 2-D, the volume Lx Ly Lz (length³) in 3-D."""
        return float(np.prod(self.box))

    @property
    def area(self) -> float:
        """Reference cell area V_rve = Lx * Ly of a 2-D packing (length², per unit thickness);
        a 3-D packing has a :attr:`volume` instead."""
        if self.dim != 2:
            raise AttributeError(
                "a 3-D packing has no area; its cell measure is Packing.volume (length³)"
            )
        return self.volume

    @property
    def volume_fraction(self) -> float:
        """Share of the cell the particles cover (overlaps counted twice): sum pi r² / area
        (disks) or sum 4/3 pi r³ / volume (spheres)."""
        return float(solid_measure(self.radii, self.dim) / self.volume)

    def __repr__(self) -> str:
        return (
            f"Packing(n_particles={self.n_particles}, dim={self.dim}, box={self.box.tolist()}, "
            f"volume_fraction={self.volume_fraction:.4f})"
        )

    def __eq__(self, other) -> bool:
        if not isinstance(other, Packing):
            return NotImplemented
        return (
            np.array_equal(self.centers, other.centers)
            and np.array_equal(self.radii, other.radii)
            and np.array_equal(self.box, other.box)
        )

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the packing to ``path`` as a versioned ``.npz`` file (exact round trip)."""
        path = os.fspath(path)
        if not path.endswith(".npz"):
            # np.savez would append the suffix silently; keep the name the user asked for.
            raise ValueError(f"packing files end in .npz, got {path!r}")
        with open(path, "wb") as f:
            np.savez(
                f,
                format=np.array(FORMAT_NAME),
                version=np.array(FORMAT_VERSION),
                centers=self.centers,
                radii=self.radii,
                box=self.box,
            )

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Packing:
        """Read a packing written by :meth:`save`.

        Raises:
            PackingFileError: the file is missing, unreadable, truncated, not a packing file or of a
                newer format version. The message names the file and what is wrong.
        """
        path = os.fspath(path)
        if not os.path.isfile(path):
            raise PackingFileError(f"packing file {path!r} does not exist")
        try:
            with np.load(path, allow_pickle=False) as data:
                fields = {key: data[key] for key in data.files}
        except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError) as err:
            raise PackingFileError(
                f"{path!r} is not a readable packing file (truncated or not an .npz written by "
                f"Packing.save): {err}"
            ) from None
        if "format" not in fields or str(fields["format"]) != FORMAT_NAME:
            raise PackingFileError(
                f"{path!r} is an .npz file but not a dolfinx_granular packing (no "
                f"'format={FORMAT_NAME}' entry)"
            )
        version = int(fields.get("version", -1))
        if version != FORMAT_VERSION:
            raise PackingFileError(
                f"{path!r} has packing format version {version}; this dolfinx_granular reads "
                f"version {FORMAT_VERSION}"
            )
        missing = [k for k in ("centers", "radii", "box") if k not in fields]
        if missing:
            raise PackingFileError(f"{path!r} lacks the entries {missing}")
        try:
            return cls(fields["centers"], fields["radii"], fields["box"])
        except ValueError as err:
            raise PackingFileError(f"{path!r} holds an invalid packing: {err}") from None


def check_dimension(dim: int) -> int:
    """``dim`` as 2 or 3; a ValueError that names it otherwise."""
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 (disks) or 3 (spheres), got {dim!r}")
    return int(dim)


def solid_measure(radii: np.ndarray, dim: int) -> float:
    """Area (2-D: sum pi r²) or volume (3-D: sum 4/3 pi r³) of particles of ``radii`` (N,).

    The powers are products and the sum is correctly rounded (numpy's r**3 calls a ``pow``
    that rounds differently by CPU): the same float everywhere, which the generator needs."""
    radii = np.asarray(radii, dtype=np.float64)
    if dim == 2:
        return np.pi * portable.total(radii * radii)
    return 4.0 / 3.0 * np.pi * portable.total(radii * radii * radii)


def require_disks(packing: Packing, who: str) -> None:
    """A ValueError unless ``packing`` is 2-D: ``who`` (a law, a tool) is built for disks."""
    if packing.dim != 2:
        raise ValueError(
            f"{who} is built for disks (2-D); this packing holds spheres (dim {packing.dim}). "
            "3-D packings take TaylorRVE"
        )


def _as_float_array(value, name: str) -> np.ndarray:
    try:
        return np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be numeric array-like: {err}") from None
