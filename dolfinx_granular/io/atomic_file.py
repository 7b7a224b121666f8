"""A file replaced atomically: a reader, or a run killed while writing, sees the old file or the
new one, never a partial one. Free of MPI, so that serial tools (the element-test and packing
caches) can use it without starting MPI."""

from __future__ import annotations

import os


def atomic_write(path: str | os.PathLike[str], data: bytes | str) -> None:
    """Replace ``path`` by ``data`` (bytes or str) atomically."""
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "wb") as f:
        f.write(data.encode() if isinstance(data, str) else data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
