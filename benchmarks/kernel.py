"""Kernel speed: µs per quadrature point for P and A, beside two plain implementations.

Run: ``.venv/bin/python benchmarks/kernel.py [--points 2000] [--sizes 70 350 700 2800]``.

For generated packings (seed 0) at about 2 % isotropic compression (each point perturbed by
~0.2 % so that no two are equal: :func:`deformations`) it prints, per particle count:
- ``taylor P+A`` / ``taylor P``: :class:`TaylorRVE` ``evaluate`` / ``stress`` (the package kernel);
- ``numba loop``: a straightforward Numba loop over the fixed candidate list, summing eqs. 10 and
  13 contact by contact into the 16 entries of A;
- ``numpy``: the same formulas vectorised over the candidates with NumPy, one point at a time.
All three are checked to agree before timing (:func:`compare`, which the performance report
``benchmarks/report.py`` uses too). One process, one thread.
"""

import argparse
import platform

from dolfinx_granular import TaylorRVE, generate_packing
from dolfinx_granular.laws.tools import singular_values_2x2
from dolfinx_granular.timing import time_per_point

import numba
import numpy as np
from numba import njit

K_N = 2.8e7  # normal contact stiffness, N/m² (table 1 of the paper)


def deformations(points, seed=0):
    """(points, 2, 2) deformation gradients at about 2 % isotropic compression, each entry
    perturbed by N(0, 2e-3): the kernel benchmark's load."""
    rng = np.random.default_rng(seed)
    return 0.98 * np.eye(2) + rng.normal(0.0, 2e-3, (points, 2, 2))


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


def compare(rve, F, repeats=5, numpy_points=50):
    """The package kernel beside the two baselines on the points F (n, 2, 2).

    Checks that all three agree, then times each with
    :func:`~dolfinx_granular.timing.time_per_point` (best of ``repeats``; NumPy on the first
    ``numpy_points`` points only, best of 2: it is slow).

    Returns:
        dict of ``candidates``; ``visited`` and ``active``: candidate contacts per point the
        kernel evaluates (|L|/R <= 1/s_min(F)) and those in touch (mean over the first 50
        points); ``agree``: largest difference between the implementations relative to max |P|
        or max |A|; ``us_pa``, ``us_p``, ``us_loop``, ``us_numpy``: µs per point of
        ``evaluate`` (P and A), ``stress`` (P), the Numba loop and NumPy (both P and A).
    """
    c = rve.candidates
    L, R, K = c.branch, c.radius_sum, rve.normal_stiffness / rve.packing.area
    m = min(len(F), numpy_points)
    W, P, A = rve.evaluate(F)
    P1, A1 = np.empty_like(P), np.empty_like(A)
    numba_loop(F, L, R, K, P1, A1)
    P2, A2 = numpy_vectorised(F[:m], L, R, K)
    scale_P, scale_A = np.abs(P).max(), np.abs(A).max()
    agree = max(
        np.abs(P1 - P).max() / scale_P,
        np.abs(A1 - A).max() / scale_A,
        np.abs(P2 - P[:m]).max() / scale_P,
        np.abs(A2 - A[:m]).max() / scale_A,
    )
    if not agree < 1e-12:
        raise AssertionError(
            f"kernel implementations disagree ({rve.packing.n_particles} particles): {agree:.2e}"
        )
    smin = singular_values_2x2(F)[1]
    return {
        "candidates": rve.n_candidates,
        "visited": float(np.mean(c.visited(smin))),
        "active": float(np.mean([len(rve.contacts(f).force) for f in F[:50]])),
        "agree": float(agree),
        "us_pa": 1e6 * time_per_point(rve.evaluate, F, repeats),
        "us_p": 1e6 * time_per_point(rve.stress, F, repeats),
        "us_loop": 1e6 * time_per_point(lambda G: numba_loop(G, L, R, K, P1, A1), F, repeats),
        "us_numpy": 1e6 * time_per_point(lambda G: numpy_vectorised(G, L, R, K), F[:m], 2),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=2000, help="quadrature points per batch")
    parser.add_argument("--sizes", type=int, nargs="+", default=[70, 350, 700, 2800])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args(argv)

    F = deformations(args.points)
    print(
        f"# kernel benchmark: {platform.processor() or platform.machine()}, "
        f"numba {numba.__version__}, numpy {np.__version__}, 1 thread, {args.points} points "
        f"at ~2 % isotropic compression"
    )
    header = (
        f"{'particles':>9} {'candidates':>10} {'contacts':>8} | {'taylor P+A':>10} "
        f"{'taylor P':>9} {'numba loop':>10} {'numpy':>9} | {'speed-up vs loop':>16}"
    )
    print(header + "\n" + "-" * len(header))
    for n in args.sizes:
        r = compare(TaylorRVE(generate_packing(n, seed=0), K_N), F, args.repeats)
        print(
            f"{n:>9} {r['candidates']:>10} {r['active']:>8.0f} | {r['us_pa']:>10.2f} "
            f"{r['us_p']:>9.2f} {r['us_loop']:>10.2f} {r['us_numpy']:>9.1f} | "
            f"{r['us_loop'] / r['us_pa']:>15.1f}x"
        )
    print("(µs per quadrature point; results of all implementations agree to < 1e-12 relative)")


if __name__ == "__main__":
    main()
