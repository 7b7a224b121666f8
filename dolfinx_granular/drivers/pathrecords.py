"""The records and stop criteria of arc-length path following
(:class:`~dolfinx_granular.ArcLength`; importable from there too).

A stop criterion is ``stop(al) -> str | None`` of the driver after a converged increment: a
reason to stop, or None.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable


@dataclass
class Increment:
    """One converged increment: the load parameter and the path length at its end."""

    step: int
    lam: float
    dlam: float
    ds: float
    iterations: int
    det_sign: int  # sign of det K at the start of the increment (0: unknown)
    increment_norm: float  # |Du| over all dofs (m)
    control: float | None = None  # value of the control dof at the end (m), if any
    residual_norm: float = float("nan")  # |R| at the end (N)
    history: list | None = None  # (iteration, |R| at its start (N), relative energy norm) per step
    converged_by: str = ""  # "energy norm" or "round-off"

    #: how an increment converged (the ``reason_name`` of
    #: :class:`~dolfinx_granular.drivers.protocol.IncrementRecord`): by this driver's corrector
    reason_name = "ARC_LENGTH"

    @property
    def t(self) -> float:
        """The load parameter at the end (lam): the driver protocol's name of it."""
        return self.lam

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class CriticalPoint:
    """A critical point crossed between two converged states: det K changed sign there, or the
    load turned back with det K keeping its sign (``det_change`` False: a non-smooth limit point,
    where the contact set changed rather than the tangent of one contact set went singular)."""

    kind: str  # "limit" (the load turns back) or "bifurcation"
    step: int  # the increment that ended past it
    lam_before: float
    lam_after: float
    det_change: bool = True

    def as_dict(self) -> dict:
        return asdict(self)


def load_reaches(target: float) -> Callable[[Any], str | None]:
    """Stop once lam has reached ``target`` from the side of zero (lam >= target for a positive
    target, lam <= target for a negative one)."""

    def stop(al):
        if (al.lam - target) * np.sign(target) >= 0:
            return f"the load parameter reached {al.lam:.6g} (target {target:g})"

    return stop


def unloaded_to(fraction: float) -> Callable[[Any], str | None]:
    """Stop once the load has fallen to ``fraction`` of its peak after a limit point."""

    def stop(al):
        peak = al.peak
        if peak is not None and peak is not al.path[-1] and abs(al.lam) <= fraction * abs(peak.lam):
            return (
                f"past the peak lam = {peak.lam:.6g} (increment {peak.step}) the load fell to "
                f"{abs(al.lam / peak.lam):.3f} of it"
            )

    return stop


def control_reaches(target: float) -> Callable[[Any], str | None]:
    """Stop once the control dof's displacement has gone past ``target`` (m)."""

    def stop(al):
        value = al.path[-1].control
        if value is not None and (value - target) * np.sign(target) >= 0:
            return f"the control displacement reached {value:.6g} m (target {target:g} m)"

    return stop
