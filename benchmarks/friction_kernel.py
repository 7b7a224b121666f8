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

``--breakdown`` adds where the time goes, per point (the first point's F and history, each phase
repeated in a compiled loop, so without call overhead and with warm caches): copying the history
in, the contact loop for the stress only and with the tangent sums (small-increment polynomial
atan), the same with the general rational atan, the second pass over the new forces
(dissipation, energy and stick sums), the per-point rest (spin, angle set-up, W, P, A from the
sums), and the frictionless kernel's moment sums without and with the tangent terms. It then
counts the machine instructions per contact in the main loop of each compiled contact pass (x86
only). Both kernels retire about 4 instructions per ns on the EPYC this was written on, so the
counts account for the ratio of their times.
"""

import argparse
import platform
import re

from dolfinx_granular import TaylorRVE, generate_packing, timing
from dolfinx_granular.laws import friction_kernel as fk
from dolfinx_granular.laws import taylor_kernel as kernel
from dolfinx_granular.laws.friction import FrictionalRVE

import numba
import numpy as np
from numba import njit

from kernel import K_N, deformations  # benchmarks/kernel.py (`kernel` here is the package's)

K_T = 0.5 * K_N
MU = 0.3


def best_time(fn, repeats):
    """Best wall time of ``fn()`` over ``repeats`` calls (s)."""
    return timing.best_time(fn, repeats)[0]


def shear(F, gamma):
    """F with a superposed simple shear gamma (x-displacement proportional to y)."""
    return np.einsum("ab,qbc->qac", np.array([[1.0, gamma], [0.0, 1.0]]), F)


def committed_state(rve, F0):
    """State after two committed steps: compression F0, then 1 % shear."""
    state = rve.initial_state(len(F0))
    for F in (F0, shear(F0, 0.01)):
        state = rve.stress(F, state)[2]
    return state


# Drivers for --breakdown: each phase `reps` times in compiled code (no on-disk cache: it breaks
# when the script is loaded under another module name).
@njit
def _drive_contact(reps, F, G, lmax2, X, Y, R, n_visit, history, work, ft, acc, general, tangent):
    F00, F01, F10, F11 = F[0, 0], F[0, 1], F[1, 0], F[1, 1]
    H = fk._spun_history(F00, F01, F10, F11, G[0, 0], G[0, 1], G[1, 0], G[1, 1])
    cq = fk._quadratic_forms(F00, F01, F10, F11, H[0], H[1], H[2], H[3], lmax2)
    for _ in range(reps):
        fk._copy_history(history, work)
        fk._contact_pass(
            F00, F01, F10, F11, cq, X, Y, R, n_visit, K_N, K_T, MU, general, tangent, work, ft, acc
        )


@njit
def _drive_copy(reps, history, ft):
    for _ in range(reps):
        fk._copy_history(history, ft)


@njit
def _drive_sums(reps, work, ft, R, n_visit, acc):
    for _ in range(reps):
        fk._history_sums(work, ft, R, n_visit, K_T, acc)


@njit
def _drive_finish(reps, F, G, acc, inv_area, W, P, A, M):
    H = fk._spun_history(F[0, 0], F[0, 1], F[1, 0], F[1, 1], G[0, 0], G[0, 1], G[1, 0], G[1, 1])
    for _ in range(reps):
        rot = fk._rotation(F[0, 0], F[0, 1], F[1, 0], F[1, 1])
        cq = fk._quadratic_forms(F[0, 0], F[0, 1], F[1, 0], F[1, 1], H[0], H[1], H[2], H[3], 1.0)
        acc[0] += cq[0] * 1e-300  # keep it
        fk._finish_point(0, F, acc, rot, K_N, inv_area, K_T, True, W, P, A, M)


@njit
def _drive_frictionless(reps, F, X, Y, R, n_visit, tangent, acc):
    # ``tangent`` None or True, a compile-time choice as in _drive_contact: one loop per driver
    for _ in range(reps):
        if tangent is None:
            kernel.moment_sums(F[0, 0], F[0, 1], F[1, 0], F[1, 1], X, Y, R, n_visit, False, acc)
        else:
            kernel.moment_sums(F[0, 0], F[0, 1], F[1, 0], F[1, 1], X, Y, R, n_visit, True, acc)


def breakdown(rve, F, state, repeats, reps=300):
    """µs per point of each phase (see the module docstring) at F[0] from state point 0."""
    F, G = np.ascontiguousarray(F[0]), np.ascontiguousarray(state.F[0])
    status, lengths = np.empty(1, np.int8), np.empty(1, np.int64)
    fk.prefix_lengths(F[None], rve.candidates.ratio, rve.min_stretch, status, lengths)
    m = int(lengths[0])
    history = np.array(state.forces(0))
    work, ft, acc = np.empty(m), np.empty(m), np.zeros(fk.N_ACC)
    X, Y = rve.candidates.components
    R = rve.candidates.radius_sum
    out = (np.empty(1), np.empty((1, 2, 2)), np.empty((1, 2, 2, 2, 2)), np.empty((6, 2, 2)))
    c = (F, G, rve.candidates.max_branch_length2, X, Y, R, m, history, work, ft, acc)
    phases = {
        "copy history": lambda: _drive_copy(reps, history, work),
        "contact P": lambda: _drive_contact(reps, *c, None, None),
        "contact P+A": lambda: _drive_contact(reps, *c, None, True),
        "general P+A": lambda: _drive_contact(reps, *c, True, True),
        "history sums": lambda: _drive_sums(reps, work, ft, R, m, acc),
        "per point": lambda: _drive_finish(reps, F, G, acc, 1.0 / rve.packing.area, *out),
        "frictionless P": lambda: _drive_frictionless(reps, F, X, Y, R, m, None, acc),
        "frictionless P+A": lambda: _drive_frictionless(reps, F, X, Y, R, m, True, acc),
    }
    result = {}
    for name, fn in phases.items():
        fn()  # compile
        result[name] = best_time(fn, repeats) / reps
    for name in ("contact P", "contact P+A", "general P+A"):
        result[name] -= result["copy history"]
    return result


_LABEL = re.compile(r"^(\.LBB\S+):")
_JUMP = re.compile(r"\s+j\w+\s+(\.LBB\S+)")
_LANES = {"zmm": 8, "ymm": 4, "xmm": 2}


def _sqrt_lanes(line):
    """Square roots that one assembly line takes (0 if it takes none)."""
    op = line.split()[0]
    if op not in ("vsqrtpd", "vsqrtsd", "sqrtpd", "sqrtsd"):
        return 0
    return 1 if op.endswith("sd") else next(n for reg, n in _LANES.items() if reg in line)


def instructions_per_contact(asm):
    """Instructions per contact in the main loop of x86 assembly ``asm``, or None.

    A loop is a label and a later jump back to it; of the innermost loops, the main one handles
    the most contacts per iteration, counted as its square roots (one per contact in both
    kernels) times their lanes."""
    lines = asm.splitlines()
    labels = {m.group(1): k for k, line in enumerate(lines) if (m := _LABEL.match(line))}
    loops = [
        (labels[m.group(1)], k)
        for k, line in enumerate(lines)
        if (m := _JUMP.match(line)) and labels.get(m.group(1), k) < k
    ]
    best = None
    for a, b in loops:
        if any(a <= c and d <= b and (c, d) != (a, b) for c, d in loops):
            continue  # an outer loop
        body = [s for s in lines[a : b + 1] if s.startswith("\t") and s[1] != "."]
        contacts = sum(_sqrt_lanes(s) for s in body)
        if contacts and (best is None or contacts > best[0]):
            best = (contacts, len(body))
    return None if best is None else best[1] / best[0]


def instruction_counts():
    """Instructions per contact of the contact passes compiled by :func:`breakdown`."""
    names = {
        ("none", "none"): "contact P",
        ("none", "bool"): "contact P+A",
        ("bool", "bool"): "general P+A",
        ("none",): "frictionless P",
        ("bool",): "frictionless P+A",
    }
    counts = {}
    for driver, flags in ((_drive_contact, slice(-2, None)), (_drive_frictionless, slice(-2, -1))):
        for sig, asm in driver.inspect_asm().items():
            key = tuple(str(t) for t in sig[flags])
            counts[names[key]] = instructions_per_contact(asm)
    return {name: counts.get(name) for name in names.values()}


def run_size(n, F0, repeats, with_breakdown=False):
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
    phases = breakdown(rve, F, state, repeats) if with_breakdown else None
    return {
        "n": n,
        "candidates": rve.n_candidates,
        "contacts": contacts,
        "sliding": sliding,
        "t0": t0,
        "t1": t1,
        "t2": t2,
        "bytes": state.nbytes / state.n_points,
        "breakdown": phases,
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=2000, help="quadrature points per batch")
    parser.add_argument("--sizes", type=int, nargs="+", default=[70, 350, 700, 2800])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--breakdown", action="store_true", help="time each phase of the kernel")
    args = parser.parse_args(argv)

    F0 = deformations(args.points)
    print(
        f"# friction kernel benchmark: {platform.processor() or platform.machine()}, "
        f"numba {numba.__version__}, numpy {np.__version__}, 1 thread, {args.points} points, "
        f"k_t/k_n = {K_T / K_N}, mu = {MU}"
    )
    header = (
        f"{'particles':>9} {'candidates':>10} {'contacts':>8} {'sliding':>7} | "
        f"{'frictionless P+A':>16} {'friction P+A':>12} {'friction P':>10} | "
        f"{'ratio':>6} | {'state B/pt':>10}"
    )
    print(header + "\n" + "-" * len(header))
    us = 1e6
    rows = []
    for n in args.sizes:
        r = run_size(n, F0, args.repeats, args.breakdown)
        rows.append(r)
        print(
            f"{n:>9} {r['candidates']:>10} {r['contacts']:>8.0f} {r['sliding']:>7.1%} | "
            f"{r['t0'] * us:>16.2f} {r['t1'] * us:>12.2f} {r['t2'] * us:>10.2f} | "
            f"{r['t1'] / r['t0']:>5.2f}x | {r['bytes']:>10.0f}"
        )
    print("(µs per quadrature point; 'sliding': share of the active contacts at the Coulomb limit)")
    if args.breakdown:
        names = list(rows[0]["breakdown"])
        print(
            f"\n# where the time goes (µs per point)\n{'particles':>9} "
            + " ".join(f"{k:>16}" for k in names)
        )
        for r in rows:
            print(f"{r['n']:>9} " + " ".join(f"{r['breakdown'][k] * us:>16.2f}" for k in names))
        counts = instruction_counts()
        print(
            "\n# machine instructions per contact in the main loop of each compiled pass\n"
            + " ".join(f"{k:>16}" for k in counts)
            + "\n"
            + " ".join(f"{v:>16.1f}" if v else f"{'n/a':>16}" for v in counts.values())
        )
        rows[0]["instructions"] = counts
    return rows


if __name__ == "__main__":
    main()
