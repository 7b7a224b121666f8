"""The strength curve of a factor-of-safety run: measured with the slope's own RVE, or read.

A factor of safety needs phi at the user's mu and at every friction mu_f the strength reduction
tries (:mod:`.safety`). A user's curve (``python -m dolfinx_granular strength``'s CSV) is read
with phi linear in mu between its rows
(:func:`~dolfinx_granular.drivers.strength.friction_angle`; the search stays inside it).
Without one, :class:`Strength` measures phi at exactly mu and at each mu_f before its trial
(:func:`measured_rows`: the biaxial tests of
:func:`~dolfinx_granular.drivers.strength.strength_curve`, each cached, on the slope's own
packings: its particle count, seeds ``seed`` to ``seed + seeds - 1``, jammed at its p / k_n),
and the answer, between the bracket's ends, is interpolated between two measured rows.
Measuring only what the search asks for saves the tests at the frictions it never tries: one
test of 70 disks to 5 % took 90 s at mu = 0.008. With rolling resistance, mu_r = r mu, the
strength reduction divides both alike: phi is read (and measured) on the curve's line mu_r = r
mu.

Either curve is read on its non-decreasing fit in mu (:meth:`Strength.phi`): more friction
cannot weaken the material, but a few packings' means can fall from one mu to the next (by
2.6° from mu = 0.3 to 0.5 on three packings of 70 disks), and a curve that falls would give a
slope that stands a factor of safety below 1. A measured curve is fitted again as its rows
come in, so a trial's FS is read on the rows measured so far.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from ..drivers.strength import falls, friction_angle, on_line, strength_curve

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from os import PathLike

#: eps1 per step of a measured curve's biaxial tests (0.5 %)
STRAIN_STEP = 0.005


def measured_rows(
    mus: Sequence[float],
    particles: int,
    seeds: Sequence[int],
    p_over_kn: float,
    k_n: float,
    k_t: float,
    max_strain: float,
    cache: str | PathLike[str],
    say: Callable[[str], None] | None = None,
    rolling_ratio: float = 0.0,
) -> list[dict]:
    """The strength curve's rows of the relaxed frictional RVE at the frictions ``mus`` (each
    with the rolling friction ``rolling_ratio`` mu) and ``p_over_kn``: biaxial tests of
    ``particles`` disks per packing, the ``seeds``, eps1 to ``max_strain`` in steps of
    :data:`STRAIN_STEP`, contact stiffnesses ``k_n``, ``k_t`` (N/m²); the tests kept in
    ``cache``."""
    steps = max(1, round(max_strain / STRAIN_STEP))
    rows = []
    for mu in mus:
        rows += strength_curve(
            particles=particles,
            seeds=tuple(seeds),
            mus=(mu,),
            pressures=(p_over_kn,),
            max_strain=max_strain,
            steps=steps,
            k_n=k_n,
            k_t=k_t,
            law="relaxed",
            cache=cache,
            say=say,
            rolling=(rolling_ratio * mu,),
        )
    return rows


class Strength:
    """phi(mu) of a strength curve at one confining pressure, measured where asked.

    Args:
        curve: rows of :func:`~dolfinx_granular.drivers.strength.strength_curve` or of its CSV
            (those measured so far where ``measure`` is given; may be empty then).
        p_over_kn: the slope's confining pressure over k_n (a tabulated one).
        mu: the contacts' friction of the slope (within the curve).
        measure: ``measure(mus)`` -> the rows at those frictions (:func:`measured_rows`), or
            None: the curve is all there is.
        rolling_ratio: mu_r / mu of the slope's contacts: phi is read on the line mu_r =
            rolling_ratio mu of the curve (the strength reduction divides both alike).

    Raises:
        ValueError: naming the problem and the fix, where the curve cannot give phi at mu (mu
            outside it, another pressure, another law, no angle in (0, 90) degrees measured
            next to mu).

    Attributes:
        curve: the rows, measured ones added (sorted by mu).
        mu_range: the frictions the search may try: the whole line where phi is measured,
            else those around mu over which every tabulated angle lies in (0, 90) degrees (a
            test that stopped early elsewhere on the curve narrows it).
    """

    def __init__(
        self,
        curve: list[dict],
        p_over_kn: float,
        mu: float,
        measure: Callable[[list[float]], list[dict]] | None = None,
        rolling_ratio: float = 0.0,
    ) -> None:
        self.curve, self.p_over_kn, self.mu = list(curve), float(p_over_kn), float(mu)
        self.measure, self.rolling_ratio = measure, float(rolling_ratio)
        self.cover([self.mu])
        laws = sorted({r["law"] for r in self.curve})
        if laws != ["relaxed"]:
            raise ValueError(
                f"the strength curve holds the laws {', '.join(laws) or 'none'}: give a curve "
                "of the relaxed RVE alone (strength --law relaxed)"
            )
        for which in ("cs", "peak"):
            self.phi(mu, which)  # (raises where the curve cannot give it)
        self.mu_range = (0.0, math.inf) if measure is not None else self._range()

    def _range(self):
        """The frictions around mu over which every tabulated angle is in (0, 90) degrees."""
        mu = self.mu
        rows = sorted((r for r in self.curve if self._here(r)), key=lambda r: float(r["mu"]))
        mus, ok = [float(r["mu"]) for r in rows], [self._inside(r) for r in rows]
        lo = max(k for k, m in enumerate(mus) if m <= mu)
        hi = min(k for k, m in enumerate(mus) if m >= mu)
        if not (ok[lo] and ok[hi]):
            raise ValueError(
                f"the strength curve has no friction angle in (0, 90) degrees next to mu = "
                f"{mu:g} at p/k_n = {self.p_over_kn:g} (its tests stopped early: see "
                "stop_reasons): measure it again, or give another curve"
            )
        while lo > 0 and ok[lo - 1]:
            lo -= 1
        while hi < len(rows) - 1 and ok[hi + 1]:
            hi += 1
        return (mus[lo], mus[hi])

    def cover(self, mus: Sequence[float]) -> None:
        """Measure phi at the frictions ``mus`` that the curve lacks (nothing without
        ``measure``); ValueError where a measured angle is not in (0, 90) degrees."""
        tabulated = [float(r["mu"]) for r in self.curve if self._here(r)]
        missing = [m for m in mus if not any(math.isclose(m, t, rel_tol=1e-12) for t in tabulated)]
        if self.measure is None or not missing:
            return
        rows = self.measure(missing)
        for r in rows:
            if not self._inside(r):
                raise ValueError(
                    f"the strength tests at mu = {float(r['mu']):g} gave no friction angle in "
                    f"(0, 90) degrees ({r.get('stop_reasons') or 'no reason given'}): give a "
                    "strength curve with --strength, or other --strength-* settings"
                )
        self.curve = sorted(self.curve + list(rows), key=lambda r: float(r["mu"]))

    def _here(self, row) -> bool:
        here = math.isclose(float(row["p_over_kn"]), self.p_over_kn, rel_tol=1e-9)
        return here and on_line(row, self.rolling_ratio)

    @staticmethod
    def _inside(row) -> bool:
        angles = (float(row["phi_cs_deg_mean"]), float(row["phi_peak_deg_mean"]))
        return all(0.0 < a < 90.0 for a in angles)

    def phi(self, mu_f: float, which: str = "cs", monotone: bool = True) -> float:
        """phi (degrees) at ``mu_f``: critical state (``"cs"``) or ``"peak"``; on the curve's
        non-decreasing fit (``monotone``), else on its measured means."""
        return friction_angle(self.curve, mu_f, self.p_over_kn, which,
                              rolling_ratio=self.rolling_ratio, monotone=monotone)  # fmt: skip

    def falls(self, which: str = "cs") -> list[tuple[float, float, float, float]]:
        """Where the measured curve falls as mu grows, so that :meth:`phi` pools it: (mu,
        the next mu, phi at each) per such pair of rows, in degrees."""
        return falls([r for r in self.curve if self._here(r)], which)

    def factor_of_safety(self, mu_f: float, which: str = "cs") -> float:
        """tan phi(mu) / tan phi(mu_f)."""
        ratio = math.tan(math.radians(self.phi(self.mu, which)))
        return ratio / math.tan(math.radians(self.phi(mu_f, which)))
