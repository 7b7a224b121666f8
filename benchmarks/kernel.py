"""Kernel speed: µs per quadrature point for P and A, beside two plain implementations.

Run: ``.venv/bin/python benchmarks/kernel.py [--points 2000] [--sizes 70 350 700 2800]``.

For generated packings (seed 0) at about 2 % isotropic compression (each point perturbed by
~0.2 % so that no two are equal) it prints, per particle count:
- ``taylor P+A`` / ``taylor P``: :class:`TaylorRVE` ``evaluate`` / ``stress`` (the package kernel);
- ``numba loop``: a straightforward Numba loop over the fixed candidate list, summing eqs. 10 and
  13 contact by contact into the 16 entries of A;
- ``numpy``: the same formulas vectorised over the candidates with NumPy, one point at a time.
All three are checked to agree before timing. One process, one thread.
"""

import argparse
import platform
import time

import numba
import numpy as np
from numba import njit

from dolfinx_granular import TaylorRVE, generate_packing

K_N = 2.8e7


@njit  # no on-disk cache: it breaks when the script is loaded under another module name
def numba_loop(F, L, R, K, P, A):
    """Straightforward baseline: every candidate, every entry of A per active contact."""
    for q in range(F.shape[0]):
        P[q] = 0.0
        A[q] = 0.0
        for c in range(L.shape[0]):
            lx = F[q, 0, 0] * L[c, 0] + F[q, 0, 1] * L[c, 1]
            ly = F[q, 1, 0] * L[c, 0] + F[q, 1, 1] * L[c, 1]
            d = np.sqrt(lx * lx + ly * ly)
            eps = R[c] - d
            if eps < 0.0:
                continue
            n = (lx / d, ly / d)
            for a in range(2):
                for b in range(2):
                    P[q, a, b] -= K * eps * n[a] * L[c, b]
                    for cc in range(2):
                        for dd in range(2):
                            m = R[c] * n[a] * n[cc] - (eps if a == cc else 0.0)
                            A[q, a, b, cc, dd] += K / d * m * L[c, b] * L[c, dd]


def numpy_vectorised(F, L, R, K):
    """Eqs. 10 and 13 vectorised over candidates, looping over points."""
    P = np.empty((len(F), 2, 2))
    A = np.empty((len(F), 2, 2, 2, 2))
    I = np.eye(2)
    for q, f in enumerate(F):
        l = L @ f.T
        d = np.sqrt(np.einsum("mi,mi->m", l, l))
        eps = R - d
        on = eps >= 0.0
        Lc, lc, dc, ec, Rc = L[on], l[on], d[on], eps[on], R[on]
        n = lc / dc[:, None]
        P[q] = -K * np.einsum("m,ma,mb->ab", ec, n, Lc)
        M = np.einsum("m,ma,mc->mac", Rc, n, n) - ec[:, None, None] * I
        A[q] = K * np.einsum("m,mac,mb,md->abcd", 1.0 / dc, M, Lc, Lc)
    return P, A


def best_time(fn, repeats):
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=2000, help="quadrature points per batch")
    parser.add_argument("--sizes", type=int, nargs="+", default=[70, 350, 700, 2800])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)

    rng = np.random.default_rng(0)
    F = 0.98 * np.eye(2) + rng.normal(0.0, 2e-3, (args.points, 2, 2))
    print(f"# kernel benchmark: {platform.processor() or platform.machine()}, "
          f"numba {numba.__version__}, numpy {np.__version__}, 1 thread, {args.points} points "
          f"at ~2 % isotropic compression")
    header = (f"{'particles':>9} {'candidates':>10} {'contacts':>8} | {'taylor P+A':>10} "
              f"{'taylor P':>9} {'numba loop':>10} {'numpy':>9} | {'speed-up vs loop':>16}")
    print(header + "\n" + "-" * len(header))
    for n in args.sizes:
        rve = TaylorRVE(generate_packing(n, seed=0), K_N)
        L, R, K = rve._L, rve._R, rve._K
        contacts = np.mean([len(rve.contacts(f).force) for f in F[:20]])
        W, P, A = rve.evaluate(F)
        P1, A1 = np.empty_like(P), np.empty_like(A)
        numba_loop(F, L, R, K, P1, A1)
        m = min(args.points, 50)
        P2, A2 = numpy_vectorised(F[:m], L, R, K)
        scale_P, scale_A = np.abs(P).max(), np.abs(A).max()
        err = max(np.abs(P1 - P).max() / scale_P, np.abs(A1 - A).max() / scale_A,
                  np.abs(P2 - P[:m]).max() / scale_P, np.abs(A2 - A[:m]).max() / scale_A)
        assert err < 1e-12, f"implementations disagree: {err:.2e}"

        t_full = best_time(lambda: rve.evaluate(F), args.repeats) / args.points
        t_stress = best_time(lambda: rve.stress(F), args.repeats) / args.points
        t_loop = best_time(lambda: numba_loop(F, L, R, K, P1, A1), args.repeats) / args.points
        t_numpy = best_time(lambda: numpy_vectorised(F[:m], L, R, K), 2) / m
        us = 1e6
        print(f"{n:>9} {rve.n_candidates:>10} {contacts:>8.0f} | {t_full * us:>10.2f} "
              f"{t_stress * us:>9.2f} {t_loop * us:>10.2f} {t_numpy * us:>9.1f} | "
              f"{t_loop / t_full:>15.1f}x")
    print("(µs per quadrature point; results of all implementations agree to < 1e-12 relative)")


if __name__ == "__main__":
    main()
