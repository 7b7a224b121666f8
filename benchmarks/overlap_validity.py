"""The slope's validity measure: how far its contacts overlap, and what the measure costs.

Run: ``.venv/bin/python benchmarks/overlap_validity.py [--particles 700] [--seed 0]
[--load-factor 1] [--path-following] [--steps 20]`` (or under ``mpirun -n 2``).

Runs the slope (:class:`~dolfinx_granular.slope.run.SlopeRun`, output in a temporary folder) and,
at its final state, prints ``SlopeModel.overlap_validity()`` (largest overlap over the smaller
disk radius, where, the points beyond 10 %), the points beyond 5, 10, 20 and 50 %, the probes of
figure 7 (:func:`~dolfinx_granular.probe` at the model's four spots) and the wall time of
``overlap_statistics`` at the material's points and at four times as many (the 6080 points of
``--refine 2``), best of 5, beside the law's ``stress`` at the same points.
"""

import argparse
import json
import tempfile

from dolfinx_granular import generate_packing
from dolfinx_granular.fem.probing import probe
from dolfinx_granular.laws.validity import overlap_ratios
from dolfinx_granular.slope.run import SlopeOptions, SlopeRun

import numpy as np
from mpi4py import MPI

from friction_kernel import best_time  # benchmarks/friction_kernel.py


def measure(model, comm):
    """The lines to print (rank 0) for the model's final state; collective."""
    summary = model.overlap_validity()
    ratios = overlap_ratios(model.material)
    above = {t: comm.allreduce(int((ratios > t).sum())) for t in (0.05, 0.10, 0.20, 0.50)}
    law, F = model.material.rve, model.material.F
    F4 = np.concatenate([F] * 4)
    law.overlap_statistics(F[:1])  # compiled before timing
    times = [best_time(lambda G=G: law.overlap_statistics(G), 5) for G in (F, F4)]
    stress = best_time(lambda: law.stress(F), 5)
    spots = model.probes(model.extremes()[1][1])
    found = probe(model.material, [s[1] for s in spots])
    lines = [
        f"settlement {model.settlement():.6f} m",
        "overlap_validity " + json.dumps(summary),
        f"points beyond {{5, 10, 20, 50}} %: {list(above.values())} of {summary['points']}",
        f"overlap_statistics: {F.shape[0]} points {1e3 * times[0]:.2f} ms, {F4.shape[0]} points "
        f"{1e3 * times[1]:.2f} ms; stress at {F.shape[0]} points {1e3 * stress:.2f} ms (rank 0)",
    ]
    for (label, *_), x, ratio, contacts, z in zip(
        spots, found.points, found.max_overlap_ratio, found.contacts, found.coordination
    ):
        lines.append(
            f"probe {label} at {np.round(x, 3).tolist()} m: overlap ratio {ratio:.4f}, "
            f"{contacts:.0f} contacts, coordination {z:.3f}"
        )
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=700)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--load-factor", type=float, default=1.0)
    parser.add_argument("--path-following", action="store_true")
    parser.add_argument("--steps", type=int, default=20)
    args = parser.parse_args(argv)
    comm = MPI.COMM_WORLD
    packing = generate_packing(args.particles, seed=args.seed)
    options = SlopeOptions(
        steps=args.steps, load_factor=args.load_factor, path_following=args.path_following
    )
    with tempfile.TemporaryDirectory() as scratch:
        out = comm.bcast(scratch if comm.rank == 0 else None)
        run = SlopeRun(packing, options, out=out, comm=comm, verbose=False)
        run.run()
        lines = measure(run.model, comm)
        run.model.solver.destroy()
        comm.barrier()
    if comm.rank == 0:
        print("\n".join(lines))
    return lines


if __name__ == "__main__":
    main()
