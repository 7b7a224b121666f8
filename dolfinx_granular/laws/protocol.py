"""What a material-point law provides: the protocols that quadrature materials accept.

Every law maps deformation gradients F (n, d, d) to the energy density W (n,), the first Piola
stress P (n, d, d) and its tangent A = dP/dF (n, d, d, d, d), all in Pa; d is the law's dimension
(2 for the disk packings' RVEs; :func:`law_dimension` reads it), and a quadrature material accepts
a law only on a mesh of the same dimension. (The shapes below are written for d = 2.)

* :class:`MaterialLaw`: no history (hyperelastic): :class:`~dolfinx_granular.TaylorRVE`,
  :class:`~dolfinx_granular.SmallStrainRVE`, :class:`~dolfinx_granular.AdaptiveRVE`.
* :class:`HistoryLaw`: the answer also depends on a committed state (e.g. the tangential contact
  forces of :class:`~dolfinx_granular.FrictionalRVE`). ``evaluate`` returns the trial
  state at F beside W, P and A and never changes its input; the caller commits the trial state
  once a load step has converged and otherwise keeps evaluating from the committed one.
* :class:`HistoryState`: what such a state provides (e.g.
  :class:`~dolfinx_granular.FrictionState`): point selection and concatenation, which
  restart files and partition-independent gathering rely on, and a flat dict of arrays.

Three things are called "history" elsewhere and are kept apart by name: the Newton iterates of a
solve (the solver's record), the law's state (this module: ``HistoryState``, held by a material and
moved only through ``export_state`` / ``restore_state``) and the displacement record of a run
(``u_history``).

The checks are structural (``isinstance(law, MaterialLaw)``): any class with these methods is a
law, without subclassing.

A law that cannot answer at some points (F outside its range, a micro-solver that fails) raises a
:class:`LawEvaluationError`: the solvers turn exactly this exception into a failed solve, which a
load stepper cuts back. Any other exception is a bug and propagates with its traceback.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

    from numpy.typing import ArrayLike


class LawEvaluationError(ValueError):
    """A law could not be evaluated at some points; the solvers cut back on it (and on nothing
    else). Subclasses name the reason, e.g.
    :class:`~dolfinx_granular.UnsupportedDeformationError`.

    Attributes:
        points: (k,) int indices of the points that failed (into the evaluated batch).
    """

    def __init__(self, message: str, points: np.ndarray | None = None) -> None:
        super().__init__(message)
        self.points = np.zeros(0, dtype=np.int64) if points is None else np.asarray(points)


@runtime_checkable
class MaterialLaw(Protocol):
    """A hyperelastic material point: W, P, A of F alone."""

    def evaluate(self, F: np.ndarray, out: tuple | None = None) -> tuple:
        """``(W (n,), P (n, 2, 2), A (n, 2, 2, 2, 2))``; writes into ``out`` if given."""

    def stress(self, F: np.ndarray, out: tuple | None = None) -> tuple:
        """``(W, P)`` without the tangent; ``out`` may be ``(W, P, None)``."""

    def cauchy(self, F: np.ndarray) -> np.ndarray:
        """Cauchy stress (n, 2, 2)."""

    def spatial_tangent(self, F: np.ndarray) -> np.ndarray:
        """Spatial tangent (n, 2, 2, 2, 2), ``a_abcd = F_bB F_dD A_aBcD / J``."""

    def small_strain_modulus(self) -> np.ndarray:
        """Linear modulus C (2, 2, 2, 2) at F = I."""


@runtime_checkable
class HistoryState(Protocol):
    """The committed state of n material points of a :class:`HistoryLaw` (immutable by
    convention: a law returns a new trial state and never changes its input)."""

    @property
    def n_points(self) -> int:
        """Number of points n."""

    def take(self, indices: ArrayLike) -> HistoryState:
        """The points ``indices`` ((k,) int, any order, repeats allowed) as a new state."""

    @classmethod
    def concatenate(cls, states: Iterable[HistoryState]) -> HistoryState:
        """The points of ``states`` one after the other."""

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Plain arrays (for ``np.savez`` and MPI), inverse of :meth:`from_arrays`."""

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, ArrayLike]) -> HistoryState:
        """The state stored by :meth:`to_arrays` (checked: a damaged file raises ValueError)."""


_STATE_METHODS = ("take", "concatenate", "to_arrays", "from_arrays", "n_points")


def check_state(state: object) -> HistoryState:
    """``state`` if it is a :class:`HistoryState`; TypeError naming what it lacks otherwise."""
    if isinstance(state, HistoryState):
        return state
    missing = [m for m in _STATE_METHODS if not hasattr(state, m)]
    raise TypeError(
        f"{type(state).__name__} is not a history state: it lacks {', '.join(missing)} (a "
        "HistoryLaw's initial_state must return a dolfinx_granular.HistoryState, e.g. a "
        "FrictionState)"
    )


@runtime_checkable
class HistoryLaw(Protocol):
    """A material point whose answer depends on a committed state as well as on F."""

    def initial_state(self, n: int) -> Any:
        """The committed state of n points at F = I (a :class:`HistoryState`)."""

    def evaluate(self, F: np.ndarray, state: Any, out: tuple | None = None) -> tuple:
        """``(W, P, A, trial_state)`` at F from the committed ``state`` (left untouched)."""

    def stress(self, F: np.ndarray, state: Any, out: tuple | None = None) -> tuple:
        """``(W, P, trial_state)`` without the tangent."""

    def cauchy(self, F: np.ndarray, state: Any) -> np.ndarray:
        """Cauchy stress (n, 2, 2) at F from ``state``."""

    def spatial_tangent(self, F: np.ndarray, state: Any) -> np.ndarray:
        """Spatial tangent (n, 2, 2, 2, 2) at F from ``state``."""

    def small_strain_modulus(self) -> np.ndarray:
        """Linear modulus C (2, 2, 2, 2) at F = I from the initial state."""


def has_history(law: object) -> bool:
    """True for a :class:`HistoryLaw`; raises TypeError for an object that is no law at all."""
    if isinstance(law, HistoryLaw):
        return True
    if isinstance(law, MaterialLaw):
        return False
    missing = [
        m
        for m in ("evaluate", "stress", "cauchy", "spatial_tangent", "small_strain_modulus")
        if not callable(getattr(law, m, None))
    ]
    raise TypeError(
        f"{type(law).__name__} is not a material law: it lacks {', '.join(missing)} (see "
        "dolfinx_granular.MaterialLaw; TaylorRVE, SmallStrainRVE, AdaptiveRVE and "
        "FrictionalRVE are laws)"
    )


def law_dimension(law: MaterialLaw | HistoryLaw) -> int:
    """The dimension d of the F (n, d, d) a law takes: its ``dim`` attribute if it has one, else
    the order of its small-strain modulus C (d, d, d, d)."""
    d = getattr(law, "dim", None)
    if d is None:
        C = np.shape(law.small_strain_modulus())
        if len(C) != 4 or len(set(C)) != 1:
            raise ValueError(
                f"{type(law).__name__}.small_strain_modulus() must have shape (d, d, d, d), got "
                f"{C}; fix the law (or give it an int attribute dim)"
            )
        d = C[0]
    return int(d)
