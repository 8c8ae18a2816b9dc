"""CG's starting point (Solver.step): the velocity extrapolated from the last two steps, 2 v_n -
v_n-1, instead of v_n. It changes where CG starts, not what it converges to: in smooth motion it
starts nearer and stops sooner; a non-finite velocity kept from a rejected step is not used."""
import numpy as np

from softhand_sim.commands import bench
from softhand_sim.physics import pcg as pcg_mod
from softhand_sim.physics import solver as solver_module
from softhand_sim.physics.model import build_model


def test_extrapolated_start_first_step_and_non_finite_history():
    v, prev, scratch = np.array([1.0, 2.0, 3.0]), np.full(3, np.nan), np.empty(3)
    solver_module._extrapolate_guess(v, prev, scratch)  # nothing before: v as it is
    np.testing.assert_array_equal(v, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(prev, [1.0, 2.0, 3.0])
    v[:] = [2.0, 2.0, 5.0]
    solver_module._extrapolate_guess(v, prev, scratch)  # 2 v - v_prev
    np.testing.assert_array_equal(v, [3.0, 2.0, 7.0])
    np.testing.assert_array_equal(prev, [2.0, 2.0, 5.0])
    prev[1] = np.inf  # a diverged step's velocity
    v[:] = [1.0, 1.0, 1.0]
    solver_module._extrapolate_guess(v, prev, scratch)
    np.testing.assert_array_equal(v, [1.0, 1.0, 1.0])
    np.testing.assert_array_equal(prev, [1.0, 1.0, 1.0])


def _open_close(extrapolate, monkeypatch, steps=150):
    """The coarse hand's benchmark open-close with a factor 4 slices old at most (the fine hand's
    situation): CG iterations per step and the final state."""
    if not extrapolate:
        def from_v_n(v, v_prev, scratch):
            v_prev[:] = v
        monkeypatch.setattr(solver_module, "_extrapolate_guess", from_v_n)
    scenes = bench.check_case("free", 1)
    asset = bench._asset("coarse")[0]
    model = build_model(asset, {}, objects=scenes["free"].objects(asset))
    solver = solver_module.Solver(model)
    # slices of 1 flop, at most 4 of them: the factor in 4 slices
    solver.factor = pcg_mod.Factor(model.dof_count, model.indptr, model.indices, slice_flops=1.0,
                                   max_slices=4, groups=solver_module.hand_block_groups(model))
    assert solver.factor.slices == 4
    state, control = model.initial_state(), model.control()
    update = scenes["free"](solver, state, control)
    iters = []
    for k in range(steps):
        update(k, k * bench.DT)
        iters.append(solver.step(state, control, bench.DT).cg_iters)
    return np.array(iters), state


def test_extrapolated_start_saves_iterations_and_changes_no_result(monkeypatch):
    """With a stale factor (4 slices) the open-close motion needs fewer CG iterations from the
    extrapolated start (mean over the motion), and ends where the start from v_n ends (within
    the CG tolerance's reach: 1 µm)."""
    iters_x, state_x = _open_close(True, monkeypatch)
    with monkeypatch.context() as patch:
        iters_v, state_v = _open_close(False, patch)
    assert iters_v[20:].mean() > 3.0  # a stale factor: CG has work to do
    assert iters_x[20:].mean() < 0.95 * iters_v[20:].mean(), (iters_x[20:].mean(), iters_v[20:].mean())
    assert np.abs(state_x.node_x - state_v.node_x).max() < 1e-6
