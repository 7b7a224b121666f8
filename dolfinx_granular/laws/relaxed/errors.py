"""The relaxed RVE's errors: a point the micro solver could not relax, a cell that lost its
rigidity (both :class:`~dolfinx_granular.LawEvaluationError`, so that load stepping cuts back)."""

from ..protocol import LawEvaluationError


class RelaxationError(LawEvaluationError):
    """The micro solver could not relax a point (no equilibrium reached, or its candidate
    contacts no longer cover the fluctuations)."""


class RigidityLostError(RelaxationError):
    """The relaxed cell has no rigid contact network left: no non-rattler disk, or a stiffness
    of the non-rattlers (one disk pinned) that is not positive definite (tension, a buckled
    network)."""
