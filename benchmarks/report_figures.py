"""The report's figures (PNG), drawn from its raw results alone.

Figures are plain ``matplotlib.figure.Figure`` objects (no pyplot, no GUI backend, nothing left
open between figures).
"""

from __future__ import annotations

import os

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter

from report_tables import (
    LEVEL_NAMES,
    level_label,
    per_iteration,
    rank_speedups,
    ranks_ok,
    speed_error_table,
)

DPI = 110


def make_figures(res, out) -> dict:
    """Draw every figure into the folder ``out``; returns ``{name: file name}``."""
    return {
        "kernel": _save(kernel_figure(res), out, "perf_kernel.png"),
        "iteration": _save(iteration_figure(res), out, "perf_iteration.png"),
        "scaling": _save(scaling_figure(res), out, "perf_scaling.png"),
        "speed_error": _save(speed_error_figure(res), out, "perf_speed_error.png"),
    }


def _save(fig, out, name) -> str:
    fig.savefig(os.path.join(out, name), dpi=DPI)
    return name


def kernel_figure(res):
    """µs per point of the kernel and its baselines; fraction of the measured peak."""
    k = res["kernel"]
    n = [r["particles"] for r in k]
    fig = Figure(figsize=(11, 4.2))
    ax = fig.subplots(1, 2)
    for key, label, style in (
        ("us_pa", "Taylor kernel, P and tangent", "o-"),
        ("us_p", "Taylor kernel, P only", "s-"),
        ("us_loop", "straightforward Numba loop (P and A)", "^--"),
        ("us_numpy", "NumPy, vectorised over contacts (P and A)", "v:"),
    ):
        ax[0].loglog(n, [r[key] for r in k], style, label=label)
    ax[0].set_xlabel("particles per RVE")
    ax[0].set_ylabel("µs per quadrature point")
    ax[0].set_title("RVE kernel, one core")
    ax[1].semilogx(n, [100 * r["peak_frac_pa"] for r in k], "o-", label="P and tangent")
    ax[1].semilogx(n, [100 * r["peak_frac_p"] for r in k], "s-", label="P only")
    ax[1].set_xlabel("particles per RVE")
    ax[1].set_ylabel(f"% of measured peak ({res['peak']['gflops_per_core']:.1f} GFLOP/s per core)")
    ax[1].set_title("fraction of the FMA peak")
    ax[1].set_ylim(bottom=0)
    for a in ax:
        a.legend(fontsize=8)
        a.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    return fig


def iteration_figure(res):
    """Stacked bars: CPU ms per Newton iteration by category, per model level."""
    it = res["iteration"]
    order = list(it)  # report_studies.ITERATION_LEVELS: the order of the runs
    cats = [
        ("F", "F evaluation"),
        ("kernel", "RVE kernel"),
        ("assembly", "assembly"),
        ("linear_solve", "linear solve (LU)"),
        ("rest", "rest (Python, PETSc driver)"),
    ]
    colors = ["#4c72b0", "#dd8452", "#55a868", "#c44e52", "#8172b3"]
    fig = Figure(figsize=(10, 3.6))
    ax = fig.subplots()
    for i, lv in enumerate(order):
        left = 0.0
        for (c, label), col in zip(cats, colors):
            w = max(it[lv]["best"][c], 0.0)
            ax.barh(i, w, left=left, color=col, label=label if i == 0 else None)
            left += w
        ax.text(
            left, i, f" {left:.2f} ms ({it[lv]['run']['iterations']} it.)", va="center", fontsize=8
        )
    ax.set_yticks(range(len(order)))
    ax.set_yticklabels([LEVEL_NAMES[lv] for lv in order], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("CPU ms per Newton iteration (best of repeats)")
    run = it["taylor"]["run"]
    ax.set_title(
        f"slope, {res['config']['particles']} particles, {run['cells']} cells, "
        f"{run['points']} RVEs, 1 rank"
    )
    ax.set_xlim(0, 1.25 * max(sum(max(it[lv]["best"][c], 0) for c, _ in cats) for lv in order))
    ax.legend(fontsize=7, loc="lower right", ncol=2)
    fig.tight_layout()
    return fig


def _ranks_panel(ax, res):
    rk = res["ranks"]
    ax.set_title(f"1 vs 2 MPI ranks, {res['config']['particles']} particles")
    if not ranks_ok(res):
        ax.text(0.5, 0.5, "MPI runs failed (see report)", ha="center", transform=ax.transAxes)
        return
    s = rank_speedups(rk)
    bars = [
        ("RVE kernel\nin run, wall", s["kernel"]),
        ("RVE kernel\nin run, CPU", s["kernel_cpu"]),
        ("RVE work\nalone, wall", s["rve_bench"]),
        ("Newton\nwall", s["newton"]),
        ("Newton\nCPU", s["newton_cpu"]),
        ("whole run\nwall", s["wall"]),
    ]
    x = np.arange(len(bars))
    values = [v for _, v in bars]
    ax.bar(x, values, 0.6, color=["#dd8452"] * 3 + ["#4c72b0"] * 3)
    for xi, v in zip(x, values):
        ax.text(xi, v, f"{v:.2f}x", ha="center", va="bottom", fontsize=8)
    ax.axhline(2.0, color="gray", ls=":", lw=1, label="ideal (2 cores)")
    ax.axhline(1.8, color="#c44e52", ls="--", lw=1, label="target for the RVE work")
    ax.axhline(1.0, color="black", lw=0.8)
    ax.set_xticks(x)
    ax.set_xticklabels([name for name, _ in bars], fontsize=8)
    ax.set_ylabel("speed-up, 1 rank / 2 ranks (max over ranks)")
    ax.set_ylim(0, max(2.6, max(v for v in values if np.isfinite(v)) * 1.3))
    ax.legend(fontsize=8, loc="upper right", ncol=2)


def _refinement_panel(ax, res):
    ref = res["refinement"]
    q = np.array([r["points"] for r in ref], dtype=float)
    t = np.array([per_iteration(r)["newton"] for r in ref])
    ax.loglog(q, t, "o-", label="whole iteration")
    ax.loglog(q, [per_iteration(r)["kernel"] for r in ref], "s-", label="RVE kernel")
    ax.loglog(q, [per_iteration(r)["linear_solve"] for r in ref], "^-", label="linear solve (LU)")
    ax.loglog(q, t[-1] * q / q[-1], "k:", label="linear through the finest")
    for qi, ti, r in zip(q, t, ref):
        ax.annotate(
            f"{r['cells']} cells", (qi, ti), textcoords="offset points", xytext=(4, -12), fontsize=8
        )
    ax.set_xlabel("quadrature points (RVEs)")
    ax.set_ylabel("CPU ms per Newton iteration")
    ax.set_title("mesh refinement, 1 rank")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)


def scaling_figure(res):
    """Speed-ups on 2 MPI ranks; time per iteration against mesh size."""
    fig = Figure(figsize=(11, 4.2))
    ax = fig.subplots(1, 2)
    _ranks_panel(ax[0], res)
    _refinement_panel(ax[1], res)
    fig.tight_layout()
    return fig


_MARKERS = {
    "small_strain": "s",
    "ufl_linear": "D",
    "taylor_skip": "P",
    "adaptive": "X",
    "adaptive_strain": "*",
}


def _error_panel(a, rows, q, title):
    tay = [r for r in rows if r["level"] == "taylor"]
    ref_row, tay = tay[-1], tay[:-1]  # the reference has zero error by definition
    x = [r["wall"][0] for r in tay]
    y = [r[q + "_rms"] * 100 for r in tay]
    a.plot(x, y, "o-", color="#4c72b0", label="Taylor RVE: rms error of one run (over seeds)")
    a.plot(
        x,
        [max(r[q + "_err"], 1e-6) * 100 for r in tay],
        "o--",
        mfc="none",
        color="#4c72b0",
        label="Taylor RVE: error of the seed mean",
    )
    for r, xi, yi in zip(tay, x, y):
        a.annotate(
            f"{r['particles']}", (xi, yi), textcoords="offset points", xytext=(5, 4), fontsize=8
        )
    a.axhline(
        100 * ref_row[q + "_rms"],
        color="gray",
        ls="--",
        lw=1,
        label=f"rms scatter of the {ref_row['particles']}-particle runs about their mean",
    )
    a.axvline(
        ref_row["wall"][0],
        color="gray",
        ls=":",
        lw=1,
        label=f"wall time of a {ref_row['particles']}-particle run",
    )
    for r in rows:
        if r["level"] == "taylor" or r["converged"] == 0:
            continue
        a.plot(
            r["wall"][0],
            r[q + "_rms"] * 100,
            _MARKERS.get(r["level"], "o"),
            ms=8,
            alpha=0.8,
            label=f"{level_label(r['level'], r['tol'])} ({r['particles']}): rms error of one run",
        )
    a.set_xscale("log")
    a.set_yscale("log")
    for axis in (a.xaxis, a.yaxis):
        axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(FormatStrFormatter("%g"))
        axis.set_minor_formatter(NullFormatter())
    a.set_xlabel("wall time of one slope run (s)")
    a.set_ylabel(f"error vs. mean of the {ref_row['particles']}-particle RVEs (%)")
    a.set_title(title)
    a.grid(True, which="both", alpha=0.3)


def speed_error_figure(res):
    """Error of settlement and max von Mises against the wall time of a run."""
    rows, _ = speed_error_table(res)
    fig = Figure(figsize=(12, 6.6))
    ax = fig.subplots(1, 2)
    _error_panel(ax[0], rows, "settlement", "footing settlement")
    _error_panel(ax[1], rows, "max_von_mises", "max von Mises stress")
    handles, labels = ax[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=8, loc="lower center", ncol=2, frameon=False)
    fig.tight_layout(rect=(0, 0.2, 1, 1))
    return fig
