"""The relaxed RVE micro solver's tolerances."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Settings:
    """Tolerances of the micro solver.

    Attributes:
        force_tol: equilibrium when every disk's net force is at most this times the mean
            contact force, or :data:`RESOLVED` times the round-off of the contact forces
            where that is larger (overlaps below ~1e-5 of the radii).
        max_iterations: Newton steps before FIRE takes over (and again after it).
        fire_tol, fire_steps: FIRE stops at this largest net force relative to the mean
            contact force, or stops after that many steps.
        final_iterations: Newton steps, without a stall limit, from where FIRE stopped
            when it ran out of steps (the micro solver's last try).
        rattler_shift: least extra diagonal of the rattlers' unknowns, relative to K (a
            rattler without contacts stays where it is).
        chord_rate: a factorisation is reused while the largest force falls at least by this
            factor per step and the contacts stay the same.
    """

    force_tol: float = 1e-10
    max_iterations: int = 60
    fire_tol: float = 1e-5
    fire_steps: int = 100_000
    final_iterations: int = 1000
    rattler_shift: float = 1e-8
    chord_rate: float = 0.2
