"""The same numbers on every DOLFINx stack of this checkout, serial and on 2 ranks.

The slope with a 70-particle RVE from one packing file: settlement and largest von Mises stress
agree to 1e-9 relative (Newton stops at round-off; measured ~1e-12 or better) between serial and
MPI runs of this stack and, where the checkout has a second stack installed (``.venv`` beside
``.venv-current``; CI's 0.11 leg runs after the 0.5.2 one has built ``.venv``), across stacks.
(Debian trixie's 0.9 is compared with 0.5.2 by ``shared/tools/trixie-check.sh``.)
"""

import sys

from dolfinx_granular import generate_packing

import pytest

import stacks as stacks_module  # benchmarks/stacks.py (the fixture below is called stacks)

TOLERANCE = 1e-9


@pytest.fixture(scope="module")
def stacks():
    here = stacks_module.probe(sys.executable, "this Python")
    assert here is not None
    return [here] + [s for s in stacks_module.installed_stacks() if not stacks_module.is_running(s)]


@pytest.fixture(scope="module")
def packing_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("stacks") / "p70.npz"
    generate_packing(70, seed=3).save(path)
    return str(path)


def assert_same(rows):
    for r in rows:
        assert r["d_settlement"] <= TOLERANCE and r["d_von_mises"] <= TOLERANCE, r
        assert r["settlement"] < 0.0


def test_serial_and_two_ranks_agree(stacks, packing_file, tmp_path):
    assert_same(stacks_module.same_numbers(stacks[:1], packing_file, str(tmp_path)))


def test_every_installed_stack_agrees(stacks, packing_file, tmp_path):
    if len(stacks) < 2:
        pytest.skip(
            "one DOLFINx stack installed in this checkout (make setup-current adds the "
            "0.11 wheel beside Debian's 0.5.2)"
        )
    rows = stacks_module.same_numbers(stacks, packing_file, str(tmp_path))
    assert len({r["stack"] for r in rows}) == len(stacks)
    assert_same(rows)
