"""Grain size distributions (sieve curves) and sampling of grain diameters from them.

A sieve curve gives the cumulative percentage P(d) of material passing a sieve of aperture d.
In 2-D we read "percent passing" as an **area** fraction: the class between two consecutive
apertures a_k < a_{k+1} carries the share dP_k of the grain area. Between sieve points P is
linear in log d (the usual semi-log plot of a grading curve), and the sampling follows exactly
that: inside a class the grain *area* is log-uniform, i.e. the number density is proportional to
d^-3. The class's number weight is then dP_k / <d²>_k with the number mean
<d²>_k = 2 ln(a_{k+1} / a_k) / (a_k^-2 - a_{k+1}^-2).

Fines below a cut size ``d_min`` are dropped (the grading is renormalised to 100 % above it):
the CEN curve spans 25:1 in size and an RVE resolving its fines would need tens of thousands of
disks.
"""

from __future__ import annotations

import csv
import decimal
import io
from importlib import resources
from typing import TYPE_CHECKING

import numpy as np

from . import portable
from .packing import check_dimension

if TYPE_CHECKING:
    from os import PathLike

    from numpy.typing import ArrayLike

#: Default cut size (mm) for the shipped CEN curve: keeps d_max / d_min = 4, so that 70 disks still
#: form a jammed network with few rattlers.
DEFAULT_D_MIN = 0.5


class SieveCurve:
    """A cumulative grain size distribution (grading curve).

    Args:
        aperture: (K,) sieve apertures in mm, > 0, strictly increasing.
        passing: (K,) cumulative percent passing, non-decreasing in [0, 100], 100 at the largest
            aperture (the coarsest grain is then at most that size).
        name: label for plots.
        source: where the data come from.

    Raises:
        ValueError: naming the problem (shape, non-positive or unsorted apertures, a curve that
            decreases, leaves [0, 100] or does not reach 100 %).
    """

    def __init__(
        self, aperture: ArrayLike, passing: ArrayLike, name: str = "sieve curve", source: str = ""
    ) -> None:
        a = _float_1d(aperture, "aperture")
        p = _float_1d(passing, "passing")
        if a.shape != p.shape:
            raise ValueError(
                f"aperture and passing must have the same length, got {a.size} and {p.size}"
            )
        if a.size < 2:
            raise ValueError(f"a sieve curve needs at least 2 points, got {a.size}")
        if np.any(a <= 0.0):
            raise ValueError(
                f"sieve apertures must be > 0 mm, got {a[a <= 0.0].tolist()}; give apertures in mm"
            )
        if np.any(np.diff(a) <= 0.0):
            raise ValueError(
                f"sieve apertures must be strictly increasing (no repeats), got {a.tolist()}; "
                "sort the points by aperture"
            )
        if np.any(p < 0.0) or np.any(p > 100.0):
            raise ValueError(f"percent passing must lie in [0, 100], got {p.tolist()}")
        if np.any(np.diff(p) < 0.0):
            raise ValueError(
                f"percent passing must not decrease with the aperture (a cumulative curve), "
                f"got {p.tolist()} for apertures {a.tolist()}"
            )
        if p[-1] != 100.0:
            raise ValueError(
                f"the sieve curve must reach 100 % passing at its largest aperture, got "
                f"{p[-1]} % at {a[-1]} mm; add the aperture that all grains pass"
            )
        if np.all(p[:-1] == 100.0):
            raise ValueError("the sieve curve is 100 % everywhere: no size class carries grains")
        self.aperture = a
        self.passing = p
        self.name = name
        self.source = source

    def __repr__(self) -> str:
        return f"SieveCurve({self.name!r}, d = {self.aperture[0]}..{self.aperture[-1]} mm)"

    # -- evaluation -------------------------------------------------------------------------------

    def passing_at(self, d: ArrayLike) -> np.ndarray:
        """Percent passing at diameters ``d`` (mm), linear in log d; 0 below, 100 above."""
        d = np.asarray(d, dtype=float)
        out = np.interp(np.log(np.maximum(d, 1e-300)), np.log(self.aperture), self.passing)
        out = np.where(d < self.aperture[0], 0.0, out)
        return out

    def diameter_at(self, percent: float) -> float:
        """Diameter (mm) at which ``percent`` passes (e.g. d50), inverse of :meth:`passing_at`."""
        if not (self.passing[0] <= percent <= 100.0):
            raise ValueError(
                f"percent must lie in [{self.passing[0]}, 100] for this curve, got {percent}"
            )
        # first index where the curve reaches `percent` (plateaus: the smallest such size)
        k = int(np.searchsorted(self.passing, percent, side="left"))
        if k == 0:
            return float(self.aperture[0])
        p0, p1 = self.passing[k - 1], self.passing[k]
        t = (percent - p0) / (p1 - p0)
        return float(self.aperture[k - 1] * (self.aperture[k] / self.aperture[k - 1]) ** t)

    def classes(self, d_min: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Size classes above the cut ``d_min`` (mm).

        Returns:
            ``(lo, hi, share)``: (m,) lower and upper class bounds in mm and (m,) area share of
            each class, summing to 1 (classes with no grains are dropped).
        """
        lo, hi = self.aperture[:-1].copy(), self.aperture[1:].copy()
        dp = np.diff(self.passing)
        if d_min is not None:
            d_min = float(d_min)
            if not (np.isfinite(d_min) and d_min > 0.0):
                raise ValueError(f"d_min must be a positive size in mm, got {d_min}")
            if d_min >= self.aperture[-1]:
                raise ValueError(
                    f"d_min = {d_min} mm cuts off the whole curve (largest aperture "
                    f"{self.aperture[-1]} mm); choose a smaller cut size"
                )
            keep = hi > d_min
            lo, hi, dp = lo[keep], hi[keep], dp[keep]
            if lo[0] < d_min:
                # the class straddling the cut keeps its share above d_min (log-linear P)
                dp[0] = _straddling_share(dp[0], lo[0], hi[0], d_min)
                lo[0] = d_min
        keep = dp > 0.0
        lo, hi, dp = lo[keep], hi[keep], dp[keep]
        if dp.size == 0:
            raise ValueError(f"no grains above d_min = {d_min} mm on this sieve curve")
        return lo, hi, dp / portable.total(dp)

    def number_fractions(
        self, d_min: float | None = None, dim: int = 2
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(lo, hi, nfrac)``: class bounds (mm) and number fraction per class (sums to 1), the
        passing read as area (``dim`` 2, disks) or volume (``dim`` 3, spheres) fraction."""
        k = check_dimension(dim)
        lo, hi, share = self.classes(d_min)
        w = share / np.array([_mean_power(a, b, k) for a, b in zip(lo, hi)])
        return lo, hi, w / portable.total(w)

    def sample_diameters(
        self,
        n: int,
        rng: np.random.Generator | int | None = None,
        d_min: float | None = None,
        dim: int = 2,
    ) -> np.ndarray:
        """Draw ``n`` grain diameters (mm) whose area (``dim`` 2, disks) or volume (``dim`` 3,
        spheres) distribution follows the curve above d_min.

        Stratified sampling of the number distribution: the i-th diameter is the inverse number
        CDF at (i + U_i) / n, U_i uniform, so even 70 grains reproduce the grading closely. The
        diameters are the same floats on every CPU and numpy release (:mod:`.portable`).

        Args:
            n: number of grains, >= 1.
            rng: ``numpy.random.Generator`` or a seed.
            d_min: cut size in mm (fines below it are dropped), None keeps the whole curve.
            dim: 2 (percent passing by area) or 3 (by volume).

        Returns:
            (n,) diameters in mm, ascending.
        """
        n = int(n)
        if n < 1:
            raise ValueError(f"n must be >= 1, got {n}")
        k = check_dimension(dim)
        rng = np.random.default_rng(rng)
        lo, hi, nfrac = self.number_fractions(d_min, k)
        cdf = np.concatenate([[0.0], np.cumsum(nfrac)])
        cdf[-1] = 1.0
        u = (np.arange(n) + rng.random(n)) / n
        c = np.clip(np.searchsorted(cdf, u, side="right") - 1, 0, lo.size - 1)
        t = np.clip((u - cdf[c]) / nfrac[c], 0.0, 1.0)
        # inverse of the class's number CDF (a^-k - d^-k) / (a^-k - b^-k), k = dim
        lo_k = np.array([float(portable.inverse_power(a, k)) for a in lo])
        hi_k = np.array([float(portable.inverse_power(b, k)) for b in hi])
        return portable.inverse_roots(lo_k[c] - t * (lo_k[c] - hi_k[c]), k)

    @staticmethod
    def area_passing(diameters: ArrayLike, d: ArrayLike, dim: int = 2) -> np.ndarray:
        """Percent of the total grain area (``dim`` 2, disks) or volume (``dim`` 3, spheres) in
        grains smaller than ``d`` — the sieve curve of a sample of ``diameters``. Both in mm;
        returns an array shaped like ``d``."""
        diam = np.sort(np.asarray(diameters, dtype=float))
        area = np.cumsum(diam ** check_dimension(dim))
        idx = np.searchsorted(diam, np.asarray(d, dtype=float), side="right")
        return 100.0 * np.where(idx > 0, area[np.maximum(idx - 1, 0)], 0.0) / area[-1]

    # -- input / output -------------------------------------------------------------------------

    @classmethod
    def from_csv(cls, path: str | PathLike[str], name: str | None = None) -> SieveCurve:
        """Read a curve from a CSV file: ``#`` comment lines (kept as the source), one header
        line, then rows ``aperture_mm, passing_percent``."""
        with open(path, encoding="utf-8") as f:
            text = f.read()
        return cls._parse(text, name or str(path), str(path))

    @classmethod
    def _parse(cls, text, name, where):
        comments, rows = [], []
        for line in io.StringIO(text):
            s = line.strip()
            if not s:
                continue
            if s.startswith("#"):
                comments.append(s.lstrip("# "))
                continue
            rows.append(s)
        if len(rows) < 3:
            raise ValueError(f"{where}: expected a header line and at least 2 data rows")
        data = []
        for lineno, row in enumerate(csv.reader(rows[1:]), start=2):
            try:
                data.append([float(v) for v in row[:2]])
                if len(row) < 2:
                    raise ValueError
            except ValueError:
                raise ValueError(
                    f"{where}: data row {lineno} {row!r} is not 'aperture_mm, passing_percent'"
                ) from None
        arr = np.array(data)
        return cls(arr[:, 0], arr[:, 1], name=name, source=" ".join(comments))


def _straddling_share(dp, lo, hi, d_min):
    """The share dp of the class [lo, hi] that lies above d_min: dp ln(hi / d_min) / ln(hi / lo)
    (P linear in log d), in decimal (the same float everywhere)."""
    ctx = portable.context()
    above = ctx.subtract(portable.ln(hi), portable.ln(d_min))
    whole = ctx.subtract(portable.ln(hi), portable.ln(lo))
    return float(ctx.divide(ctx.multiply(decimal.Decimal(float(dp)), above), whole))


def _mean_power(lo, hi, k):
    """<d^k> of the class [lo, hi] with the number density ~ d^-(k+1) of a log-uniform area
    (k = 2) or volume (k = 3): k ln(hi / lo) / (lo^-k - hi^-k), in decimal."""
    ctx = portable.context()
    log_ratio = ctx.subtract(portable.ln(hi), portable.ln(lo))
    span = ctx.subtract(portable.inverse_power(lo, k), portable.inverse_power(hi, k))
    return float(ctx.divide(ctx.multiply(log_ratio, k), span))


def cen_standard_sand() -> SieveCurve:
    """The shipped quartz sand: CEN standard sand (EN 196-1), mean grading, 0.08-2 mm."""
    text = (
        resources.files("dolfinx_granular")
        .joinpath("data/cen_standard_sand.csv")
        .read_text(encoding="utf-8")
    )
    return SieveCurve._parse(text, "CEN standard sand (EN 196-1)", "cen_standard_sand.csv")


def as_sieve_curve(gsd: SieveCurve | tuple[ArrayLike, ArrayLike] | None) -> SieveCurve:
    """Accept a :class:`SieveCurve`, None (the CEN sand) or an ``(aperture, passing)`` pair."""
    if gsd is None:
        return cen_standard_sand()
    if isinstance(gsd, SieveCurve):
        return gsd
    try:
        aperture, passing = gsd
    except (TypeError, ValueError):
        raise ValueError(
            "gsd must be a SieveCurve, None (CEN standard sand) or a pair (aperture_mm, "
            f"passing_percent) of arrays; got {type(gsd).__name__}"
        ) from None
    return SieveCurve(aperture, passing, name="user sieve curve")


def _float_1d(value, name):
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be a 1-D array of numbers: {err}") from None
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} has non-finite values: {arr.tolist()}")
    return arr
