"""Cell fields: the Cauchy stress as volume-weighted DG0 cell means, written to XDMF and read back
by pyvista with its components in place. Marked ``mpi`` (2 ranks: a distributed mesh)."""

import numpy as np
import pytest

dolfinx = pytest.importorskip("dolfinx")
from dolfinx_granular import TaylorRVE, generate_packing  # noqa: E402
from dolfinx_granular.fem.compat import evaluate, expression, repair_xdmf, vector_space  # noqa: E402
from dolfinx_granular.fem.fields import (  # noqa: E402
    cauchy_field,
    cauchy_output,
    cell_means,
    point_weights,
)
from dolfinx_granular.fem.material import GranularMaterial  # noqa: E402

import ufl  # noqa: E402
from dolfinx import fem, io, mesh  # noqa: E402
from mpi4py import MPI  # noqa: E402

RVE = TaylorRVE(generate_packing(70, seed=1), 2.8e7)


def loaded_material(cells=None):
    """Skewed Q1 cells (non-constant Jacobians) under a non-homogeneous compression."""
    msh = mesh.create_rectangle(
        MPI.COMM_WORLD, [[0, 0], [2, 1]], [4, 3], mesh.CellType.quadrilateral
    )
    x = msh.geometry.x
    x[:, 0] += 0.15 * np.sin(3 * x[:, 1]) * x[:, 0] ** 2
    u = fem.Function(vector_space(msh), name="displacement")
    u.interpolate(lambda x: np.stack([-0.01 * x[0] * x[1], -0.03 * x[1] ** 2 * (1 + x[0])]))
    if cells is not None:
        cells = mesh.locate_entities(msh, 2, cells)
    material = GranularMaterial(RVE, u, cells=cells)
    material.update(tangent=False)
    return material


def integral(f, msh):
    return msh.comm.allreduce(fem.assemble_scalar(fem.form(f * ufl.dx(domain=msh))))


@pytest.mark.mpi
@pytest.mark.parametrize("subdomain", [None, lambda x: x[0] <= 1.0 + 1e-9], ids=["all", "half"])
def test_cell_means_integrate_like_the_quadrature(subdomain):
    material = loaded_material(subdomain)
    sigma = material.cauchy()
    field = cauchy_field(material)
    for i, j in ((0, 0), (0, 1), (1, 0), (1, 1)):
        exact = material.integrate(sigma[:, i, j])
        assert integral(field[i, j], material.mesh) == pytest.approx(exact, rel=1e-12)
    # the plain mean of the points would not: the weights matter on these cells
    plain = material.cell_average(sigma)[:, 1, 1]
    areas = point_weights(material).reshape(-1, material.n_qp).sum(axis=1)
    plain_integral = MPI.COMM_WORLD.allreduce(float(np.sum(plain * areas)))
    assert plain_integral != pytest.approx(material.integrate(sigma[:, 1, 1]), rel=1e-6)


@pytest.mark.mpi
def test_point_weights_sum_to_the_material_area():
    material = loaded_material(lambda x: x[0] <= 1.0 + 1e-9)
    area = MPI.COMM_WORLD.allreduce(float(point_weights(material).sum()))
    assert area == pytest.approx(integral(material.indicator, material.mesh), rel=1e-13)


def test_cell_means_reject_a_wrong_number_of_rows():
    material = loaded_material()
    with pytest.raises(ValueError, match="one row per point of the material"):
        cell_means(material, np.zeros((material.n_points + 1, 2, 2)))


def _centroids_and_means(material):
    """(centres (n, 2), cell means (n, 2, 2)) of every cell, gathered on rank 0 (None elsewhere)."""
    msh = material.mesh
    centre = expression(ufl.SpatialCoordinate(msh), np.array([[0.5, 0.5]]))
    centres = evaluate(centre, msh, material.cells)  # the mean of a Q1 cell's vertices
    means = cell_means(material, material.cauchy())
    parts = msh.comm.gather((centres, means), root=0)
    if msh.comm.rank:
        return None
    return tuple(np.concatenate(p) for p in zip(*parts))


@pytest.mark.mpi
def test_xdmf_cauchy_reads_back_with_its_components_in_place(tmp_path_factory):
    pv = pytest.importorskip("pyvista")
    comm = MPI.COMM_WORLD
    folder = comm.bcast(str(tmp_path_factory.mktemp("xdmf")) if comm.rank == 0 else None)
    material = loaded_material()
    path = f"{folder}/cauchy.xdmf"
    with io.XDMFFile(comm, path, "w") as xdmf:
        xdmf.write_mesh(material.mesh)
        xdmf.write_function(cauchy_output(material), 0.0)
    expected = _centroids_and_means(material)
    if comm.rank:
        return
    repair_xdmf(path)
    reader = pv.get_reader(path)
    reader.set_active_time_value(reader.time_values[0])
    grid = reader.read()["cauchy"]
    values = np.asarray(grid.cell_data["cauchy"]).reshape(-1, 3, 3)
    centres = np.asarray(grid.cell_centers().points)[:, :2]
    order = [int(np.argmin(np.linalg.norm(expected[0] - c, axis=1))) for c in centres]
    assert sorted(order) == list(range(len(order)))  # one written cell per cell
    sigma = expected[1][order]
    np.testing.assert_allclose(values[:, :2, :2], sigma, rtol=1e-6)  # float32 on reading
    assert not values[:, 2, :].any() and not values[:, :, 2].any()


def test_xdmf_output_holds_the_field_in_its_upper_left_block():
    material = loaded_material()
    field, out = cauchy_field(material), cauchy_output(material)
    size = 4 * out.x.array.size // field.x.array.size  # 4 (as it is) or 9 (3x3 copy)
    assert size in (4, 9) and out.name == "cauchy"
    values = out.x.array.reshape(-1, 3, 3)[:, :2, :2] if size == 9 else out.x.array
    np.testing.assert_array_equal(values.reshape(-1), field.x.array)
    if size == 9:
        assert not out.x.array.reshape(-1, 3, 3)[:, 2].any()
