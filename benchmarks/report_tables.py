"""Numbers derived from the report's raw results: per-iteration splits, best of repeats, the
speed-against-error rows and the targets. Pure functions of plain data (no measurement), so that
``report.py --render`` redraws everything from ``performance.json``.
"""

from __future__ import annotations

import numpy as np

LEVEL_NAMES = {
    "taylor": "Taylor RVE (full)",
    "taylor_skip": "Taylor, stress-only final residual",
    "small_strain": "SmallStrainRVE (eq. 15, quadrature)",
    "ufl_linear": "UFL linear (isotropic eq. 15)",
    "adaptive": "AdaptiveRVE (provable)",
    "adaptive_strain": "AdaptiveRVE (strain only)",
}
#: categories of a run's ``times`` / ``cpu`` that :func:`per_iteration` divides
_TIMED = (
    "F",
    "kernel",
    "assembly",
    "residual_assembly",
    "jacobian_assembly",
    "scale_assembly",
    "linear_solve",
    "newton",
)


def public(run) -> dict:
    """The run dict without its private entries (keys starting with ``_``: final F, law)."""
    return {k: v for k, v in run.items() if not k.startswith("_")}


def level_label(level, tol=None) -> str:
    return LEVEL_NAMES[level] + (f", tol {tol:g}" if tol is not None else "")


def per_iteration(run, clock="cpu") -> dict:
    """ms per Newton iteration of each category of a run, process CPU time (``"cpu"``) or wall
    time (``"wall"``); ``rest`` makes the parts add up to ``newton``, ``non_kernel`` is all but
    the kernel."""
    it = max(run["iterations"], 1)
    t = run["cpu"] if clock == "cpu" else run["times"]
    out = {k: 1e3 * t[k] / it for k in _TIMED}
    out["rest"] = out["newton"] - out["F"] - out["kernel"] - out["assembly"] - out["linear_solve"]
    out["non_kernel"] = out["newton"] - out["kernel"]
    return out


def best_of(runs, clock="cpu") -> dict:
    """Per category the minimum over repeated runs (same call counts) of the ms per iteration;
    the total is re-derived so that the parts add up."""
    rows = [per_iteration(r, clock) for r in runs]
    best = {k: min(r[k] for r in rows) for k in rows[0]}
    best["newton"] = (
        best["F"] + best["kernel"] + best["assembly"] + best["linear_solve"] + best["rest"]
    )
    best["non_kernel"] = best["newton"] - best["kernel"]
    return best


def iteration_summary(runs) -> dict:
    """``{level: {"run", "best", "best_wall", "spread_newton", "spread_wall"}}`` of the repeats
    ``{level: [runs]}``: the run with the least CPU time, the best-of split in CPU and wall time,
    and every repeat's ms per iteration (CPU, wall)."""
    out = {}
    for level, group in runs.items():
        fastest = min(group, key=lambda r: r["cpu"]["newton"])
        out[level] = {
            "run": public(fastest),
            "best": best_of(group),
            "best_wall": best_of(group, "wall"),
            "spread_newton": [per_iteration(r)["newton"] for r in group],
            "spread_wall": [per_iteration(r, "wall")["newton"] for r in group],
        }
    return out


def matched_linear(taylor, linear) -> float:
    """The UFL material's non-kernel CPU ms per iteration re-weighted to the Taylor run's call
    mix: its per-call residual assembly, Jacobian assembly and linear solve times times the Taylor
    run's calls per iteration, plus its own F, other assembly (round-off test) and rest per
    iteration (``taylor``, ``linear``: entries of :func:`iteration_summary`)."""
    lt, ll, b = taylor["run"], linear["run"], linear["best"]
    it_t, it_l = lt["iterations"], ll["iterations"]
    res_call = b["residual_assembly"] * it_l / ll["calls"]["residual"]
    jac_call = b["jacobian_assembly"] * it_l / ll["calls"]["jacobian"]
    lin_call = b["linear_solve"] * it_l / max(ll["calls"]["ksp"], 1)
    other = b["assembly"] - b["residual_assembly"] - b["jacobian_assembly"]
    return (
        (
            res_call * lt["calls"]["residual"]
            + jac_call * lt["calls"]["jacobian"]
            + lin_call * lt["calls"]["ksp"]
        )
        / it_t
        + other
        + b["rest"]
        + b["F"]
    )


def stats(values):
    """Mean and standard deviation (ddof 1; 0 for one value)."""
    v = np.asarray(values, dtype=float)
    return float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else 0.0


def speed_error_table(res):
    """Rows of the speed-against-error study and the reference values: mean and spread over
    seeds, errors against the mean of the largest RVE (and, for levels, against Taylor on the
    same packing)."""
    sizes = sorted({r["particles"] for r in res["sizes"]})
    ref_runs = [r for r in res["sizes"] if r["particles"] == sizes[-1] and r["converged"]]
    ref = {q: float(np.mean([r[q] for r in ref_runs])) for q in ("settlement", "max_von_mises")}
    rows, taylor_by_seed = [], {}
    for n in sizes:
        group = [r for r in res["sizes"] if r["particles"] == n]
        rows.append(_row(("taylor", None, n), group, ref))
        taylor_by_seed.update({(n, i): r for i, r in enumerate(group)})
    n0 = res["config"]["particles"]
    keys = list(dict.fromkeys((r["level"], r["tol"]) for r in res["levels"]))
    for level, tol in keys:
        group = [r for r in res["levels"] if r["level"] == level and r["tol"] == tol]
        base = [taylor_by_seed.get((n0, i)) for i in range(len(group))]
        rows.append(_row((level, tol, n0), group, ref, base))
    return rows, ref


def _row(key, group, ref, base=None) -> dict:
    level, tol, n = key
    ok = [r for r in group if r["converged"]]
    row = {
        "level": level,
        "tol": tol,
        "particles": n,
        "runs": len(group),
        "converged": len(ok),
        "wall": stats([r["wall_time"] for r in group]),
        "iterations": float(np.mean([r["iterations"] for r in group])),
    }
    for q in ("settlement", "max_von_mises"):
        nan = float("nan")
        row[q], row[q + "_err"], row[q + "_rms"] = (nan, nan), nan, nan
        if ok:
            mean, sd = stats([r[q] for r in ok])
            row[q] = (mean, sd)
            row[q + "_err"] = abs(mean - ref[q]) / abs(ref[q])
            rms = np.sqrt(np.mean([(r[q] - ref[q]) ** 2 for r in ok]))
            row[q + "_rms"] = float(rms) / abs(ref[q])
        if base and ok:
            diffs = [
                abs(r[q] - b[q]) / abs(b[q]) for r, b in zip(group, base) if b and r["converged"]
            ]
            row[q + "_model_err"] = float(np.mean(diffs)) if diffs else nan
    counts = [r["level_counts"] for r in group if r.get("level_counts")]
    if counts:
        linear = sum(c["linear"] for c in counts)
        total = sum(c["linear"] + c["taylor"] for c in counts)
        row["linear_fraction"] = linear / total if total else 0.0
    return row


def refinement_stats(runs) -> dict:
    """Of the mesh-refinement runs: CPU seconds per iteration per point (``per_point``), its
    largest deviation from the finest mesh's (``dev``), the log-log slope of time per iteration
    against points (``slope``) and the growth of LU time per point (``lu_growth``)."""
    per_point = [r["cpu"]["newton"] / max(r["iterations"], 1) / r["points"] for r in runs]
    q = np.array([r["points"] for r in runs], float)
    t = np.array([r["cpu"]["newton"] / max(r["iterations"], 1) for r in runs])
    slope = float(np.polyfit(np.log(q), np.log(t), 1)[0]) if len(q) > 1 else float("nan")
    lu = [per_iteration(r)["linear_solve"] / r["points"] for r in runs]
    return {
        "per_point": per_point,
        "dev": max(abs(p / per_point[-1] - 1) for p in per_point),
        "slope": slope,
        "lu_growth": lu[-1] / lu[0],
    }


def ranks_ok(res) -> bool:
    return all("error" not in res["ranks"][r] for r in (1, 2))


def rank_speedups(rk) -> dict:
    """1-rank over 2-rank times of the rank runs ``{1: run, 2: run}``."""
    return {
        "kernel": rk[1]["times"]["kernel"] / rk[2]["times"]["kernel"],
        "kernel_cpu": rk[1]["cpu"]["kernel"] / rk[2]["cpu"]["kernel"],
        "rve_bench": rk[1]["rve_bench"] / rk[2]["rve_bench"],
        "newton": rk[1]["times"]["newton"] / rk[2]["times"]["newton"],
        "newton_cpu": rk[1]["cpu"]["newton"] / rk[2]["cpu"]["newton"],
        "wall": rk[1]["wall_time"] / rk[2]["wall_time"],
    }


def targets(res) -> dict:
    """The measured values of the report's targets."""
    it = res["iteration"]
    t, lin = it["taylor"], it["ufl_linear"]
    out = {
        "non_kernel_raw": t["best"]["non_kernel"] / lin["best"]["non_kernel"],
        "non_kernel_matched": t["best"]["non_kernel"] / res["matched_linear"],
        "non_kernel_wall": t["best_wall"]["non_kernel"] / lin["best_wall"]["non_kernel"],
    }
    if ranks_ok(res):
        s = rank_speedups(res["ranks"])
        out.update(
            rank_speedup_kernel=s["kernel"],
            rank_speedup_kernel_cpu=s["kernel_cpu"],
            rank_speedup_newton=s["newton"],
            rank_speedup_newton_cpu=s["newton_cpu"],
            rank_speedup_rve_bench=s["rve_bench"],
        )
    ref = refinement_stats(res["refinement"])
    out.update(linear_growth_dev=ref["dev"], loglog_slope=ref["slope"])
    return out
