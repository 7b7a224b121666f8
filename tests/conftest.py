import os
import sys

import numpy as np
import pytest

import dolfinx_granular  # noqa: F401  (first: loads the MPI of DOLFINx's PyPI wheel)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
