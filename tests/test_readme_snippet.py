"""The README's "Use it in your own DOLFINx model" snippet runs as printed (serial and MPI)."""

import os
import re

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SECTION = "## Use it in your own DOLFINx model"


def readme_snippet():
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as f:
        text = f.read()
    assert SECTION in text, f"README.md lost its section {SECTION!r}"
    section = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1, "the section should hold exactly one python block"
    return blocks[0]


def test_snippet_is_short():
    assert len(readme_snippet().strip().splitlines()) <= 25


@pytest.mark.mpi
def test_snippet_runs_and_converges(capsys):
    pytest.importorskip("dolfinx")
    namespace = {"__name__": "readme_snippet"}
    exec(compile(readme_snippet(), "README.md", "exec"), namespace)
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines() if line.startswith("p = ")]
    assert len(lines) == 3 and all(line.endswith("converged: True") for line in lines), out
    assert all(r"Newton steps" in line for line in lines)
    assert namespace["result"].converged
    # The column settles under the pressure (u_y < 0 somewhere on every rank that owns a node).
    u = namespace["u"]
    assert u.x.array[1::2].min() < 0.0
