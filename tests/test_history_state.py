"""History as a protocol: a law's state is a HistoryState (checked like MaterialLaw), and a
material's committed state moves only through export_state / restore_state, which restarts use
(PointOrder.gather_material / restore_material) on any partition."""

from dolfinx_granular import FrictionState, generate_packing
from dolfinx_granular.laws.friction import FrictionalRVE
from dolfinx_granular.laws.protocol import HistoryState, check_state

import numpy as np
import pytest
from mpi4py import MPI

from helpers import granular_column

K_N = 2.8e7


def frictional_rve():
    return FrictionalRVE(
        generate_packing(70, seed=4), normal_stiffness=K_N, tangential_stiffness=K_N, friction=0.5
    )


def test_a_friction_state_is_a_history_state_and_a_dict_is_not():
    state = frictional_rve().initial_state(3)
    assert isinstance(state, FrictionState) and isinstance(state, HistoryState)
    assert check_state(state) is state
    lacks = "lacks take, concatenate, to_arrays, from_arrays, n_points"
    with pytest.raises(TypeError, match=lacks):
        check_state({"F": np.zeros((1, 2, 2))})


def test_a_history_law_whose_state_is_no_history_state_is_refused():
    class DictStateRVE(FrictionalRVE):
        def initial_state(self, n):
            return {"F": np.tile(np.eye(2), (n, 1, 1))}

    rve = DictStateRVE(
        generate_packing(70, seed=4), normal_stiffness=K_N, tangential_stiffness=K_N, friction=0.5
    )
    with pytest.raises(TypeError, match="dict is not a history state: it lacks take"):
        granular_column(rve, "dict_state_")


@pytest.mark.mpi
def test_export_and_restore_move_the_committed_state():
    solver, material, u, p = granular_column(frictional_rve(), "export_state_", n=3)
    p.value = 2e5
    assert solver.solve().converged
    first = material.export_state()
    assert first is material.state and isinstance(first, HistoryState)
    p.value = 3e5
    assert solver.solve().converged and material.export_state() is not first
    material.restore_state(first)
    assert material.state is first and material.trial_state is first
    with pytest.raises(AttributeError):
        material.state = first  # read-only: restore_state is the way in
    with pytest.raises(ValueError, match="restore_state needs a FrictionState of"):
        material.restore_state(first.take(np.arange(first.n_points - 1)))
    solver.destroy()


@pytest.mark.mpi
def test_point_order_restores_a_material_state_on_another_material():
    """gather_material on rank 0, to_arrays, restore_material into a fresh material of the same
    mesh: the same state at every point, whatever the partition."""
    from dolfinx_granular.io.runwriter import PointOrder

    solver, material, u, p = granular_column(frictional_rve(), "gather_state_", n=3)
    p.value = 2e5
    assert solver.solve().converged
    order = PointOrder(MPI.COMM_WORLD, material.points, 1e-9)
    gathered = order.gather_material(material)
    arrays = MPI.COMM_WORLD.bcast(gathered.to_arrays() if gathered is not None else None, root=0)
    X = MPI.COMM_WORLD.bcast(order.X, root=0)
    _, fresh, *_ = granular_column(frictional_rve(), "gather_state_fresh_", n=3)
    order.restore_material(fresh, arrays, X)
    assert fresh.export_state().equals(material.export_state())
    assert MPI.COMM_WORLD.allreduce(float(np.abs(arrays["force"]).sum())) > 0
    solver.destroy()


def test_a_law_without_history_exports_none():
    from dolfinx_granular import TaylorRVE

    _, material, *_ = granular_column(
        TaylorRVE(generate_packing(70, seed=1), normal_stiffness=K_N), "no_state_", n=2
    )
    assert material.export_state() is None and not material.has_state and not material.history
    material.restore_state(None)
    with pytest.raises(ValueError, match="has no history; pass None"):
        material.restore_state(frictional_rve().initial_state(material.n_points))
