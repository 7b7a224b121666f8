"""Packing generation speed: seconds of ``generate_packing(n, seed=...)`` and the log-log slope.

Run: ``.venv/bin/python benchmarks/generation.py [--sizes 700 2800 11200 45000] [--seed 0]
[--progress]``.

Per size it prints the wall time (the Numba compilation is done beforehand by a 70-disk run and
not counted), the volume fraction, the FIRE steps of the jamming search in all, the wall time per
disk and step (ns; the whole run over steps x n, so it includes the stages after the jamming), the
packing's sha256 (first 12 hex digits of ``portable.digest(centers, radii, box)``: the same on
every machine, so a different one means a different packing, not a slower one) and the slope
d log(t) / d log(n) from the previous size; at the end the least-squares slope over all sizes. A
slope of 1 is linear time. One process, one thread; ``--progress`` prints the generator's
progress lines to stderr.
"""

import argparse
import platform
import re
import sys
import time

from dolfinx_granular import generate_packing
from dolfinx_granular.packings.portable import digest

import numba
import numpy as np

_STEPS = re.compile(r"after (\d+) FIRE steps")


def fire_steps(lines):
    """FIRE steps in all of the jamming search, from its progress lines ("... after N FIRE
    steps")."""
    return sum(int(m.group(1)) for m in map(_STEPS.search, lines) if m)


def time_sizes(sizes, seed=0, progress=None):
    """Seconds (len(sizes),) of one ``generate_packing(n, seed=seed)`` per n, and the packings."""
    generate_packing(70, seed=9)  # compile (or load the cached kernels) outside the timing
    seconds, packings = [], []
    for n in sizes:
        t0 = time.perf_counter()
        packings.append(generate_packing(n, seed=seed, progress=progress))
        seconds.append(time.perf_counter() - t0)
    return np.array(seconds), packings


def loglog_slope(sizes, seconds):
    """Least-squares slope of log(seconds) over log(sizes) (nan for fewer than two sizes)."""
    if len(sizes) < 2:
        return float("nan")
    return float(np.polyfit(np.log(sizes), np.log(seconds), 1)[0])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[700, 2800, 11200, 45000])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--progress", action="store_true", help="progress lines on stderr")
    args = parser.parse_args(argv)
    sizes = sorted(args.sizes)

    lines = []

    def show(line):
        lines.append(line)
        if args.progress:
            print(f"    {line}", file=sys.stderr, flush=True)

    print(
        f"generate_packing, seed {args.seed}: Python {platform.python_version()}, numba "
        f"{numba.__version__}, numpy {np.__version__}"
    )
    print(
        f"{'n':>8} {'seconds':>10} {'phi':>8} {'FIRE steps':>11} {'ns/disk/step':>13} "
        f"{'sha256':>12} {'slope':>7}"
    )
    seconds = []
    for k, n in enumerate(sizes):
        lines.clear()
        t, (p,) = time_sizes([n], args.seed, show)
        seconds.append(t[0])
        steps = fire_steps(lines)
        slope = f"{loglog_slope(sizes[k - 1 : k + 1], seconds[-2:]):7.2f}" if k else ""
        print(
            f"{n:8d} {t[0]:10.2f} {p.volume_fraction:8.4f} {steps:11d} "
            f"{1e9 * t[0] / (steps * n):13.1f} {digest(p.centers, p.radii, p.box)[:12]} {slope}",
            flush=True,
        )
    print(f"log-log slope over all sizes: {loglog_slope(sizes, seconds):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
