"""Relaxed RVE speed: ms per quadrature point beside the Taylor kernel, and where the time goes.

Run: ``.venv/bin/python benchmarks/relaxed.py [--points 100] [--particles 700] [--step 1e-4]``.

A generated packing (seed 0, k_n = 2.8e7 N/m²) is relaxed once at an isotropic compression
``--compression`` (default 0.5 %, p / k_n ~ 1e-3), and that equilibrium is the committed state of
every point. Each point then takes its own strain step of size ``--step`` in a random direction
(a Newton iterate of the next load step) and is timed:

- ``Taylor P+A``: :class:`TaylorRVE` ``evaluate`` at the same F (µs per point);
- ``relaxed P+A``: :class:`RelaxedRVE` ``evaluate`` warm-started from the committed state, in ms
  per point, split into the points whose contact network stayed and those that rearranged;
- ``ratio``: relaxed over Taylor, per point, in this one run;
- Newton steps, factorisations and FIRE steps per point, and the time of one contact state
  (overlaps, forces, rattlers) and one tangent (a factorisation and the condensation) at the
  committed state;
- where the time goes: assembly, factorisations, solves, line search, FIRE and the tangent, in
  ms per point over one more pass under cProfile;
- one factorisation of the network's stiffness at the committed state by other sparse
  libraries, where they are installed (none is a dependency): QDLDL (``pip install qdldl``) and
  CHOLMOD (``pip install scikit-sparse`` on SuiteSparse's headers), each refactorising on a
  symbolic analysis done once, the least any of them could cost per factorisation;
- the block LDL^T in 2 x 2 blocks (:mod:`~dolfinx_granular.laws.block_ldlt`) beside SuperLU:
  its factorisation on the pattern of every candidate pair (as a solver keeps it while the list
  holds) and on the network's own pairs (the least it could be), its flops and the blocks of L
  (in scalar entries beside SuperLU's nnz(L)), one solve, and the assembly straight into its
  values beside the COO triplets and their conversion to CSC that SuperLU needs.
"""

import argparse
import dataclasses
import time

from dolfinx_granular import TaylorRVE, generate_packing
from dolfinx_granular.laws import block_ldlt, relaxation
from dolfinx_granular.laws.relaxed import RelaxedRVE, RelaxedState
from dolfinx_granular.laws.relaxed_cell import ContactState

import numpy as np

K_N = 2.8e7


def best_time(fn, repeats=3):
    """Best wall time of ``fn()`` over ``repeats`` calls (s) and its last result."""
    best, out = np.inf, None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def committed(rve, compression, n):
    """The equilibrium at F = (1 - compression) I as the committed state of n points."""
    F0 = np.eye(2) * (1.0 - compression)
    _, _, _, one = rve.evaluate(F0[None], rve.initial_state(1))
    return F0, RelaxedState.concatenate([one] * n)


def steps(F0, n, size, seed=0):
    """F0 + size * (random unit direction) for n points, (n, 2, 2)."""
    d = np.random.default_rng(seed).normal(size=(n, 2, 2))
    d /= np.linalg.norm(d, axis=(1, 2))[:, None, None]
    return F0[None] + size * d


def against_superlu(rve, F, state, block):
    """Seconds of ``rve.evaluate(F, state)`` with the SuperLU factorisation on the same cell,
    and the largest difference over the points of its W, P and A from ``block`` (the block
    LDL^T's ``(W, P, A, state)``), each relative to the point's largest entry."""
    settings = rve.settings
    rve.settings = dataclasses.replace(settings, factorisation="superlu")
    try:
        t, ref = best_time(lambda: rve.evaluate(F, state), 1)
    finally:
        rve.settings = settings
    return t, [relative_difference(a, b) for a, b in zip(block[:3], ref[:3])]


def relative_difference(a, b):
    """max over points of max|a - b| / max|b| ((n, ...) arrays)."""
    a, b = np.reshape(a, (len(a), -1)), np.reshape(b, (len(b), -1))
    return float((np.abs(a - b).max(axis=1) / np.abs(b).max(axis=1)).max())


def per_point(rve, F0, F, state):
    """Time (s), steps, factorisations and FIRE steps of each point, and whether its network
    (the contacts between non-rattlers) differs from the committed one at F0."""
    committed = relaxation.at_rest(rve.cell, F0, state.w[0], False).network  # (all points')
    rows, rearranged = [], []
    for q in range(F.shape[0]):
        t = time.perf_counter()
        eq = rve.equilibrium(F[q], state, q)
        rows.append((time.perf_counter() - t, eq.steps, eq.factorisations, eq.fire_steps))
        rearranged.append(not np.array_equal(eq.network, committed))
    return np.array(rows), np.array(rearranged)


_BLOCK, _SUPERLU = relaxation._BlockStiffness, relaxation._SuperLUStiffness
#: the micro solver's parts, by the functions that do each (cumulative time under cProfile;
#: both factorisations' methods)
PARTS = {
    "assembly": (_BLOCK.assemble, _SUPERLU.assemble),
    "factorisation": (_BLOCK.factorise, _SUPERLU.factorise),
    "solves": (_BLOCK.solve, _SUPERLU.solve),
    "line search": (relaxation._line_search,),
    "FIRE": (relaxation.fire,),
    "tangent": (relaxation.condensation,),
}


def where_time_goes(rve, F, state):
    """ms per point in each of :data:`PARTS` over one pass of the points, under cProfile
    (which slows the Python parts: read the shares, not the sum), and the factorisations per
    point, the shifted tries included."""
    import cProfile
    import pstats

    profile = cProfile.Profile()
    profile.enable()
    for q in range(F.shape[0]):
        rve.equilibrium(F[q], state, q)
    profile.disable()
    stats = pstats.Stats(profile).stats  # {(file, line, name): (cc, nc, tt, ct, callers)}
    keys = {(f.__code__.co_filename, f.__code__.co_firstlineno, f.__name__): k
            for k, fs in PARTS.items() for f in fs}  # fmt: skip
    times, factorisations = {}, 0
    for key, (_, nc, _, ct, _) in stats.items():
        if key in keys:
            times[keys[key]] = times.get(keys[key], 0.0) + ct
            factorisations += nc if keys[key] == "factorisation" else 0
    n = F.shape[0]
    return {k: 1e3 * v / n for k, v in times.items()}, factorisations / n


def phases(rve, F0, state):
    """Seconds of one contact state and one tangent (the network's factorisation and the
    condensation) at the committed state."""
    w = state.w[0]
    t_state, s = best_time(lambda: ContactState(rve.cell, F0, w), 20)
    t_tangent, _ = best_time(lambda: relaxation.condensation(rve.cell, F0, s), 5)
    return t_state, t_tangent


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=100)
    ap.add_argument("--particles", type=int, default=700)
    ap.add_argument("--step", type=float, default=1e-4)
    ap.add_argument("--compression", type=float, default=0.005)
    a = ap.parse_args(argv)
    packing = generate_packing(a.particles, seed=0)
    rve, taylor = RelaxedRVE(packing, K_N), TaylorRVE(packing, K_N)
    F0, state = committed(rve, a.compression, a.points)
    F = steps(F0, a.points, a.step)
    t_taylor, _ = best_time(lambda: taylor.evaluate(F))
    t_relaxed, block = best_time(lambda: rve.evaluate(F, state), 1)
    t_superlu, agree = against_superlu(rve, F, state, block)
    rows, rearranged = per_point(rve, F0, F, state)
    t_state, t_tangent = phases(rve, F0, state)
    us = 1e6 / a.points
    print(
        f"{a.particles} particles, {a.points} points, step {a.step:g} at compression "
        f"{a.compression:g}"
    )
    print(f"Taylor P+A    {t_taylor * us:9.2f} µs/point")
    print(f"relaxed P+A   {t_relaxed * us / 1e3:9.2f} ms/point   ratio {t_relaxed / t_taylor:.0f}")
    print(
        f"  with SuperLU {t_superlu * us / 1e3:9.2f} ms/point (the earlier factorisation); W, P, "
        f"A agree to {agree[0]:.1e}, {agree[1]:.1e}, {agree[2]:.1e} (largest relative "
        "difference over the points)"
    )
    for name, mask in (("kept network", ~rearranged), ("rearranged", rearranged)):
        if mask.any():
            r = rows[mask]
            print(
                f"  {name:13s} {mask.sum():4d} points: {1e3 * r[:, 0].mean():8.2f} ms, "
                f"{r[:, 1].mean():.1f} Newton steps, {r[:, 2].mean():.1f} factorisations, "
                f"{r[:, 3].mean():.0f} FIRE steps per point"
            )
    print(
        f"one contact state {1e3 * t_state:.3f} ms, one tangent (factorisation and "
        f"condensation) {1e3 * t_tangent:.3f} ms"
    )
    parts, factorisations = where_time_goes(rve, F, state)
    print(
        f"where the time goes (ms per point under cProfile; {factorisations:.1f} "
        "factorisations per point, the shifted tries included):"
    )
    print("  " + ", ".join(f"{k} {v:.1f}" for k, v in parts.items()))
    print("  (the tangent holds its own assembly and factorisation; the line search the contact")
    print("  states of its tries)")
    n, libraries = factorisation_libraries(rve, F0, state)
    print(
        f"one factorisation of the network's stiffness ({n} unknowns), ms: "
        + ", ".join(f"{k} {v:.2f}" for k, v in libraries.items())
    )
    print_block_ldlt(block_ldlt_times(rve, F0, state))


def factorisation_libraries(rve, F0, state):
    """ms of one factorisation of the network's stiffness at the committed state: SuperLU as
    the micro solver calls it, and QDLDL's and CHOLMOD's refactorisations (their symbolic
    analysis reused) where the libraries are installed."""
    s = ContactState(rve.cell, F0, state.w[0])
    H = network_matrix(rve.cell, F0, s).H
    times = {"SuperLU": best_time(lambda: relaxation._factorise(H), 20)[0]}
    try:
        import qdldl

        solver = qdldl.Solver(H)
        times["QDLDL"] = best_time(lambda: solver.update(H), 20)[0]
    except ImportError:
        pass
    try:
        from sksparse.cholmod import cholesky

        factor = cholesky(H)
        times["CHOLMOD"] = best_time(lambda: factor.cholesky_inplace(H), 20)[0]
    except ImportError:
        pass
    return H.shape[0], {k: 1e3 * v for k, v in times.items()}


def network_matrix(cell, F, s):
    """The network's stiffness at the contact state s on the non-rattlers but the first, as
    the SuperLU solver assembles it (``.H`` CSC, ``.dof``, ``.n``)."""
    net = relaxation._SuperLUStiffness(cell)
    free = s.keep.copy()
    free[np.argmax(s.keep)] = False
    net.assemble(F, s, s.network, s.network, int(np.argmax(s.keep)), free)
    return net


def block_ldlt_times(rve, F0, state, repeats=50):
    """The block LDL^T beside SuperLU on the network's stiffness at the committed state (the
    tangent's matrix; the rattlers' unknowns on the diagonal alone): ms per factorisation,
    solve and assembly (best of ``repeats``), flops, nnz(L) in scalar entries, and the largest
    difference of the two solutions relative to SuperLU's."""
    cell = rve.cell
    s = ContactState(cell, F0, state.w[0])
    net = network_matrix(cell, F0, s)
    H = net.H
    lu, _ = relaxation._factorise(H)
    pinned = int(np.argmax(s.keep))
    shift = np.where(s.keep, 0.0, cell.K)
    args = (F0, cell.pi[: s.m], cell.pj[: s.m], s.lx, s.ly, s.d, s.e, cell.R[: s.m], cell.K,
            s.network, s.network)  # fmt: skip
    network = np.zeros(cell.pi.size, np.bool_)
    network[: s.m] = s.network
    own = np.c_[cell.pi, np.where(network, cell.pj, cell.pi)]  # (i, i): no block
    g = np.random.default_rng(0).normal(size=(cell.n_disks, 2))
    g[~s.keep] = 0.0
    ref = relaxation._scatter(lu.solve(relaxation._gather(g, net.dof, net.n)), net.dof,
                              cell.n_disks)  # fmt: skip
    out = {"SuperLU": {
        "factorisation": best_time(lambda: relaxation._factorise(H), repeats // 2)[0],
        "solve": best_time(lambda: lu.solve(np.ones(net.n)), repeats)[0],
        "assembly": best_time(lambda: relaxation._matrix(cell, F0, s, s.network, s.network,
                                                         net.dof, net.n), repeats)[0],
        "nnz(L)": lu.L.nnz,
    }}  # fmt: skip
    for name, pairs in (("candidates", np.c_[cell.pi, cell.pj]), ("network", own)):
        p = block_ldlt.analyse(cell.n_disks, pairs, pinned=pinned)
        values, factor = p.zeros(), p.new_factor()
        assemble = lambda p=p, v=values: block_ldlt.assemble(  # noqa: E731
            *args, p.diag_slot, p.pair_slot, v
        )
        assemble()
        out[name] = {
            "factorisation": best_time(
                lambda p=p, v=values, f=factor: block_ldlt.factorise(p, v, f, shift), repeats
            )[0],
            "solve": best_time(lambda p=p, f=factor: block_ldlt.solve(p, f, g), repeats)[0],
            "assembly": best_time(assemble, repeats)[0],
            "nnz(L)": 4 * p.nnz_L + 3 * p.n,
            "flops": p.flops,
            "agree": float(np.abs(block_ldlt.solve(p, factor, g) - ref).max() / np.abs(ref).max()),
        }
    return out


def print_block_ldlt(times):
    """The lines of :func:`block_ldlt_times`."""
    su = times["SuperLU"]
    print(
        f"block LDL^T beside SuperLU (ms, best of many; nnz(L) in scalar entries): SuperLU "
        f"factorisation {1e3 * su['factorisation']:.3f}, solve {1e3 * su['solve']:.3f}, COO "
        f"assembly and CSC {1e3 * su['assembly']:.3f}, nnz(L) {su['nnz(L)']}"
    )
    for name, label in (("candidates", "candidates'"), ("network", "network's")):
        t = times[name]
        print(
            f"  on the {label} pattern: factorisation {1e3 * t['factorisation']:.3f} "
            f"({t['flops'] / 1e6:.2f} MFLOP), solve {1e3 * t['solve']:.3f}, assembly "
            f"{1e3 * t['assembly']:.3f}, nnz(L) {t['nnz(L)']}, agrees to {t['agree']:.1e}"
        )


if __name__ == "__main__":
    main()
