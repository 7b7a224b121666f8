"""Any dimension in the DOLFINx glue: a 3-D law written in NumPy on hexahedra and tetrahedra,
solved with the README's API (GranularMaterial + NewtonSolver), converges quadratically and
matches the same law written in UFL; a law of another dimension than the mesh is refused; one
flattening rule for any d."""

from dolfinx_granular import GranularMaterial, NewtonSolver, TaylorRVE, generate_packing
from dolfinx_granular.fem import compat as dfx
from dolfinx_granular.fem.fields import cauchy_field, cell_means
from dolfinx_granular.fem.probing import probe
from dolfinx_granular.fem.quadrature import QuadratureMaterial, flatten, unflatten
from dolfinx_granular.laws.protocol import MaterialLaw, law_dimension

import numpy as np
import pytest
import ufl
from dolfinx import fem, mesh
from mpi4py import MPI

LAM, MU = 2.0e6, 1.0e6  # Lamé constants (Pa)


class NeoHookeNumPy:
    """Compressible neo-Hookean law on F (n, 3, 3):
    W = mu/2 (tr C - 3) - mu ln J + lam/2 (ln J)^2, P = mu (F - F^-T) + lam ln J F^-T (Pa)."""

    dim = 3

    def __init__(self, lam=LAM, mu=MU):
        self.lam, self.mu = lam, mu

    def _parts(self, F):
        F = np.asarray(F, dtype=float)
        Fi = np.linalg.inv(F)
        lnJ = np.log(np.linalg.det(F))
        W = 0.5 * self.mu * (np.einsum("qij,qij->q", F, F) - 3) - self.mu * lnJ
        W += 0.5 * self.lam * lnJ**2
        FiT = Fi.transpose(0, 2, 1)
        P = self.mu * (F - FiT) + self.lam * lnJ[:, None, None] * FiT
        return F, Fi, lnJ, W, P

    def _tangent(self, Fi, lnJ):
        # dP_aB/dF_cD = mu d_ac d_BD + (mu - lam ln J) Fi_Da Fi_Bc + lam Fi_Ba Fi_Dc
        I = np.eye(3)
        A = self.mu * np.einsum("ac,BD->aBcD", I, I)[None]
        A = A + np.einsum("q,qDa,qBc->qaBcD", self.mu - self.lam * lnJ, Fi, Fi)
        return A + self.lam * np.einsum("qBa,qDc->qaBcD", Fi, Fi)

    def evaluate(self, F, out=None):
        F, Fi, lnJ, W, P = self._parts(F)
        A = self._tangent(Fi, lnJ)
        if out is None:
            return W, P, A
        out[0][...], out[1][...], out[2][...] = W, P, A
        return out

    def stress(self, F, out=None):
        _, _, _, W, P = self._parts(F)
        if out is None:
            return W, P
        out[0][...], out[1][...] = W, P
        return out[0], out[1]

    def cauchy(self, F):
        F, _, _, _, P = self._parts(F)
        return np.einsum("qaB,qbB->qab", P, F) / np.linalg.det(F)[:, None, None]

    def spatial_tangent(self, F):
        F, Fi, lnJ, _, _ = self._parts(F)
        A = self._tangent(Fi, lnJ)
        J = np.linalg.det(F)[:, None, None, None, None]
        return np.einsum("qbB,qdD,qaBcD->qabcd", F, F, A) / J

    def small_strain_modulus(self):
        I = np.eye(3)
        return self.lam * np.einsum("ab,cd->abcd", I, I) + self.mu * (
            np.einsum("ac,bd->abcd", I, I) + np.einsum("ad,bc->abcd", I, I)
        )


class NeoHookeUFL(QuadratureMaterial):
    """The same law written in UFL (the forms carry it; ufl.derivative gives the Jacobian)."""

    def __init__(self, u, lam=LAM, mu=MU, quadrature_degree=2):
        super().__init__(u, quadrature_degree)
        self.lam, self.mu = lam, mu

    def stress(self):
        F = ufl.variable(ufl.Identity(self.dim) + ufl.grad(self.u))
        lnJ = ufl.ln(ufl.det(F))
        W = self.mu / 2 * (ufl.tr(F.T * F) - 3) - self.mu * lnJ + self.lam / 2 * lnJ**2
        return ufl.diff(W, F)

    def update(self, tangent=True):
        """Nothing to evaluate: the forms carry the law."""


def _box(cell):
    cell_type = getattr(mesh.CellType, cell)
    return mesh.create_box(MPI.COMM_WORLD, [[0, 0, 0], [1, 1, 1]], [2, 2, 2], cell_type)


def _problem(msh, make_material, prefix):
    """Clamped at z = 0, the top face z = 1 moved by (0.05, 0.02, -0.1) m in one solve."""
    V = dfx.vector_space(msh)
    u, v = fem.Function(V), ufl.TestFunction(V)
    material = make_material(u)
    fdim = msh.topology.dim - 1
    bcs = []
    for z, shift in ((0.0, (0.0, 0.0, 0.0)), (1.0, (0.05, 0.02, -0.1))):
        facets = mesh.locate_entities_boundary(msh, fdim, lambda x, z=z: np.isclose(x[2], z))
        dofs = fem.locate_dofs_topological(V, fdim, facets)
        bcs.append(fem.dirichletbc(np.array(shift, dtype=float), dofs, V))
    residual = material.residual_form(v)
    jacobian = material.jacobian_form(ufl.TrialFunction(V), v)
    solver = NewtonSolver(residual, jacobian, u, bcs, material, prefix=prefix)
    result = solver.solve()
    solver.destroy()
    return result, u, material


@pytest.mark.mpi
@pytest.mark.parametrize("cell", ["hexahedron", "tetrahedron"])
def test_numpy_law_in_3d_converges_quadratically_and_matches_ufl(cell):
    msh = _box(cell)
    law = NeoHookeNumPy()
    assert isinstance(law, MaterialLaw) and law_dimension(law) == 3
    result, u, material = _problem(msh, lambda u: GranularMaterial(law, u), f"nh3_{cell}_")
    assert result.converged and material.P.function_space.mesh is msh
    assert material.A.ufl_shape == (9, 9) and material.F.shape == (material.n_points, 3, 3)
    # quadratic: each residual (relative to the first) at most a modest multiple of the square
    # of the one before, while above round-off
    r = np.array([h[1] for h in result.history])
    e = r / r[0]
    pairs = [(a, b) for a, b in zip(e[:-1], e[1:]) if 1e-12 < b and a < 1e-1]
    assert pairs, e
    assert all(b <= 10.0 * a**2 for a, b in pairs), e
    ref, u_ufl, _ = _problem(msh, NeoHookeUFL, f"nh3_ufl_{cell}_")
    assert ref.converged
    np.testing.assert_allclose(u.x.array, u_ufl.x.array, rtol=0, atol=1e-10)
    assert MPI.COMM_WORLD.allreduce(np.abs(u.x.array).max(), op=MPI.MAX) > 0.05  # it deformed
    _check_outputs(material, law)


def _check_outputs(material, law):
    """Probes and cell fields of a 3-D material: (3, 3) values of the law at the point found."""
    target = np.array([0.3, 0.6, 0.7])
    found = probe(material, target)
    assert found.F.shape == found.P.shape == found.cauchy.shape == (1, 3, 3)
    assert found.distance[0] == pytest.approx(np.linalg.norm(found.points[0] - target))
    np.testing.assert_allclose(found.P, law.stress(found.F)[1], rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(found.cauchy, law.cauchy(found.F), rtol=1e-12, atol=1e-6)
    field = cauchy_field(material)
    assert field.ufl_shape == (3, 3)
    dofs = dfx.cell_dofs(field.function_space.dofmap)[material.cells, 0]
    means = cell_means(material, material.cauchy()).reshape(-1, 9)
    np.testing.assert_allclose(field.x.array.reshape(-1, 9)[dofs], means, rtol=1e-14)


def test_a_law_of_another_dimension_than_the_mesh_is_refused():
    hexes = _box("hexahedron")
    u3 = fem.Function(dfx.vector_space(hexes))
    with pytest.raises(ValueError, match="2-D law .* mesh is 3-D"):
        GranularMaterial(TaylorRVE(generate_packing(70, seed=1), normal_stiffness=2.8e7), u3)
    square = mesh.create_unit_square(MPI.COMM_WORLD, 2, 2, mesh.CellType.quadrilateral)
    u2 = fem.Function(dfx.vector_space(square))
    with pytest.raises(ValueError, match="3-D law .* mesh is 2-D"):
        GranularMaterial(NeoHookeNumPy(), u2)


def test_law_dimension_is_read_from_the_modulus():
    class NoDim(NeoHookeNumPy):
        dim = None

    assert law_dimension(NoDim()) == 3
    assert law_dimension(TaylorRVE(generate_packing(70, seed=1), normal_stiffness=2.8e7)) == 2


@pytest.mark.parametrize("d", [2, 3])
def test_one_flattening_rule_for_any_dimension(d):
    """flatten is row-major (t[d*a + b] = T[a, b]) and unflatten its inverse, in UFL."""
    T = ufl.as_matrix([[float(10 * a + b) for b in range(d)] for a in range(d)])
    t = flatten(T)
    assert t.ufl_shape == (d * d,)
    for a in range(d):
        for b in range(d):
            assert float(t[d * a + b]) == 10 * a + b
            assert float(unflatten(t)[a, b]) == 10 * a + b
