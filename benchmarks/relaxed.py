"""Relaxed RVE speed: ms per quadrature point beside the Taylor kernel, what a point costs, and
the floor its arithmetic sets.

Run: ``.venv/bin/python benchmarks/relaxed.py [--points 100] [--particles 700] [--step 1e-4]
[--save W.npz] [--against W.npz]``.

A generated packing (seed 0, k_n = 2.8e7 N/m²) is relaxed once at an isotropic compression
``--compression`` (default 0.5 %, p / k_n ~ 1e-3), and that equilibrium is the committed state of
every point. Each point then takes its own strain step of size ``--step`` in a random direction
(a Newton iterate of the next load step). Printed:

- ``Taylor P+A``: :class:`TaylorRVE` ``evaluate`` at the same F (µs per point, best of 3);
- ``relaxed P+A``: :class:`RelaxedRVE` ``evaluate`` warm-started from the committed state (ms
  per point, best of ``--repeats``), and its ratio to Taylor's in this one run;
- per point, split into the points whose network stayed and those that rearranged: time,
  Newton steps, the steps that factorised, every numeric factorisation (the shifted tries and
  the tangent's included), solves, line-search trial states and FIRE steps;
- the parts, each timed alone at the committed state (best of many): one factorisation on the
  solver's pattern (the prefix of the candidates that holds the contacts) with its flops and
  rate, one solve; the same factorisation on the network's own pattern (the least any pattern
  could cost), SciPy's SuperLU, and QDLDL's and CHOLMOD's refactorisations where they are
  installed (none is a dependency: ``pip install qdldl``, ``pip install scikit-sparse``);
- the floor: the mean counts times those parts' times (the factorisations and solves alone, no
  line search, no contact states, no Python), in ms per point and MFLOP per point, beside the
  measured time;
- ``frictional P+A``: :class:`FrictionalRelaxedRVE` (mu = ``--friction``, k_t = k_n), its
  committed state the same compression reached along its own path, the same steps: ms per
  point, its ratio to the frictionless relaxed RVE and to Taylor, and where its time goes (the
  compiled Newton loop, the rest: the path, the tangent, the history, in Python), the block
  LU's numeric factorisation with its flops and rate, and the floor it sets;
- ``--save`` writes the points' W, P and A (the frictionless and the frictional relaxed RVE's)
  to an ``.npz``; ``--against`` compares them with such a file (from another version of the
  solver: the largest relative difference per quantity and the points beyond 1e-10).
"""

import argparse
import time

from dolfinx_granular import FrictionalRelaxedRVE, TaylorRVE, generate_packing
from dolfinx_granular.laws.relaxed import RelaxedRVE, RelaxedState, at_rest, block_ldlt, newton
from dolfinx_granular.laws.relaxed.assembly import assemble
from dolfinx_granular.laws.relaxed.contact_state import ContactState
from dolfinx_granular.laws.relaxed_friction import block_lu, cell_state
from dolfinx_granular.laws.relaxed_friction import newton as friction_newton
from dolfinx_granular.timing import best_time

import numpy as np
from scipy.sparse.linalg import splu

K_N = 2.8e7
#: the counts of a point (:class:`~dolfinx_granular.laws.relaxed.Equilibrium`), as printed
COUNTS = {
    "steps": "Newton steps",
    "factorisations": "factorised",
    "numeric_factorisations": "factorisations",
    "solves": "solves",
    "trial_states": "trial states",
    "fire_steps": "FIRE steps",
}


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


def relative_difference(a, b):
    """Per point max|a - b| / max|b| ((n, ...) arrays): (n,)."""
    a, b = np.reshape(a, (len(a), -1)), np.reshape(b, (len(b), -1))
    return np.abs(a - b).max(axis=1) / np.abs(b).max(axis=1)


def per_point(rve, F0, F, state):
    """Each point's time (s) and counts (:data:`COUNTS`), and whether its network (the
    contacts between non-rattlers) differs from the committed one at F0."""
    committed = at_rest(rve.cell, F0, state.w[0], False).network  # (all points')
    rows, rearranged = [], []
    for q in range(F.shape[0]):
        t = time.perf_counter()
        eq = rve.equilibrium(F[q], state, q)
        rows.append([time.perf_counter() - t] + [getattr(eq, k) for k in COUNTS])
        rearranged.append(not np.array_equal(eq.network, committed))
    return np.array(rows), np.array(rearranged)


def network_values(cell, F, s, pattern):
    """The network's stiffness at the contact state s in ``pattern``'s values, and the shift
    that puts K on the rattlers' diagonal (the tangent's matrix)."""
    values = pattern.zeros()
    assemble(
        F, cell.pi[: s.m], cell.pj[: s.m], s.lx, s.ly, s.d, s.e, cell.R[: s.m], cell.K,
        s.network, s.network, pattern.diag_slot, pattern.pair_slot, values,
    )  # fmt: skip
    return values, np.where(s.keep, 0.0, cell.K)


def parts(rve, F0, state, repeats=50):
    """One factorisation of the network's stiffness at the committed state (s) on the solver's
    pattern, on the network's own, by SuperLU and by the libraries installed; one solve on
    the solver's pattern; the flops of both patterns."""
    cell = rve.cell
    s = ContactState(cell, F0, state.w[0])
    pinned = int(np.argmax(s.keep))
    solver_pattern, _, _ = cell.block_pattern(pinned, newton.held(s.network, cell.pi, cell.pj, s.m))
    network = np.zeros(cell.pi.size, np.bool_)
    network[: s.m] = s.network
    own = block_ldlt.analyse(cell.n_disks, np.c_[cell.pi, np.where(network, cell.pj, cell.pi)],
                             pinned)  # fmt: skip
    out = {}
    for name, p in (("solver's pattern", solver_pattern), ("network's own pattern", own)):
        values, shift = network_values(cell, F0, s, p)
        out[name] = time_pattern(p, values, shift, repeats)
    H = own.to_csc(values, shift)
    keep = np.repeat(np.arange(cell.n_disks) != pinned, 2)
    H = H[keep][:, keep].tocsc()
    out["SuperLU"] = {"factorisation": best_time(lambda: splu(H), repeats // 2)[0]}
    for name, refactorise in libraries(H).items():
        out[name] = {"factorisation": best_time(refactorise, repeats)[0]}
    return out


def time_pattern(p, values, shift, repeats):
    """Seconds of one factorisation of ``values`` + ``shift`` on the pattern p and of one solve
    (the compiled substitution the solver calls), and the factorisation's flops."""
    factor = p.new_factor()
    t, _ = best_time(lambda: block_ldlt.factorise(p, values, factor, shift), repeats)
    b = np.ones((p.n_blocks, p.d, 1))
    x = np.zeros_like(b)
    args = (p.dims, p.n, p.perm, p.Lp, p.Li, factor.Lx, factor.Dinv, b, x)
    solve, _ = best_time(lambda: block_ldlt.substitute(*args), repeats)
    return {"factorisation": t, "flops": p.flops, "solve": solve}


def libraries(H):
    """Refactorisations of H on a kept symbolic analysis by the sparse libraries installed."""
    out = {}
    try:
        import qdldl

        solver = qdldl.Solver(H)
        out["QDLDL"] = lambda: solver.update(H)
    except ImportError:
        pass
    try:
        from sksparse.cholmod import cholesky

        factor = cholesky(H)
        out["CHOLMOD"] = lambda: factor.cholesky_inplace(H)
    except ImportError:
        pass
    return out


def floor(counts, timed):
    """ms and MFLOP per point of the factorisations and solves alone, at the mean counts."""
    p = timed["solver's pattern"]
    ms = 1e3 * (
        counts["numeric_factorisations"] * p["factorisation"] + counts["solves"] * p["solve"]
    )
    return ms, counts["numeric_factorisations"] * p["flops"] / 1e6


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=100)
    ap.add_argument("--particles", type=int, default=700)
    ap.add_argument("--step", type=float, default=1e-4)
    ap.add_argument("--compression", type=float, default=0.005)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--friction", type=float, default=0.5)
    ap.add_argument("--save", help="write the points' W, P, A to this .npz")
    ap.add_argument("--against", help="compare the points' W, P, A with this .npz")
    a = ap.parse_args(argv)
    packing = generate_packing(a.particles, seed=0)
    rve, taylor = RelaxedRVE(packing, K_N), TaylorRVE(packing, K_N)
    F0, state = committed(rve, a.compression, a.points)
    F = steps(F0, a.points, a.step)
    t_taylor, _ = best_time(lambda: taylor.evaluate(F))
    t_relaxed, (W, P, A, _) = best_time(lambda: rve.evaluate(F, state), a.repeats)
    rows, rearranged = per_point(rve, F0, F, state)
    print(
        f"{a.particles} particles, {a.points} points, step {a.step:g} at compression "
        f"{a.compression:g}"
    )
    ms = 1e3 * t_relaxed / a.points
    print(f"Taylor P+A    {1e6 * t_taylor / a.points:9.2f} µs/point")
    print(f"relaxed P+A   {ms:9.2f} ms/point   ratio {t_relaxed / t_taylor:.0f}")
    print_counts(rows, rearranged)
    timed = parts(rve, F0, state)
    print_parts(timed)
    counts = dict(zip(COUNTS, rows[:, 1:].mean(axis=0)))
    f_ms, f_mflop = floor(counts, timed)
    print(
        f"floor: {counts['numeric_factorisations']:.2f} factorisations and "
        f"{counts['solves']:.2f} solves per point take {f_ms:.2f} ms ({f_mflop:.2f} MFLOP) of "
        f"the {ms:.2f}"
    )
    points = {"W": W, "P": P, "A": A}
    points.update(frictional(packing, a, F0, F, t_relaxed, t_taylor))
    if a.save:
        np.savez(a.save, **points)
    if a.against:
        print_against(np.load(a.against), points)


def frictional(packing, a, F0, F, t_relaxed, t_taylor):
    """Time the frictional relaxed RVE on the same steps and print where its time goes;
    returns its points' W, P and A (keys ``*_frictional``)."""
    rve = FrictionalRelaxedRVE(packing, K_N, K_N, a.friction)
    _, _, _, one = rve.evaluate(F0, rve.initial_state(1))
    state = type(one).concatenate([one] * a.points)
    t, (W, P, A, _) = best_time(lambda: rve.evaluate(F, state), a.repeats)
    ms = 1e3 * t / a.points
    print(
        f"frictional P+A {ms:8.2f} ms/point   (mu = {a.friction:g}) {t / t_relaxed:.1f} x the "
        f"frictionless relaxed RVE, {t / t_taylor:.0f} x Taylor"
    )
    counts = [rve.equilibrium(F[q], state, q)[0].counts for q in range(a.points)]
    keys = ("steps", "factorisations", "chord_steps", "fire_steps", "newton_seconds")
    mean = {k: np.mean([getattr(c, k) for c in counts]) for k in keys}
    newton_ms = 1e3 * mean["newton_seconds"]
    print(
        f"  per point: {mean['steps']:.2f} Newton steps ({mean['chord_steps']:.2f} chord), "
        f"{mean['factorisations']:.2f} factorisations and the tangent's; the compiled Newton "
        f"loop {newton_ms:.2f} ms, the rest (path, tangent, history; Python) "
        f"{ms - newton_ms:.2f} ms; FIRE steps {mean['fire_steps']:.1f}"
    )
    inc = rve.increment(state, 0)
    s = cell_state.CellState(rve.cell, rve.springs, F0, inc.w0, inc.th0, inc)
    lu = friction_newton.factorise(rve.cell, rve.springs, F0, s, False)[0]
    print_block_lu(lu, t_relaxed / a.points, mean["factorisations"] + 1)
    return {"W_frictional": W, "P_frictional": P, "A_frictional": A}


def print_block_lu(lu, t_relaxed, factorisations):
    """The block LU's numeric factorisation alone (its assembly and solve aside), its flops and
    rate, and the floor it sets: the factorisations of a point, and the least a point needs
    (one Newton step and the tangent), beside the frictionless relaxed RVE's time."""
    if not isinstance(lu, block_lu.BlockLU):
        print("  (the block LU refused the committed state's Jacobian: SuperLU factorised it)")
        return
    t, _ = best_time(lu.factorise, 20)
    mflop = block_lu.flops(lu.pattern) / 1e6
    p = lu.pattern
    print(
        f"  block LU: {p.n} blocks of 3, {p.nnz_L} blocks in L, numeric factorisation "
        f"{1e3 * t:.2f} ms ({mflop:.2f} MFLOP, {mflop / 1e3 / t:.1f} GFLOP/s); floor "
        f"{factorisations:.2f} of them {1e3 * t * factorisations:.2f} ms = "
        f"{t * factorisations / t_relaxed:.1f} x, 2 of them {2e3 * t:.2f} ms = "
        f"{2 * t / t_relaxed:.1f} x the frictionless relaxed RVE"
    )


def print_counts(rows, rearranged):
    """The per-point lines of :func:`per_point`."""
    for name, mask in (("kept network", ~rearranged), ("rearranged", rearranged)):
        if mask.any():
            r = rows[mask].mean(axis=0)
            print(
                f"  {name:13s} {mask.sum():4d} points: {1e3 * r[0]:6.2f} ms, "
                + ", ".join(f"{v:.2f} {label}" for v, label in zip(r[1:], COUNTS.values()))
            )


def print_parts(timed):
    """The lines of :func:`parts`."""
    print("one factorisation of the network's stiffness at the committed state (ms, best of 50):")
    for name, t in timed.items():
        line = f"  {name:22s} {1e3 * t['factorisation']:.3f}"
        if "flops" in t:
            line += (
                f" ({t['flops'] / 1e6:.2f} MFLOP, {t['flops'] / t['factorisation'] / 1e9:.1f} "
                f"GFLOP/s; one solve {1e3 * t['solve']:.3f})"
            )
        print(line)


def print_against(ref, points):
    """The largest relative differences of the points' W, P, A (frictionless and frictional)
    from ``ref``'s, and the points beyond 1e-10 (a quantity ``ref`` lacks: skipped)."""
    for name, x in points.items():
        if name not in ref:
            print(f"  {name}: not in the file compared with")
            continue
        d = relative_difference(x, ref[name])
        far = np.flatnonzero(d > 1e-10)
        print(f"  {name}: largest relative difference {d.max():.1e}; points beyond 1e-10: {far}")


if __name__ == "__main__":
    main()
