# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Frictional Taylor RVE under confined simple shear
#
# One material point (a `FrictionalRVE`, model in `shared/notes/friction-taylor.md`) is sheared
# in plane strain, F = [[1, γ], [0, 1 + e22]], while e22 is solved at every step so that the
# vertical Cauchy stress stays at the confining pressure, σ22 = −p (a shear box with rigid side
# walls: F11 = 1). Three results, as figures and CSV: hysteresis loops of cyclic shear for
# μ = 0, 0.3, 0.5; the mobilised stress ratio q/p in monotonic shear for μ = 0 ... 10 (does it
# saturate?); the dissipated energy per cycle against the area of the loop.

# %%
"""Frictional Taylor RVE under confined simple shear: hysteresis, mobilised q/p, dissipation.

    python demos/friction_study.py [--out results/friction_study] [--small] [--no-cache] [--force]

``--small`` (or ``DEMO_SMALL=1``) is the reduced run of the tests, written to
``results/friction_study-small`` by default; under ``mpirun`` rank 0 runs the (serial) study
and the other ranks exit. An ``--out`` that holds the study's tables or figures is refused (exit
status 2) unless ``--force``, which replaces those files and no others (the packing cache stays).

* packing: ``generate_packing(n, seed)`` through
  :class:`~dolfinx_granular.packings.cache.PackingCache`
  (350 particles, seeds 0-4 for monotonic shear, seed 0 for the cycles; ``--small``: 70, seed 0);
* contacts: k_n = 2.8e7 N/m² (table 1 of the paper), k_t = k_n (a common DEM choice), Coulomb μ;
* every test starts from F = I, is compressed to σ22 = −p (p = 100 kPa, in 10 pressure steps at
  γ = 0, F11 = 1) and is then sheared under σ22 = −p with F11 = 1 (:func:`confined_shear_step`);
* cyclic shear γ: 0 → +2 % → −2 % → +2 % ... (3 cycles, ``--small`` 2; cycle c runs from +2 %
  to +2 %) for μ = 0, 0.3, 0.5 on seed 0; monotonic shear to γ = 10 % for
  μ = 0, 0.1, 0.3, 0.5, 1, 2, 5, 10 on every seed.

Stress ratios (2-D, compression positive): p_m = −(σ11 + σ22)/2 and
q = √(((σ11 − σ22)/2)² + σ12²), so q/p_m = sin φ_mobilised (the radius of Mohr's circle over its
centre; q/p_m = 1: a principal stress is zero, q/p_m > 1: one is tensile), and
τ/p = σ12/(−σ22) = σ12/p on the horizontal plane of the box.

Writes to ``--out``: ``friction_cycles.csv`` (every step of the cycles), ``friction_monotonic.csv``
(every step of monotonic shear), ``friction_summary.csv`` (one row per μ: mean and std over the
seeds of q/p at γ = 0, its peak (and γ there) and final value, peak and final τ/p, K0, final e22
and dissipation; dissipation, loop area and their relative difference per cycle) and the figures
``friction_hysteresis.png``, ``friction_qp_gamma.png`` (every μ), ``friction_qp_mu.png``,
``friction_dissipation.png``. Packings are cached in ``OUT/packings``.
"""

from __future__ import annotations

import csv
import os
import sys
import time
from dataclasses import dataclass

from dolfinx_granular.drivers.material_point import ControlError, solve_point
from dolfinx_granular.io.commandline import Parser, world_comm
from dolfinx_granular.io.outfolder import claim_or_refuse, claim_out
from dolfinx_granular.io.shear_figures import (
    dissipation_figure,
    hysteresis_figure,
    qp_gamma_figure,
    qp_mu_figure,
    save_figure,
    stress_ratios,
)
from dolfinx_granular.laws.friction import FrictionalRVE, FrictionState
from dolfinx_granular.packings.cache import PackingCache

import numpy as np

K_N = 2.8e7  # normal contact stiffness, N/m² (table 1 of the paper)
K_T = K_N  # tangential stiffness k_t = k_n (a common DEM choice), N/m²
PRESSURE = 1e5  # confining pressure p, Pa
RAMP_STEPS = 10  # pressure steps of the initial compression at gamma = 0
AMPLITUDE = 0.02  # shear strain amplitude of the cycles
MAX_SHEAR = 0.10  # final shear strain of monotonic shear
MU_CYCLIC = (0.0, 0.3, 0.5)
MU_MONOTONIC = (0.0, 0.1, 0.3, 0.5, 1.0, 2.0, 5.0, 10.0)  # large mu: does q/p saturate?
RTOL = 1e-10  # the driver's tolerance: |sigma_22 + p| <= RTOL p
# |loop area - dissipation| / dissipation of a cycle is a first-order discretisation error of the
# trapezoidal work sum: measured 0.07 / m (mu = 0.3) and 0.2 / m (mu = 0.5) for m = 10 ... 80
# steps per quarter cycle; the stated tolerance is LOOP_RTOL_STEPS / m.
LOOP_RTOL_STEPS = 0.5
DPI = 110

FULL = dict(particles=350, seeds=(0, 1, 2, 3, 4), quarter_steps=40, cycles=3, monotonic_steps=200)
SMALL = dict(particles=70, seeds=(0,), quarter_steps=20, cycles=2, monotonic_steps=50)
#: the files it writes in --out (what --force replaces; the packing cache is kept)
FILES = ("friction_cycles.csv", "friction_monotonic.csv", "friction_summary.csv",
         "friction_hysteresis.png", "friction_qp_gamma.png", "friction_qp_mu.png",
         "friction_dissipation.png")  # fmt: skip


# %% [markdown]
# ## The mixed-control driver
#
# F11 = 1, F12 = γ and F21 = 0 are prescribed, F22 = 1 + e22 is unknown and σ22 = −p is the
# equation: the package's material-point driver (`dolfinx_granular.solve_point`) with
# `stress={(1, 1): -p}`. Newton on the scalar e22 uses the consistent tangent dσ22/dF22
# (chain rule of σ = P Fᵀ / J with A = dP/dF); a bracket on e22 and bisection catch the rare
# iterate that leaves it (stick/slip switches make σ22(e22) only piecewise smooth). Every iterate
# starts from the committed state; the caller commits the returned state only after convergence.


# %%
class ConfinementError(ControlError):
    """The mixed-control iteration did not reach |sigma_22 + p| <= rtol p."""


@dataclass(frozen=True)
class ShearStep:
    """A converged confined-shear step; commit ``state`` to go on.

    Attributes:
        F: (2, 2) deformation gradient [[1, gamma], [0, 1 + e22]].
        W: stored energy density (Pa).  P: (2, 2) first Piola stress (Pa).
        sigma: (2, 2) Cauchy stress (Pa), sigma[1, 1] = -p to the tolerance.
        state: the FrictionState after the step (from the committed state to F).
        iterations: Newton iterations (0: the guess was converged).
        residuals: sigma_22 + p (Pa) at every iterate.
    """

    F: np.ndarray
    W: float
    P: np.ndarray
    sigma: np.ndarray
    state: FrictionState
    iterations: int
    residuals: tuple

    @property
    def e22(self) -> float:
        return float(self.F[1, 1] - 1.0)


def shear_F(gamma, e22):
    """Plane strain simple shear with vertical stretch: [[1, gamma], [0, 1 + e22]] (2, 2)."""
    return np.array([[1.0, gamma], [0.0, 1.0 + e22]])


def confined_shear_step(
    rve, gamma, state, pressure, F_guess=None, rtol=RTOL, max_iter=50, max_increment=0.02
):
    """Solve e22 so that sigma_22 = -pressure at shear gamma, from the committed ``state``.

    Control: F11 = 1, F12 = gamma, F21 = 0 fixed (a shear box with rigid side walls: sigma_11
    follows from the material), F22 = 1 + e22 free with sigma_22 = -pressure. Newton on e22 with
    d sigma_22 / d F_22 from the consistent tangent, steps capped at ``max_increment``, bisection
    when an iterate leaves the bracket of the root found so far.

    Args:
        rve: a FrictionalRVE (any object with its ``evaluate``).
        gamma: shear F12.  state: committed 1-point FrictionState (never modified).
        pressure: p > 0 in Pa.  F_guess: (2, 2), its F22 starts the iteration (default 1).
        rtol: converged when |sigma_22 + p| <= rtol p.  max_iter: Newton iterations allowed.

    Returns:
        :class:`ShearStep`. Raises :class:`ConfinementError` (with the residual history) when
        not converged; nothing is committed then.
    """
    if not pressure > 0.0:
        raise ValueError(f"pressure must be > 0 Pa, got {pressure!r}")
    F22 = 1.0 if F_guess is None else float(F_guess[1][1])  # the guess of the unknown F22
    try:
        r = solve_point(
            rve,
            np.array([[1.0, gamma], [0.0, F22]]),
            {(1, 1): -pressure},
            state,
            rtol=rtol,
            max_iter=max_iter,
            max_increment=max_increment,
        )
    except ControlError as err:
        raise ConfinementError(f"confined shear step gamma = {gamma:.6g}: {err}") from None
    return ShearStep(r.F, r.W, r.P, r.sigma, r.state, r.iterations, r.residuals)


# %% [markdown]
# ## Load paths
#
# Every test is compressed to σ22 = −p at γ = 0 in pressure steps, then follows a γ path. The
# cycles use an integer grid, so that a branch and its reverse visit bitwise the same γ.


# %%
@dataclass
class LoadPath:
    """Committed history of one load path (one entry per converged step, k = 0 ... steps).

    Attributes: gamma, e22 (k,); F, P, sigma (k, 2, 2) in Pa; W, D (k,) stored energy and
    cumulative dissipation in Pa; iterations (k,) Newton iterations; active, sliding (k,) contacts
    with overlap > 0 and those at the Coulomb limit in the step (mu = 0: every active contact).
    """

    gamma: np.ndarray
    e22: np.ndarray
    F: np.ndarray
    P: np.ndarray
    sigma: np.ndarray
    W: np.ndarray
    D: np.ndarray
    iterations: np.ndarray
    active: np.ndarray
    sliding: np.ndarray


def confine(rve, pressure=PRESSURE, ramp_steps=RAMP_STEPS):
    """Compress the virgin RVE (F = I) to sigma_22 = -pressure at gamma = 0, F11 = 1, in
    ``ramp_steps`` equal pressure steps. Returns ``(last ShearStep, the committed state before
    it)``; the step's own state is the confined one."""
    state, F = rve.initial_state(1), np.eye(2)
    for p in np.linspace(0.0, pressure, ramp_steps + 1)[1:]:
        before, step = state, confined_shear_step(rve, 0.0, state, p, F)
        state, F = step.state, step.F  # commit: converged
    return step, before


def shear_path(rve, gammas, start, pressure=PRESSURE):
    """Shear along ``gammas`` (k,) under sigma_22 = -pressure. ``start = (step, before)``: the
    converged step the path begins with (entry 0; ``gammas[0]`` is its gamma) and the committed
    state before it, as :func:`confine` returns. Returns ``(LoadPath, final committed state)``."""
    first, before = start
    steps, counts = [first], [_contact_counts(rve, first.F, before)]
    state = first.state
    for g in gammas[1:]:
        step = confined_shear_step(rve, g, state, pressure, steps[-1].F)
        counts.append(_contact_counts(rve, step.F, state))
        state = step.state  # commit only now: the step converged
        steps.append(step)
    active, sliding = np.array(counts).T
    return LoadPath(
        gamma=np.array([s.F[0, 1] for s in steps]),
        e22=np.array([s.e22 for s in steps]),
        F=np.array([s.F for s in steps]),
        P=np.array([s.P for s in steps]),
        sigma=np.array([s.sigma for s in steps]),
        W=np.array([s.W for s in steps]),
        D=np.array([s.state.dissipation[0] for s in steps]),
        iterations=np.array([s.iterations for s in steps]),
        active=active,
        sliding=sliding,
    ), state


def _contact_counts(rve, F, committed):
    """(active, sliding) contacts of the step from the ``committed`` state to F."""
    c = rve.contacts(F, committed)
    return int(np.count_nonzero(c.overlap > 0.0)), int(np.count_nonzero(c.sliding))


def cyclic_gammas(amplitude, cycles, quarter_steps):
    """gamma of 0 -> +a -> -a -> +a ... (``cycles`` full cycles after the first quarter) and the
    cycle of each point: 0 for the first quarter, c = 1 ... for the points of cycle c (which runs
    from index m + 4 m (c - 1) to m + 4 m c, m = quarter_steps). Returns (gamma, cycle), (k,)."""
    m = quarter_steps
    ticks = list(range(m + 1))
    for _ in range(cycles):
        ticks += list(range(m - 1, -m - 1, -1)) + list(range(-m + 1, m + 1))
    idx = np.arange(len(ticks))
    cycle = np.where(idx <= m, 0, (idx - m + 4 * m - 1) // (4 * m))
    return amplitude * np.array(ticks, dtype=float) / m, cycle


# %% [markdown]
# ## Measures: stress ratios and the energy of a cycle
#
# The work of a cycle is the trapezoidal sum of P : ΔF over its steps; work minus the change of
# stored energy W is the area of the loop, which must equal the increase of the dissipation
# (`state.dissipation`) up to the discretisation error of the sum.


# %%
def work_increments(F, P):
    """Trapezoidal work per step, 0.5 (P_k + P_k+1) : (F_k+1 - F_k), (k - 1,) in Pa."""
    return np.einsum("kab,kab->k", 0.5 * (P[1:] + P[:-1]), F[1:] - F[:-1])


def cycle_energy(path, quarter_steps, cycles):
    """Per cycle (list of dicts): dissipation (increase of D), work, change of W, loop area =
    work - change of W (all Pa), their relative difference (NaN without dissipation) and the
    drift of e22 over the cycle."""
    m, dw, rows = quarter_steps, work_increments(path.F, path.P), []
    for c in range(1, cycles + 1):
        a, b = m + 4 * m * (c - 1), m + 4 * m * c
        dissipation, work, stored = path.D[b] - path.D[a], dw[a:b].sum(), path.W[b] - path.W[a]
        area = work - stored
        rows.append(
            dict(
                cycle=c,
                dissipation_Pa=dissipation,
                work_Pa=work,
                stored_change_Pa=stored,
                loop_area_Pa=area,
                rel_difference=(area - dissipation) / dissipation
                if dissipation > 0
                else float("nan"),
                e22_drift=path.e22[b] - path.e22[a],
            )
        )
    return rows


def loop_rtol(quarter_steps):
    """Stated tolerance of |loop area - dissipation| / dissipation per cycle (first order)."""
    return LOOP_RTOL_STEPS / quarter_steps


# %% [markdown]
# ## The two tests
#
# Cyclic shear on one packing per μ; monotonic shear on every seed per μ.


# %%
def cyclic_test(packing, mu, quarter_steps, cycles, amplitude=AMPLITUDE, pressure=PRESSURE):
    """Confine, then cycle gamma; returns ``(LoadPath, cycle (k,), energy rows)``."""
    rve = FrictionalRVE(packing, normal_stiffness=K_N, tangential_stiffness=K_T, friction=mu)
    gammas, cycle = cyclic_gammas(amplitude, cycles, quarter_steps)
    path, _ = shear_path(rve, gammas, confine(rve, pressure), pressure)
    return path, cycle, cycle_energy(path, quarter_steps, cycles)


def monotonic_test(packing, mu, steps, max_shear=MAX_SHEAR, pressure=PRESSURE):
    """Confine, then shear monotonically to ``max_shear`` in ``steps`` steps; returns the
    LoadPath."""
    rve = FrictionalRVE(packing, normal_stiffness=K_N, tangential_stiffness=K_T, friction=mu)
    gammas = np.linspace(0.0, max_shear, steps + 1)
    return shear_path(rve, gammas, confine(rve, pressure), pressure)[0]


def monotonic_measures(path):
    """Scalars of one monotonic path: q/p at gamma = 0, peak (and its gamma) and final q/p, peak
    and final tau/p, K0 = sigma_11 / sigma_22 at gamma = 0, final e22 and dissipation (Pa)."""
    qp, tp = stress_ratios(path.sigma)
    k = int(np.argmax(qp))
    return dict(
        qp_start=qp[0],
        qp_peak=qp[k],
        gamma_peak=path.gamma[k],
        qp_final=qp[-1],
        taup_peak=tp.max(),
        taup_final=tp[-1],
        K0=path.sigma[0, 0, 0] / path.sigma[0, 1, 1],
        e22_final=path.e22[-1],
        dissipation_final_Pa=path.D[-1],
    )


# %% [markdown]
# ## Tables


# %%
def write_csv(path, header, rows):
    """Floats as their shortest round-trip repr: the tables reproduce the computed numbers."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(
            [
                [repr(float(v)) if isinstance(v, (float, np.floating)) else v for v in row]
                for row in rows
            ]
        )


STEP_COLUMNS = [
    "step",
    "gamma",
    "e22",
    "sigma11_Pa",
    "sigma12_Pa",
    "sigma22_Pa",
    "q_over_p",
    "tau_over_p",
    "W_Pa",
    "dissipation_Pa",
    "dissipation_step_Pa",
    "newton_iterations",
    "active_contacts",
    "sliding_contacts",
]


def step_rows(path):
    """One row per step in the order of STEP_COLUMNS."""
    qp, tp = stress_ratios(path.sigma)
    dD = np.diff(path.D, prepend=path.D[0])
    return [
        [
            k,
            path.gamma[k],
            path.e22[k],
            path.sigma[k, 0, 0],
            path.sigma[k, 0, 1],
            path.sigma[k, 1, 1],
            qp[k],
            tp[k],
            path.W[k],
            path.D[k],
            dD[k],
            int(path.iterations[k]),
            int(path.active[k]),
            int(path.sliding[k]),
        ]
        for k in range(path.gamma.size)
    ]


def summary_table(mono, energy, cycles):
    """Header and rows of friction_summary.csv: one row per mu (monotonic measures as mean and
    standard deviation over the seeds; cycle columns empty for mu without cycles)."""
    keys = [
        "qp_start",
        "qp_peak",
        "gamma_peak",
        "qp_final",
        "taup_peak",
        "taup_final",
        "K0",
        "e22_final",
        "dissipation_final_Pa",
    ]
    header = ["mu", "seeds"] + [f"{k}_{s}" for k in keys for s in ("mean", "std")]
    for c in range(1, cycles + 1):
        header += [f"dissipation_cycle{c}_Pa", f"loop_area_cycle{c}_Pa", f"rel_diff_cycle{c}"]
    rows = []
    for mu in sorted(set(mono) | set(energy)):
        m = [monotonic_measures(p) for p in mono.get(mu, [])]
        row = [mu, len(m)]
        for k in keys:
            v = np.array([x[k] for x in m])
            row += [v.mean(), v.std(ddof=1 if v.size > 1 else 0)] if v.size else ["", ""]
        for e in energy.get(mu, [{}] * cycles):
            row += [
                e.get("dissipation_Pa", ""),
                e.get("loop_area_Pa", ""),
                e.get("rel_difference", ""),
            ]
        rows.append(row)
    return header, rows


# %% [markdown]
# ## The study


# %%
def write_tables(out, cyc, mono, energy, seeds, cycles):
    """The three CSV files (``energy``: ``{mu: energy rows}`` of the cycles); returns the
    summary's header and rows."""
    write_csv(
        os.path.join(out, "friction_cycles.csv"),
        ["mu", "cycle"] + STEP_COLUMNS,
        [
            [mu, int(cycle[k])] + row
            for mu, (path, cycle, _) in cyc.items()
            for k, row in enumerate(step_rows(path))
        ],
    )
    write_csv(
        os.path.join(out, "friction_monotonic.csv"),
        ["mu", "seed"] + STEP_COLUMNS,
        [
            [mu, s] + row
            for mu, paths in mono.items()
            for s, path in zip(seeds, paths)
            for row in step_rows(path)
        ],
    )
    header, rows = summary_table(mono, energy, cycles)
    write_csv(os.path.join(out, "friction_summary.csv"), header, rows)
    return header, rows


def print_tables(say, header, rows, energy, rtol):
    """The summary and the energy of every cycle (``energy``: ``{mu: energy rows}``)."""
    col = {h: i for i, h in enumerate(header)}
    say(
        "\n  mu     K0   q/p(γ=0)  peak q/p (at γ)      final q/p     peak τ/p  final τ/p"
        "  e22 final"
    )
    for r in rows:
        if r[col["seeds"]]:
            v = {h: r[i] for h, i in col.items()}
            say(
                f"{v['mu']:4g}  {v['K0_mean']:5.3f}  {v['qp_start_mean']:8.3f}  "
                f"{v['qp_peak_mean']:6.3f}±{v['qp_peak_std']:.3f} "
                f"({100 * v['gamma_peak_mean']:4.1f} %)  "
                f"{v['qp_final_mean']:6.3f}±{v['qp_final_std']:.3f}  "
                f"{v['taup_peak_mean']:8.3f}  {v['taup_final_mean']:9.3f}  "
                f"{100 * v['e22_final_mean']:6.2f} %"
            )
    say(
        f"\n  mu  cycle  dissipation [Pa]  loop area [Pa]  (area - D)/D   e22 drift"
        f"   (tolerance {100 * rtol:.2f} %)"
    )
    for mu, cycle_rows in energy.items():
        for e in cycle_rows:
            say(
                f"{mu:4g}  {e['cycle']:5d}  {e['dissipation_Pa']:16.4f}  {e['loop_area_Pa']:14.4f}"
                f"  {e['rel_difference']:12.2e}  {e['e22_drift']:10.2e}"
            )


def run(out="results/friction_study", small=False, use_cache=True, verbose=True, force=False):
    """Run the study, write CSVs and figures to ``out``; returns a summary dict (runtime_s,
    config, loop_rtol, summary header and rows, per-cycle energy per mu). An ``out`` that holds
    a study raises ``RunExistsError`` first, unless ``force`` (which removes its files, no
    others; the packing cache stays)."""
    claim_out(out, FILES, force, "friction_study")
    t_start = time.perf_counter()
    cfg = SMALL if small else FULL
    say = print if verbose else (lambda *a, **k: None)
    cache = PackingCache(os.path.join(out, "packings"), use_cache)
    seeds, m, cycles = list(cfg["seeds"]), cfg["quarter_steps"], cfg["cycles"]
    packings = [cache.get(cfg["particles"], s) for s in seeds]
    say(f"{cfg['particles']} particles, seeds {seeds} ({time.perf_counter() - t_start:.1f} s)")
    cyc = {mu: cyclic_test(packings[0], mu, m, cycles) for mu in MU_CYCLIC}
    say(f"cyclic shear, μ = {MU_CYCLIC} ({time.perf_counter() - t_start:.1f} s)")
    mono = {
        mu: [monotonic_test(p, mu, cfg["monotonic_steps"]) for p in packings] for mu in MU_MONOTONIC
    }
    say(f"monotonic shear, μ = {MU_MONOTONIC} ({time.perf_counter() - t_start:.1f} s)")
    energy = {mu: e for mu, (_, _, e) in cyc.items()}
    header, rows = write_tables(out, cyc, mono, energy, seeds, cycles)
    figures = {
        "hysteresis": hysteresis_figure(cyc, PRESSURE),
        "qp_gamma": qp_gamma_figure(mono, seeds),
        "qp_mu": qp_mu_figure(header, rows, MAX_SHEAR),
        "dissipation": dissipation_figure(energy, m),
    }
    for name, fig in figures.items():
        save_figure(fig, os.path.join(out, f"friction_{name}.png"), DPI)
    print_tables(say, header, rows, energy, loop_rtol(m))
    runtime = time.perf_counter() - t_start
    say(f"\nwrote {out}/ in {runtime:.1f} s")
    return dict(
        runtime_s=runtime,
        config=dict(cfg),
        loop_rtol=loop_rtol(m),
        header=header,
        rows=rows,
        energy=energy,
    )


def parse_args(argv=None):
    """The options; ``out`` resolved (``results/friction_study[-small]``)."""
    parser = Parser(description=__doc__.split("\n")[0])
    parser.add_output("friction_study")
    parser.add_argument("--no-cache", action="store_true", help="regenerate the packings")
    return parser.parse_args(argv)


def main(argv=None):
    args = parse_args(argv)
    comm = world_comm()
    # every rank takes rank 0's answer (exit status 2 alike) before any work
    if claim_or_refuse(args.out, FILES, args.force, "friction_study", comm):
        return 2
    if comm is None or comm.rank == 0:  # a serial study: rank 0 runs it, the others rest
        run(args.out, small=args.small, use_cache=not args.no_cache, force=args.force)
    return 0


# %% [markdown]
# Run as a script; in a notebook call `run("results/friction_study")` instead of this cell
# (`force=True` replaces an earlier study there).

# %%
if __name__ == "__main__":
    sys.exit(main())
