"""Command line: ``python -m dolfinx_granular <command> ...`` (installed as ``dolfinx-granular``).

Commands:
    generate N [--seed S] [-o packing.npz] [--force] [--d-min MM] [--sieve-curve CSV] [--aspect A]
        Write a jammed, stress-free periodic packing of N disks (see
        :func:`dolfinx_granular.generate_packing`); an existing file is kept unless
        ``--force``. The arguments are checked before the output file.
    relax PACKING -o OUT.npz [--force]
        Make an overlapping packing stress-free (see
        :func:`dolfinx_granular.relax_overlaps`): minimal moves of the disks, or, for
        overlaps too large for that, the disks jammed afresh in the same cell.
    strength [--law relaxed|taylor] [--particles N] [--seeds 0,1,2] [--mus 0,0.1,0.3,0.5,1]
            [--pressures 1e-2,1e-3] [--max-strain 0.3] [--steps K] [--kn KN] [--kt KT]
            [--substep H] [--budget S] [--cache DIR] [-o strength.csv] [--force] [--each-step]
        Biaxial tests of the frictional relaxed (or Taylor) RVE: print and write the strength
        curve, peak and critical-state friction angles per mu and p / k_n (see
        :func:`dolfinx_granular.drivers.strength.strength_curve`); each test is cached in
        ``--cache``, so that a run started again goes on where it stopped.

A user error (bad argument, bad sieve curve, unwritable file) prints one line ``error: ...`` to
stderr and exits with status 2; ``--debug`` shows the traceback instead. New commands register a
sub-parser in :func:`build_parser` and a handler taking the parsed arguments.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import TYPE_CHECKING

import numpy as np

from .io.commandline import Parser, checked_values, world_rank

if TYPE_CHECKING:
    from collections.abc import Sequence


class _Parser(Parser):
    """argparse with one-line errors (``error: ...``, exit 2) instead of the usage block."""

    def error(self, message):
        raise _UsageError(f"{message} (see '{self.prog} --help')")


class _UsageError(ValueError):
    pass


PROGRESS_AFTER = 1.0  # seconds before `generate` prints progress: a fast run stays silent
PROGRESS_EVERY = 10.0  # seconds between heartbeat lines of `generate` (stage events: always)
_AUTO = object()  # --d-min not given: 0.5 mm for the shipped sand, none for a user curve


def _integer(text):
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def _d_min(text):
    if text.lower() in ("none", "0", "off"):
        return None
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a size in mm or 'none', got {text!r}") from None


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="python -m dolfinx_granular",
        description="dolfinx_granular's command line (also installed as "
        "dolfinx-granular). 'python -m dolfinx_granular COMMAND --help' describes a "
        "command; the slope benchmark is 'python -m dolfinx_granular.slope'.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    gen = sub.add_parser(
        "generate",
        help="write a jammed periodic packing from a sieve curve",
        description="Generate a jammed, stress-free periodic disk packing (FIRE soft-disk "
        "jamming, O'Hern et al. 2003) sized by a sieve curve (default: CEN standard sand).",
    )
    gen.add_argument("n_particles", type=_integer, help="number of disks (>= 2)")
    gen.add_argument("--seed", type=_integer, default=0, help="random seed (default 0)")
    gen.add_argument(
        "-o",
        "--output",
        default="packing.npz",
        help="output .npz file (default packing.npz; kept if it exists, see --force)",
    )
    gen.add_argument("--force", action="store_true", help="overwrite an existing output file")
    gen.add_argument(
        "--d-min",
        type=_d_min,
        default=_AUTO,
        metavar="MM",
        help="cut size in mm: finer grains are left out ('none' keeps the whole curve; "
        "default 0.5 for the CEN sand, none for a user curve)",
    )
    gen.add_argument(
        "--sieve-curve",
        metavar="CSV",
        help="sieve curve file: '#' comments, a header, rows 'aperture_mm, passing_percent'",
    )
    gen.add_argument("--aspect", type=float, default=1.0, help="cell height / width (default 1)")
    gen.add_argument("--quiet", action="store_true", help="no progress lines")
    gen.add_argument("--debug", action="store_true", help=argparse.SUPPRESS)
    gen.set_defaults(handler=_cmd_generate)

    relax = sub.add_parser(
        "relax",
        help="make a packing whose disks overlap stress-free",
        description="Move the disks of a packing file minimally so that every contact of its "
        "network overlaps by 1e-11 of the mean diameter (the generator's last stage): a "
        "prestressed reference state becomes stress-free. Overlaps too large for small moves "
        "(e.g. radii x 1.5 of a generated packing) are removed by jamming the disks afresh in the "
        "same cell, at radii scaled by one common factor.",
    )
    relax.add_argument("packing", help="input packing .npz")
    relax.add_argument("-o", "--output", required=True, help="output .npz file")
    relax.add_argument("--force", action="store_true", help="overwrite an existing output file")
    relax.add_argument("--debug", action="store_true", help=argparse.SUPPRESS)
    relax.set_defaults(handler=_cmd_relax)
    _add_strength(sub)
    return parser


def _add_strength(sub):
    """The ``strength`` sub-parser (defaults: the issue's curve, 200 disks, 3 seeds)."""
    from .packings.generation import MAX_PRESSURE

    st = sub.add_parser(
        "strength",
        help="the strength curve of an RVE: biaxial tests, peak and critical friction angles",
        description="Biaxial tests (sigma_11 = -p held, the axial strain eps1 prescribed) of "
        "the frictional relaxed RVE on jammed packings, for each contact friction mu, "
        "confining pressure p / k_n and seed; prints and writes the strength curve per mu and "
        "p / k_n: sin phi = q / p at the peak and at the critical state (the mean over the last "
        "quarter of the strain reached), phi in degrees and tan phi, mean and std over the "
        "seeds, how far the tests got and why any stopped. Every test is kept in --cache: a "
        "run started again (or with more mu, p or seeds) runs only the tests it lacks.",
    )
    whole = checked_values(int, lambda v: v >= 10, "a whole number >= 10", "200")
    seeds = checked_values(int, lambda v: v >= 0, "comma-separated whole numbers >= 0", "0,1", True)
    mus = checked_values(float, lambda v: v >= 0.0, "comma-separated mu >= 0", "0,0.5", True)
    range_p = f"comma-separated p / k_n in (0, {MAX_PRESSURE:g}]"
    pressures = checked_values(float, lambda v: 0.0 < v <= MAX_PRESSURE, range_p, "1e-2", True)
    strain = checked_values(float, lambda v: 0.0 < v < 0.9, "an axial strain in (0, 0.9)", "0.3")
    steps = checked_values(int, lambda v: v >= 1, "a whole number >= 1", "60")
    stiffness = checked_values(float, lambda v: v > 0.0, "a stiffness > 0 in N/m²", "2.8e7")
    substep = checked_values(float, lambda v: v > 0.0, "a substep > 0", "5e-4")
    budget = checked_values(float, lambda v: v >= 0.0, "seconds >= 0 (0: none)", "600")
    add = st.add_argument
    add("--law", choices=("relaxed", "taylor"), default="relaxed",
        help="relaxed: FrictionalRelaxedRVE (default); taylor: FrictionalRVE")  # fmt: skip
    add("--particles", type=whole, default=200, help="disks per packing (default 200)")
    add("--seeds", type=seeds, default=(0, 1, 2), help="packing seeds (default 0,1,2)")
    add("--mus", type=mus, default=(0.0, 0.1, 0.3, 0.5, 1.0),
        help="contact friction coefficients (default 0,0.1,0.3,0.5,1)")  # fmt: skip
    rolling = checked_values(float, lambda v: v >= 0.0, "comma-separated mu_r >= 0", "0,0.1", True)
    add("--rolling", type=rolling, default=(0.0,),
        help="rolling friction coefficients mu_r of the relaxed RVE, each with every mu: the "
        "rolling moment's cap mu_r r_eff f_n (default 0: none)")  # fmt: skip
    add("--pressures", type=pressures, default=(1e-2, 1e-3),
        help="confining pressures p / k_n (default 1e-2,1e-3)")  # fmt: skip
    add("--max-strain", type=strain, default=0.3, help="the last axial strain (default 0.3)")
    add("--steps", type=steps, default=60, help="equal steps to --max-strain (default 60)")
    add("--kn", type=stiffness, default=2.8e7, help="k_n in N/m² (default 2.8e7)")
    add("--kt", type=stiffness, default=2.8e7, help="k_t in N/m² (default 2.8e7)")
    add("--substep", type=substep, help="the relaxed RVE's substep (default its own, 1e-3)")
    add("--budget", type=budget, default=0.0,
        help="wall seconds per test (default 0: none); a test stopped by it goes on from its "
        "last step under a larger one")  # fmt: skip
    add("--cache", metavar="DIR", help="folder of the packings and tests (default: "
        "strength_cache beside the output file; kept by --force)")  # fmt: skip
    add("-o", "--output", default="strength.csv",
        help="output CSV (default strength.csv; kept if it exists, see --force)")  # fmt: skip
    add("--force", action="store_true", help="overwrite an existing output file")
    add("--quiet", action="store_true", help="no line per test")
    add("--each-step", action="store_true", help="a line per step of the tests that run, too")
    add("--debug", action="store_true", help=argparse.SUPPRESS)
    st.set_defaults(handler=_cmd_strength)


def _cmd_generate(args) -> int:
    from .packings.generation import _check_sizes, _seed, generate_packing, network_stats
    from .packings.gsd import DEFAULT_D_MIN, SieveCurve

    gsd = SieveCurve.from_csv(args.sieve_curve) if args.sieve_curve else None
    d_min = args.d_min
    if d_min is _AUTO:
        d_min = None if gsd is not None else DEFAULT_D_MIN
    # the arguments first: a bad count is the error to fix, whatever the output file
    _check_sizes(args.n_particles, gsd, d_min, args.aspect)
    _seed(args.seed)
    _check_output(args)
    t0 = time.perf_counter()

    last = [-PROGRESS_EVERY]  # time of the last printed line

    def progress(line):
        # slow runs (large N, first-call compilation) print every stage event (each
        # minimisation's pressure and steps, the jammed state, the end) and, in between, a
        # heartbeat at most every PROGRESS_EVERY seconds
        now = time.perf_counter() - t0
        if args.quiet or now < PROGRESS_AFTER:
            return
        if line.heartbeat and now - last[0] < PROGRESS_EVERY:
            return
        last[0] = now
        print(f"[{now:6.1f} s] {line.strip()}", file=sys.stderr, flush=True)

    packing = generate_packing(
        args.n_particles, gsd, seed=args.seed, d_min=d_min, aspect=args.aspect, progress=progress
    )
    packing.save(args.output)
    s = network_stats(packing)
    print(
        f"wrote {args.output}: {packing.n_particles} disks, box {packing.box[0]:.4g} x "
        f"{packing.box[1]:.4g} mm, volume fraction {s.volume_fraction:.4f}, coordination "
        f"{s.coordination:.3f}, rattlers {100 * s.rattler_fraction:.1f} % "
        f"({time.perf_counter() - t0:.1f} s)"
    )
    return 0


def _check_output(args):
    if not args.output.endswith(".npz"):
        raise ValueError(f"the output file must end in .npz, got {args.output!r}")
    if os.path.exists(args.output) and not args.force:
        raise ValueError(
            f"{args.output!r} exists; choose another name with -o, or pass --force to overwrite it"
        )


def _cmd_relax(args) -> int:
    from .laws.taylor import TaylorRVE
    from .packings.generation import relax_overlaps
    from .packings.packing import Packing

    _check_output(args)
    before = Packing.load(args.packing)
    after = relax_overlaps(before)
    after.save(args.output)
    ratio = TaylorRVE(after, 1.0).prestress_ratio
    # displacements between nearest images: a disk that crossed the cell boundary moved little
    step = after.centers - before.centers
    step -= np.rint(step / before.box) * before.box
    moved = np.abs(step).max() / before.radii.mean()
    print(
        f"wrote {args.output}: {after.n_particles} disks, centres moved up to {100 * moved:.2g} "
        f"% of the mean radius, radii changed up to "
        f"{100 * np.abs(after.radii / before.radii - 1).max():.2g} %; |P(I)| / |C| = {ratio:.1e}"
    )
    return 0


def _cmd_strength(args) -> int:
    from .drivers.strength import curve_rows, strength_tests
    from .io.strength_table import curve_lines, write_curve

    if not args.output.endswith(".csv"):
        raise ValueError(f"the output file must end in .csv, got {args.output!r}")
    if os.path.exists(args.output) and not args.force:
        raise ValueError(
            f"{args.output!r} exists; choose another name with -o, or pass --force to overwrite it"
        )
    folder = os.path.dirname(args.output) or "."
    if not os.path.isdir(folder):
        raise ValueError(f"the folder of {args.output!r} does not exist: create it, or choose -o")
    if args.substep is not None and args.law != "relaxed":
        raise ValueError("--substep is a setting of the relaxed RVE: leave it out for --law taylor")
    if any(args.rolling) and args.law != "relaxed":
        raise ValueError("--rolling is a setting of the relaxed RVE: leave it out for --law taylor")
    if world_rank() != 0:  # (a serial command: under mpirun rank 0 runs it, the others rest)
        return 0
    cache = args.cache or os.path.join(os.path.dirname(args.output), "strength_cache")
    say = None if args.quiet else (lambda line: print(line, flush=True))
    t0 = time.perf_counter()
    tests = strength_tests(
        particles=args.particles, seeds=args.seeds, mus=args.mus, pressures=args.pressures,
        max_strain=args.max_strain, steps=args.steps, k_n=args.kn, k_t=args.kt, law=args.law,
        substep=args.substep, budget=args.budget or None, cache=cache, say=say,
        rolling=args.rolling, each_step=args.each_step,
    )  # fmt: skip
    curve = curve_rows(tests)
    write_curve(args.output, curve)
    print("\n".join(curve_lines(curve)))
    ran = sum(not t["cached"] for t in tests)
    print(f"wrote {args.output}: {len(curve)} rows, {len(tests)} tests ({ran} run, "
          f"{len(tests) - ran} from {cache}) in {time.perf_counter() - t0:.1f} s")  # fmt: skip
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help(sys.stderr)
            return 2
        return args.handler(args)
    except (ValueError, OSError) as err:
        if debug:
            raise
        if world_rank() == 0:  # (once under mpirun)
            print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
