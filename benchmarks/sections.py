"""Sections of ``docs/performance.md`` that a benchmark script other than ``report.py`` writes.

Each such script owns one section between its two markers (:func:`markers`) and replaces only
that; ``report.py`` rewrites the rest of the file and carries every marked section over."""

from __future__ import annotations

import os
import re
import shlex
import sys

_BLOCK = re.compile(r"<!-- begin: (\S+) -->.*?<!-- end: \1 -->", re.S)


def markers(script: str) -> tuple[str, str]:
    """The begin and end markers of the section written by ``benchmarks/<script>``."""
    return f"<!-- begin: benchmarks/{script} -->", f"<!-- end: benchmarks/{script} -->"


def command_line(script: str, argv=None) -> str:
    """``python benchmarks/<script> ARGS``, the command that generated a section or report: ARGS
    are ``argv`` (shell-quoted), or this process's arguments where ``argv`` is None (a script run
    from the shell; ``main([])`` called from Python, e.g. by a test, has no arguments)."""
    args = sys.argv[1:] if argv is None else argv
    return f"python benchmarks/{script}" + "".join(" " + shlex.quote(str(a)) for a in args)


def marked_sections(text: str) -> list[str]:
    """Every marked section in ``text``, markers included, in order."""
    return [m.group(0) for m in _BLOCK.finditer(text)]


def write_section(md_path: str, section: str) -> None:
    """Put ``section`` (which starts and ends with its markers) into ``md_path``: in place of the
    section with the same markers, else appended."""
    begin, end = section.strip().splitlines()[0], section.strip().splitlines()[-1]
    text = open(md_path).read() if os.path.exists(md_path) else ""
    if begin in text and end in text.split(begin, 1)[1]:
        head, rest = text.split(begin, 1)
        text = head + section.strip("\n") + rest.split(end, 1)[1]
    else:
        text = text.rstrip("\n") + "\n\n\n" + section.strip("\n") + "\n"
    with open(md_path, "w") as f:
        f.write(text)


def write_keeping_sections(md_path: str, text: str) -> None:
    """Write ``text`` to ``md_path``, carrying over at its end the marked sections of the file
    there before (sorted by their heading, so that section numbers stay in order)."""
    kept = []
    if os.path.isfile(md_path):
        with open(md_path) as f:
            kept = marked_sections(f.read())
    kept.sort(key=lambda block: block.splitlines()[1] if len(block.splitlines()) > 1 else "")
    if kept:
        text = text.rstrip("\n") + "\n\n\n" + "\n\n\n".join(kept) + "\n"
    with open(md_path, "w") as f:
        f.write(text)
