"""What the tests share: the scripts they run (demos imported as modules, the slope's command
line, serially or under MPI, and its outputs), small packings with known properties built without
the generator, and the granular column the solver, loading and model-level tests solve.

Benchmark scripts need nothing here: pytest puts ``benchmarks/`` on the path (``pythonpath`` in
pyproject.toml), so tests ``import kernel``."""

import csv
import importlib
import importlib.util
import json
import os
import subprocess
import sys
from collections import namedtuple

from dolfinx_granular import Packing
from dolfinx_granular.laws.relaxed.errors import CellFloats, RelaxationError, RigidityLostError

import numpy as np

# -- scripts ---------------------------------------------------------------------------------------

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SLOPE = os.path.join(ROOT, "demos", "slope.py")
# mpirun as root (CI containers) needs these
#: fields of the slope's XDMF per load step: displacement, von Mises, Cauchy stress
XDMF_FIELDS = 3
MPI_ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")


def load_demo(name):
    """The module ``demos/<name>.py``."""
    spec = importlib.util.spec_from_file_location(name, os.path.join(ROOT, "demos", f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # (dataclasses look their module up there)
    spec.loader.exec_module(module)
    return module


def slope_command(*args, ranks=1):
    """``python demos/slope.py *args``, under MPI with ``ranks`` processes if ranks > 1 (with the
    launcher of this Python's MPI; the test fails without one)."""
    cmd = [sys.executable, SLOPE, *map(str, args)]
    if ranks > 1:
        from dolfinx_granular.fem.compat import mpi_command

        launcher = mpi_command(ranks)
        assert launcher is not None, "no MPI launcher (mpiexec/mpirun) found"
        cmd = [*launcher, *cmd]
    return cmd


def is_png(path):
    """True if the file ``path`` starts with the PNG signature."""
    with open(path, "rb") as f:
        return f.read(8) == b"\x89PNG\r\n\x1a\n"


def run_slope_demo(out, *args, ranks=1, timeout=600, check=True):
    """Run ``python demos/slope.py *args --out out`` (no ``--out`` if ``out`` is None) from the
    checkout's root, under MPI with ``ranks`` processes if ranks > 1, with ``MPI_ENV``.

    Returns ``(proc, summary)``: the ``subprocess.CompletedProcess`` (text ``stdout`` and
    ``stderr``, ``returncode``) and the run's ``summary.json`` as a dict (None if ``out`` is None
    or the run wrote none). ``check``: assert that the run exited with status 0."""
    extra = () if out is None else ("--out", out)
    proc = subprocess.run(
        slope_command(*args, *extra, ranks=ranks),
        cwd=ROOT,
        env=MPI_ENV,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    if check:
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    summary = None
    if out is not None and os.path.isfile(os.path.join(out, "summary.json")):
        with open(os.path.join(out, "summary.json")) as f:
            summary = json.load(f)
    return proc, summary


def assert_user_error(proc, *words, mpirun=False):
    """``proc`` (a finished slope run) failed as bad input: exit status 2, no traceback, one line
    ``error: ...`` on stderr that contains every one of ``words``; returns that line."""
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2, out[-3000:]
    assert "Traceback" not in out, out[-3000:]
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and not ln.startswith("INFO")]
    if mpirun:  # mpirun adds its own notice about the exit status
        lines = [ln for ln in lines if ln.startswith("error: ")]
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr[-3000:]
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def read_outputs(out):
    """The slope demo's ``summary.json`` (a dict) and ``convergence.csv`` (a list of row dicts)
    in the folder ``out``."""
    with open(os.path.join(out, "summary.json")) as f:
        summary = json.load(f)
    with open(os.path.join(out, "convergence.csv")) as f:
        rows = list(csv.DictReader(f))
    return summary, rows


# -- packings --------------------------------------------------------------------------------------


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


def random_spheres(n=40, phi=0.6, seed=0):
    """Spheres at random centres in a box of three different sides: many overlapping
    (prestressed) contacts in random directions."""
    rng = np.random.default_rng(seed)
    radii = rng.uniform(0.35, 0.65, n)
    side = (4.0 / 3.0 * np.pi * np.sum(radii**3) / phi / (1.1 * 0.9)) ** (1.0 / 3.0)
    box = np.array([side, 1.1 * side, 0.9 * side])
    return Packing(rng.uniform(0.0, 1.0, (n, 3)) * box, radii, box)


def fcc_lattice(n=3, overlap=1e-9):
    """Face-centred cubic lattice of n^3 cubic cells (4 n^3 spheres, 12 contacts each) with
    neighbour distance 1, radii enlarged by a relative ``overlap`` so that every lattice contact
    is active despite rounding."""
    s = np.sqrt(2.0)  # the cubic cell's side
    basis = np.array([[0, 0, 0], [0.5, 0.5, 0], [0.5, 0, 0.5], [0, 0.5, 0.5]]) + 0.25
    cells = np.array([(i, j, k) for i in range(n) for j in range(n) for k in range(n)])
    centers = (cells[:, None, :] + basis[None]).reshape(-1, 3) * s
    return Packing(centers, np.full(len(centers), 0.5 * (1.0 + overlap)), np.full(3, n * s))


# -- the granular column ---------------------------------------------------------------------------

Column = namedtuple("Column", "solver material u p")


def granular_column(
    rve, prefix, n=4, pressure=0.0, material_class=None, stabilise=0.0, hold=False, **solver_kwargs
):
    """A 10 m x 10 m column of n x n Q1 cells: fixed base, rollers on the sides, a top pressure
    ``p * (1 + 0.05 x)`` (p a Constant in Pa, positive = downward; the variation makes the
    solution non-homogeneous). ``material_class`` defaults to GranularMaterial. ``hold``: the
    boundary carries the holding traction P(I) N of a confined packing's reference stress, so
    that u = 0 is at rest under p = 0. Returns ``Column(solver, material, u, p)``."""
    # DOLFINx only here: the packings and scripts above serve tests that run without it
    from dolfinx_granular.drivers.newton import NewtonSolver
    from dolfinx_granular.fem.compat import vector_space
    from dolfinx_granular.fem.material import GranularMaterial

    import ufl
    from dolfinx import fem, mesh
    from mpi4py import MPI

    material_class = material_class or GranularMaterial
    msh = mesh.create_rectangle(
        MPI.COMM_WORLD, [[0, 0], [10, 10]], [n, n], mesh.CellType.quadrilateral
    )
    V = vector_space(msh)
    u, v, du = fem.Function(V), ufl.TestFunction(V), ufl.TrialFunction(V)
    material = material_class(rve, u, **({"stabilise": stabilise} if stabilise else {}))
    top = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 10))
    bottom = mesh.locate_entities_boundary(msh, 1, lambda x: np.isclose(x[1], 0))
    walls = mesh.locate_entities_boundary(
        msh, 1, lambda x: np.isclose(x[0], 0) | np.isclose(x[0], 10)
    )
    ds = ufl.Measure("ds", msh, subdomain_data=mesh.meshtags(msh, 1, top, np.full_like(top, 1)))
    x = ufl.SpatialCoordinate(msh)
    p = fem.Constant(msh, float(pressure))
    residual = material.residual_form(v) + p * (1 + 0.05 * x[0]) * v[1] * ds(1)
    if hold:
        from dolfinx_granular.drivers.confinement import holding_traction

        residual -= ufl.dot(holding_traction(material), v) * ds  # (ds: all of the boundary)
    bcs = [
        fem.dirichletbc(np.zeros(2), fem.locate_dofs_topological(V, 1, bottom), V),
        fem.dirichletbc(0.0, fem.locate_dofs_topological(V.sub(0), 1, walls), V.sub(0)),
    ]
    solver = NewtonSolver(
        residual, material.jacobian_form(du, v), u, bcs, material, prefix=prefix, **solver_kwargs
    )
    return Column(solver, material, u, p)


# -- laws of one point with a jump (the material-point driver's tests) -----------------------------


class LinearLaw:
    """P = lam tr(H) I + mu (H + H^T), H = F - I: linear in F, its tangent constant (Pa)."""

    dim = 2

    def __init__(self, lam=2e6, mu=1e6):
        self.lam, self.mu = lam, mu
        I = np.eye(2)
        self.A = lam * np.einsum("ij,kl->ijkl", I, I) + mu * (
            np.einsum("ik,jl->ijkl", I, I) + np.einsum("il,jk->ijkl", I, I)
        )

    def evaluate(self, F):
        H = np.asarray(F) - np.eye(2)
        P = np.einsum("ijkl,kl->ij", self.A, H)
        return 0.5 * np.sum(P * H), P, self.A


class JumpLaw(LinearLaw):
    """LinearLaw's P plus ``jump`` (Pa) on P11 where F11 > 1 + ``at``: a stress with no F
    between two branches (a relaxed RVE that rearranges), its tangent the linear one's times
    ``stiff`` (a tangent that overestimates the slope: Newton crawls)."""

    def __init__(self, jump=0.0, at=1e-3, stiff=1.0):
        super().__init__()
        self.jump, self.at, self.stiff = jump, at, stiff

    def evaluate(self, F):
        W, P, A = super().evaluate(F)
        P = P.copy()
        if F[0, 0] > 1.0 + self.at:
            P[0, 0] += self.jump
        return W, P, self.stiff * A


class UnjamLaw(LinearLaw):
    """LinearLaw whose cell comes apart (RigidityLostError, as a relaxed RVE's) where F11 >
    ``edge``, its tangent the linear one's times ``stiff`` (< 1: Newton overshoots)."""

    def __init__(self, stiff=0.3, edge=1.0):
        super().__init__()
        self.stiff, self.edge = stiff, edge

    def evaluate(self, F):
        if F[0, 0] > self.edge:
            raise RigidityLostError("no disk has 2 contacts or more (all are rattlers)")
        W, P, A = super().evaluate(F)
        return W, P, self.stiff * A


class CollapsingLaw(UnjamLaw):
    """UnjamLaw held at ``hold`` Pa more compression in P11 while it holds (F11 <= 1): at
    F11 = 1 it jumps from P11 = hold to apart, as a loose cell that collapses when dilated."""

    def __init__(self, hold):
        super().__init__(stiff=1.0)
        self.hold = hold

    def evaluate(self, F):
        W, P, A = super().evaluate(F)
        P = P.copy()
        P[0, 0] += self.hold
        return W, P, A


class GivingWayLaw(CollapsingLaw):
    """CollapsingLaw whose micro solver finds no equilibrium (RelaxationError, not a lost
    network) for F11 in (1, 1 + ``band``], between its jammed branch and its cell come apart,
    as a relaxed cell at the edge of jamming that does not come to rest."""

    def __init__(self, hold, band=1e-3):
        super().__init__(hold)
        self.band = band

    def evaluate(self, F):
        if 1.0 < F[0, 0] <= 1.0 + self.band:
            raise RelaxationError("no equilibrium: the cell did not come to rest")
        return super().evaluate(F)


class CollapsingHistoryLaw(LinearLaw):
    """A history law of one point: jammed, its cell holds ``hold`` Pa more compression in P11
    than LinearLaw's (F11 <= 1), and a round-off further it comes apart, raising
    :class:`CellFloats` with the state it came apart in, as the frictional relaxed RVE's loose
    cell does. Committed there, the cell jams again ``further`` in F11: P11 rises from 0 at
    F11 = 1 - further with LinearLaw's stiffness. Its state (n,): that shift of the jammed
    branch (0 before the collapse)."""

    def __init__(self, hold, further=2e-3):
        super().__init__()
        self.hold, self.further = hold, further

    def initial_state(self, n):
        return np.zeros(n)

    def evaluate(self, F, state):
        shift = float(state[0])
        if F[0, 0] > 1.0 - shift:
            apart = (0.0, np.zeros((2, 2)), np.zeros((2, 2, 2, 2)), np.array([self.further]))
            raise CellFloats("no disk has 2 contacts or more: the cell has come apart",
                             np.array([0]), apart)  # fmt: skip
        moved = np.array(F, dtype=float)
        moved[0, 0] += shift
        W, P, A = super().evaluate(moved)
        P = P.copy()
        if shift == 0.0:
            P[0, 0] += self.hold
        return W, P, A, state.copy()


# -- the Taylor test -------------------------------------------------------------------------------


def taylor_remainders(L, a, u, direction, update, h0, halvings=5):
    """Taylor test of a residual against its Jacobian at ``u`` in the direction ``direction``
    (a Function of u's space): with ``L`` and ``a`` the compiled residual and Jacobian forms and
    ``update()`` bringing the materials' stress (and tangent) to the current u, the remainders

        r1(h) = |R(u + h d) - R(u)|,   r2(h) = |R(u + h d) - R(u) - h J(u) d|

    for h = h0, h0 / 2, ... (``halvings`` values) and their convergence rates
    log2(r(h) / r(h / 2)): r1 falls as O(h), r2 as O(h^2) for the consistent Jacobian.
    u is restored on return. Returns ``(rate1, rate2, r1, r2)`` (arrays)."""
    from dolfinx_granular.fem.compat import petsc_vec

    from dolfinx.fem.petsc import assemble_matrix, assemble_vector
    from petsc4py import PETSc

    def residual():
        update()
        b = assemble_vector(L)
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return b

    u0 = u.x.array.copy()
    R0 = residual()  # (also leaves the materials' tangent at u for the Jacobian)
    J = assemble_matrix(a)
    J.assemble()
    Jd = J.createVecLeft()
    J.mult(petsc_vec(direction), Jd)
    r1, r2 = [], []
    try:
        for h in [h0 / 2**k for k in range(halvings)]:
            u.x.array[:] = u0 + h * direction.x.array
            Rh = residual()
            Rh.axpy(-1.0, R0)
            r1.append(Rh.norm())
            Rh.axpy(-h, Jd)
            r2.append(Rh.norm())
            Rh.destroy()
    finally:
        u.x.array[:] = u0
    for vec in (R0, Jd, J):
        vec.destroy()
    r1, r2 = np.array(r1), np.array(r2)
    return np.log2(r1[:-1] / r1[1:]), np.log2(r2[:-1] / r2[1:]), r1, r2


# -- demos -----------------------------------------------------------------------------------------

#: every demo in demos/, each honouring ``--small`` and ``DEMO_SMALL=1`` (tests/test_demos.py)
DEMOS = (
    "fabric3d",
    "footing3d",
    "granular_column",
    "friction_study",
    "relaxed_study",
    "relaxed_friction_study",
    "rve_study",
    "slope",
    "slope_collapse",
)


def demo_command(name, *args, ranks=1):
    """``python demos/<name>.py *args``, under this Python's MPI launcher with ``ranks``
    processes if ranks > 1 (the test fails without one)."""
    cmd = [sys.executable, os.path.join(ROOT, "demos", f"{name}.py"), *map(str, args)]
    if ranks > 1:
        from dolfinx_granular.fem.compat import mpi_command

        launcher = mpi_command(ranks)
        assert launcher is not None, "no MPI launcher (mpiexec/mpirun) found"
        cmd = [*launcher, *cmd]
    return cmd


def run_demo(name, *args, ranks=1, env=None, timeout=900):
    """Run :func:`demo_command` from the checkout's root with ``MPI_ENV`` and ``env`` added;
    asserts exit status 0 and returns the ``subprocess.CompletedProcess`` (text output)."""
    proc = subprocess.run(
        demo_command(name, *args, ranks=ranks),
        cwd=ROOT,
        env=dict(MPI_ENV, **(env or {})),
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc


def net_forces(packing, x, F):
    """Net contact force (N, 2) on every disk at current centres x (N, 2) in the cell spanned by
    F box, and the mean overlap of the contacts (the mean contact force), by brute force over
    all pairs and images (linear springs, k_n = 1)."""
    a = F @ np.diag(packing.box)  # columns: the current lattice vectors
    r = packing.radii
    f, overlaps = np.zeros_like(x), []
    for sx in (-1, 0, 1):
        for sy in (-1, 0, 1):
            d = x[None, :, :] + (a @ [sx, sy])[None, None, :] - x[:, None, :]  # (i, j, 2)
            dist = np.linalg.norm(d, axis=2)
            eps = r[:, None] + r[None, :] - dist
            if sx == 0 and sy == 0:
                np.fill_diagonal(eps, -1.0)
            on = eps > 0.0
            n = np.where(on[..., None], d / np.where(dist > 0, dist, 1.0)[..., None], 0.0)
            f -= np.einsum("ij,ijk->ik", np.where(on, eps, 0.0), n)  # pushed away from j
            overlaps.append(eps[on])
    return f, np.concatenate(overlaps).mean()


def frictional_balance(packing, F, w, c):
    """Net force (N, 2) and moment (N,) of every disk of the frictional relaxed cell at F with
    fluctuations w (N, 2) and contacts c (a ``ContactSet`` with ``tangential`` and
    ``rolling``), every pair and image found by brute force (and checked to be in the set), and
    the mean normal force."""
    r = packing.radii
    xi = packing.centers + w
    wraps = np.floor(xi / packing.box).astype(int)
    x = (xi - wraps * packing.box) @ F.T  # (the centres in the current cell, as positions())
    a = F @ np.diag(packing.box)
    known = {
        (int(i), int(j), int(s0), int(s1)): k
        for k, ((i, j), (s0, s1)) in enumerate(zip(c.pairs, c.shift))
    }
    f, M, found = np.zeros_like(x), np.zeros(len(r)), np.zeros(len(c.force), bool)
    for i in range(len(r)):
        for j in range(i, len(r)):
            for s0 in (-1, 0, 1):
                for s1 in (-1, 0, 1):
                    l = x[j] + a @ [s0, s1] - x[i]
                    d = np.linalg.norm(l)
                    if (i == j and s0 == s1 == 0) or d >= r[i] + r[j]:
                        continue
                    # the image in the candidates' convention (of the unwrapped centres; a
                    # candidate may list the pair the other way round)
                    sh = (s0 - wraps[j, 0] + wraps[i, 0], s1 - wraps[j, 1] + wraps[i, 1])
                    a_, b_ = i, j
                    if (i, j) + sh not in known:
                        sh, a_, b_, l = (-sh[0], -sh[1]), j, i, -l
                    if (a_, b_) + sh not in known:  # (only at a rattler's zero overlap)
                        assert r[i] + r[j] - d <= 1e-12 * (r[i] + r[j])
                        continue
                    k = known[(a_, b_) + sh]
                    found[k] = True
                    n = l / d
                    t = np.array([-n[1], n[0]])
                    force = c.force[k] * n + c.tangential[k] * (r[i] + r[j]) / d * t
                    f[b_] += force
                    f[a_] -= force
                    M[a_] -= r[a_] * c.tangential[k] + c.rolling[k]
                    M[b_] -= r[b_] * c.tangential[k] - c.rolling[k]
    # every contact of the set is found, but one whose overlap is round-off (~1e-16 of the
    # radii: either side of touching, its force nothing against the balance's 1e-9)
    assert found[c.force > 1e-12 * c.force.mean()].all()
    return f, M, c.force.mean()
