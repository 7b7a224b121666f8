"""Figures of confined simple shear at one material point (demos/friction_study.py).

The inputs are the study's records: a load path has ``gamma`` (k,), ``e22`` (k,) and ``sigma``
(k, 2, 2) Cauchy stresses in Pa; energy rows are dicts with ``dissipation_Pa``, ``loop_area_Pa``
and ``rel_difference`` per cycle. Stress ratios (2-D, compression positive): p_m = -(s11 + s22)/2,
q = sqrt(((s11 - s22)/2)^2 + s12^2), so q/p_m = sin(phi mobilised), and tau/p = s12 / (-s22).
"""

from __future__ import annotations

import numpy as np
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure


def stress_ratios(sigma):
    """``(q/p_m, tau/p)`` (k,) of Cauchy stresses (k, 2, 2): 2-D mean stress p_m, Mohr radius q
    (compression positive) and sigma_12 / (-sigma_22)."""
    s11, s22, s12 = sigma[:, 0, 0], sigma[:, 1, 1], sigma[:, 0, 1]
    p_m = -0.5 * (s11 + s22)
    q = np.hypot(0.5 * (s11 - s22), s12)
    return q / p_m, s12 / -s22


def _colors(n):
    """n distinct colours, in order along a colormap: a fixed palette would run out (and zip
    would drop the curves past its end)."""
    return colormaps["viridis"](np.linspace(0.0, 0.9, n))


def save_figure(fig, path, dpi=110):
    """Write ``fig`` to ``path`` through the Agg canvas: no GUI backend, no pyplot state."""
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=dpi)


def hysteresis_figure(cyc, pressure):
    """tau = sigma_12 (top) and e22 (bottom) against gamma, one column per mu, one colour per
    cycle. ``cyc``: ``{mu: (LoadPath, cycle (k,), energy rows)}``."""
    mus = list(cyc)
    fig = Figure(figsize=(4.0 * len(mus), 6.6))
    for j, mu in enumerate(mus):
        path, cycle, energy = cyc[mu]
        top = fig.add_subplot(2, len(mus), j + 1)
        bot = fig.add_subplot(2, len(mus), len(mus) + j + 1, sharex=top)
        colors = _colors(int(cycle.max()))
        for c in range(int(cycle.max()) + 1):
            idx = np.flatnonzero(cycle == c)
            idx = np.r_[idx[0] - 1, idx] if c > 0 else idx  # join to the previous cycle's end
            style = dict(color="0.55", ls="--") if c == 0 else dict(color=colors[c - 1])
            label = "first loading" if c == 0 else f"cycle {c}"
            top.plot(
                100 * path.gamma[idx], path.sigma[idx, 0, 1] / 1e3, lw=1.1, label=label, **style
            )
            bot.plot(100 * path.gamma[idx], 100 * path.e22[idx], lw=1.1, **style)
        d = [e["dissipation_Pa"] for e in energy]
        top.set_title(
            f"μ = {mu:g}: dissipation per cycle {', '.join(f'{x:.0f}' for x in d)} Pa", fontsize=9
        )
        top.set_ylabel("τ = σ12 [kPa]")
        bot.set_ylabel("vertical strain e22 = F22 − 1 [%]")
        bot.set_xlabel("shear strain γ = F12 [%]")
        for ax in (top, bot):
            ax.grid(True, alpha=0.3)
        top.legend(fontsize=7)
    fig.suptitle(
        f"Cyclic confined simple shear (σ22 = −{pressure / 1e3:g} kPa, F11 = 1): "
        "hysteresis (top) and dilatancy (bottom)",
        fontsize=10,
    )
    fig.tight_layout()
    return fig


def qp_gamma_figure(mono, seeds):
    """q/p_m and tau/p against gamma, one colour per mu (every mu of ``mono``: ``{mu: [LoadPath
    per seed]}``); the first seed thick, the others thin."""
    fig = Figure(figsize=(10.4, 4.3))
    axes = [fig.add_subplot(1, 2, k + 1) for k in range(2)]
    for color, (mu, paths) in zip(_colors(len(mono)), mono.items()):
        for s, path in zip(seeds, paths):
            for ax, ratio in zip(axes, stress_ratios(path.sigma)):
                ax.plot(
                    100 * path.gamma,
                    ratio,
                    color=color,
                    lw=1.5 if s == seeds[0] else 0.6,
                    alpha=1.0 if s == seeds[0] else 0.6,
                    label=f"μ = {mu:g}" if s == seeds[0] else None,
                )
    axes[0].axhline(1.0, color="0.3", ls=":", lw=1, label="q/p = 1 (a principal stress is 0)")
    axes[0].set_ylabel("q / p_m = sin φ_mobilised")
    axes[1].set_ylabel("τ / p = σ12 / (−σ22)")
    for ax in axes:
        ax.set_xlabel("shear strain γ [%]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(
        f"Monotonic confined simple shear: mobilised stress ratio ({len(seeds)} "
        f"packings; thick: seed {seeds[0]})",
        fontsize=10,
    )
    fig.tight_layout()
    return fig


def qp_mu_figure(header, rows, max_shear):
    """Peak and final q/p_m (with q/p_m at gamma = 0) and tau/p against mu, mean ± std over the
    seeds, from the summary table."""
    col = {h: i for i, h in enumerate(header)}
    rows = [r for r in rows if r[col["seeds"]]]
    mu = np.array([r[0] for r in rows])

    def get(key):
        return np.array([r[col[key]] for r in rows], dtype=float)

    fig = Figure(figsize=(10.4, 4.2))
    for k, (name, label) in enumerate((("qp", "q / p_m"), ("taup", "τ / p"))):
        ax = fig.add_subplot(1, 2, k + 1)
        for what, marker, size in (("peak", "o-", 9), ("final", "s--", 4)):
            ax.errorbar(
                mu,
                get(f"{name}_{what}_mean"),
                yerr=get(f"{name}_{what}_std"),
                fmt=marker,
                ms=size,
                mfc="none" if what == "peak" else None,
                capsize=3,
                label=f"{what} (γ ≤ {100 * max_shear:g} %)",
            )
        if name == "qp":
            ax.plot(mu, get("qp_start_mean"), "^:", color="0.4", label="at γ = 0 (confined)")
            ax.axhline(1.0, color="0.3", ls=":", lw=1)
        else:
            ax.plot(mu, mu, ":", color="0.4", label="contact friction μ (reference)")
        ax.set_xlabel("contact friction coefficient μ")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(
        "Macroscopic stress ratio against contact friction (mean ± std over seeds)", fontsize=10
    )
    fig.tight_layout()
    return fig


def dissipation_figure(energy, quarter_steps):
    """Bars: dissipation per cycle per mu; crosses: the loop area of the same cycle."""
    fig = Figure(figsize=(6.4, 4.3))
    ax = fig.add_subplot()
    mus = list(energy)
    cycles = len(energy[mus[0]])
    width = 0.8 / cycles
    colors = _colors(cycles)
    for c in range(cycles):
        x = np.arange(len(mus)) + (c - (cycles - 1) / 2) * width
        d = [energy[mu][c]["dissipation_Pa"] for mu in mus]
        a = [energy[mu][c]["loop_area_Pa"] for mu in mus]
        ax.bar(x, d, width * 0.9, color=colors[c], label=f"cycle {c + 1}: Δ dissipation")
        ax.plot(x, a, "kx", ms=7, label="loop area ∮P:dF − ΔW" if c == 0 else None)
    ax.set_xticks(np.arange(len(mus)))
    ax.set_xticklabels([f"μ = {mu:g}" for mu in mus])
    ax.set_ylabel("energy per cycle [Pa = J/m³]")
    worst = np.nanmax(
        [
            abs(e["rel_difference"])
            for rows in energy.values()
            for e in rows
            if np.isfinite(e["rel_difference"])
        ]
        or [0.0]
    )
    ax.set_title(
        f"Dissipated energy per cycle ({quarter_steps} steps per quarter cycle; "
        f"|area − D| / D ≤ {100 * worst:.2f} %)",
        fontsize=9,
    )
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
