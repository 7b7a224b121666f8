"""The strength curve (:mod:`~dolfinx_granular.drivers.strength`) as a CSV file and a printed
table.

:func:`write_curve` writes :data:`~dolfinx_granular.drivers.strength.COLUMNS` (floats as their
shortest round-trip repr, NaN as an empty cell) atomically; :func:`read_curve` reads it back
with numbers as numbers, for :func:`~dolfinx_granular.drivers.strength.friction_angle`;
:func:`merge_curves` makes one curve of several (more seeds at some frictions);
:func:`curve_lines` is the table the ``strength`` command prints.
"""

from __future__ import annotations

import csv
import io
import math
from typing import TYPE_CHECKING

from ..drivers.strength import COLUMNS, falls, on_line
from .runwriter import atomic_write

if TYPE_CHECKING:
    from os import PathLike

#: the columns read back as text (the others are numbers)
TEXT = ("law", "stop_reasons")
#: columns a curve written by an older version may lack, with their value there
OPTIONAL = {"mu_r": 0.0}
#: the columns that name a row: a later curve's row with the same values replaces it
ROW_KEY = ("law", "mu", "mu_r", "p_over_kn")
#: what a replacing row must share with the row it replaces (the same material, measured again)
SAME_MATERIAL = ("particles", "k_n", "k_t")


def _cell(v):
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    return v


def write_curve(path: str | PathLike[str], curve: list[dict]) -> None:
    """Write the rows of ``curve`` (:data:`COLUMNS`, in that order) to the CSV ``path``,
    replacing it atomically."""
    text = io.StringIO(newline="")
    w = csv.DictWriter(text, fieldnames=COLUMNS, lineterminator="\n")
    w.writeheader()
    w.writerows({k: _cell(r[k]) for k in COLUMNS} for r in curve)
    atomic_write(path, text.getvalue())


def read_curve(path: str | PathLike[str]) -> list[dict]:
    """The rows of a curve's CSV: text columns as text, whole numbers as int, others float
    (an empty cell as NaN)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    missing = sorted(set(COLUMNS) - set(rows[0] if rows else COLUMNS) - set(OPTIONAL))
    if missing:
        raise ValueError(f"{path} is no strength curve (no column {', '.join(missing)}): give "
                         "the CSV that 'python -m dolfinx_granular strength' wrote")  # fmt: skip
    for r in rows:
        for k, v in OPTIONAL.items():
            r.setdefault(k, repr(v))
        for k in COLUMNS:
            if k not in TEXT:
                v = r[k]
                r[k] = math.nan if v == "" else (int(v) if v.lstrip("-").isdigit() else float(v))
    return rows


def merge_curves(curves: list[list[dict]]) -> list[dict]:
    """One curve from several (each :func:`read_curve`'s rows, in order): a row of a later curve
    replaces the one of an earlier curve with the same law, mu, mu_r and p / k_n, in its place
    (e.g. those frictions measured again with more seeds); the other rows are kept. ValueError
    where the two rows were measured with other particles, k_n or k_t."""
    merged: dict[tuple, dict] = {}
    for rows in curves:
        for r in rows:
            key = tuple(r[k] for k in ROW_KEY)
            old = merged.get(key)
            other = [k for k in SAME_MATERIAL if old is not None and old[k] != r[k]]
            if other:
                raise ValueError(
                    f"the rows at law {r['law']}, mu {r['mu']:g}, mu_r {r['mu_r']:g}, p/kn "
                    f"{r['p_over_kn']:g} differ in {', '.join(other)} "
                    f"({', '.join(f'{old[k]:g} and {r[k]:g}' for k in other)}): merge curves "
                    "measured with the same particles and stiffnesses"
                )
            merged[key] = r
    return list(merged.values())


def curve_lines(curve: list[dict]) -> list[str]:
    """The printed table: per (law, mu, mu_r, p / k_n) sin phi, phi and tan phi at the peak
    and the critical state (mean ± std over the seeds), the strain reached and the tests
    stopped."""
    lines = [
        "strength: mean ± std over the seeds; peak: the largest q/p = sin phi of a test; cs: the "
        "mean over the last quarter of the strain it reached",
        "  law      mu     mu_r    p/kn    sin phi_p     sin phi_cs    phi_p [deg]  phi_cs [deg]  "
        "tan phi_p  tan phi_cs  eps1 reached (min)  stopped",
    ]
    for r in curve:
        lines.append(
            f"  {r['law']:7s} {r['mu']:5g}  {r['mu_r']:6g}  {r['p_over_kn']:7.1e}  "
            f"{r['sin_phi_peak_mean']:.3f}±{r['sin_phi_peak_std']:.3f}  "
            f"{r['sin_phi_cs_mean']:.3f}±{r['sin_phi_cs_std']:.3f}  "
            f"{r['phi_peak_deg_mean']:5.1f}±{r['phi_peak_deg_std']:4.1f}   "
            f"{r['phi_cs_deg_mean']:5.1f}±{r['phi_cs_deg_std']:4.1f}   "
            f"{r['tan_phi_peak_mean']:9.3f}  {r['tan_phi_cs_mean']:10.3f}  "
            f"{100 * r['eps1_reached_mean']:6.2f} % ({100 * r['eps1_reached_min']:5.2f} %)  "
            f"{r['stopped']} of {r['seeds']}"
        )
    lines += [f"  stopped: {r['law']} mu {r['mu']:g} mu_r {r['mu_r']:g} p/kn {r['p_over_kn']:g}: "
              f"{r['stop_reasons'][:300]}" for r in curve if r["stopped"]]  # fmt: skip
    return lines + falling_lines(curve)


def falling_lines(curve: list[dict]) -> list[str]:
    """A line per pair of neighbours in mu on one line of the curve (law, p / k_n, mu_r / mu)
    whose mean phi falls as mu grows: the seeds' scatter, which the factor of safety's reading
    pools (:func:`~dolfinx_granular.drivers.strength.nondecreasing`)."""
    lines = []
    for law, p in dict.fromkeys((r["law"], r["p_over_kn"]) for r in curve):
        here = [r for r in curve if r["law"] == law and r["p_over_kn"] == p]
        ratios = []  # (mu_r / mu of each line once: 0.2 x 0.3 / 0.3 is not 0.2 in floating point)
        for r in here:
            if r["mu"] > 0 and not any(on_line(r, q) for q in ratios):
                ratios.append(r["mu_r"] / r["mu"])
        for ratio in ratios or [0.0]:
            for which in ("peak", "cs"):
                for mu_a, mu_b, a, b in falls([r for r in here if on_line(r, ratio)], which):
                    lines.append(
                        f"  falls: {law} p/kn {p:g} mu_r/mu {ratio:g}: phi_{which} {a:.1f} deg "
                        f"at mu {mu_a:g} > {b:.1f} deg at mu {mu_b:g} (the seeds' scatter: more "
                        "seeds narrow it; the factor of safety reads the curve's non-decreasing "
                        "fit)"
                    )
    return lines
