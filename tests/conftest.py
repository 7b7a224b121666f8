import dolfinx_granular  # noqa: F401  (first: loads the MPI of DOLFINx's PyPI wheel)

import numpy as np
import pytest

# (tests/ and benchmarks/ are on the import path through pytest's `pythonpath` setting)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
