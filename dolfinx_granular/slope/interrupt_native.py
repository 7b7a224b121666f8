"""What a SIGINT or SIGTERM must do at the instant it arrives, whatever the process is doing.

Python runs a signal handler only between bytecodes of its main thread: a rank inside a Numba
kernel, a sparse factorisation or an MPI collective that waits for another rank does not see it
for seconds, and Open MPI's ``mpirun`` kills the ranks one second after its SIGTERM. So the
handler here is C code (a Numba ``cfunc`` installed with libc's ``signal``), built once per
process over buffers that Python fills beforehand. At the first signal it

1. writes a prepared line to stdout (the resume hint, on the console before any kill);
2. writes a prepared file (``summary.json`` marked interrupted) and renames it into place;
3. hands the signal on to Python's own handler (``PyErr_SetInterruptEx``), which then stops the
   run at its next safe point as before (:mod:`.interrupt`).

A second signal ends the process at once with exit status 128 + its number. Everything it calls
(``write``, ``creat``, ``close``, ``rename``, ``_exit``, ``PyErr_SetInterruptEx``) is
async-signal-safe. Python disarms a buffer while it refills it (its length 0), so a signal in
between writes nothing half-made.
"""

from __future__ import annotations

import ctypes
import os
import signal

import numpy as np
from numba import carray, cfunc, types
from numba.extending import intrinsic

#: the signals handled, in the order of the buffers' slots
SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: capacities (bytes) of a console line, a file path and a file's content
LINE_BYTES, PATH_BYTES, FILE_BYTES = 4096, 4096, 8 << 20

_libc = ctypes.CDLL(None)
_ssize, _int, _ptr, _size = ctypes.c_ssize_t, ctypes.c_int, ctypes.c_void_p, ctypes.c_size_t
_write = ctypes.CFUNCTYPE(_ssize, _int, _ptr, _size)(("write", _libc))
_creat = ctypes.CFUNCTYPE(_int, _ptr, ctypes.c_uint)(("creat", _libc))
_close = ctypes.CFUNCTYPE(_int, _int)(("close", _libc))
_rename = ctypes.CFUNCTYPE(_int, _ptr, _ptr)(("rename", _libc))
_exit = ctypes.CFUNCTYPE(None, _int)(("_exit", _libc))
_set_interrupt = ctypes.CFUNCTYPE(_int, _int)(
    ctypes.cast(ctypes.pythonapi.PyErr_SetInterruptEx, _ptr).value
)
_signal = _libc.signal
_signal.restype, _signal.argtypes = _ptr, [_int, _ptr]


@intrinsic
def _int64_pointer(typingctx, address):
    """The int64 array at ``address`` (an integer known when the handler is built)."""

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(types.CPointer(types.int64)))

    return types.CPointer(types.int64)(types.intp), codegen


@intrinsic
def _void_pointer(typingctx, address):
    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(types.voidptr))

    return types.voidptr(types.intp), codegen


# slots of the int64 header: [signals seen, line length x2, file length x2]
_COUNT, _LINE, _FILE = 0, 1, 3


def _build(header, lines, paths, files):
    """The C handler over the buffers' addresses (they live as long as the process)."""
    h, ln, pa, fi = (a.ctypes.data for a in (header, lines, paths, files))
    sigint, tmp, final = int(signal.SIGINT), PATH_BYTES, 0

    @cfunc(types.void(types.int32))
    def handler(signum):
        m = carray(_int64_pointer(h), 5)
        m[_COUNT] += 1
        if m[_COUNT] > 1:
            _exit(128 + signum)
        k = 0 if signum == sigint else 1
        if m[_LINE + k] > 0:
            _write(1, _void_pointer(ln + k * LINE_BYTES), m[_LINE + k])
        if m[_FILE + k] > 0:
            fd = _creat(_void_pointer(pa + tmp), 0o644)
            if fd >= 0:
                _write(fd, _void_pointer(fi + k * FILE_BYTES), m[_FILE + k])
                _close(fd)
                _rename(_void_pointer(pa + tmp), _void_pointer(pa + final))
        _set_interrupt(signum)

    return handler


class NativeHandler:
    """The C-level SIGINT/SIGTERM handler of this process (see the module docstring).

    :meth:`install` after Python's ``signal.signal`` (whose handler then runs as before, handed
    on); :meth:`say` and :meth:`keep` prepare what a first signal writes.
    """

    _handler = None  # one per process: its buffers are baked into the compiled code

    def __init__(self) -> None:
        cls = type(self)
        if cls._handler is None:
            cls._header = np.zeros(5, np.int64)
            cls._lines = np.zeros(2 * LINE_BYTES, np.uint8)
            cls._paths = np.zeros(2 * PATH_BYTES, np.uint8)  # final path, temporary path
            cls._files = np.zeros(2 * FILE_BYTES, np.uint8)
            cls._handler = _build(cls._header, cls._lines, cls._paths, cls._files)

    def install(self, fresh: bool = True) -> None:
        """Put the C handler on SIGINT and SIGTERM, over what Python installed; ``fresh``: the
        count of signals seen starts again."""
        if fresh:
            self._header[_COUNT] = 0
        for s in SIGNALS:
            _signal(int(s), self._handler.address)

    def say(self, lines: dict[int, str] | None) -> None:
        """The line a first signal writes to stdout, by signal (None: nothing)."""
        for k, s in enumerate(SIGNALS):
            text = (lines or {}).get(s, "")
            self._header[_LINE + k] = 0
            data = (text + "\n").encode()[:LINE_BYTES] if text else b""
            self._lines[k * LINE_BYTES : k * LINE_BYTES + len(data)] = np.frombuffer(data, np.uint8)
            self._header[_LINE + k] = len(data)

    def keep(self, path: str | None, contents: dict[int, str] | None = None) -> None:
        """The file a first signal writes at ``path``, its content by signal (None: none). A
        content over :data:`FILE_BYTES` is not kept (the signal then writes no file)."""
        self._header[_FILE : _FILE + 2] = 0
        if path is None:
            return
        for offset, name in ((0, path), (PATH_BYTES, f"{path}.tmp-signal")):
            data = os.fsencode(os.path.abspath(name)) + b"\0"
            if len(data) > PATH_BYTES:
                return
            self._paths[offset : offset + len(data)] = np.frombuffer(data, np.uint8)
        for k, s in enumerate(SIGNALS):
            data = (contents or {}).get(s, "").encode()
            if len(data) <= FILE_BYTES:
                self._files[k * FILE_BYTES : k * FILE_BYTES + len(data)] = np.frombuffer(
                    data, np.uint8
                )
                self._header[_FILE + k] = len(data)
