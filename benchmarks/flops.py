"""Measured floating-point peak of this machine: GFLOP/s per core of a vectorised Numba FMA loop.

Run: ``.venv/bin/python benchmarks/flops.py [--seconds 0.01] [--repeats 30]``.

Each of ``LANES`` independent accumulators is updated as ``a = a * b + c`` (one fused multiply-add,
2 flops) per step. The accumulators are separate scalar locals, which LLVM keeps in registers and
its SLP vectoriser packs 4 to an AVX2 register (``fastmath`` lets it contract to FMA); LANES = 40
gives 10 independent vector FMA chains, enough to hide an FMA latency of 4-5 cycles on two FMA pipes
(32 lanes already reach the plateau on the AMD EPYC this was written on; an accumulator *array*
round-trips through memory every step and reaches a tenth of it). One thread, so the figure is per
core; the machine's peak is that times the cores. It is what this interpreter actually reaches
here, not a datasheet value.
"""

import argparse
import json
import os
import subprocess
import sys
import time

import numba.core.config
import numpy as np
from numba import njit

LANES = 40  # independent accumulators (doubles): 10 AVX2 registers


def _make_loop(lanes):
    """Compile ``fma_loop(steps, b, c, init, out)`` with ``lanes`` scalar accumulators (source
    generated here, so that every accumulator is a separate local variable)."""
    lines = ["def fma_loop(steps, b, c, init, out):"]
    lines += [f"    a{k} = init[{k}]" for k in range(lanes)]
    lines.append("    for _ in range(steps):")
    lines += [f"        a{k} = a{k} * b + c" for k in range(lanes)]
    lines += [f"    out[{k}] = a{k}" for k in range(lanes)]
    namespace = {}
    exec("\n".join(lines), namespace)  # noqa: S102 - source generated above from integers only
    return njit(fastmath=True)(namespace["fma_loop"])


_LOOPS = {}


def flops_per_call(steps, lanes=LANES):
    """Floating-point operations of one loop call (an FMA counts 2)."""
    return 2.0 * lanes * steps


def measure(seconds=0.01, repeats=30, lanes=LANES):
    """Best GFLOP/s of one core over ``repeats`` runs of about ``seconds`` each.

    Many short runs: on a shared machine the best one is the one that had a core to itself.
    Numba >= 0.59 leaves LLVM's SLP vectoriser off, and then the loop runs on scalar registers (a
    quarter of the peak with AVX2): the measurement then runs in a child process with
    ``NUMBA_SLP_VECTORIZE=1``, leaving this process's Numba settings as they are.

    Returns:
        dict with ``gflops_per_core``, ``cores`` (os.cpu_count()), ``gflops_machine`` (per core
        times cores: the bound for a perfectly parallel code, not measured with threads),
        ``steps``, ``lanes`` and ``seconds`` (best run).
    """
    if not getattr(numba.core.config, "SLP_VECTORIZE", True):
        env = dict(os.environ, NUMBA_SLP_VECTORIZE="1")
        code = (
            f"import json, flops; print(json.dumps(flops.measure({seconds!r}, {repeats!r}, "
            f"{lanes!r})))"
        )
        proc = subprocess.run(
            [sys.executable, "-c", code],
            cwd=os.path.dirname(__file__),
            env=env,
            capture_output=True,
            text=True,
            timeout=600,
            check=True,
        )
        return json.loads(proc.stdout.strip().splitlines()[-1])
    if lanes not in _LOOPS:
        _LOOPS[lanes] = _make_loop(lanes)
    loop = _LOOPS[lanes]
    b, c = 0.999999, 1e-7  # a -> c / (1 - b) = 0.1: bounded, no overflow, no denormals
    init, out = np.linspace(0.5, 0.6, lanes), np.empty(lanes)
    loop(10, b, c, init, out)  # compile
    steps = 1000
    while True:
        t = time.perf_counter()
        loop(steps, b, c, init, out)
        dt = time.perf_counter() - t
        if dt > 0.02:
            break
        steps *= 4
    steps = max(int(steps * seconds / dt), 1)
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        loop(steps, b, c, init, out)
        best = min(best, time.perf_counter() - t)
    assert np.isfinite(out).all()
    g = flops_per_call(steps, lanes) / best / 1e9
    cores = os.cpu_count() or 1
    return {
        "gflops_per_core": g,
        "cores": cores,
        "gflops_machine": g * cores,
        "steps": steps,
        "lanes": lanes,
        "seconds": best,
    }


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=0.01, help="duration of one timed run")
    p.add_argument("--repeats", type=int, default=30, help="timed runs (the best counts)")
    a = p.parse_args(argv)
    m = measure(a.seconds, a.repeats)
    print(
        f"measured peak: {m['gflops_per_core']:.1f} GFLOP/s per core (FMA = 2 flops, {m['lanes']} "
        f"independent accumulators, best of {a.repeats} runs of {m['seconds'] * 1e3:.0f} ms); "
        f"x {m['cores']} cores = {m['gflops_machine']:.1f} GFLOP/s"
    )
    return m


if __name__ == "__main__":
    main()
