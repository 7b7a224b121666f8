"""The methods every history law derives from its one evaluation (laws/history_methods.py):
``stress`` against ``evaluate``, with and without the caller's arrays; the Cauchy stress and the
spatial tangent against the push-forward of P and A computed here; one point as (2, 2)."""

from dolfinx_granular import (
    FrictionalRelaxedRVE,
    FrictionalRVE,
    RelaxedRVE,
    generate_packing,
)

import numpy as np
import pytest

K_N = 1e8
#: a compression, then a shear under it, at two points
F_ONE = np.array([[0.99, 0.0], [0.0, 0.99]])
F_TWO = np.stack([[[0.99, 0.004], [0.001, 0.992]], [[0.992, -0.002], [0.003, 0.989]]])


@pytest.fixture(scope="module")
def packing():
    return generate_packing(70, seed=1)


LAWS = {
    "frictional_taylor": lambda p: FrictionalRVE(p, K_N, K_N, friction=0.3),
    "relaxed": lambda p: RelaxedRVE(p, K_N),
    "frictional_relaxed": lambda p: FrictionalRelaxedRVE(p, K_N, K_N, friction=0.3),
}


@pytest.fixture(scope="module", params=sorted(LAWS))
def law_and_state(packing, request):
    """A law and its state committed at F_ONE, at both points of F_TWO."""
    law = LAWS[request.param](packing)
    committed = law.evaluate(F_ONE, law.initial_state(1))[3]
    return law, committed.take([0, 0])


def rel(a, b):
    return np.abs(a - b).max() / np.abs(b).max()


def test_stress_is_evaluate_without_the_tangent(law_and_state):
    law, state = law_and_state
    W, P, _, _ = law.evaluate(F_TWO, state)
    W2, P2, new = law.stress(F_TWO, state)
    # the same equilibrium; the relaxed RVE's path without the tangent sums in another order
    assert rel(W2, W) <= 1e-13 and rel(P2, P) <= 1e-13 and new.n_points == 2
    for out in ((np.empty(2), np.empty((2, 2, 2))), (np.empty(2), np.empty((2, 2, 2)), None)):
        W3, P3, _ = law.stress(F_TWO, state, out=out)
        assert W3 is out[0] and P3 is out[1]
        assert np.array_equal(P3, P2) and np.array_equal(W3, W2)


def test_cauchy_and_spatial_tangent_push_forward(law_and_state):
    law, state = law_and_state
    _, P, A, _ = law.evaluate(F_TWO, state)
    J = np.linalg.det(F_TWO)
    sigma = np.einsum("qaB,qbB->qab", P, F_TWO) / J[:, None, None]
    a = np.einsum("qbB,qdD,qaBcD->qabcd", F_TWO, F_TWO, A) / J[:, None, None, None, None]
    assert rel(law.cauchy(F_TWO, state), sigma) <= 1e-14
    assert rel(law.spatial_tangent(F_TWO, state), a) <= 1e-14
    one = state.take([1])
    assert rel(law.cauchy(F_TWO[1], one), sigma[1]) <= 1e-14
    assert law.spatial_tangent(F_TWO[1], one).shape == (2, 2, 2, 2)
