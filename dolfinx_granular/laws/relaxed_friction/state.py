"""The committed state of frictional relaxed points: where the disks are, how far they have
turned, and the tangential force of every contact.

The tangential forces are keyed by their pair and periodic image (one int64 each,
:meth:`~dolfinx_granular.laws.relaxed.cell.Cell.keys_of`), not by a candidate index: the list of
candidates grows with a run, and a restarted run builds it afresh.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

    from numpy.typing import ArrayLike

_KEYS = ("w", "theta", "F", "sensitivity", "dissipation", "fluctuation", "offsets", "keys",
         "force", "sliding", "rolling")  # fmt: skip
#: per-contact arrays, (k,) each
_CONTACT_KEYS = ("keys", "force", "sliding", "rolling")


def _offsets(lengths):
    off = np.zeros(len(lengths) + 1, np.int64)
    np.cumsum(lengths, out=off[1:])
    return off


@dataclass(frozen=True, eq=False)
class FrictionalRelaxedState:
    """Relaxed positions, rotations and contact history of n points (immutable by convention).

    Attributes:
        w: (n, N, 2) fluctuations of the disks in the reference frame (x = F (X + w)).
        theta: (n, N) rotations of the disks (rad, counter-clockwise).
        F: (n, 2, 2) the deformation gradient the state is relaxed at.
        sensitivity: (n, N, 3, 4) d(w, theta)/dF at the state (F flattened row-major; zero
            where no tangent was computed): the next increment's first-order predictor.
        dissipation: (n,) energy dissipated by sliding since F = I (Pa).
        fluctuation: (n,) root mean square of |F w_i| over the disks, over the mean radius.
        offsets: (n + 1,) int64: point q's contacts are ``keys[offsets[q]:offsets[q + 1]]``.
        keys: (k,) int64 pair-and-image keys of the contacts (overlap > 0) of every point.
        force: (k,) their committed tangential forces f_t (N per unit thickness; the force on
            the second disk along t is -f_t, :mod:`.contact_law`).
        sliding: (k,) bool, True where the contact slipped in the increment to this state.
        rolling: (k,) their committed rolling moments m_r (N m per unit thickness; the couple
            on the second disk, :mod:`.rolling`; zero without rolling resistance).
    """

    w: np.ndarray
    theta: np.ndarray
    F: np.ndarray
    sensitivity: np.ndarray
    dissipation: np.ndarray
    fluctuation: np.ndarray
    offsets: np.ndarray
    keys: np.ndarray
    force: np.ndarray
    sliding: np.ndarray
    rolling: np.ndarray

    @property
    def n_points(self) -> int:
        return self.w.shape[0]

    def contacts(self, q: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(keys, forces, sliding, rolling moments)`` of point q's committed contacts."""
        a, b = self.offsets[q], self.offsets[q + 1]
        return self.keys[a:b], self.force[a:b], self.sliding[a:b], self.rolling[a:b]

    def take(self, indices: ArrayLike) -> FrictionalRelaxedState:
        idx = np.asarray(indices, dtype=np.int64)
        start, lengths = self.offsets[idx], np.diff(self.offsets)[idx]
        off = _offsets(lengths)
        gather = np.repeat(start - off[:-1], lengths) + np.arange(off[-1])
        per_point = (getattr(self, k)[idx] for k in _KEYS[:6])
        per_contact = (getattr(self, k)[gather] for k in _CONTACT_KEYS)
        return FrictionalRelaxedState(*per_point, off, *per_contact)

    @classmethod
    def concatenate(cls, states: Iterable[FrictionalRelaxedState]) -> FrictionalRelaxedState:
        states = list(states)
        per_point = (np.concatenate([getattr(s, k) for s in states]) for k in _KEYS[:6])
        off = _offsets(np.concatenate([np.diff(s.offsets) for s in states]))
        per_contact = (np.concatenate([getattr(s, k) for s in states]) for k in _CONTACT_KEYS)
        return cls(*per_point, off, *per_contact)

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {k: np.array(getattr(self, k)) for k in _KEYS}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, ArrayLike]) -> FrictionalRelaxedState:
        """The state of :meth:`to_arrays`, checked (a damaged file raises ValueError; one
        written before rolling resistance existed, without ``rolling``, has none)."""
        missing = [k for k in _KEYS if k not in arrays and k != "rolling"]
        if missing:
            raise ValueError(f"FrictionalRelaxedState arrays lack {', '.join(missing)}")
        a = {k: np.asarray(arrays[k]) for k in _KEYS if k in arrays}
        a.setdefault("rolling", np.zeros(a["force"].shape))
        w = a["w"]
        if w.ndim != 3 or w.shape[2] != 2:
            raise ValueError(f"FrictionalRelaxedState: w must be (n, N, 2), got {w.shape}")
        n, N = w.shape[:2]
        shapes = {"theta": (n, N), "F": (n, 2, 2), "sensitivity": (n, N, 3, 4),
                  "dissipation": (n,), "fluctuation": (n,), "offsets": (n + 1,)}  # fmt: skip
        for k, shape in shapes.items():
            if a[k].shape != shape:
                raise ValueError(f"FrictionalRelaxedState: {k} must be {shape}, got {a[k].shape}")
        off = a["offsets"]
        if off[0] != 0 or np.any(np.diff(off) < 0) or off[-1] != a["keys"].size:
            raise ValueError("FrictionalRelaxedState: offsets do not match the keys")
        if a["keys"].ndim != 1 or len({a[k].shape for k in _CONTACT_KEYS}) != 1:
            raise ValueError(
                "FrictionalRelaxedState: keys, force, sliding and rolling must be (k,) each"
            )
        if not all(np.isfinite(a[k]).all() for k in ("w", "theta", "F", "force", "rolling")):
            raise ValueError("FrictionalRelaxedState has NaN or inf entries")
        return cls(
            *(np.asarray(a[k], dtype=np.float64) for k in _KEYS[:6]),
            off.astype(np.int64),
            a["keys"].astype(np.int64),
            a["force"].astype(np.float64),
            a["sliding"].astype(bool),
            a["rolling"].astype(np.float64),
        )

    def equals(self, other: object) -> bool:
        """Bit-for-bit equality of every array."""
        return isinstance(other, FrictionalRelaxedState) and all(
            getattr(self, k).shape == getattr(other, k).shape
            and getattr(self, k).tobytes() == getattr(other, k).tobytes()
            for k in _KEYS
        )
