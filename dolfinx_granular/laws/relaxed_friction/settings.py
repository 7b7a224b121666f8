"""The frictional relaxed RVE's micro solver and path: its tolerances and the substep."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Settings:
    """Tolerances of the micro solver and the length of the path's substeps.

    Attributes:
        force_tol: equilibrium when every disk's net force is at most this times the mean
            contact force and its net moment at most this times the mean contact force times
            the mean radius (or a few times the round-off of the contact forces, where that is
            larger: overlaps below ~1e-5 of the radii).
        max_iterations: Newton steps of one solve before the fallback takes over.
        pseudo_steps: steps of the first fallback, pseudo-transient continuation (implicit
            damped steps of the same increment, :mod:`.pseudo_time`), before the second takes
            over.
        fire_tol, fire_steps: the second fallback (explicit damped dynamics of the same
            increment) stops at this net force, or after that many steps, and Newton takes
            over; up to
            :data:`~dolfinx_granular.laws.relaxed_friction.point.FIRE_ROUNDS` such rounds.
        settle_steps: where all of those fail, the cell rearranges (damped dynamics with the
            friction law step by step, :func:`~dolfinx_granular.laws.relaxed_friction.fire.
            settle`) for at most this many steps.
        substep, substep_overlap: the quasi-static path's substeps |U_k+1 - U_k| (the right
            stretch, Frobenius norm) are at most ``substep``, and at most ``substep_overlap``
            times the mean overlap over the mean radius sum (of the committed state or, if
            larger, of its positions carried affinely to the new F): a strain of the overlaps'
            order changes every contact's force by its own size; at least a hundredth of
            ``substep``. With friction the path changes the answer: this is part of the model
            (each substep is one backward-Euler increment of the contact law).
    """

    force_tol: float = 1e-10
    max_iterations: int = 60
    pseudo_steps: int = 2000
    fire_tol: float = 1e-5
    fire_steps: int = 20_000
    settle_steps: int = 1_000_000
    substep: float = 1e-3
    substep_overlap: float = 0.25
