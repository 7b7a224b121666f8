"""Packing: validation, wrapping and the .npz file format."""

import math
import zipfile

from dolfinx_granular import Packing, PackingFileError
from dolfinx_granular.packings.packing import FORMAT_NAME, FORMAT_VERSION, solid_measure

import numpy as np
import pytest

from helpers import random_packing


def test_attributes_and_wrapping():
    p = Packing([[-0.25, 1.5], [2.25, 0.5]], [0.4, 0.3], (2.0, 1.0))
    assert p.centers.tolist() == [[1.75, 0.5], [0.25, 0.5]]
    assert p.radii.dtype == np.float64 and p.box.tolist() == [2.0, 1.0]
    assert np.all((p.centers >= 0) & (p.centers < p.box))
    assert p.n_particles == 2 and p.area == 2.0
    assert p.volume_fraction == pytest.approx(np.pi * 0.25 / 2.0)


def test_spheres_in_a_box():
    p = Packing([[-0.25, 1.5, 0.5], [2.25, 0.5, 3.5]], [0.4, 0.3], (2.0, 1.0, 3.0))
    assert p.dim == 3 and p.centers.tolist() == [[1.75, 0.5, 0.5], [0.25, 0.5, 0.5]]
    assert p.volume == 6.0
    assert p.volume_fraction == pytest.approx(4 / 3 * np.pi * (0.4**3 + 0.3**3) / 6.0)
    with pytest.raises(AttributeError, match="Packing.volume"):
        _ = p.area
    assert "dim=3" in repr(p)


def test_a_3d_packing_round_trips(tmp_path):
    p = Packing(np.random.default_rng(0).random((5, 3)), np.full(5, 0.1), (1.0, 1.0, 1.0))
    p.save(tmp_path / "p.npz")
    assert Packing.load(tmp_path / "p.npz") == p


def test_tiny_negative_center_stays_inside_box():
    p = Packing([[-1e-20, 0.5], [0.5, 0.5]], [0.1, 0.1], (1.0, 1.0))
    assert np.all(p.centers < p.box)


@pytest.mark.parametrize(
    "centers, radii, box, words",
    [
        (np.zeros((3, 4)), np.ones(3), (5, 5), r"centers must have shape \(N, 2\) \(disks\)"),
        (np.zeros((3, 3)), np.ones(3), (5, 5), r"box must be \(Lx, Ly, Lz\)"),
        (np.zeros((3, 2)), np.ones(2), (5, 5), r"radii must have shape"),
        (np.zeros((3, 2)), np.ones(3), (5, 5, 5), r"box must be"),
        (np.zeros((1, 2)), np.ones(1), (5, 5), "at least 2 particles"),
        ([[0, 0], [np.nan, 1]], [1, 1], (5, 5), "centers has non-finite"),
        ([[0, 0], [1, 1]], [1, np.inf], (5, 5), "radii has non-finite"),
        ([[0, 0], [1, 1]], [1, 1], (5, np.nan), "box has non-finite"),
        ([[0, 0], [1, 1]], [1, 0.0], (5, 5), "radii must be > 0"),
        ([[0, 0], [1, 1]], [1, -1.0], (5, 5), "radii must be > 0"),
        ([[0, 0], [1, 1]], [1, 1], (5, 0.0), "box lengths must be > 0"),
        ([[0, 0], [1, 1]], [1, 2.5], (10, 5), "own periodic image"),
        ([[0, 0], [1, 1]], [1, "a"], (5, 5), "numeric"),
    ],
)
def test_bad_input_raises(centers, radii, box, words):
    with pytest.raises(ValueError, match=words):
        Packing(centers, radii, box)


def test_save_load_round_trip(tmp_path):
    p = random_packing(30, seed=1)
    p.save(tmp_path / "p.npz")
    q = Packing.load(tmp_path / "p.npz")
    assert q == p


def test_save_needs_npz_suffix(tmp_path):
    with pytest.raises(ValueError, match=r"\.npz"):
        random_packing(5).save(tmp_path / "p.dat")


def test_load_missing_file(tmp_path):
    with pytest.raises(PackingFileError, match="does not exist"):
        Packing.load(tmp_path / "nope.npz")


def test_load_truncated_file(tmp_path):
    random_packing(30).save(tmp_path / "p.npz")
    data = (tmp_path / "p.npz").read_bytes()
    (tmp_path / "t.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(PackingFileError, match="not a readable packing file"):
        Packing.load(tmp_path / "t.npz")


def test_load_text_file(tmp_path):
    (tmp_path / "x.npz").write_text("centers,radii\n1,2\n")
    with pytest.raises(PackingFileError, match="not a readable packing file"):
        Packing.load(tmp_path / "x.npz")


def test_load_foreign_npz(tmp_path):
    np.savez(tmp_path / "f.npz", centers=np.zeros((2, 2)), radii=np.ones(2))
    with pytest.raises(PackingFileError, match="not a dolfinx_granular packing"):
        Packing.load(tmp_path / "f.npz")


def test_load_future_version(tmp_path):
    np.savez(
        tmp_path / "v.npz",
        format=np.array(FORMAT_NAME),
        version=np.array(FORMAT_VERSION + 1),
        centers=np.zeros((2, 2)),
        radii=np.ones(2),
        box=np.ones(2) * 5,
    )
    with pytest.raises(PackingFileError, match=f"version {FORMAT_VERSION + 1}; .* reads version"):
        Packing.load(tmp_path / "v.npz")


def test_load_invalid_contents(tmp_path):
    np.savez(
        tmp_path / "v.npz",
        format=np.array(FORMAT_NAME),
        version=np.array(FORMAT_VERSION),
        centers=np.zeros((2, 2)),
        radii=np.array([1.0, -1.0]),
        box=np.ones(2) * 5,
    )
    with pytest.raises(PackingFileError, match="radii must be > 0"):
        Packing.load(tmp_path / "v.npz")


def test_load_pickled_object_array_is_refused(tmp_path):
    np.savez(
        tmp_path / "o.npz",
        format=np.array(FORMAT_NAME),
        version=np.array(FORMAT_VERSION),
        centers=np.array([None, None], dtype=object),
        radii=np.ones(2),
        box=np.ones(2),
    )
    with pytest.raises(PackingFileError, match="o.npz' is not a readable packing file"):
        Packing.load(tmp_path / "o.npz")


def test_zip_without_arrays(tmp_path):
    with zipfile.ZipFile(tmp_path / "z.npz", "w") as z:
        z.writestr("hello.txt", "hi")
    with pytest.raises(PackingFileError, match="z.npz' is an .npz file but not a dolfinx_granular"):
        Packing.load(tmp_path / "z.npz")


@pytest.mark.parametrize("dim", [2, 3])
def test_solid_measure_is_the_correctly_rounded_sum(dim):
    """Products and math.fsum: no pow and no summation order in it (the generator sizes its cell
    from it), so any order of the radii gives the same float."""
    r = np.random.default_rng(3).random(10001) + 0.25
    total = solid_measure(r, dim)
    power = r * r if dim == 2 else r * r * r
    factor = np.pi if dim == 2 else 4.0 / 3.0 * np.pi
    assert total == factor * math.fsum(power.tolist())
    assert solid_measure(r[::-1], dim) == solid_measure(np.sort(r), dim) == total
