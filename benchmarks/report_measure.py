"""The report's measurements outside the slope runs: the kernel against its baselines (as a
fraction of the machine's floating-point peak, which ``benchmarks/flops.py`` measures),
post-processing and force-network costs, the machine and software versions.
"""

from __future__ import annotations

import os
import platform
import subprocess
import time

from dolfinx_granular import TaylorRVE
from dolfinx_granular.timing import time_per_point

import numpy as np

import kernel as kbench  # benchmarks/kernel.py: the one kernel comparison

BENCHMARKS = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(BENCHMARKS)
K_N = kbench.K_N  # N/m², table 1 of the paper

# Floating-point operations per visited candidate in kernel._moment_sums (sqrt and division
# counted as one each): l = F L (6), d (4), eps (1), 1/d (1), products xx, xy, yy (3), b (1),
# sum eps^2 (2), S (6) -> 24; the tangent adds r/d^3 (3) and T (15) -> 42. Per point, outside the
# candidate loop: F check ~20, P 16, W 2; A 16 x 13 = 208.
FLOPS_CANDIDATE = {"P": 24, "PA": 42}
FLOPS_POINT = {"P": 38, "PA": 246}


def kernel_rows(sizes, points, repeats, packings, peak) -> list[dict]:
    """One row per particle count: :func:`kernel.compare` on ``points`` deformation gradients
    (seed-0 packing of ``packings``, a PackingCache), plus contacts per second, GFLOP/s and the
    fraction of the measured peak (``peak``: :func:`flops.measure`)."""
    F = kbench.deformations(points)
    rows = []
    for n in sizes:
        r = kbench.compare(TaylorRVE(packings.get(n, 0), K_N), F, repeats)
        t_pa, t_p = 1e-6 * r["us_pa"], 1e-6 * r["us_p"]
        gf_pa = (r["visited"] * FLOPS_CANDIDATE["PA"] + FLOPS_POINT["PA"]) / t_pa / 1e9
        gf_p = (r["visited"] * FLOPS_CANDIDATE["P"] + FLOPS_POINT["P"]) / t_p / 1e9
        rows.append(
            dict(
                r,
                particles=n,
                visited_per_s_pa=r["visited"] / t_pa,
                active_per_s_pa=r["active"] / t_pa,
                visited_per_s_p=r["visited"] / t_p,
                gflops_pa=gf_pa,
                gflops_p=gf_p,
                peak_frac_pa=gf_pa / peak["gflops_per_core"],
                peak_frac_p=gf_p / peak["gflops_per_core"],
            )
        )
    return rows


def final_state_costs(rve, F, repeats) -> dict:
    """At the final state of a slope run (F (n, 2, 2) at every point, the law ``rve``):
    ``post``, :func:`stress_only_costs` and the points; ``network``,
    :func:`force_network_costs` at 4 points spread over the list, as the slope's figure has."""
    post = dict(stress_only_costs(rve, F, repeats), points=len(F))
    probes = np.linspace(0, len(F) - 1, 4).astype(int)
    return {"post": post, "network": force_network_costs(rve, F, probes)}


def stress_only_costs(rve, F, repeats) -> dict:
    """Seconds for post-processing at all points F (n, 2, 2): Cauchy stress or P alone against
    P and A or the spatial tangent (best of ``repeats``)."""
    n = len(F)
    return {
        name: n * time_per_point(getattr(rve, name), F, repeats)
        for name in ("cauchy", "stress", "evaluate", "spatial_tangent")
    }


def force_network_costs(rve, F, probes) -> dict:
    """Force networks (``rve.contacts``) at the figure's probe points only, against every point
    of F (n, 2, 2): seconds, contacts and bytes."""
    t = time.perf_counter()
    few = sum(len(rve.contacts(F[q]).force) for q in probes)
    t_few = time.perf_counter() - t
    t = time.perf_counter()
    total = sum(len(rve.contacts(f).force) for f in F)
    t_all = time.perf_counter() - t
    # a ContactSet holds per contact: pairs (2 int64), shift (2 int64), branch (2 float64),
    # overlap and force (float64): 64 bytes
    return {
        "points_few": len(probes),
        "time_few": t_few,
        "contacts_few": few,
        "bytes_few": 64 * few,
        "points_all": len(F),
        "time_all": t_all,
        "contacts_all": total,
        "bytes_all": 64 * total,
    }


def versions() -> dict:
    """Versions of the package (with the git commit), Python and the numerical stack."""
    import dolfinx_granular

    import dolfinx
    import mpi4py
    import numba
    import petsc4py
    import ufl
    from mpi4py import MPI
    from petsc4py import PETSc

    try:
        sha = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=10,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        sha = ""
    mpi = MPI.Get_library_version().replace("\x00", "").strip().splitlines()[0]
    return {
        "dolfinx_granular": dolfinx_granular.__version__ + (f" (git {sha})" if sha else ""),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "dolfinx": dolfinx.__version__,
        "ufl": ufl.__version__,
        "petsc4py": petsc4py.__version__,
        "PETSc": ".".join(map(str, PETSc.Sys.getVersion())),
        "mpi4py": mpi4py.__version__,
        "MPI": " ".join(mpi.split(",")[0].split()),
    }


def lu_solver() -> str:
    """The LU the solver uses: MUMPS where PETSc has it, else PETSc's own (serial only)."""
    from petsc4py import PETSc

    return "MUMPS" if PETSc.Sys.hasExternalPackage("mumps") else "PETSc's own LU"


def cpu_model() -> str:
    """The processor's name (``/proc/cpuinfo``, else what ``platform`` knows)."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()
