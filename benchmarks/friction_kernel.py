"""Frictional kernel speed: µs per quadrature point, frictional vs frictionless, and state memory.

Run: ``.venv/bin/python benchmarks/friction_kernel.py [--points 2000] [--sizes 70 350 700 2800]``.

For generated packings (seed 0), k_n = 2.8e7 N/m², k_t = k_n / 2, mu = 0.3, every point is taken
along a confined shear path (about 2 % isotropic compression, each point perturbed by ~0.2 %, then
a shear of 1 %), its state committed, and timed at a further shear increment of 0.2 % (a Newton
iterate of the next load step), where a fraction of the contacts slides. It prints, per particle
count:
- ``frictionless P+A``: :class:`TaylorRVE` ``evaluate`` at the same F (the package kernel);
- ``friction P+A`` / ``friction P``: :class:`FrictionalRVE` ``evaluate`` / ``stress``;
- ``ratio``: friction P+A over frictionless P+A;
- ``state B/pt``: ``FrictionState.nbytes`` per point of the committed state.
The frictional stress is checked against the frictionless one at mu = 0 before timing.
"""

import argparse
import platform
import time

import numba
import numpy as np

from dolfinx_granular import TaylorRVE, generate_packing
from dolfinx_granular.friction import FrictionalRVE

K_N = 2.8e7
K_T = 0.5 * K_N
MU = 0.3


def best_time(fn, repeats):
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def shear(F, gamma):
    """F with a superposed simple shear gamma (x-displacement proportional to y)."""
    return np.einsum("ab,qbc->qac", np.array([[1.0, gamma], [0.0, 1.0]]), F)


def committed_state(rve, F0):
    """State after two committed steps: compression F0, then 1 % shear."""
    state = rve.initial_state(len(F0))
    for F in (F0, shear(F0, 0.01)):
        state = rve.stress(F, state)[2]
    return state


def run_size(n, F0, repeats):
    packing = generate_packing(n, seed=0)
    taylor = TaylorRVE(packing, K_N)
    rve = FrictionalRVE(packing, K_N, K_T, MU)
    state = committed_state(rve, F0)
    F = shear(F0, 0.012)
    frictionless = FrictionalRVE(packing, K_N, K_T, 0.0)
    P0 = frictionless.stress(F, frictionless.initial_state(len(F)))[1]
    P_ref = taylor.stress(F)[1]
    err = np.abs(P0 - P_ref).max() / np.abs(P_ref).max()
    assert err < 1e-12, f"mu = 0 differs from the frictionless kernel: {err:.2e}"
    cs = [rve.contacts(F[q], state.take([q])) for q in range(min(len(F), 20))]
    contacts = np.mean([len(c.overlap) for c in cs])
    sliding = np.mean([c.sliding.mean() for c in cs])
    rve.evaluate(F, state)  # compiled before timing
    m = len(F)
    t0 = best_time(lambda: taylor.evaluate(F), repeats) / m
    t1 = best_time(lambda: rve.evaluate(F, state), repeats) / m
    t2 = best_time(lambda: rve.stress(F, state), repeats) / m
    return dict(n=n, candidates=rve.n_candidates, contacts=contacts, sliding=sliding,
                t0=t0, t1=t1, t2=t2, bytes=state.nbytes / state.n_points)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=2000, help="quadrature points per batch")
    parser.add_argument("--sizes", type=int, nargs="+", default=[70, 350, 700, 2800])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)

    rng = np.random.default_rng(0)
    F0 = 0.98 * np.eye(2) + rng.normal(0.0, 2e-3, (args.points, 2, 2))
    print(f"# friction kernel benchmark: {platform.processor() or platform.machine()}, "
          f"numba {numba.__version__}, numpy {np.__version__}, 1 thread, {args.points} points, "
          f"k_t/k_n = {K_T / K_N}, mu = {MU}")
    header = (f"{'particles':>9} {'candidates':>10} {'contacts':>8} {'sliding':>7} | "
              f"{'frictionless P+A':>16} {'friction P+A':>12} {'friction P':>10} | "
              f"{'ratio':>6} | {'state B/pt':>10}")
    print(header + "\n" + "-" * len(header))
    us = 1e6
    rows = []
    for n in args.sizes:
        r = run_size(n, F0, args.repeats)
        rows.append(r)
        print(f"{n:>9} {r['candidates']:>10} {r['contacts']:>8.0f} {r['sliding']:>7.1%} | "
              f"{r['t0'] * us:>16.2f} {r['t1'] * us:>12.2f} {r['t2'] * us:>10.2f} | "
              f"{r['t1'] / r['t0']:>5.2f}x | {r['bytes']:>10.0f}")
    print("(µs per quadrature point; 'sliding': share of the active contacts at the Coulomb limit)")
    return rows


if __name__ == "__main__":
    main()
