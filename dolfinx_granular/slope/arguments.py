"""What the slope's command-line arguments make: the run's :class:`~.options.SlopeOptions`
(:func:`options_of`), its packing (:func:`make_packing`), and :class:`UserError`, the bad input
that the command line reports as one line (:mod:`.cli`, :mod:`.safety_cli`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..packings.packing import Packing
from .geometry import SlopeGeometry
from .options import SlopeOptions

if TYPE_CHECKING:
    import argparse
    from os import PathLike


class UserError(ValueError):
    """Bad input (options, files): reported as one line ``error: ...`` with exit status 2."""


def options_of(a: argparse.Namespace) -> SlopeOptions:
    """The run's options from parsed command-line arguments (--tangential-stiffness with
    --friction 0 is the frictionless model: k_t has no effect there)."""
    geometry = _geometry(a.slope_ratio, a.rows).refined(a.refine)
    try:
        return SlopeOptions(
            steps=a.steps,
            gravity_steps=a.gravity_steps,
            load_factor=a.load_factor,
            stabilise=a.stabilise,
            petsc_options={"snes_linesearch_type": a.line_search},
            friction=a.friction,
            tangential_stiffness=a.tangential_stiffness,
            unload=a.unload,
            path_following=a.path_following,
            max_increments=a.max_increments,
            geometry=geometry,
            allow_overlaps=a.allow_overlaps,
            rve=a.rve,
            linear_solver=a.linear_solver,
            confinement=a.confinement,
            rolling_friction=a.rolling_friction,
            residual_tolerance=a.residual_tolerance,
        )
    except ValueError as err:
        raise UserError(str(err)) from None


def _geometry(ratio: float, rows: int = SlopeGeometry.rows) -> SlopeGeometry:
    """The slope of ``--slope-ratio`` on the coarse columns and ``rows`` rows (``--refine``
    keeps its slope)."""
    try:
        return SlopeGeometry.with_slope_ratio(ratio, rows=rows)
    except ValueError as err:
        raise UserError(f"--slope-ratio {ratio:g}: {err}") from None


def make_packing(
    particles: int,
    seed: int | None,
    packing_file: str | PathLike[str] | None = None,
    pressure: float | None = None,
) -> Packing:
    """The RVE's packing: from ``packing_file`` if given; the shipped reference packing for the
    default 700 particles of seed 0 (the same on every stack, where generation differs in the
    last bits); else ``generate_packing``, jammed at ``pressure`` (p / k_n) if given."""
    if packing_file:
        return Packing.load(packing_file)
    from ..packings import reference_packing as shipped

    if (particles, seed) == (shipped.PARTICLES, shipped.SEED) and pressure is None:
        return shipped.reference_packing()
    from ..packings.generation import generate_packing

    if pressure is None:
        return generate_packing(particles, seed=seed)
    return generate_packing(particles, seed=seed, pressure=pressure)
