"""What a history law derives from its one evaluation ``_run(F, state, tangent, out)``.

:class:`HistoryLawMethods` gives :class:`~dolfinx_granular.FrictionalRVE`,
:class:`~dolfinx_granular.RelaxedRVE` and :class:`~dolfinx_granular.FrictionalRelaxedRVE` their
``stress``, ``cauchy`` and ``spatial_tangent``: each law writes ``_run``, returning ``(W, P, A,
trial_state)`` (A None without ``tangent``; ``out`` as :func:`~.tools.output_buffers` takes it).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .tools import as_batch, push_forward


class HistoryLawMethods:
    """``stress``, ``cauchy`` and ``spatial_tangent`` from the law's ``_run``."""

    def _run(self, F, state, tangent: bool, out: tuple | None = None) -> tuple:
        raise NotImplementedError

    def stress(self, F: np.ndarray, state: Any, out: tuple | None = None) -> tuple:
        """``(W (n,), P (n, 2, 2), trial_state)`` at F from the committed ``state`` (left
        untouched), without the tangent; ``out`` may be ``(W, P)`` or ``(W, P, None)``."""
        if out is not None:
            out = (out[0], out[1], None)
        W, P, _, new = self._run(F, state, False, out)
        return W, P, new

    def cauchy(self, F: np.ndarray, state: Any) -> np.ndarray:
        """Cauchy stress sigma = P F^T / J (n, 2, 2) at F from ``state``, in Pa."""
        Fb, single = as_batch(F)
        sigma, _ = push_forward(Fb, self._run(Fb, state, False, None)[1], None)
        return sigma[0] if single else sigma

    def spatial_tangent(self, F: np.ndarray, state: Any) -> np.ndarray:
        """Spatial tangent a_abcd = F_bB F_dD A_aBcD / J (n, 2, 2, 2, 2) at F from ``state``,
        in Pa."""
        Fb, single = as_batch(F)
        _, P, A, _ = self._run(Fb, state, True, None)
        _, a = push_forward(Fb, P, A)
        return a[0] if single else a
